"""Structured light: a projector casts known patterns so that correspondence no longer depends on texture.

Two uses, one projector model (a projector is an inverse camera — a :class:`data_gen.Camera` used the other
way round: the light reaching a surface point is the pattern sampled where the point projects into the
projector, times visibility from the projector — a shadow ray — times the Lambertian term;
:func:`projector_light`, rendered through data_gen by :func:`~stereonet.active.render.render_captures`):

* **Active stereo** — a random dot pattern (like an infrared depth sensor) gives textureless or repetitive
  surfaces a unique texture; any passive matcher then runs on the two camera images unchanged
  (:func:`render_active_pair`).
* **Camera + projector** — coded patterns tell each camera pixel which projector column lights it, and the
  projector plays the second camera: the pixel ray is intersected with that column's light plane
  (:func:`decode_gray_code`, :func:`decode_phase_shift`, :func:`unwrap_phase`, :func:`projector_depth`).
  Gray code gives a robust coarse column (one bit per pattern, each with its inverse for a per-pixel
  threshold); N-step phase shift gives the sub-pixel position inside a period; the Gray code chooses the period.

Undecodable pixels — projector shadow, too dark, too little contrast between a pattern and its inverse,
saturated anywhere in the sequence, Gray code and phase disagreeing, or a code beyond the projector — come
back invalid, never with a depth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F

from data_gen import Camera, Scene, visible_from
from data_gen.render import LightsFn
from stereonet.active.render import Capture, View, render_captures
from stereonet.active.triangulate import projector_column_planes, ray_plane_depth, reject_depth_edges
from stereonet.checks import StereoInputError, check_shape, check_tensor

# ----------------------------------------------------------------------------------------------- patterns


def random_dot_pattern(height: int, width: int, density: float = 0.08, dot_sigma: float = 0.8,
                       seed: int = 0) -> torch.Tensor:
    """Random dots like an infrared depth sensor's: :math:`(H, W)` float32 in [0, 1].

    ``density`` = fraction of projector pixels that are dot centres; each dot is a Gaussian of ``dot_sigma``
    projector pixels. The pattern is a pure function of ``seed``.
    """
    if not 0 < density <= 1:
        raise StereoInputError(f"density: expected 0 < density <= 1, got {density}")
    if dot_sigma <= 0:
        raise StereoInputError(f"dot_sigma: expected > 0, got {dot_sigma}")
    g = torch.Generator().manual_seed(int(seed))
    centres = (torch.rand(1, 1, height, width, generator=g) < density).float()
    r = max(1, int(math.ceil(3 * dot_sigma)))
    x = torch.arange(-r, r + 1, dtype=torch.float32)
    k1 = torch.exp(-0.5 * (x / dot_sigma) ** 2)
    blurred = F.conv2d(F.conv2d(centres, k1.view(1, 1, 1, -1), padding=(0, r)), k1.view(1, 1, -1, 1), padding=(r, 0))
    return blurred[0, 0].clamp(0, 1)


def gray_code(n: torch.Tensor) -> torch.Tensor:
    """Binary-reflected Gray code of non-negative integers: ``n ^ (n >> 1)``."""
    return n ^ (n >> 1)


def gray_to_binary(g: torch.Tensor, bits: int) -> torch.Tensor:
    """Inverse of :func:`gray_code` for ``bits``-bit codes (prefix XOR)."""
    n = g.clone()
    shift = 1
    while shift < bits:
        n = n ^ (n >> shift)
        shift *= 2
    return n


def gray_code_bits(width: int, unit: int = 1) -> int:
    """Number of Gray-code bits that give every ``unit``-pixel-wide stripe of a ``width``-column projector a code."""
    return max(1, int(math.ceil(math.log2(math.ceil(width / unit)))))


def gray_code_patterns(height: int, width: int, unit: int = 1) -> torch.Tensor:
    """Column Gray-code patterns, most significant bit first, each followed by its inverse.

    Projector column ``c`` belongs to stripe unit ``c // unit``; pattern ``2k`` shows bit ``k`` of that unit's
    Gray code, pattern ``2k + 1`` its complement. Returns :math:`(2 B, H, W)` float32 in {0, 1},
    ``B = gray_code_bits(width, unit)``.
    """
    bits = gray_code_bits(width, unit)
    code = gray_code(torch.arange(width) // unit)  # W
    shifts = torch.arange(bits - 1, -1, -1)
    b = ((code[None] >> shifts[:, None]) & 1).float()  # BxW
    pats = torch.stack([b, 1 - b], dim=1).reshape(2 * bits, 1, width)  # (2B)x1xW
    return pats.expand(2 * bits, height, width).contiguous()


def phase_shift_patterns(height: int, width: int, period: float, steps: int = 4) -> torch.Tensor:
    """N-step phase-shift patterns ``0.5 + 0.5 cos(phi(c) - 2 pi n / N)`` with ``phi(c) = 2 pi (c + 0.5) / period``.

    ``phi`` is 0 at the left edge of column 0 so that each period starts on a Gray-code stripe boundary when
    ``period = 2 * unit``. Returns :math:`(N, H, W)` float32 in [0, 1].
    """
    if steps < 3:
        raise StereoInputError(f"steps: expected >= 3 phase steps, got {steps}")
    if period < 2:
        raise StereoInputError(f"period: expected >= 2 projector pixels, got {period}")
    phi = 2 * math.pi * (torch.arange(width, dtype=torch.float64) + 0.5) / period
    shifts = 2 * math.pi * torch.arange(steps, dtype=torch.float64) / steps
    p = 0.5 + 0.5 * torch.cos(phi[None] - shifts[:, None])  # NxW
    return p[:, None].expand(steps, height, width).float().contiguous()


# ----------------------------------------------------------------------------------------------- decoding


def _check_stack(x: object, name: str) -> torch.Tensor:
    x = check_tensor(x, name)
    check_shape(x, ["B", "K", "H", "W"], name)
    if not x.is_floating_point():
        raise TypeError(f"{name}: expected a float image stack in [0, 1], got dtype {x.dtype}")
    return x


def decode_gray_code(captures: torch.Tensor, bits: int | None = None, min_contrast: float = 0.05,
                     saturation: float = 0.99, min_relative_contrast: float = 0.0) -> tuple[torch.Tensor, torch.Tensor]:
    """Decode camera captures of :func:`gray_code_patterns` (pattern, inverse, pattern, inverse, ...).

    Args:
        captures: :math:`(B, 2 n, H, W)` grey images in [0, 1], in pattern order.
        bits: number of bits ``n`` (default: half the stack).
        min_contrast: a bit is readable only where ``|I - I_inverse| >= min_contrast``; dark pixels and
            projector shadows fail this for every bit.
        saturation: a pixel reaching this level in any capture is clipped and cannot be trusted.
        min_relative_contrast: every bit's contrast must reach this fraction of the pixel's best bit contrast.
            A pixel that mixes two surfaces (or straddles a stripe edge) sees full contrast where its parts
            agree and less where they disagree, so this rejects mixed pixels (0 = off).

    Returns:
        stripe unit index :math:`(B, 1, H, W)` int64 (0 where invalid) and valid :math:`(B, 1, H, W)` bool.
    """
    captures = _check_stack(captures, "captures")
    n = captures.shape[1] // 2 if bits is None else int(bits)
    if captures.shape[1] != 2 * n or n < 1:
        raise StereoInputError(f"captures: expected 2 * bits = {2 * n} images (pattern + inverse per bit), "
                               f"got shape {tuple(captures.shape)}")
    pos, neg = captures[:, 0::2], captures[:, 1::2]  # BxnxHxW each
    bit = (pos > neg).long()
    weights = (2 ** torch.arange(n - 1, -1, -1, device=captures.device)).view(1, n, 1, 1)
    code = (bit * weights).sum(1, keepdim=True)
    unit = gray_to_binary(code, n)
    contrast = (pos - neg).abs()
    readable = (contrast >= min_contrast).all(1, keepdim=True)
    readable &= contrast.amin(1, keepdim=True) >= min_relative_contrast * contrast.amax(1, keepdim=True)
    unsaturated = (captures < saturation).all(1, keepdim=True)
    valid = readable & unsaturated
    return torch.where(valid, unit, torch.zeros_like(unit)), valid


def decode_phase_shift(captures: torch.Tensor, min_modulation: float = 0.03,
                       saturation: float = 0.99) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Wrapped phase of N-step phase-shift captures ``I_n = A + M cos(phi - 2 pi n / N)``.

    ``phi = atan2(sum I_n sin(2 pi n / N), sum I_n cos(2 pi n / N))`` and ``M = 2/N |sum I_n e^{i 2 pi n/N}|``.

    Args:
        captures: :math:`(B, N, H, W)`, N >= 3.
        min_modulation: pixels with ``M`` below this (dark, shadowed, or washed out) are invalid.
        saturation: clipped pixels are invalid (a clipped sinusoid has a biased phase).

    Returns:
        phase :math:`(B, 1, H, W)` in [0, 2 pi), modulation :math:`(B, 1, H, W)`, valid :math:`(B, 1, H, W)` bool.
    """
    captures = _check_stack(captures, "captures")
    steps = captures.shape[1]
    if steps < 3:
        raise StereoInputError(f"captures: expected >= 3 phase steps, got shape {tuple(captures.shape)}")
    ang = 2 * math.pi * torch.arange(steps, dtype=captures.dtype, device=captures.device) / steps
    s = (captures * torch.sin(ang).view(1, -1, 1, 1)).sum(1, keepdim=True)
    c = (captures * torch.cos(ang).view(1, -1, 1, 1)).sum(1, keepdim=True)
    phase = torch.remainder(torch.atan2(s, c), 2 * math.pi)
    modulation = 2.0 / steps * torch.sqrt(s * s + c * c)
    valid = (modulation >= min_modulation) & (captures < saturation).all(1, keepdim=True)
    return phase, modulation, valid


def unwrap_phase(phase: torch.Tensor, phase_valid: torch.Tensor, unit_index: torch.Tensor,
                 unit_valid: torch.Tensor, period: float, tolerance: float = 0.125
                 ) -> tuple[torch.Tensor, torch.Tensor]:
    """Absolute sub-pixel projector column from wrapped phase + Gray-code stripe units of width ``period / 2``.

    The Gray code puts the column within a quarter period of its unit centre ``x_g``; the phase fixes it inside
    a period up to whole periods: ``x = phase * period / 2 pi - 0.5 + m * period`` with ``m`` the integer that
    brings ``x`` nearest ``x_g``. If even that ``x`` is more than ``(1/4 + tolerance) * period`` from ``x_g`` the
    two codes disagree and the pixel is invalid.

    Returns column :math:`(B, 1, H, W)` float (0 where invalid) and valid.
    """
    half = period / 2.0
    x_g = unit_index.to(phase.dtype) * half + (half - 1) / 2.0
    x_phase = phase * period / (2 * math.pi) - 0.5
    m = torch.round((x_g - x_phase) / period)
    x = x_phase + m * period
    agree = (x - x_g).abs() <= (0.25 + tolerance) * period
    valid = phase_valid & unit_valid & agree
    return torch.where(valid, x, torch.zeros_like(x)), valid


# ----------------------------------------------------------------------------------------------- rendering


def projector_light(scene: Scene, projector: Camera, patterns: torch.Tensor, power: float = 0.8) -> LightsFn:
    """The projector as a data_gen emitter with one state per pattern of ``patterns`` :math:`(P, H_p, W_p)`.

    Irradiance :math:`(N, P)` at surface points ``X``: ``power * pattern(projector.project(X)) * max(0, n . l)
    * visible``, sampled bilinearly (pixel centres at integers), zero outside the projector's image; ``visible``
    is :func:`data_gen.visible_from` from the projector (its frustum and the shadows of the scene).
    """
    check_shape(patterns, ["P", "Hp", "Wp"], "patterns")
    w, h = projector.size
    if tuple(patterns.shape[1:]) != (h, w):
        raise StereoInputError(f"patterns: expected (P, {h}, {w}) for this projector, got {tuple(patterns.shape)}")
    pats = patterns[None].float()  # 1xPxHpxWp
    centre = torch.as_tensor(projector.center)

    def lights(points: torch.Tensor, normals: torch.Tensor, ids: torch.Tensor) -> torch.Tensor:
        pix, z = projector.project(points)
        # normalised projector coordinates for grid_sample (align_corners=True: pixel centres at -1 ... 1)
        grid = torch.stack([2 * pix[:, 0] / max(w - 1, 1) - 1, 2 * pix[:, 1] / max(h - 1, 1) - 1], -1)
        val = F.grid_sample(pats, grid.view(1, 1, -1, 2).float(), mode="bilinear", padding_mode="zeros",
                            align_corners=True)[0, :, 0].T.to(points.dtype)  # NxP
        to_p = centre.to(points.dtype) - points
        lam = ((normals * to_p).sum(-1) / to_p.norm(dim=-1).clamp_min(1e-12)).clamp_min(0)
        vis = visible_from(scene, projector, points, projected=(pix, z))
        return power * val * (lam * vis * (ids >= 0))[:, None]

    return lights


def capture_patterns(scene: Scene, camera: Camera, projector: Camera, patterns: torch.Tensor,
                     power: float = 0.8, ambient: float | None = 0.2, light: float | None = 0.25,
                     noise_std: float = 0.005, seed: int = 0, samples: int = 1) -> Capture:
    """Render ``camera``'s images of ``scene`` while ``projector`` shows each of ``patterns`` :math:`(P, H_p, W_p)`.

    The projector is :func:`projector_light`; ``ambient`` and ``light`` set the scene's ambient level and
    directional light strength (None keeps the scene's own). Camera rays, projections and shadow rays are
    computed once for the whole sequence; ``samples x samples`` rays anti-alias object edges; noise is per
    capture (see :func:`~stereonet.active.render.render_captures`).
    """
    return render_captures(scene, camera, projector_light(scene, projector, patterns, power), ambient, light,
                           samples, noise_std, seed)


def to_grey(images: torch.Tensor) -> torch.Tensor:
    """:math:`(P, 3, H, W)` -> :math:`(1, P, H, W)` mean over colour (the stack layout the decoders take)."""
    return images.mean(1)[None]


# ----------------------------------------------------------------------------------------------- depth


def projector_depth(columns: torch.Tensor, valid: torch.Tensor, camera: Camera, projector: Camera,
                    min_angle_deg: float = 0.5) -> tuple[torch.Tensor, torch.Tensor]:
    """Depth of every camera pixel from its decoded projector column (the projector as the second camera).

    Args:
        columns: :math:`(B, 1, H, W)` sub-pixel projector columns; valid: same shape, bool.

    Returns:
        depth :math:`(B, 1, H, W)` float64 (0 where invalid) and valid. Columns outside the projector image
        or within one pixel of its border, and rays grazing their light plane, are invalid.
    """
    check_shape(columns, ["B", "1", "H", "W"], "columns")
    if valid.shape != columns.shape:
        raise StereoInputError(f"valid: expected shape {tuple(columns.shape)} like columns, got {tuple(valid.shape)}")
    b, _, h, w = columns.shape
    if (h, w) != (camera.height, camera.width):
        raise StereoInputError(f"columns: expected (B, 1, {camera.height}, {camera.width}) for this camera, "
                               f"got {tuple(columns.shape)}")
    # a pixel within a projector pixel of the frustum border is partly unlit: its decoded column is biased
    inside = valid & (columns >= 0.5) & (columns <= projector.width - 1.5)
    n_c, c_c = projector_column_planes(columns[:, 0], camera, projector)  # BxHxWx3, BxHxW
    v, u = torch.meshgrid(torch.arange(h, dtype=torch.float64), torch.arange(w, dtype=torch.float64), indexing="ij")
    uv = torch.stack([u, v], dim=-1).expand(b, h, w, 2)
    depth, ok = ray_plane_depth(camera.K, uv, n_c, c_c, min_angle_deg=min_angle_deg, degenerate="invalid")
    ok = ok[:, None] & inside
    return torch.where(ok, depth[:, None], torch.zeros_like(depth[:, None])), ok


@dataclass
class CodedScan:
    """Camera + projector scan: ``depth``/``valid`` :math:`(1, 1, H, W)`, decoded ``columns``, the captures,
    the GT ``view`` of the camera, the GT projector column of each pixel's surface point ``gt_columns`` and
    ``column_tolerance``: the decoding error (projector px) beyond which a column is a wrong code, not
    quantisation (half a stripe + 1 px for Gray code, 1 px for phase shift)."""

    depth: torch.Tensor
    valid: torch.Tensor
    columns: torch.Tensor
    captures: torch.Tensor
    view: View
    gt_columns: torch.Tensor
    column_tolerance: float

    def errors(self) -> dict[str, float]:
        """Median / 95th-percentile absolute depth error over valid pixels, density (% of GT pixels decoded),
        and ``wrong_code``: % of valid pixels whose column is off by more than ``column_tolerance`` (should
        be ~0: a wrong code reported valid), plus the median column error in projector pixels."""
        gt = self.view.depth[None, None]
        m = self.valid & (gt > 0)
        e = (self.depth - gt)[m].abs()
        ec = (self.columns - self.gt_columns)[m].abs()
        q = lambda x, p: float(torch.quantile(x, p)) if x.numel() else math.nan
        return {"median_abs_err": q(e, 0.5), "p95_abs_err": q(e, 0.95), "median_column_err": q(ec, 0.5),
                "density": 100.0 * float(m.sum()) / max(1, int((gt > 0).sum())),
                "wrong_code": 100.0 * float((ec > self.column_tolerance).float().mean()) if e.numel() else math.nan}


def coded_light_scan(scene: Scene, camera: Camera, projector: Camera, method: str = "gray+phase",
                     period: int = 16, steps: int = 4, unit: int = 1, min_contrast: float = 0.05,
                     max_relative_jump: float | None = None, **capture_options) -> CodedScan:
    """Project a coded sequence, decode every camera pixel's projector column, triangulate.

    ``method``: ``"gray"`` (Gray code of ``unit``-column stripes, depth quantised to stripes) or ``"gray+phase"`` (Gray code of ``period/2``-wide stripes choosing the period, ``steps``-step
    phase shift for the sub-pixel column). Pixels mixing two surfaces decode to either: for Gray code the
    relative-contrast test of :func:`decode_gray_code` drops them; for ``gray+phase`` pixels at depth jumps
    above ``max_relative_jump`` (default 0.03; pass 0 to disable) are dropped
    (:func:`~stereonet.active.triangulate.reject_depth_edges`) — not for ``gray``, whose depth is quantised.
    """
    hp, wp = projector.height, projector.width
    if method == "gray":
        pats = gray_code_patterns(hp, wp, unit=unit)
        cap = capture_patterns(scene, camera, projector, pats, **capture_options)
        index, ok = decode_gray_code(to_grey(cap.images), min_contrast=min_contrast, min_relative_contrast=0.6)
        cols = index.to(torch.float64) * unit + (unit - 1) / 2.0  # stripe centre
        tol = unit / 2 + 1.0
    elif method == "gray+phase":
        if period % 2:
            raise StereoInputError(f"period: expected an even number of projector pixels, got {period}")
        gray = gray_code_patterns(hp, wp, unit=period // 2)
        pats = torch.cat([gray, phase_shift_patterns(hp, wp, period, steps)])
        cap = capture_patterns(scene, camera, projector, pats, **capture_options)
        grey = to_grey(cap.images).to(torch.float64)
        index, uok = decode_gray_code(grey[:, :gray.shape[0]], min_contrast=min_contrast)
        phase, _, pok = decode_phase_shift(grey[:, gray.shape[0]:], min_modulation=min_contrast / 2)
        cols, ok = unwrap_phase(phase, pok, index, uok, period)
        tol = 1.0
    else:
        raise StereoInputError(f"method: expected 'gray' or 'gray+phase', got {method!r}")
    depth, valid = projector_depth(cols, ok, camera, projector)
    if method == "gray+phase" and max_relative_jump is None:
        max_relative_jump = 0.03
    if method == "gray+phase" and max_relative_jump:
        valid = reject_depth_edges(depth, valid, max_relative_jump)
        depth = torch.where(valid, depth, torch.zeros_like(depth))
    gt_cols = projector.project(cap.view.points)[0][..., 0][None, None]
    return CodedScan(depth, valid, cols, cap.images, cap.view, gt_cols, tol)


# ----------------------------------------------------------------------------------------------- active stereo


@dataclass
class ActivePair:
    """A rectified pair rendered with the projector showing ``pattern`` (or off): ``left``/``right``
    :math:`(1, 3, H, W)` float32, GT ``disparity`` :math:`(1, 1, H, W)`, ``valid``, ``occlusion`` (True = not seen
    by the right camera), and the left ``depth`` :math:`(H, W)`."""

    left: torch.Tensor
    right: torch.Tensor
    disparity: torch.Tensor
    valid: torch.Tensor
    occlusion: torch.Tensor
    depth: torch.Tensor


def render_active_pair(scene: Scene, rig, pattern: torch.Tensor | None, seed: int = 0, samples: int = 2,
                       **capture_options) -> ActivePair:
    """Render ``rig`` (a :class:`~stereonet.active.scenes.Rig`) with its projector showing ``pattern``
    :math:`(H_p, W_p)` (None = projector off), plus the exact left-referenced GT disparity ``f B / z``."""
    proj = rig.projector
    pat = torch.zeros(1, proj.height, proj.width) if pattern is None else pattern[None]
    capl = capture_patterns(scene, rig.left, proj, pat, seed=2 * seed, samples=samples, **capture_options)
    capr = capture_patterns(scene, rig.right, proj, pat, seed=2 * seed + 1, samples=samples, **capture_options)
    view = capl.view
    depth = view.depth
    valid = view.hit & (depth > 0)
    disp = torch.where(valid, rig.focal * rig.baseline / torch.where(valid, depth, torch.ones_like(depth)),
                       torch.zeros_like(depth))
    seen = visible_from(scene, rig.right, view.points.reshape(-1, 3)).view(depth.shape)  # frustum + occluders
    f32 = lambda x: x[None, None].float()
    return ActivePair(capl.images, capr.images, f32(disp), valid[None, None], (~seen | ~valid)[None, None], depth)


def compare_active_passive(scene: Scene, rig, method: str, pattern: torch.Tensor, seed: int = 0,
                           max_disp: int | None = None, **options) -> dict[str, dict[str, float]]:
    """Run the same matcher on the pair with the projector off and on; metrics of each
    (:func:`stereonet.metrics.evaluate` keys, including ``bad2_noc``; missing answers count as errors)."""
    from stereonet.matchers import match
    from stereonet.metrics import evaluate

    max_disp = rig.max_disp() if max_disp is None else max_disp
    out = {}
    for name, pat in (("passive", None), ("active", pattern)):
        pair = render_active_pair(scene, rig, pat, seed=seed)
        res = match(method, pair.left, pair.right, max_disp, **options)
        out[name] = evaluate(res.disparity, pair.disparity, pair.valid, res.valid, occlusion=pair.occlusion,
                             see=False)
    return out
