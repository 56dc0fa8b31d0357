"""Local matchers (``bm-*``) and semi-global matching (``sgm``) behind the matcher signature.

Pipeline of every ``bm-*`` method (textbook block matching):
cost volume (window mean of the cost) -> WTA -> sub-pixel (parabola) -> uniqueness ratio -> left-right
check of the integer WTA against the right-reference WTA of the same volume (``|dL - dR| <= disp12_max_diff``); invalid pixels are
left invalid (``fill=False``; eval.py has ``--fill``). ``sgm`` adds semi-global aggregation of a census
(or AD-census) cost before the selection, and a median + speckle filter after it.

Speed: on the CPU (float32, no gradient) ``bm-*`` never builds the volume: one fused numba pass per image
slides the window sums along the rows and selects on each finished cost row
(:func:`~stereonet.select.wta.block_select_disparity`, tested equal to the volume path), so the output has
``cost_volume=None`` unless ``keep_volume=True``. Inputs are checked once, by the matcher registry.
``sgm`` on the CPU (float32, no gradient, pixelwise census) computes the census volume as uint8
(:func:`~stereonet.cost.volume.census_pixel_volumes_u8`) straight into the numba aggregation in 16-bit fixed
point (:func:`~stereonet.aggregate.sgm.sgm_aggregate_fixed_hwd`), and selects with the cost-margin confidence
in one pass from the int16 aggregate (:func:`~stereonet.select.wta.select_disparity_confidence_fixed`):
the same numbers as the documented composition of public functions (tested equal).

``sgm`` defaults: :data:`SGM_DEFAULTS`, chosen on the six real pairs of ../shared/data against opencv-sgbm
with ``scripts/bench_classical.py``. Candidates tried (bad-2 %, all pixels, filled; tsukuba / venus / cones /
teddy / kitti2012 / kitti2015): census 5x5, P1=1, P2=8 constant: 4.78 / 1.18 / 7.26 / 8.00 / 10.60 / 15.22
(loses KITTI 2012 to SGBM's 8.04); AD-census was worse on KITTI (14-19 %); census 7x7 with P1=2, P2=48 and
the edge-adapted P2 (alpha 20): 3.93 / 1.06 / 7.51 / 7.49 / 7.71 / 13.31 with the LR check on sub-pixel
disparities, 3.74 / 1.65 / 7.42 / 7.40 / 7.59 / 14.26 with it on the integer WTA (the default: denser, 86 %
instead of 83 % on Cones), both below SGBM (4.76 / 2.20 / 11.91 / 18.92 / 8.04 / 21.73) on every pair;
16 paths gave no consistent gain for twice the time.
"""

from __future__ import annotations

import numpy as np
import torch

from stereonet.aggregate.sgm import (
    CENSUS_PENALTY_STEP,
    check_sgm_options,
    fixed_point_scale_for,
    p2_maps_array,
    quantize_penalty,
    sgm_aggregate,
    sgm_aggregate_fixed_hwd,
    sgm_aggregate_hwd,
    sgm_directions,
)
from stereonet.checks import StereoInputError, check_number, check_window
from stereonet.cost import build_cost_volume
from stereonet.cost.prefilter import prefilter_image
from stereonet.cost.volume import (
    CENSUS_U8_MAX_WINDOW,
    census_pixel_volumes_u8,
)
from stereonet.kernels import use_numba
from stereonet.matchers import register
from stereonet.select.fill import fill_occlusions
from stereonet.select.filters import (
    WMF_SIGMA_COLOR,
    WMF_STRIDE,
    check_wmf_options,
    filled_weighted_median,
    median_filter,
    speckle_filter,
)
from stereonet.select.wta import (
    block_select_disparity,
    select_disparity,
    select_disparity_confidence,
    select_disparity_confidence_fixed,
)
from stereonet.types import StereoOutput

# The matcher options use OpenCV's names and meanings where cv2.StereoBM / cv2.StereoSGBM have the knob
# (opencv-bm and opencv-sgbm take the same names): name -> (the back end's argument, conversion).
OPENCV_OPTIONS = {
    "block_size": ("window", lambda v: check_window(v, "block_size")),  # bm-*: the matching window; sgm: the
    # cost's box window before the aggregation
    "uniqueness_ratio": ("uniqueness", lambda v: check_number(v, "uniqueness_ratio") / 100.0),  # percent margin
    "disp12_max_diff": ("lr_tol", lambda v: None if v is None or check_number(v, "disp12_max_diff", None) < 0
                        else float(v)),  # px; < 0 / None: off
    "speckle_window": ("speckle_size", lambda v: int(check_number(v, "speckle_window"))),  # largest removed, px
    "speckle_range": ("speckle_diff", lambda v: check_number(v, "speckle_range")),  # largest step in one region, px
}
_OPENCV_NAME = {inner: outer for outer, (inner, _) in OPENCV_OPTIONS.items()}


def from_opencv_names(options: dict) -> dict:
    """Matcher options (OpenCV's vocabulary) -> the back end's arguments; the back end's own names for
    those knobs are refused with one line naming the option to use."""
    out = {}
    for key, value in options.items():
        if key in _OPENCV_NAME:
            raise StereoInputError(f"{key}: this option is called {_OPENCV_NAME[key]} (OpenCV's name and unit)")
        inner, convert = OPENCV_OPTIONS.get(key, (key, None))
        out[inner] = convert(value) if convert is not None else value
    return out


BM_DEFAULTS = dict(subpixel="parabola", uniqueness_ratio=10, disp12_max_diff=1, median=0, speckle_window=0,
                   speckle_range=1, fill=False)
_BACK_END = from_opencv_names(BM_DEFAULTS)  # the same defaults in the back end's argument names

# Chosen on the six real pairs of ../shared/data (bad-2 after the textbook fill, see the module doc):
# census 7x7 (48 bits, pixelwise), P1 = 2 and P2 = 48 Hamming bits with P2 lowered across intensity edges
# (P2 / (1 + 20 |dI|), dI in [0, 1], never below P1), 8 paths, parabola, uniqueness 5 %, LR tolerance 1 px,
# 3x3 median over valid pixels, speckles < 100 px (steps <= 1 px) removed.
# A cost mixed into sgm's census (``extra_cost``, siamese-census-sgm) is rounded to this grid (bits) in every
# backend, so that the CPU aggregates it in 16-bit fixed point like plain census (quarter bits: 4 * 49 < 256)
MIX_STEP = 0.25

SGM_DEFAULTS = dict(cost="census", census_window=7, block_size=1, P1=2.0, P2=48.0, p2_alpha=20.0, paths=8,
                    subpixel="parabola", uniqueness_ratio=5, disp12_max_diff=1, median=3, speckle_window=100,
                    speckle_range=1, fill=False)


def select_and_filter(cost: torch.Tensor, *, subpixel: str | None = "parabola", uniqueness: float = 0.1,
                      lr_tol: float | None = 1.0, median: int = 0, speckle_size: int = 0,
                      speckle_diff: float = 1.0, fill: bool = False) -> StereoOutput:
    """The local back end shared by ``bm-*`` and ``sgm``.

    Args:
        cost: :math:`(B, D, H, W)` (aggregated) costs.
        subpixel: ``"parabola"``, ``"equiangular"`` or None.
        uniqueness: uniqueness ratio (0 = off).
        lr_tol: LR-check tolerance in pixels (None = no LR check).
        median: median filter size on the disparity (0 = off), over valid pixels only.
        speckle_size: speckle filter region size (0 = off), regions with steps <= ``speckle_diff``.
        fill: fill invalid pixels with :func:`~stereonet.select.fill.fill_occlusions` (they stay invalid);
            otherwise invalid pixels keep their raw WTA disparity.

    Returns:
        :class:`StereoOutput` with ``cost_volume=cost`` and extras ``disparity_right`` (right-reference
        WTA), ``lr_valid`` and ``unique`` (bool masks).
    """
    selection = select_disparity(cost, subpixel, uniqueness, lr_tol)
    return _filter(selection, cost, median=median, speckle_size=speckle_size, speckle_diff=speckle_diff, fill=fill)


def _filter(selection: tuple, cost: torch.Tensor | None, *, median: int, speckle_size: int, speckle_diff: float,
            fill: bool) -> StereoOutput:
    """Post-filters of :func:`select_and_filter` on a ``(disp, min_cost, unique, disp_right, lr_ok)`` tuple."""
    disp, _, unique, disp_right, lr_ok = selection
    valid = unique & lr_ok
    if median:
        disp = median_filter(disp, median, valid)
    if speckle_size:
        valid = speckle_filter(disp, valid, speckle_size, speckle_diff)
    if fill:
        disp = fill_occlusions(disp, valid)
    return StereoOutput(disp, valid, cost_volume=cost,
                        extras={"disparity_right": disp_right, "lr_valid": lr_ok, "unique": unique})


def _split(options: dict, defaults: dict) -> tuple[dict, dict]:
    merged = {**defaults, **options}
    back = {k: merged.pop(k) for k in list(merged) if k in _BACK_END}
    return merged, back


def block_matching(left: torch.Tensor, right: torch.Tensor, max_disp: int, cost: str, window: int, *,
                   keep_volume: bool = False, **options) -> StereoOutput:
    """Block matching with ``cost`` over ``window`` + the local back end (:func:`select_and_filter`).

    Inputs must be checked already (the matcher registry does), and ``options`` must hold every back-end
    option (the registered ``bm-*`` merge :data:`BM_DEFAULTS` first). For float32 CPU input without gradient
    and ``keep_volume=False`` the volume is never built: :func:`~stereonet.select.wta.block_select_disparity`
    fuses cost, window sums and selection in one numba pass (same disparities as the volume path) and
    the output has ``cost_volume=None``; ``keep_volume=True`` (or a torch backend) builds the volume and
    returns it as ``cost_volume``.
    """
    cost_opts, back = _split(options, {})  # the registered bm-* merged BM_DEFAULTS already
    if not keep_volume and use_numba(left, right, backend=cost_opts.get("backend", "auto")):
        selection = block_select_disparity(left, right, max_disp, cost, window, back.pop("subpixel"),
                                           back.pop("uniqueness"), back.pop("lr_tol"), **cost_opts)
        return _filter(selection, None, **back)
    vol = build_cost_volume(left, right, max_disp, cost=cost, window=window, **cost_opts)
    return select_and_filter(vol, **back)


def _bm(name: str, cost: str, window: int, description: str, **fixed):
    @register(name, kind="classical", description=description)
    def run(left: torch.Tensor, right: torch.Tensor, max_disp: int, **options) -> StereoOutput:
        opts = from_opencv_names({**BM_DEFAULTS, "block_size": window, **fixed, **options})
        return block_matching(left, right, max_disp, cost, opts.pop("window"), **opts)

    run.__name__ = name.replace("-", "_")
    run.__doc__ = (f"{description}. Options (OpenCV's names and units, :data:`OPENCV_OPTIONS`): block_size, "
                   "subpixel, uniqueness_ratio (%), disp12_max_diff (px, < 0 = off), median, speckle_window, "
                   "speckle_range, fill, keep_volume (return the cost volume; slower).")
    return run


bm_sad = _bm("bm-sad", "sad", 9, "Block matching, SAD 9x9 + WTA, parabola, uniqueness, LR check")
bm_ssd = _bm("bm-ssd", "ssd", 9, "Block matching, SSD 9x9 + WTA, parabola, uniqueness, LR check")
bm_zsad = _bm("bm-zsad", "zsad", 9, "Block matching, zero-mean SAD 9x9 + WTA, parabola, uniqueness, LR check")
bm_lssad = _bm("bm-lssad", "lssad", 9, "Block matching, locally scaled SAD 9x9 + WTA, parabola, uniqueness, LR")
bm_ncc = _bm("bm-ncc", "ncc", 9, "Block matching, 1 - NCC 9x9 + WTA, parabola, uniqueness, LR check")
bm_census = _bm("bm-census", "census", 5, "Block matching, census 7x7 Hamming averaged 5x5 + WTA, LR check",
                census_window=7)
bm_adaptive = _bm("bm-adaptive", "adaptive", 7,
                  "Block matching, SAD over 5 shiftable 7x7 windows (centre + best 2 corners), LR check")


def _hwd(other: torch.Tensor, i: int) -> np.ndarray:
    """Item ``i`` of a (B, D, H, W) volume as a contiguous float32 (H, W, D) array (no copy for a view of a
    (B, H, W, D) buffer, as the numba Siamese cost returns)."""
    return np.ascontiguousarray(other[i].detach().to("cpu", torch.float32).permute(1, 2, 0).numpy())


def _mixed_hwd(own: list[np.ndarray], w_own: float, w_extra: float, other: torch.Tensor,
               mix_step: float | None = None):
    """``w_own * own[i] + w_extra * other[i]`` per image as (H, W, D) float32 (``other``: (B, D, H, W)), one
    image at a time (a generator, as :func:`~stereonet.aggregate.sgm.sgm_aggregate_hwd` consumes it); rounded
    to the ``mix_step`` grid unless it is None (the torch expression's numbers either way)."""
    from stereonet.kernels.cost import mix_costs_hwd

    for i, vol in enumerate(own):
        out = mix_costs_hwd(vol, _hwd(other, i), np.float32(w_own), np.float32(w_extra))
        if mix_step is not None:
            q = np.float32(1.0 / mix_step)
            out = np.multiply(np.rint(np.multiply(out, q, out=out), out=out), np.float32(mix_step), out=out)
        yield out


def _mixed_u8_hwd(own: list[np.ndarray], w_own: float, w_extra: float, other: torch.Tensor,
                  q: float) -> list[np.ndarray] | None:
    """``rint(q * (w_own * own[i] + w_extra * other[i]))`` per image as uint8 (H, W, D) (the mixed cost in
    units of ``1 / q``), or None when a value falls outside 0..255 (then the float32 kernel runs)."""
    from stereonet.kernels.cost import mix_costs_u8_hwd

    out = []
    for i, vol in enumerate(own):
        mixed, fits = mix_costs_u8_hwd(vol, _hwd(other, i), np.float32(w_own), np.float32(w_extra), np.float32(q))
        if not fits:
            return None
        out.append(mixed)
    return out


def _fixed_output(selection, confidence: torch.Tensor, accs: list[np.ndarray], scale: int, fixed_volume: bool,
                  back: dict) -> StereoOutput:
    """``sgm``'s output from the 16-bit path: the filters of the back end, the confidence 0 where they rejected, and
    with ``fixed_volume`` the int16 aggregate in ``extras["aggregate_fixed"]`` (a (B, D, H, W) view of the kernel's
    (H, W, D) arrays, no copy for one item) in units of ``1 / extras["aggregate_scale"]`` cost units."""
    fixed = None
    if fixed_volume:
        fixed = (torch.from_numpy(accs[0])[None] if len(accs) == 1
                 else torch.stack([torch.from_numpy(a) for a in accs])).permute(0, 3, 1, 2)
    del accs
    out = _filter(selection, None, **back)
    out.confidence = confidence * out.valid.to(confidence.dtype)
    if fixed is not None:
        out.extras.update(aggregate_fixed=fixed, aggregate_scale=torch.tensor(scale))
    return out


def _given_p2_maps(maps, left: torch.Tensor, P1: float, P2: float, paths: int,
                   step: float | None) -> tuple[torch.Tensor, float]:
    """Checked ``p2_maps`` on the penalty grid, and the largest penalty (``P2`` or above) for the 16-bit check."""
    b, _, h, w = left.shape
    if not isinstance(maps, torch.Tensor) or tuple(maps.shape) != (b, len(sgm_directions(paths)), h, w):
        shape = tuple(maps.shape) if isinstance(maps, torch.Tensor) else type(maps).__name__
        raise StereoInputError(f"p2_maps: expected a tensor (B, paths, H, W) = ({b}, {paths}, {h}, {w}), got {shape}")
    maps = quantize_penalty(maps.detach().to(left.device, torch.float32), step)
    if not bool(torch.isfinite(maps).all()) or bool((maps < P1).any()):
        raise StereoInputError(f"p2_maps: expected finite penalties >= P1 ({P1})")
    return maps, max(float(P2), float(maps.max()))


@register("sgm", kind="classical",
          description="Semi-global matching: census 7x7, 8 paths, edge-adapted P2, parabola, LR, median, speckle")
def sgm(left: torch.Tensor, right: torch.Tensor, max_disp: int, wmf_radius: int = 0,
        wmf_sigma_color: float = WMF_SIGMA_COLOR, wmf_stride: int = WMF_STRIDE, **options) -> StereoOutput:
    """Semi-global matching (Hirschmüller 2008); see :func:`sgm_core` for the options. ``wmf_radius`` > 0 (off by
    default): the map is then filled by eval.py's rule (:func:`~stereonet.select.fill.fill_occlusions`) and
    filtered by the image-guided weighted median (:func:`~stereonet.select.filters.weighted_median_filter`, that
    radius, ``wmf_sigma_color``, votes every ``wmf_stride`` px capped at the radius), every pixel valid,
    ``extras["lr_consistent"]`` the validity before the fill: ``sgm-refine``'s last step on the classical map
    (model card, thirty-second and thirty-third sessions: radius 9, 0.2, stride 2 took the real pairs' median
    bad-2 from 7.4 to 6.2)."""
    check_wmf_options(wmf_radius, wmf_sigma_color, wmf_stride)
    out = sgm_core(left, right, max_disp, **options)
    if not wmf_radius:
        return out
    disp = filled_weighted_median(out.disparity, out.valid, left, wmf_radius, wmf_sigma_color, wmf_stride)
    return StereoOutput(disp, torch.ones_like(out.valid), confidence=out.confidence, cost_volume=out.cost_volume,
                        extras={**out.extras, "lr_consistent": out.valid})


def sgm_core(left: torch.Tensor, right: torch.Tensor, max_disp: int, **options) -> StereoOutput:
    """Semi-global matching (Hirschmüller 2008) on a census (default) or any ``cost`` volume.

    Options (defaults in :data:`SGM_DEFAULTS`; OpenCV's names and units where StereoSGBM has the knob,
    :data:`OPENCV_OPTIONS`): ``cost``, ``census_window``, ``block_size`` (box window of the cost before the
    aggregation, 1 = pixelwise), ``P1``, ``P2`` (in cost units: Hamming bits for census), ``p2_alpha`` (P2
    adaptation to the left image gradient), ``paths`` (4/8/16), then the back end of :func:`select_and_filter`:
    ``subpixel``, ``uniqueness_ratio`` (%), ``disp12_max_diff`` (px, < 0 = no LR check), ``median``,
    ``speckle_window``, ``speckle_range``, ``fill``, ``keep_volume``. ``confidence`` is the aggregated cost's
    margin (:func:`~stereonet.select.confidence.cost_margin_confidence`), 0 on invalid pixels. The returned
    ``cost_volume`` is the aggregated cost, except on the CPU fast path (16-bit fixed point, below) without
    ``keep_volume=True``, where the float32 volume is never built (``cost_volume=None``, as for ``bm-*``).
    ``keep_volume="fixed"``: on that path (census alone or with a mixed-in cost), the int16 aggregate itself in
    ``extras["aggregate_fixed"]`` (a (B, D, H, W) view of the kernel's (H, W, D) arrays, in units of
    ``1 / extras["aggregate_scale"]``; what ``graphcut``'s census proposals rank and ``sgm-refine``'s cross costs
    read, without the float32 copy), elsewhere the float32 ``cost_volume``.

    Census costs are integers, so ``P1`` and the edge-adapted ``P2`` are rounded to multiples of
    :data:`~stereonet.aggregate.sgm.CENSUS_PENALTY_STEP` (1/16 bit) in every backend; the CPU fast path then
    aggregates in int16 (exact, OpenCV's SGBM also aggregates in 16 bits) and selects from it directly.
    ``extra_cost=(w_own, w_extra, V)`` mixes a volume ``V`` (B, D, H, W) into the cost (``w_own * cost +
    w_extra * V``; siamese-census-sgm on census). With census the mix is rounded to ``mix_step`` bits
    (:data:`MIX_STEP`, a power of two; None = unrounded, float32 kernel) in every backend, which lets the CPU
    run the same 16-bit path on it (uint8 in units of ``mix_step``; a mix outside 0..255 units falls back to
    the float32 kernel, same numbers); other costs are mixed unrounded. ``p2_maps`` (B, paths, H, W): large-jump
    penalties per pixel and path direction instead of ``P2`` and its image rule (``sgm-penalties``' learned maps;
    rounded to the penalty grid, each at least ``P1``). ``prefilter`` (None, "vertical" or "binomial"): the images
    the cost reads are smoothed first (:func:`~stereonet.cost.prefilter.prefilter_image`; against sensor noise and
    sub-pixel vertical offsets); the penalties' image rule reads the left image unfiltered.
    """
    opts = from_opencv_names({**SGM_DEFAULTS, **options})
    P1, P2, p2_alpha, paths = opts.pop("P1"), opts.pop("P2"), opts.pop("p2_alpha"), opts.pop("paths")
    prefilter = opts.pop("prefilter", None)
    # the cost reads the pre-filtered images; the penalties' image rule (p2_alpha) reads the left image as it is
    cost_left, cost_right = prefilter_image(left, prefilter), prefilter_image(right, prefilter)
    keep_volume = opts.pop("keep_volume", False)
    fixed_volume = isinstance(keep_volume, str) and keep_volume == "fixed"
    if isinstance(keep_volume, str) and not fixed_volume:
        raise StereoInputError(f"keep_volume: expected a bool or 'fixed', got {keep_volume!r}")
    keep_volume = bool(keep_volume) and not fixed_volume
    cost_opts, back = _split(opts, {})
    cost_name, window = cost_opts.pop("cost"), cost_opts.pop("window")
    if cost_name not in ("census", "census_ad"):
        cost_opts.pop("census_window", None)
    # the registry validated left/right: no second check of the images
    extra = cost_opts.pop("extra_cost", None)
    mix_step = cost_opts.pop("mix_step", MIX_STEP)
    maps = cost_opts.pop("p2_maps", None)
    from stereonet.kernels.sgm import grid_scale  # (numba loads with the first kernel, not with the package)

    if mix_step is not None and (not isinstance(mix_step, (int, float)) or isinstance(mix_step, bool)
                                 or not 0 < mix_step <= 1 or grid_scale(float(mix_step)) is None):
        raise StereoInputError(f"mix_step: expected None or 1 / 2^k (1, 0.5, 0.25, ...), got {mix_step!r}")
    if cost_name != "census":
        mix_step = None  # a grid in Hamming bits: other costs (not integers) are mixed unrounded
    census_window = cost_opts.get("census_window", 5)
    # census costs are integers (Hamming bits): penalties on a 1/16-bit grid make the recurrence exact in
    # 16-bit fixed point (the same result in every backend; aggregate.sgm module doc). A mixed-in cost is in
    # the same units and gets the same penalties (float32 kernel), so its weight 0 is plain sgm.
    step = CENSUS_PENALTY_STEP if cost_name == "census" else None
    if maps is not None:  # given large-jump penalties (sgm-penalties' learned maps) instead of P2's image rule
        maps, P2 = _given_p2_maps(maps, left, P1, P2, paths, step)
    if (cost_name == "census" and window == 1 and set(cost_opts) <= {"census_window", "backend"}
            and isinstance(census_window, int) and 3 <= census_window <= CENSUS_U8_MAX_WINDOW
            and use_numba(left, right, backend=cost_opts.get("backend", "auto"))):
        # CPU fast path, the same numbers: the pixelwise census volume as (H, W, D) uint8 straight into the
        # numba aggregation (a quarter of the memory traffic of the float32 volume; tested equal); a mixed-in
        # volume is added by one numba pass per image (mix_costs_hwd, the float32 sum of the torch path)
        directions = check_sgm_options(P1, P2, paths, p2_alpha)
        vols = census_pixel_volumes_u8(cost_left, cost_right, max_disp, census_window)
        bits = census_window * census_window  # >= every census distance and the out-of-image fill
        s = None if extra is not None or keep_volume else fixed_point_scale_for(P1, P2, directions, step, bits)
        if extra is not None and mix_step is not None and not keep_volume:
            # the mixed cost on the mix_step grid as uint8 in units of mix_step: the same 16-bit path with the
            # penalties in those units (exact scalings by a power of two), selected in cost units again
            q = 1.0 / mix_step
            mixed = _mixed_u8_hwd(vols, *extra, q)
            if mixed is not None:
                sq = fixed_point_scale_for(P1 * q, P2 * q, directions, step * q, 255)
                if sq is not None:
                    del vols
                    accs = [sgm_aggregate_fixed_hwd(v, P1 * q, P2 * q, directions, left[i], p2_alpha, step * q, sq,
                                                    None if maps is None else p2_maps_array(maps * q, i))
                            for i, v in enumerate(mixed)]
                    del mixed
                    selection, confidence = select_disparity_confidence_fixed(
                        accs, int(sq * q), back.pop("subpixel"), back.pop("uniqueness"), back.pop("lr_tol"),
                        left.dtype, left.device)
                    return _fixed_output(selection, confidence, accs, int(sq * q), fixed_volume, back)
        if s is not None:
            # 16-bit fixed point: select straight from the int16 aggregate (no float32 volume)
            accs = [sgm_aggregate_fixed_hwd(v, P1, P2, directions, left[i], p2_alpha, step, s,
                                            None if maps is None else p2_maps_array(maps, i))
                    for i, v in enumerate(vols)]
            del vols
            selection, confidence = select_disparity_confidence_fixed(
                accs, s, back.pop("subpixel"), back.pop("uniqueness"), back.pop("lr_tol"), left.dtype, left.device)
            return _fixed_output(selection, confidence, accs, s, fixed_volume, back)
        if extra is not None:
            vols = _mixed_hwd(vols, *extra, mix_step)
        agg = sgm_aggregate_hwd(vols, P1, P2, directions, left, p2_alpha, step, p2_maps=maps).to(left.device)
        del vols
    else:
        vol = build_cost_volume(cost_left, cost_right, max_disp, cost=cost_name, window=window, **cost_opts)
        if extra is not None:  # (w_own, w_extra, volume): a learned cost mixed in (siamese-census-sgm)
            w_own, w_extra, other = extra
            vol = w_own * vol + w_extra * other.to(vol)
            if mix_step is not None:  # on the mix_step grid, as the CPU's 16-bit path
                vol = torch.round(vol * (1.0 / mix_step)) * mix_step
        agg = sgm_aggregate(vol, P1, P2, paths=paths, image=left, p2_alpha=p2_alpha, penalty_step=step, p2_maps=maps)
        del vol
    # selection and the cost margin of the aggregated cost in one pass over it (select_and_filter +
    # cost_margin_confidence, the same numbers); confidence 0 where LR / uniqueness / speckles rejected
    selection, confidence = select_disparity_confidence(agg, back.pop("subpixel"), back.pop("uniqueness"),
                                                        back.pop("lr_tol"))
    out = _filter(selection, agg, **back)
    out.confidence = confidence * out.valid.to(agg.dtype)
    return out
