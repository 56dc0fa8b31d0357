"""Matching-cost volumes ``(B, D, H, W)``, ``D = max_disp + 1``, lower = better.

``cost[b, d, y, x]`` compares the left pixel ``(y, x)`` with the right pixel ``(y, x - d)``. Every windowed
cost is a pixelwise cost aggregated by a box filter (:func:`stereonet.cost.box.box_mean`, O(1) per pixel and
disparity, any odd window), so all window costs are *means* over the window (independent of its size).

Costs (``cost=`` of :func:`build_cost_volume`), images in [0, 1], colour channels averaged unless noted:

- ``"ad"``: pixelwise absolute difference (``window`` is ignored).
- ``"sad"``: mean absolute difference over the window.
- ``"ssd"``: mean squared difference over the window.
- ``"zsad"``: SAD of zero-mean images ``I - box_mean(I)`` (each pixel minus the mean of the window centred
  on it). This is the O(1) form used in practice (exact ZSAD subtracts the mean of the window centred on the
  reference pixel from all its members, which is not a box filter); it removes additive bias just the same.
- ``"lssad"``: SAD of locally scaled images ``I / (box_mean(I) + 1/255)``: removes multiplicative gain, the
  same O(1) form as ``zsad``.
- ``"ncc"``: ``1 - NCC`` on grey images, exact for windows inside both images. Where either window has
  (near-)zero variance (``var < 1e-6``, e.g. a constant image) the NCC is *defined* as 0, i.e. cost 1:
  "no information", never NaN. Costs lie in [0, 2].
- ``"census"``: Hamming distance of ``census_window`` census codes of grey images (bits, 0 .. cw**2 - 1),
  box-averaged over ``window`` (``window=1``: pixelwise Hamming).
- ``"census_ad"``: AD-Census (Mei et al. 2011): ``2 - exp(-census/lambda_census) - exp(-ad/lambda_ad)``,
  in [0, 2), box-averaged over ``window``.

Right positions outside the image (``x - d < 0``) are compared against the replicated border column while
aggregating, and their final cost is set to ``max(volume before this fill) + 1`` (so above every in-image
cost) — a large *finite* cost, so WTA never picks them unless nothing else exists and SGM/DP recurrences
stay finite.

Adaptive windows (``cost="adaptive"``, :func:`adaptive_cost_volume`): Hirschmüller's five shifted windows
(centre + the two best of four corner windows) or the shiftable window (best of all windows containing the
pixel) over a pixelwise SAD/SSD.

Backends: a vectorised torch path (differentiable, any device, chunked) and numba CPU kernels
(:mod:`stereonet.kernels.cost`, tested equal) that ``backend="auto"`` picks for float32 CPU input
without gradient; the numba path returns a ``(B, D, H, W)`` view of a ``(B, H, W, D)`` buffer and needs
one volume of memory (no chunking needed beyond that).

Memory: the torch path allocates the output volume once; the intermediate per-disparity work is done in
chunks of disparities sized to ``memory_budget`` bytes (default 512 MiB), so e.g. KITTI (1242x375, 192
disparities, a 341 MiB float32 volume) builds with about 400 MiB peak.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import torch

from stereonet.checks import StereoInputError, check_image, check_max_disp, check_stereo_inputs, check_window
from stereonet.cost.box import box_mean, min_filter
from stereonet.cost.census import BITS_PER_WORD, census_transform, grey_numpy, popcount, to_grey
from stereonet.cost.correlation import correlation_1d
from stereonet.kernels import use_numba

DEFAULT_MEMORY_BUDGET = 512 * 2**20
NCC_MIN_VARIANCE = 1e-6
LSSAD_EPS = 1.0 / 255.0
COSTS = ("ad", "sad", "ssd", "zsad", "lssad", "ncc", "census", "census_ad")

PixelCost = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]


def shifted_stack(right: torch.Tensor, d0: int, d1: int) -> torch.Tensor:
    """``out[:, :, i, y, x] = right[:, :, y, max(x - (d0 + i), 0)]`` for ``d0 <= d0 + i < d1``.

    Args:
        right: :math:`(B, C, H, W)` (any dtype).
    Returns:
        :math:`(B, C, d1 - d0, H, W)` contiguous (a copy of the chunk; the replicated border column
        stands in for right pixels left of the image).
    """
    b, c, h, w = right.shape
    out = right.new_empty((b, c, d1 - d0, h, w))
    for i, d in enumerate(range(d0, d1)):
        d = min(d, w)
        out[:, :, i, :, d:] = right[..., : w - d]
        out[:, :, i, :, :d] = right[..., :1]
    return out


def _invalid_mask(d0: int, d1: int, width: int, device: torch.device) -> torch.Tensor:
    """(d1 - d0, 1, W) bool: True where ``x - d < 0`` (right pixel outside the image)."""
    d = torch.arange(d0, d1, device=device).view(-1, 1, 1)
    x = torch.arange(width, device=device).view(1, 1, -1)
    return x < d


def sweep_cost_volume(left_feat: torch.Tensor, right_feat: torch.Tensor, max_disp: int,
                      pixel_cost: PixelCost,
                      aggregate: Callable[[torch.Tensor], torch.Tensor] | None = None,
                      finalize: Callable[[torch.Tensor, int, int], torch.Tensor] | None = None,
                      memory_budget: int = DEFAULT_MEMORY_BUDGET, invalid: str = "max+1",
                      out_dtype: torch.dtype | None = None) -> torch.Tensor:
    """Generic disparity sweep: pixelwise cost, aggregation and finalisation per chunk of disparities.

    Args:
        left_feat, right_feat: :math:`(B, C, H, W)` per-pixel features (images, census codes ...).
        max_disp: largest disparity; ``D = max_disp + 1``.
        pixel_cost: ``(left (B,C,1,H,W), right_shifted (B,C,Dc,H,W)) -> (B, Dc, H, W)`` float.
        aggregate: optional ``(B, Dc, H, W) -> (B, Dc, H, W)`` (e.g. a box filter).
        finalize: optional ``(aggregated chunk, d0, d1) -> chunk`` (e.g. NCC normalisation).
        memory_budget: bytes for the intermediates of one chunk.
        invalid: ``"max+1"`` (costs: largest cost of the volume + 1), ``"zero"`` (similarities) or ``"none"``.
        out_dtype: output dtype (default: the left feature dtype if floating, else float32).

    Returns:
        :math:`(B, D, H, W)`.
    """
    b, c, h, w = left_feat.shape
    n_disp = max_disp + 1
    dtype = out_dtype or (left_feat.dtype if left_feat.is_floating_point() else torch.float32)
    out = torch.empty((b, n_disp, h, w), dtype=dtype, device=left_feat.device)
    itemsize = max(left_feat.element_size(), torch.finfo(dtype).bits // 8)
    per_disp = b * max(c, 1) * h * w * itemsize * 6  # shifted copy, difference, aggregation temporaries
    chunk = max(1, min(n_disp, memory_budget // max(per_disp, 1)))
    left5 = left_feat.unsqueeze(2)  # BxCx1xHxW
    running_max = None
    for d0 in range(0, n_disp, chunk):
        d1 = min(n_disp, d0 + chunk)
        vol = pixel_cost(left5, shifted_stack(right_feat, d0, d1))  # BxDcxHxW
        if aggregate is not None:
            vol = aggregate(vol)
        if finalize is not None:
            vol = finalize(vol, d0, d1)
        if invalid == "max+1":
            m = vol.detach().amax()
            running_max = m if running_max is None else torch.maximum(running_max, m)
        out[:, d0:d1] = vol
    if invalid == "none":
        return out
    if invalid == "max+1":
        fill = float(running_max) + 1.0 if running_max is not None and math.isfinite(float(running_max)) else 1.0
    else:
        fill = 0.0
    return fill_out_of_image(out, fill)


def fill_out_of_image(vol: torch.Tensor, fill: float | None = None) -> torch.Tensor:
    """Set ``vol[:, d, :, x]`` for ``x < d`` (right pixel outside the image) to ``fill``.

    Args:
        vol: :math:`(B, D, H, W)`.
        fill: value; default ``max(vol) + 1`` (before filling).
    Returns:
        :math:`(B, D, H, W)` (in place unless ``vol`` requires grad).
    """
    n_disp, w = vol.shape[1], vol.shape[-1]
    bad = _invalid_mask(0, n_disp, w, vol.device)  # Dx1xW
    if fill is None:
        fill = float(vol.detach().amax()) + 1.0
    if vol.requires_grad:
        return vol.masked_fill(bad, fill)
    return vol.masked_fill_(bad, fill)


def _chw(img: torch.Tensor) -> np.ndarray:
    """(C, H, W) tensor -> (C, H, W) float32 C-contiguous array (no copy for a contiguous float32 CPU tensor)."""
    return np.ascontiguousarray(img.detach().to("cpu", torch.float32).numpy())


_NO_CODES = np.zeros((1, 1, 1), np.uint64)
_NO_MAP = np.zeros((1, 1), np.float32)


def numba_engine_args(left: torch.Tensor, right: torch.Tensor, cost: str, window: int, *,
                      census_window: int = 5, lambda_census: float = 30.0, lambda_ad: float = 10.0 / 255.0,
                      mode: str = "multiwindow", base: str = "sad") -> tuple:
    """Arguments ``(kind, L, R, CL, CR, window, post, post_window, lam_c, lam_a, mu_l, isd_l, mu_r, isd_r)`` of :func:`stereonet.kernels.block.block_cost_rows` for one pair ``(C, H, W)`` (inputs
    already checked), i.e. the definition of ``cost`` as pixelwise cost + box window + post-processing."""
    from stereonet.kernels import block as E
    from stereonet.kernels.cost import census_khw

    if cost not in COSTS + ("adaptive",):
        raise StereoInputError(f"cost: expected one of {', '.join(COSTS + ('adaptive',))}, got {cost!r}")
    if cost == "adaptive" and (mode not in ("multiwindow", "shiftable") or base not in ("sad", "ssd")):
        raise StereoInputError(f"mode/base: expected 'multiwindow'|'shiftable' and 'sad'|'ssd', got {mode!r}, {base!r}")
    if cost == "ncc" and window < 3:
        raise StereoInputError(f"window: NCC needs a window of at least 3, got {window}")
    codes_l = codes_r = _NO_CODES
    maps = (_NO_MAP,) * 4
    post, post_window = E.POST_NONE, 1
    if cost in ("census", "census_ad"):
        check_window(census_window, "census_window")
        if census_window < 3:
            raise StereoInputError(f"census_window: expected an odd integer >= 3, got {census_window}")
        gl, gr = grey_numpy(left), grey_numpy(right)
        codes_l = census_khw(gl, census_window, BITS_PER_WORD)  # KxHxW
        codes_r = census_khw(gr, census_window, BITS_PER_WORD)
    if cost == "census":
        kind, li, ri = E.KIND_HAMMING, gl[None], gr[None]
    elif cost == "ncc":
        gl, gr = grey_numpy(left), grey_numpy(right)
        kind, li, ri, post = E.KIND_PROD, gl[None], gr[None], E.POST_NCC
        # box(g), box(g * g), the clamped variance and its inverse root (0 at or below NCC_MIN_VARIANCE: NCC defined
        # as 0 there) in two numba passes per image
        floor = np.float32(NCC_MIN_VARIANCE)
        maps = (*E.ncc_window_stats(gl, window, floor), *E.ncc_window_stats(gr, window, floor))
    else:
        li, ri = _chw(left), _chw(right)
        squared = cost == "ssd" or (cost == "adaptive" and base == "ssd")
        kind = E.KIND_CENSUS_AD if cost == "census_ad" else (E.KIND_SQ if squared else E.KIND_ABS)
        if cost in ("zsad", "lssad"):  # li - box mean, or li / (box mean + eps), in the box's own pass
            op, eps = (E.BOX_ZERO_MEAN, np.float32(0)) if cost == "zsad" else (E.BOX_SCALED, np.float32(LSSAD_EPS))
            li, ri = E.box_planes(li, window, op, eps), E.box_planes(ri, window, op, eps)
        if cost == "adaptive":
            post, post_window = (E.POST_MULTIWINDOW if mode == "multiwindow" else E.POST_SHIFTABLE), window
    box = 1 if cost == "ad" else window
    return (kind, np.ascontiguousarray(li, np.float32), np.ascontiguousarray(ri, np.float32), codes_l, codes_r,
            box, post, post_window, np.float32(lambda_census), np.float32(lambda_ad), *maps)


def run_block_engine(mode: int, args: tuple, n_disp: int, method: int = 0, ratio: float = 0.0,
                     lr_tol: float = -1.0) -> tuple:
    """Call :func:`stereonet.kernels.block.block_cost_rows` with :func:`numba_engine_args` ``args``."""
    from stereonet.kernels.block import MODE_VOLUME, MODE_VOLUME_ROWS, block_cost_rows

    kind, li, ri, cl, cr, box, post, post_window, lam_c, lam_a, mu_l, isd_l, mu_r, isd_r = args
    _, h, w = li.shape
    # the volume is allocated here, by numpy (large buffers get transparent huge pages: far fewer page faults)
    shape = {MODE_VOLUME: (h, w, n_disp), MODE_VOLUME_ROWS: (h, n_disp, w)}.get(mode, (1, 1, 1))
    vol = np.empty(shape, np.float32)
    return block_cost_rows(mode, kind, li, ri, cl, cr, n_disp, box, post, post_window, lam_c, lam_a,
                           mu_l, isd_l, mu_r, isd_r, method, float(ratio), float(lr_tol), vol)


def out_of_image_cost(row_maxima: list[np.ndarray]) -> np.float32:
    """The cost of positions ``x < d``: ``max(volume before filling) + 1`` over the whole batch."""
    return np.float32(max(float(m.max()) for m in row_maxima) + 1.0)


def numba_cost_volume(left: torch.Tensor, right: torch.Tensor, max_disp: int, cost: str, window: int,
                      layout: str = "hwd", **options) -> torch.Tensor:
    """The numba CPU path of every cost (inputs already checked): same definitions as the torch path,
    computed row by row by :func:`stereonet.kernels.block.block_cost_rows` (``options``: those of
    :func:`numba_engine_args`).

    Returns:
        :math:`(B, D, H, W)` float32 *view* of a ``(B, H, W, D)`` buffer (``layout="hwd"``: disparity innermost,
        the layout the numba SGM and selection kernels read without copying) or of a ``(B, H, D, W)`` buffer
        (``"hdw"``: each image row as ``D`` runs of ``W`` costs, the engine's own rows, for ``bp``), cast to the
        input dtype. Same values either way.
    """
    from stereonet.kernels.block import MODE_VOLUME, MODE_VOLUME_ROWS
    from stereonet.kernels.cost import fill_invalid_hdw, fill_invalid_hwd

    rows = check_layout(layout) == "hdw"
    vols, maxima = [], []
    for b in range(left.shape[0]):
        res = run_block_engine(MODE_VOLUME_ROWS if rows else MODE_VOLUME,
                               numba_engine_args(left[b], right[b], cost, window, **options), max_disp + 1)
        vols.append(res[0])
        maxima.append(res[1])
    fill = out_of_image_cost(maxima)
    for v in vols:
        (fill_invalid_hdw if rows else fill_invalid_hwd)(v, fill)
    out = torch.from_numpy(np.stack(vols) if len(vols) > 1 else vols[0][None])  # BxHxWxD or BxHxDxW
    out = out.permute(0, 2, 1, 3) if rows else out.permute(0, 3, 1, 2)  # BxDxHxW view
    return out.to(device=left.device, dtype=left.dtype)


CENSUS_U8_MAX_WINDOW = 15  # census windows whose distances (and max + 1) fit in uint8: 15 * 15 - 1 = 224 bits


def census_pixel_volumes_u8(left: torch.Tensor, right: torch.Tensor, max_disp: int,
                            census_window: int) -> list[np.ndarray]:
    """The pixelwise (``window=1``) census volume of :func:`census_cost_volume` as B ``(H, W, D)`` uint8
    arrays (inputs already checked, ``3 <= census_window <= 15``): the same values (integers in bits,
    ``x < d`` = ``max + 1`` over the batch) in a quarter of the memory, for the numba SGM kernel.
    """
    from stereonet.kernels.cost import census_hamming_hwd_u8, census_khw, fill_triangle_u8

    check_window(census_window, "census_window")
    if not 3 <= census_window <= CENSUS_U8_MAX_WINDOW:
        raise StereoInputError(f"census_window: expected an odd integer in [3, {CENSUS_U8_MAX_WINDOW}], "
                               f"got {census_window}")
    vols, maxima = [], []
    for b in range(left.shape[0]):
        codes_l = census_khw(grey_numpy(left[b]), census_window, BITS_PER_WORD)  # KxHxW
        codes_r = census_khw(grey_numpy(right[b]), census_window, BITS_PER_WORD)
        vol, row_max = census_hamming_hwd_u8(codes_l, codes_r, max_disp + 1)
        vols.append(vol)
        maxima.append(row_max)
    fill = int(out_of_image_cost(maxima))  # max + 1 over the batch, as numba_cost_volume
    for v in vols:
        fill_triangle_u8(v, np.uint8(fill))
    return vols


def _box(window: int) -> Callable[[torch.Tensor], torch.Tensor] | None:
    return None if window == 1 else (lambda v: box_mean(v, window))


def _abs_diff(lf: torch.Tensor, rs: torch.Tensor) -> torch.Tensor:
    return (lf - rs).abs().mean(1)


def _sq_diff(lf: torch.Tensor, rs: torch.Tensor) -> torch.Tensor:
    return (lf - rs).square().mean(1)


def _prepare(left: torch.Tensor, right: torch.Tensor, max_disp: int, window: int, layout: str = "hwd") -> tuple:
    left, right, max_disp = check_stereo_inputs(left, right, max_disp)
    check_layout(layout)
    return left, right, max_disp, check_window(window)


LAYOUTS = ("hwd", "hdw")
"""Memory orders of a numba cost volume behind its ``(B, D, H, W)`` view: disparity innermost (``"hwd"``, what the
numba SGM and selection kernels read) or image rows of ``D`` runs of ``W`` costs (``"hdw"``, what ``bp`` reads).
The values are the same; the torch path returns a contiguous ``(B, D, H, W)`` volume whatever the layout."""


def check_layout(layout: object) -> str:
    if layout not in LAYOUTS:
        raise StereoInputError(f"layout: expected one of {', '.join(LAYOUTS)}, got {layout!r}")
    return layout


def ad_cost_volume(left: torch.Tensor, right: torch.Tensor, max_disp: int, *,
                   memory_budget: int = DEFAULT_MEMORY_BUDGET,
                   backend: str = "auto", layout: str = "hwd") -> torch.Tensor:
    """Pixelwise absolute difference (mean over channels). ``left``/``right`` (B, C, H, W) -> (B, D, H, W)."""
    left, right, max_disp, _ = _prepare(left, right, max_disp, 1, layout)
    if use_numba(left, right, backend=backend):
        return numba_cost_volume(left, right, max_disp, "ad", 1, layout=layout)
    return sweep_cost_volume(left, right, max_disp, _abs_diff, memory_budget=memory_budget)


def sad_cost_volume(left: torch.Tensor, right: torch.Tensor, max_disp: int, window: int = 5, *,
                    memory_budget: int = DEFAULT_MEMORY_BUDGET,
                    backend: str = "auto", layout: str = "hwd") -> torch.Tensor:
    """Window mean of absolute differences. (B, C, H, W) pair -> (B, D, H, W)."""
    left, right, max_disp, window = _prepare(left, right, max_disp, window, layout)
    if use_numba(left, right, backend=backend):
        return numba_cost_volume(left, right, max_disp, "sad", window, layout=layout)
    return sweep_cost_volume(left, right, max_disp, _abs_diff, _box(window), memory_budget=memory_budget)


def ssd_cost_volume(left: torch.Tensor, right: torch.Tensor, max_disp: int, window: int = 5, *,
                    memory_budget: int = DEFAULT_MEMORY_BUDGET,
                    backend: str = "auto", layout: str = "hwd") -> torch.Tensor:
    """Window mean of squared differences. (B, C, H, W) pair -> (B, D, H, W)."""
    left, right, max_disp, window = _prepare(left, right, max_disp, window, layout)
    if use_numba(left, right, backend=backend):
        return numba_cost_volume(left, right, max_disp, "ssd", window, layout=layout)
    return sweep_cost_volume(left, right, max_disp, _sq_diff, _box(window), memory_budget=memory_budget)


def zsad_cost_volume(left: torch.Tensor, right: torch.Tensor, max_disp: int, window: int = 5, *,
                     memory_budget: int = DEFAULT_MEMORY_BUDGET,
                     backend: str = "auto", layout: str = "hwd") -> torch.Tensor:
    """SAD of zero-mean images ``I - box_mean(I, window)`` (see module doc). -> (B, D, H, W)."""
    left, right, max_disp, window = _prepare(left, right, max_disp, window, layout)
    if use_numba(left, right, backend=backend):
        return numba_cost_volume(left, right, max_disp, "zsad", window, layout=layout)
    lz, rz = left - box_mean(left, window), right - box_mean(right, window)
    return sweep_cost_volume(lz, rz, max_disp, _abs_diff, _box(window), memory_budget=memory_budget)


def lssad_cost_volume(left: torch.Tensor, right: torch.Tensor, max_disp: int, window: int = 5, *,
                      memory_budget: int = DEFAULT_MEMORY_BUDGET,
                      backend: str = "auto", layout: str = "hwd") -> torch.Tensor:
    """SAD of locally scaled images ``I / (box_mean(I, window) + 1/255)`` (see module doc). -> (B, D, H, W)."""
    left, right, max_disp, window = _prepare(left, right, max_disp, window, layout)
    if use_numba(left, right, backend=backend):
        return numba_cost_volume(left, right, max_disp, "lssad", window, layout=layout)
    ls = left / (box_mean(left, window) + LSSAD_EPS)
    rs = right / (box_mean(right, window) + LSSAD_EPS)
    return sweep_cost_volume(ls, rs, max_disp, _abs_diff, _box(window), memory_budget=memory_budget)


def ncc_cost_volume(left: torch.Tensor, right: torch.Tensor, max_disp: int, window: int = 5, *,
                    memory_budget: int = DEFAULT_MEMORY_BUDGET,
                    backend: str = "auto", layout: str = "hwd") -> torch.Tensor:
    """``1 - NCC`` over the window on grey images; zero variance -> NCC := 0 (cost 1). -> (B, D, H, W) in [0, 2]."""
    left, right, max_disp, window = _prepare(left, right, max_disp, window, layout)
    if use_numba(left, right, backend=backend):
        return numba_cost_volume(left, right, max_disp, "ncc", window, layout=layout)
    if window < 3:
        raise StereoInputError(f"window: NCC needs a window of at least 3, got {window}")
    gl, gr = to_grey(left), to_grey(right)
    mu_l, mu_r = box_mean(gl, window), box_mean(gr, window)
    var_l = (box_mean(gl * gl, window) - mu_l * mu_l).clamp(min=0)
    var_r = (box_mean(gr * gr, window) - mu_r * mu_r).clamp(min=0)

    def finalize(e_lr: torch.Tensor, d0: int, d1: int) -> torch.Tensor:
        mr = shifted_stack(mu_r, d0, d1)[:, 0]  # BxDcxHxW
        vr = shifted_stack(var_r, d0, d1)[:, 0]
        cov = e_lr - mu_l * mr
        ok = (var_l > NCC_MIN_VARIANCE) & (vr > NCC_MIN_VARIANCE)
        denom = torch.sqrt(torch.where(ok, var_l * vr, torch.ones_like(vr)))
        ncc = torch.where(ok, cov / denom, torch.zeros_like(cov)).clamp(-1.0, 1.0)
        return 1.0 - ncc

    def product(lf: torch.Tensor, rs: torch.Tensor) -> torch.Tensor:
        return (lf * rs)[:, 0]

    return sweep_cost_volume(gl, gr, max_disp, product, _box(window), finalize, memory_budget=memory_budget)


def _hamming_stack(lf: torch.Tensor, rs: torch.Tensor) -> torch.Tensor:
    return popcount(lf ^ rs).sum(1)


def census_cost_volume(left: torch.Tensor, right: torch.Tensor, max_disp: int, window: int = 1, *,
                       census_window: int = 5, memory_budget: int = DEFAULT_MEMORY_BUDGET,
                       backend: str = "auto", layout: str = "hwd") -> torch.Tensor:
    """Hamming distance of census codes, box-averaged over ``window``. -> (B, D, H, W) in bits."""
    left, right, max_disp, window = _prepare(left, right, max_disp, window, layout)
    if use_numba(left, right, backend=backend):
        return numba_cost_volume(left, right, max_disp, "census", window, census_window=census_window,
                                 layout=layout)
    cl, cr = census_transform(left, census_window), census_transform(right, census_window)

    def pixel(lf: torch.Tensor, rs: torch.Tensor) -> torch.Tensor:
        return _hamming_stack(lf, rs).to(left.dtype)

    return sweep_cost_volume(cl, cr, max_disp, pixel, _box(window), memory_budget=memory_budget,
                             out_dtype=left.dtype)


def census_ad_cost_volume(left: torch.Tensor, right: torch.Tensor, max_disp: int, window: int = 1, *,
                          census_window: int = 5, lambda_census: float = 30.0, lambda_ad: float = 10.0 / 255.0,
                          memory_budget: int = DEFAULT_MEMORY_BUDGET,
                          backend: str = "auto", layout: str = "hwd") -> torch.Tensor:
    """AD-Census ``2 - exp(-hamming/lambda_census) - exp(-ad/lambda_ad)``. -> (B, D, H, W) in [0, 2)."""
    left, right, max_disp, window = _prepare(left, right, max_disp, window, layout)
    if use_numba(left, right, backend=backend):
        return numba_cost_volume(left, right, max_disp, "census_ad", window, census_window=census_window,
                                 lambda_census=lambda_census, lambda_ad=lambda_ad, layout=layout)
    cl, cr = census_transform(left, census_window), census_transform(right, census_window)

    def pixel(lf: torch.Tensor, rs: torch.Tensor) -> torch.Tensor:
        return _hamming_stack(lf, rs).to(left.dtype)

    census = sweep_cost_volume(cl, cr, max_disp, pixel, None, memory_budget=memory_budget, out_dtype=left.dtype,
                               invalid="none")
    ad = sweep_cost_volume(left, right, max_disp, _abs_diff, None, memory_budget=memory_budget, invalid="none")
    vol = 2.0 - torch.exp(-census / lambda_census) - torch.exp(-ad / lambda_ad)
    del census, ad
    return fill_out_of_image(box_mean(vol, window) if window > 1 else vol)


def adaptive_cost_volume(left: torch.Tensor, right: torch.Tensor, max_disp: int, window: int = 5, *,
                         base: str = "sad", mode: str = "multiwindow",
                         memory_budget: int = DEFAULT_MEMORY_BUDGET,
                         backend: str = "auto", layout: str = "hwd") -> torch.Tensor:
    """Adaptive-window aggregation of a pixelwise ``base`` cost (``"sad"`` or ``"ssd"``).

    ``mode="multiwindow"`` (Hirschmüller et al. 2002, five windows): the mean over the centre window plus
    the two best of the four ``window``-sized windows centred on the corners of the centre window, divided
    by 3. ``mode="shiftable"``: the best of all ``window``-sized windows that contain the pixel (min filter
    of the box mean). Both adapt to depth edges (a window can avoid the other side of the edge).

    Returns:
        :math:`(B, D, H, W)` mean costs.
    """
    left, right, max_disp, window = _prepare(left, right, max_disp, window, layout)
    if use_numba(left, right, backend=backend):
        return numba_cost_volume(left, right, max_disp, "adaptive", window, mode=mode, base=base, layout=layout)
    pixel = {"sad": _abs_diff, "ssd": _sq_diff}.get(base)
    if pixel is None:
        raise StereoInputError(f"base: expected 'sad' or 'ssd', got {base!r}")
    if mode == "shiftable":
        def aggregate(v: torch.Tensor) -> torch.Tensor:
            return min_filter(box_mean(v, window), window)
    elif mode == "multiwindow":
        r = window // 2

        def aggregate(v: torch.Tensor) -> torch.Tensor:
            agg = box_mean(v, window)
            padded = torch.nn.functional.pad(agg, (r, r, r, r), mode="replicate")
            h, w = agg.shape[-2:]
            corners = torch.stack([padded[..., oy:oy + h, ox:ox + w] for oy in (0, 2 * r) for ox in (0, 2 * r)])
            best2 = corners.topk(2, dim=0, largest=False).values.sum(0)
            return (agg + best2) / 3.0
    else:
        raise StereoInputError(f"mode: expected 'multiwindow' or 'shiftable', got {mode!r}")
    # the multiwindow temporaries are ~6x a chunk: shrink the budget accordingly
    return sweep_cost_volume(left, right, max_disp, pixel, aggregate, memory_budget=memory_budget // 3)


def build_cost_volume(left: torch.Tensor, right: torch.Tensor, max_disp: int, cost: str = "sad",
                      window: int = 5, **options) -> torch.Tensor:
    """Cost volume of ``cost`` (one of :data:`COSTS` or ``"adaptive"``), see the module doc.

    Args:
        left, right: :math:`(B, C, H, W)` float images in [0, 1], same shape, C = 1 or 3.
        max_disp: ``0 < max_disp < W``; the volume has ``D = max_disp + 1`` disparities 0..max_disp.
        cost: cost name.
        window: odd aggregation window (ignored by ``"ad"``).
        **options: per-cost keywords (``census_window``, ``memory_budget``, ``mode``/``base`` for adaptive,
            ``layout``: the numba volume's memory order, :data:`LAYOUTS`,
            ``backend``: ``"auto"`` (default: the numba kernels for float32 CPU input that needs no gradient,
            else torch), ``"torch"`` (chunked to ``memory_budget``, differentiable) or ``"numba"``).

    Returns:
        :math:`(B, D, H, W)` costs, lower = better, same dtype/device as ``left``.
    """
    builders = {"sad": sad_cost_volume, "ssd": ssd_cost_volume, "zsad": zsad_cost_volume,
                "lssad": lssad_cost_volume, "ncc": ncc_cost_volume, "census": census_cost_volume,
                "census_ad": census_ad_cost_volume, "adaptive": adaptive_cost_volume}
    if cost == "ad":
        return ad_cost_volume(left, right, max_disp, **options)
    if cost not in builders:
        raise StereoInputError(f"cost: expected one of {', '.join(COSTS + ('adaptive',))}, got {cost!r}")
    return builders[cost](left, right, max_disp, window, **options)


def correlation_similarity(feat_left: torch.Tensor, feat_right: torch.Tensor, max_disp: int) -> torch.Tensor:
    """Correlation *similarity* volume (higher = better) for learned features.

    ``sim[b, d, y, x] = mean_c feat_left[b, c, y, x] * feat_right[b, c, y, x - d]`` (the channel-normalised
    dot product of DispNet-C / GwcNet); 0 where ``x - d < 0``. Differentiable.

    Args:
        feat_left, feat_right: :math:`(B, C, H, W)` float features, any C.
        max_disp: ``0 < max_disp < W``.

    Returns:
        :math:`(B, D, H, W)`, ``D = max_disp + 1``.
    """
    if not isinstance(feat_left, torch.Tensor) or not isinstance(feat_right, torch.Tensor):
        raise TypeError("feat_left/feat_right: expected torch.Tensor features of shape (B, C, H, W)")
    check_image(feat_left, "feat_left", channels=(feat_left.shape[1],) if feat_left.dim() == 4 else (1,))
    check_image(feat_right, "feat_right", channels=(feat_left.shape[1],))
    if feat_left.shape != feat_right.shape:
        raise StereoInputError(f"feat_right: expected shape {tuple(feat_left.shape)}, got {tuple(feat_right.shape)}")
    max_disp = check_max_disp(max_disp, feat_left.shape[-1])
    return correlation_1d(feat_left, feat_right, max_disp)  # the one correlation (stereonet.cost.correlation)
