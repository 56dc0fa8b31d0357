"""Laser stripe scanning: a laser sheet sweeps the scene, one camera sees the stripe, each stripe point is
triangulated by intersecting its camera ray with the known laser plane.

Pipeline (:func:`laser_scan`):

1. :func:`sweep_planes` — the laser sits at ``origin`` and turns about ``axis``; at angle ``theta`` its sheet
   contains the axis and the direction ``cos(theta) forward + sin(theta) side``.
2. :func:`render_stripe_images` — the camera's view of each sheet, rendered through data_gen: the laser is an
   emitter (:func:`laser_light`) of irradiance ``power * exp(-angle_to_sheet^2 / 2 sigma^2) * Lambert *
   visible-from-laser`` on top of ambient light, one state per sheet angle.
3. :func:`stripe_peaks` — per scanline, the brightest column of the laser-on minus laser-off image, refined to
   sub-pixel by a 3-point Gaussian fit (exact for a Gaussian profile). Rows with no stripe, a saturated peak,
   a peak at the border or a second comparable peak (ambiguous) are invalid.
4. :func:`~stereonet.active.triangulate.ray_plane_depth` — ray ∩ plane; grazing rays are invalid and a
   sheet that contains the camera centre (parallel to every camera ray) gives no depth.
   :func:`reject_stripe_breaks` drops stripe points where the stripe is cut by an occluding edge.
5. The stripe points of all angles are written into a range image (nearest pixel, the sample closest to the
   pixel centre wins).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass

import torch

from data_gen import Camera, Scene, raycast, visible_from_point
from data_gen.render import LightsFn
from stereonet.active.render import render_captures
from stereonet.active.triangulate import depth_to_points, plane_to_camera, ray_plane_depth
from stereonet.checks import StereoInputError, check_image

log = logging.getLogger(__name__)


def sweep_planes(origin: Sequence[float], angles_deg: Sequence[float] | torch.Tensor,
                 axis: Sequence[float] = (0.0, 1.0, 0.0),
                 forward: Sequence[float] = (0.0, 0.0, 1.0)) -> tuple[torch.Tensor, torch.Tensor]:
    """World planes ``n . X = c`` of a laser sheet at ``origin`` turning about ``axis``.

    At angle ``theta`` the sheet contains ``axis`` and ``cos(theta) forward + sin(theta) (axis x forward)``.
    Returns normals :math:`(A, 3)` (unit) and offsets :math:`(A,)` for ``A = len(angles_deg)``.
    """
    o = torch.as_tensor(origin, dtype=torch.float64)
    a = torch.as_tensor(axis, dtype=torch.float64)
    a = a / a.norm()
    f = torch.as_tensor(forward, dtype=torch.float64)
    f = f - (f @ a) * a
    if float(f.norm()) < 1e-9:
        raise StereoInputError("forward: expected a direction not parallel to axis")
    f = f / f.norm()
    side = torch.linalg.cross(a, f)
    th = torch.deg2rad(torch.as_tensor(angles_deg, dtype=torch.float64).reshape(-1))
    in_sheet = torch.cos(th)[:, None] * f + torch.sin(th)[:, None] * side  # Ax3
    normals = torch.linalg.cross(a.expand_as(in_sheet), in_sheet)
    normals = normals / normals.norm(dim=-1, keepdim=True)
    return normals, normals @ o


@dataclass
class StripeImages:
    """Stripe images of a sweep: ``on`` :math:`(A, 1, H, W)` laser on, ``off`` :math:`(1, 1, H, W)` laser off
    (float32 [0, 1], grey), and the camera's GT ``depth``/``hit`` :math:`(H, W)` for evaluation."""

    on: torch.Tensor
    off: torch.Tensor
    depth: torch.Tensor
    hit: torch.Tensor


def laser_light(scene: Scene, origin: Sequence[float], normals: torch.Tensor, offsets: torch.Tensor,
                power: float, sigma: float) -> LightsFn:
    """The laser as a data_gen emitter with one state per sheet (world planes ``normals`` :math:`(A, 3)`,
    ``offsets`` :math:`(A,)` through ``origin``): irradiance :math:`(N, A)` at surface points
    ``power * exp(-s^2 / 2 sigma^2) * max(0, n . l) * visible``, where ``s`` is the sine of the angle between the
    sheet and the ray from the laser (``sigma``: the sheet's angular half-thickness, radians) and ``visible``
    the shadow test :func:`data_gen.visible_from_point`."""
    src = torch.as_tensor(origin, dtype=torch.float64)
    sheets_n, sheets_c = normals.to(torch.float64), offsets.to(torch.float64)

    def lights(points: torch.Tensor, nrm: torch.Tensor, ids: torch.Tensor) -> torch.Tensor:
        to_src = src.to(points.dtype) - points
        dist = to_src.norm(dim=-1).clamp_min(1e-12)
        lambert = ((nrm * to_src).sum(-1) / dist).clamp_min(0)
        lit = lambert * visible_from_point(scene, src, points) * (ids >= 0)
        ang = (points @ sheets_n.T.to(points.dtype) - sheets_c.to(points.dtype)) / dist[:, None]  # NxA
        return power * torch.exp(-0.5 * (ang / sigma) ** 2) * lit[:, None]

    return lights


def render_stripe_images(scene: Scene, camera: Camera, origin: Sequence[float], normals: torch.Tensor,
                         offsets: torch.Tensor, power: float = 1.5, sigma_deg: float | None = None,
                         ambient: float = 0.15, noise_std: float = 0.005, seed: int = 0) -> StripeImages:
    """Render the camera's grey view of each laser sheet (normals :math:`(A, 3)`, offsets :math:`(A,)`, world
    frame) and of the scene with the laser off, under ``ambient`` light alone.

    The camera rays and the shadow test toward the laser do not depend on the sheet angle, so they are cast
    once (:func:`~stereonet.active.render.render_captures`); each sheet only changes the Gaussian profile across
    it (``sigma_deg`` = angular half-thickness as seen from the laser; default 0.8 of the camera's pixel angle,
    so the stripe spans ~2-3 pixels like a laser line focused for its camera — a much thinner line would fall
    between pixel centres).
    """
    sigma = 0.8 / float(camera.K[0, 0]) if sigma_deg is None else math.radians(sigma_deg)
    sheets = laser_light(scene, origin, normals, offsets, power, sigma)

    def off_then_sheets(points: torch.Tensor, nrm: torch.Tensor, ids: torch.Tensor) -> torch.Tensor:
        return torch.cat([torch.zeros_like(points[:, :1]), sheets(points, nrm, ids)], dim=1)  # state 0: laser off

    cap = render_captures(scene, camera, off_then_sheets, ambient=ambient, light=0.0, noise_std=noise_std,
                          seed=seed, grey=True)
    return StripeImages(cap.images[1:], cap.images[:1], cap.view.depth, cap.view.hit)


def stripe_peaks(image: torch.Tensor, min_peak: float = 0.05, saturation: float = 0.99,
                 background: torch.Tensor | None = None, exclusion: int = 4,
                 ambiguity_ratio: float = 0.5, min_side_ratio: float = 0.03) -> tuple[torch.Tensor, torch.Tensor]:
    """Sub-pixel column of the laser stripe on every scanline.

    Args:
        image: :math:`(B, 1, H, W)` stripe images in [0, 1].
        min_peak: rows whose stripe signal (after background subtraction) stays below this have no stripe.
        saturation: a peak at or above this raw intensity is clipped, its shape unknown -> invalid.
        background: optional laser-off image :math:`(B or 1, 1, H, W)` subtracted first.
        exclusion: half-width (px) around the peak ignored when looking for a competing second peak.
        ambiguity_ratio: a second peak above this fraction of the first makes the row ambiguous -> invalid.
        min_side_ratio: both neighbours of the peak pixel must carry at least this fraction of its signal;
            a stripe cut off by an occluding edge or a shadow has one dark side and a biased centre -> invalid.

    Returns:
        columns :math:`(B, 1, H)` float (sub-pixel, pixel centres at integers; 0 where invalid) and
        valid :math:`(B, 1, H)` bool. The 3-point fit ``delta = (ln a - ln c) / (2 (ln a - 2 ln b + ln c))`` of
        a Gaussian through the peak ``b`` and its neighbours ``a, c`` is exact for Gaussian stripes.
    """
    image = check_image(image, "image", channels=(1,))
    signal = image if background is None else image - check_image(background, "background", channels=(1,))
    b, _, h, w = image.shape
    if w < 3:
        raise StereoInputError(f"image: expected width >= 3 for a 3-point peak fit, got shape {tuple(image.shape)}")
    peak, col = signal.max(dim=-1)  # Bx1xH
    raw_peak = torch.gather(image, -1, col[..., None])[..., 0]
    inner = (col > 0) & (col < w - 1)
    cm, cp = (col - 1).clamp(0, w - 1), (col + 1).clamp(0, w - 1)
    s_m = torch.gather(signal, -1, cm[..., None])[..., 0]
    s_p = torch.gather(signal, -1, cp[..., None])[..., 0]
    tiny = 1e-6
    la, lb, lc = (torch.log(x.clamp_min(tiny)) for x in (s_m, peak, s_p))
    den = la - 2 * lb + lc
    gauss_ok = (s_m > tiny) & (s_p > tiny) & (den < -1e-9)
    par_den = s_m - 2 * peak + s_p
    delta = torch.where(gauss_ok, 0.5 * (la - lc) / torch.where(gauss_ok, den, -torch.ones_like(den)),
                        0.5 * (s_m - s_p) / torch.where(par_den < -1e-9, par_den, -torch.ones_like(par_den)))
    # a competing peak outside the exclusion window means two stripe candidates on one scanline
    cols = torch.arange(w, device=image.device).view(1, 1, 1, w)
    far = (cols - col[..., None]).abs() > exclusion
    second = torch.where(far, signal, torch.full_like(signal, -math.inf)).max(dim=-1).values
    valid = ((peak >= min_peak) & (raw_peak < saturation) & inner & (delta.abs() <= 0.5)
             & (second < ambiguity_ratio * peak) & (torch.minimum(s_m, s_p) >= min_side_ratio * peak))
    columns = torch.where(valid, col.to(image.dtype) + delta, torch.zeros_like(peak))
    return columns, valid


@dataclass
class LaserScan:
    """Result of :func:`laser_scan`.

    ``range_image`` :math:`(H, W)` depth (0 where invalid), ``valid`` :math:`(H, W)`; ``points`` :math:`(N, 3)`
    camera-frame stripe points; ``uv`` :math:`(N, 2)` their sub-pixel image positions; ``sheet`` :math:`(N,)` the
    index of the laser sheet (``normals[sheet]``, ``offsets[sheet]``, world frame); ``gt_depth`` :math:`(N,)`
    the renderer's depth along the same sub-pixel rays; ``depth_map_gt`` :math:`(H, W)` the GT depth map.
    """

    range_image: torch.Tensor
    valid: torch.Tensor
    points: torch.Tensor
    uv: torch.Tensor
    sheet: torch.Tensor
    normals: torch.Tensor
    offsets: torch.Tensor
    gt_depth: torch.Tensor
    depth_map_gt: torch.Tensor
    stripes: StripeImages

    def errors(self) -> dict[str, float]:
        """Median / 95th-percentile absolute depth error of the stripe points and of the range image
        (against the GT depth map at the same pixel), plus the range-image density (% of hit pixels)."""
        e_pts = (self.points[:, 2] - self.gt_depth).abs()
        m = self.valid & (self.depth_map_gt > 0)
        e_img = (self.range_image - self.depth_map_gt)[m].abs()
        q = lambda e, p: float(torch.quantile(e, p)) if e.numel() else math.nan
        return {"points": int(e_pts.numel()), "median_abs_err": q(e_pts, 0.5), "p95_abs_err": q(e_pts, 0.95),
                "range_image_median_abs_err": q(e_img, 0.5), "range_image_p95_abs_err": q(e_img, 0.95),
                "density": 100.0 * float(m.sum()) / max(1, int((self.depth_map_gt > 0).sum()))}


def triangulate_stripes(columns: torch.Tensor, valid: torch.Tensor, camera: Camera,
                        normals_world: torch.Tensor, offsets_world: torch.Tensor,
                        min_angle_deg: float = 0.5) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Triangulate stripe columns :math:`(A, 1, H)` of ``A`` laser sheets (world planes :math:`(A, 3)`, :math:`(A,)`).

    Returns camera-frame points :math:`(A, H, 3)`, their pixel coordinates :math:`(A, H, 2)` and valid
    :math:`(A, H)`. Sheets containing the camera centre are logged and give no points.
    """
    n_c, c_c = plane_to_camera(normals_world, offsets_world, camera)  # Ax3, A
    a, _, h = columns.shape
    rows = torch.arange(h, dtype=torch.float64).expand(a, h)
    uv = torch.stack([columns[:, 0].to(torch.float64), rows], dim=-1)  # AxHx2
    through = c_c.abs() < 1e-9
    if bool(through.any()):
        log.warning("laser sheets %s contain the camera centre: no depth from them",
                    through.nonzero().flatten().tolist())
    depth, ok = ray_plane_depth(camera.K, uv, n_c[:, None, :].expand(a, h, 3), c_c[:, None].expand(a, h),
                                min_angle_deg=min_angle_deg, degenerate="invalid")
    pts = depth_to_points(depth, torch.ones_like(ok), camera.K, uv).view(a, h, 3)
    return pts, uv, ok & valid[:, 0]


def reject_stripe_breaks(depth: torch.Tensor, valid: torch.Tensor, max_relative_jump: float = 0.02) -> torch.Tensor:
    """Keep a stripe point only where the measured surface continues smoothly around it.

    Where a stripe crosses an occluding edge it is cut off or merges with the stripe on the surface behind,
    and the sub-pixel peak of that profile lies on neither surface. Inverse depth varies smoothly (affinely
    on a plane) both along one sheet's stripe (scanline ``v``) and across neighbouring sheets on one
    scanline (sheet ``a``), so its second difference along either axis must stay below
    ``max_relative_jump / z``. Along a stripe, points whose neighbour is missing (segment ends next to
    shadows and edges) are dropped too; across sheets they are checked only when both neighbours exist.
    ``depth``/``valid``: :math:`(A, H)` per sheet and scanline. Returns the new valid mask.
    """
    inv = torch.where(valid, 1.0 / torch.where(valid, depth, torch.ones_like(depth)), torch.zeros_like(depth))
    keep = valid.clone()
    for x, ok, k, strict in ((inv, valid, keep, True), (inv.T, valid.T, keep.T, False)):  # rows, then sheets
        both = torch.zeros_like(ok)
        both[:, 1:-1] = ok[:, :-2] & ok[:, 2:]
        second = torch.zeros_like(x)
        second[:, 1:-1] = (x[:, :-2] - 2 * x[:, 1:-1] + x[:, 2:]).abs()
        smooth = second <= max_relative_jump * x
        k &= (both & smooth) if strict else (~both | smooth)  # k is a view of keep: updated in place
    return keep


def laser_scan(scene: Scene, camera: Camera, origin: Sequence[float], angles_deg: Sequence[float],
               axis: Sequence[float] = (0.0, 1.0, 0.0), forward: Sequence[float] = (0.0, 0.0, 1.0),
               min_angle_deg: float = 0.5, seed: int = 0, **render_options) -> LaserScan:
    """Sweep a laser sheet over ``scene`` and build ``camera``'s range image (see module doc)."""
    normals, offsets = sweep_planes(origin, angles_deg, axis, forward)
    stripes = render_stripe_images(scene, camera, origin, normals, offsets, seed=seed, **render_options)
    cols, ok = stripe_peaks(stripes.on, background=stripes.off)
    pts, uv, ok = triangulate_stripes(cols, ok, camera, normals, offsets, min_angle_deg)
    ok = reject_stripe_breaks(pts[..., 2], ok)
    sheet = torch.arange(ok.shape[0])[:, None].expand_as(ok)[ok]
    pts, uv = pts[ok], uv[ok]  # Nx3, Nx2
    # GT along the same sub-pixel rays (exact evaluation of the triangulation); ray parameter = depth
    gt = raycast(scene, torch.as_tensor(camera.center), camera.ray_dirs(uv[:, 0], uv[:, 1]))
    gt_depth = torch.where(gt.ids >= 0, gt.t, torch.zeros_like(gt.t))
    h, w = camera.height, camera.width
    range_image = torch.zeros(h, w, dtype=torch.float64)
    valid = torch.zeros(h, w, dtype=torch.bool)
    if pts.shape[0]:
        px = uv.round().long()
        off = (uv - px).norm(dim=-1)
        inside = (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)
        idx = (px[:, 1] * w + px[:, 0])[inside]
        best = torch.full((h * w,), math.inf, dtype=torch.float64).scatter_reduce(0, idx, off[inside], "amin")
        win = off[inside] == best[idx]  # per pixel, the stripe sample closest to the pixel centre
        range_image.view(-1)[idx[win]] = pts[inside][win, 2]
        valid.view(-1)[idx[win]] = True
    return LaserScan(range_image, valid, pts, uv, sheet, normals, offsets, gt_depth, stripes.depth, stripes)
