"""Semi-global matching (Hirschmüller, PAMI 2008): cost aggregation along 8 or 16 straight paths.

For a path direction ``r`` each path cost is the recurrence (pixel ``p``, predecessor ``p - r``)::

    L_r(p, d) = C(p, d) + min(L_r(p-r, d), L_r(p-r, d-1) + P1, L_r(p-r, d+1) + P1, m + P2(p, r)) - m,
    m = min_k L_r(p-r, k)

with ``L_r(p, d) = C(p, d)`` where ``p - r`` is outside the image. The aggregated cost is
``S(p, d) = sum_r L_r(p, d)`` (same shape as the cost volume, lower = better).

Directions ``r = (dx, dy)`` (the path walks ``+r``): 8 paths = the 4 axis and 4 diagonal directions;
16 paths add the 8 knight moves ``(±2, ±1), (±1, ±2)`` of the paper.

Gradient-adapted P2: with a guide ``image`` (grey, in [0, 1]) the penalty for large jumps becomes
``P2(p, r) = max(P1, P2 / (1 + p2_alpha * |I(p) - I(p - r)|))`` — smaller across intensity edges, where
depth discontinuities are likely (the paper's ``P2 / |ΔI|`` made bounded). ``image=None`` or
``p2_alpha=0`` keeps ``P2`` constant.

Two implementations with one result: :func:`sgm_aggregate_torch` (reference, vectorised along the axis
perpendicular to the walk, differentiable almost everywhere) and a parallel numba kernel
(:mod:`stereonet.kernels.sgm`, float32, rows/columns in parallel) chosen by ``backend="auto"``
for CPU tensors without gradient.

Penalties on a grid (``penalty_step``, optional): ``P1`` and every ``P2(p, r)`` rounded to the nearest
multiple of ``penalty_step`` (:func:`quantize_penalty`). With integer costs (census Hamming distances) and a
step ``1 / 2^k`` every path cost is then a multiple of the step, so the float recurrence is exact and the
numba backend can run it in 16-bit integers (OpenCV's SGBM does the same) with the identical result, twice the
SIMD lanes and half the memory traffic of float32. ``sgm`` on census costs uses :data:`CENSUS_PENALTY_STEP`.
"""

from __future__ import annotations

import numpy as np
import torch

from stereonet.checks import StereoInputError, check_cost_volume, check_image, check_shape
from stereonet.cost.census import grey_numpy, to_grey
from stereonet.kernels import use_numba

DIRECTIONS_8 = ((1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (-1, 1), (1, -1), (-1, -1))
DIRECTIONS_16 = DIRECTIONS_8 + ((2, 1), (-2, 1), (2, -1), (-2, -1), (1, 2), (-1, 2), (1, -2), (-1, -2))

# 1/16 of a Hamming bit: the edge-adapted P2 keeps its resolution (P2 = 48 varies in steps of ~0.1-3 bits
# across edges), while 8 paths x (48 + 48) x 16 = 12 288 fits int16 with room to spare.
CENSUS_PENALTY_STEP = 1.0 / 16.0


def quantize_penalty(x, step: float | None):
    """``x`` (float, numpy array or tensor) rounded to the nearest multiple of ``step`` (None: unchanged).

    Halves round to even (numpy/torch ``round``), the same in every backend."""
    if step is None:
        return x
    if isinstance(x, torch.Tensor):
        return torch.round(x / step) * step
    if isinstance(x, np.ndarray):
        return (np.round(x / np.float32(step)) * np.float32(step)).astype(x.dtype)
    return float(np.round(float(x) / step) * step)


def sgm_directions(paths: int) -> tuple[tuple[int, int], ...]:
    """The ``(dx, dy)`` walk directions for ``paths`` in {4, 8, 16} (4 = the axis directions)."""
    if paths == 4:
        return DIRECTIONS_8[:4]
    if paths == 8:
        return DIRECTIONS_8
    if paths == 16:
        return DIRECTIONS_16
    raise StereoInputError(f"paths: expected 4, 8 or 16, got {paths!r}")


def predecessor_slices(dx: int, dy: int, h: int, w: int) -> tuple[slice, slice, slice, slice]:
    """``(ys, xs, yp, xp)``: the rows/columns of the pixels of an ``h x w`` image that have a predecessor along the
    walk direction ``(dx, dy)`` (``[ys, xs]``), and those predecessors, ``(y - dy, x - dx)`` (``[yp, xp]``)."""
    ys, yp = slice(max(dy, 0), h + min(dy, 0)), slice(max(-dy, 0), h - max(dy, 0))
    xs, xp = slice(max(dx, 0), w + min(dx, 0)), slice(max(-dx, 0), w - max(dx, 0))
    return ys, xs, yp, xp


def p2_maps(P1: float, P2: float, directions, image: torch.Tensor | None, shape: tuple[int, int, int],
            p2_alpha: float, dtype: torch.dtype, device: torch.device,
            penalty_step: float | None = None) -> torch.Tensor:
    """Per-direction large-jump penalties :math:`(B, R, H, W)` (see module doc), on the ``penalty_step``
    grid when given (``P1`` and ``P2`` are expected already on it).

    Pixels without a predecessor keep ``P2`` (their value is not used).
    """
    b, h, w = shape
    out = torch.full((b, len(directions), h, w), float(P2), dtype=dtype, device=device)
    if image is None or p2_alpha == 0:
        return out
    grey = to_grey(image).to(dtype)[:, 0]  # BxHxW
    for i, (dx, dy) in enumerate(directions):
        ys, xs, yp, xp = predecessor_slices(dx, dy, h, w)
        grad = (grey[:, ys, xs] - grey[:, yp, xp]).abs()
        out[:, i, ys, xs] = quantize_penalty(torch.clamp(float(P2) / (1.0 + p2_alpha * grad), min=float(P1)),
                                             penalty_step)
    return out


def p2_maps_numpy(P1: float, P2: float, directions, grey: np.ndarray, p2_alpha: float,
                  penalty_step: float | None = None) -> np.ndarray:
    """:func:`p2_maps` for one grey image (H, W) float32 in numpy (the numba backend's input, no torch
    threading): the same float32 operations, (R, H, W) float32."""
    h, w = grey.shape
    out = np.full((len(directions), h, w), np.float32(P2), dtype=np.float32)
    if p2_alpha == 0:
        return out
    for i, (dx, dy) in enumerate(directions):
        ys, xs, yp, xp = predecessor_slices(dx, dy, h, w)
        grad = np.abs(grey[ys, xs] - grey[yp, xp])
        out[i, ys, xs] = quantize_penalty(
            np.maximum(np.float32(P2) / (np.float32(1.0) + np.float32(p2_alpha) * grad), np.float32(P1)), penalty_step)
    return out


def _path_step(c: torch.Tensor, prev: torch.Tensor, has_prev: torch.Tensor, P1: float,
               p2: torch.Tensor) -> torch.Tensor:
    """One recurrence step. c, prev: (B, D, N); has_prev: (N,) bool; p2: (B, 1, N) -> (B, D, N)."""
    m = prev.min(dim=1, keepdim=True).values
    inf = torch.full_like(prev[:, :1], float("inf"))
    lower = torch.cat([inf, prev[:, :-1]], dim=1) + P1  # L(d - 1) + P1
    upper = torch.cat([prev[:, 1:], inf], dim=1) + P1  # L(d + 1) + P1
    t = torch.minimum(torch.minimum(prev, lower), torch.minimum(upper, m + p2))
    return torch.where(has_prev, c + (t - m), c)


def _path_torch(cost: torch.Tensor, dx: int, dy: int, P1: float, p2: torch.Tensor) -> torch.Tensor:
    """L_r for one direction. cost (B, D, H, W), p2 (B, H, W) -> (B, D, H, W)."""
    b, n, h, w = cost.shape
    if dy == 0:  # walk along x; the whole column (B, D, H) is one vector
        xs = range(w) if dx > 0 else range(w - 1, -1, -1)
        cols: dict[int, torch.Tensor] = {}
        for x in xs:
            xp = x - dx
            if 0 <= xp < w:
                has = torch.ones(h, dtype=torch.bool, device=cost.device)
                cols[x] = _path_step(cost[..., x], cols[xp], has, P1, p2[:, None, :, x])
            else:
                cols[x] = cost[..., x]
        return torch.stack([cols[x] for x in range(w)], dim=3)
    ys = range(h) if dy > 0 else range(h - 1, -1, -1)
    rows: dict[int, torch.Tensor] = {}
    x = torch.arange(w, device=cost.device)
    has = (x - dx >= 0) & (x - dx < w)
    for y in ys:
        yp = y - dy
        if 0 <= yp < h:
            prev = rows[yp]  # BxDxW, shift so that prev_shift[..., x] = prev[..., x - dx]
            if dx > 0:
                prev = torch.cat([prev[..., :1].expand(-1, -1, dx), prev[..., : w - dx]], dim=2)
            elif dx < 0:
                prev = torch.cat([prev[..., -dx:], prev[..., -1:].expand(-1, -1, -dx)], dim=2)
            rows[y] = _path_step(cost[:, :, y], prev, has, P1, p2[:, None, y])
        else:
            rows[y] = cost[:, :, y]
    return torch.stack([rows[y] for y in range(h)], dim=2)


def check_sgm_options(P1: float, P2: float, paths: int, p2_alpha: float,
                      penalty_step: float | None = None) -> tuple[tuple[int, int], ...]:
    """Validate the penalties, the path count and the penalty grid; returns :func:`sgm_directions` of ``paths``."""
    directions = sgm_directions(paths)
    if penalty_step is not None and not (np.isfinite(penalty_step) and penalty_step > 0):
        raise StereoInputError(f"penalty_step: expected a positive number or None, got {penalty_step!r}")
    if not (P1 >= 0 and P2 >= P1):
        raise StereoInputError(f"P1/P2: expected 0 <= P1 <= P2, got P1={P1}, P2={P2}")
    if p2_alpha < 0:
        raise StereoInputError(f"p2_alpha: expected >= 0, got {p2_alpha}")
    return directions


def _check_sgm_args(cost, P1, P2, paths, image, p2_alpha, penalty_step=None):
    check_cost_volume(cost)
    directions = check_sgm_options(P1, P2, paths, p2_alpha, penalty_step)
    if image is not None:
        check_image(image, "image")
        b, _, h, w = cost.shape
        check_shape(image, [str(b), "C", str(h), str(w)], "image")
    return directions


def sgm_aggregate_torch(cost: torch.Tensor, P1: float, P2: float, paths: int = 8,
                        image: torch.Tensor | None = None, p2_alpha: float = 0.0,
                        penalty_step: float | None = None) -> torch.Tensor:
    """Torch reference of :func:`sgm_aggregate` (differentiable; slow: one Python step per row/column)."""
    directions = _check_sgm_args(cost, P1, P2, paths, image, p2_alpha, penalty_step=penalty_step)
    P1, P2 = quantize_penalty(P1, penalty_step), quantize_penalty(P2, penalty_step)
    b, n, h, w = cost.shape
    p2 = p2_maps(P1, P2, directions, image, (b, h, w), p2_alpha, cost.dtype, cost.device, penalty_step)
    return sgm_aggregate_maps_torch(cost, P1, p2, directions)


def sgm_aggregate_maps_torch(cost: torch.Tensor, P1: float, p2: torch.Tensor, directions) -> torch.Tensor:
    """The torch recurrence with given large-jump penalties ``p2`` :math:`(B, R, H, W)` (one map per direction
    of ``directions``; differentiable in ``cost`` and ``p2``, as learned penalties are trained) -> ``S``."""
    total = None
    for i, (dx, dy) in enumerate(directions):
        path = _path_torch(cost, dx, dy, float(P1), p2[:, i])
        total = path if total is None else total + path
    return total


def sgm_aggregate(cost: torch.Tensor, P1: float, P2: float, paths: int = 8, image: torch.Tensor | None = None,
                  p2_alpha: float = 0.0, backend: str = "auto", *,
                  penalty_step: float | None = None, p2_maps: torch.Tensor | None = None) -> torch.Tensor:
    """Semi-global aggregation of any cost volume (see module doc).

    Args:
        cost: :math:`(B, D, H, W)` costs, lower = better.
        P1: penalty for a disparity change of 1 between path neighbours (cost units).
        P2: penalty for larger changes (``P2 >= P1``), adapted to ``image`` gradients when given.
        paths: 4, 8 or 16.
        image: optional guide :math:`(B, C, H, W)` in [0, 1] (the left image).
        p2_alpha: strength of the P2 adaptation (0 = constant P2).
        backend: ``"auto"`` (numba on CPU without gradient, else torch), ``"torch"`` or ``"numba"``.
        penalty_step: round ``P1`` and every ``P2(p, r)`` to multiples of this (see module doc); None = exact.
        p2_maps: optional :math:`(B, R, H, W)` large-jump penalties, one map per path direction (learned ones,
            :class:`~stereonet.models.penalty.PenaltyNet`), used instead of ``P2`` and its image adaptation
            (expected on the ``penalty_step`` grid already, each at least ``P1``).

    Returns:
        :math:`(B, D, H, W)` aggregated cost ``S = sum_r L_r`` (dtype of ``cost``; the numba backend
        computes in float32). The numba result is a permuted view of a ``(B, H, W, D)`` buffer.
    """
    directions = _check_sgm_args(cost, P1, P2, paths, image, p2_alpha, penalty_step=penalty_step)
    if p2_maps is not None:
        b, _, h, w = cost.shape
        check_shape(p2_maps, [str(b), str(len(directions)), str(h), str(w)], "p2_maps")
    if not use_numba(cost, backend=backend, float32_only=False):  # the kernel computes in float32
        if p2_maps is not None:
            return sgm_aggregate_maps_torch(cost, quantize_penalty(P1, penalty_step), p2_maps.to(cost), directions)
        return sgm_aggregate_torch(cost, P1, P2, paths, image, p2_alpha, penalty_step)
    b = cost.shape[0]
    costs = (cost[i].detach().to("cpu", torch.float32).permute(1, 2, 0).contiguous().numpy() for i in range(b))
    total = sgm_aggregate_hwd(costs, P1, P2, directions, image, p2_alpha, penalty_step, p2_maps=p2_maps)
    return total.to(device=cost.device, dtype=cost.dtype)


def p2_maps_array(p2_maps: torch.Tensor, i: int) -> np.ndarray:
    """Item ``i`` of given penalty maps :math:`(B, R, H, W)` as the kernels' C-contiguous float32 (R, H, W)."""
    return np.ascontiguousarray(p2_maps[i].detach().to("cpu", torch.float32).numpy())


def sgm_aggregate_hwd(costs, P1: float, P2: float, directions, image: torch.Tensor | None,
                      p2_alpha: float, penalty_step: float | None = None,
                      p2_maps: torch.Tensor | None = None) -> torch.Tensor:
    """The numba backend of :func:`sgm_aggregate` on ``(H, W, D)`` arrays (arguments already checked).

    Args:
        costs: an iterable of B C-contiguous ``(H, W, D)`` float32 or uint8 cost arrays (integer costs such
            as census distances may come as uint8: the same result, a quarter of the memory traffic, and
            with a ``penalty_step`` of ``1 / 2^k`` the 16-bit kernel); each is consumed before the next is
            taken, so a generator keeps one converted volume at a time.
        directions: from :func:`sgm_directions`; image: the guide :math:`(B, C, H, W)` or None.
        penalty_step, p2_maps: see :func:`sgm_aggregate` (``p2_maps`` replaces ``P2`` and ``image``'s rule).

    Returns:
        :math:`(B, D, H, W)` float32 CPU, a permuted view of a ``(B, H, W, D)`` buffer.
    """
    from stereonet.kernels.sgm import sgm_numba_hwd

    dirs = np.asarray(directions, dtype=np.int64)
    P1, P2 = quantize_penalty(P1, penalty_step), quantize_penalty(P2, penalty_step)
    outs = []
    for i, c_hwd in enumerate(costs):
        h, w = c_hwd.shape[:2]
        if p2_maps is not None:
            p2 = p2_maps_array(p2_maps, i)
        elif image is None:
            p2 = p2_maps_numpy(P1, P2, directions, np.zeros((h, w), np.float32), 0.0)
        else:
            p2 = p2_maps_numpy(P1, P2, directions, grey_numpy(image[i]), p2_alpha, penalty_step)
        outs.append(torch.from_numpy(sgm_numba_hwd(c_hwd, np.float32(P1), p2, dirs, penalty_step)))
        del c_hwd
    total = torch.stack(outs) if len(outs) > 1 else outs[0][None]  # BxHxWxD
    return total.permute(0, 3, 1, 2)  # BxDxHxW


def fixed_point_scale_for(P1: float, P2: float, directions, penalty_step: float | None,
                          cost_max: int) -> int | None:
    """``s`` for :func:`sgm_aggregate_fixed_hwd` when 16-bit fixed point is exact for uint8 costs up to
    ``cost_max`` and these penalties (``penalty_step`` = ``1 / s`` with ``s = 2^k``, and the sums over the
    ``directions`` within int16: :func:`stereonet.kernels.sgm.fits_int16`; every ``P2(p, r)`` is at most
    ``P2``), else None (use :func:`sgm_aggregate_hwd`). Decided from the scalars alone, once per call."""
    from stereonet.kernels.sgm import fits_int16, grid_scale

    s = grid_scale(penalty_step)
    if s is None:
        return None
    P1, P2 = quantize_penalty(P1, penalty_step), quantize_penalty(P2, penalty_step)
    return s if fits_int16(s, cost_max, P1, P2, len(directions)) else None


def sgm_aggregate_fixed_hwd(cost_hwd: np.ndarray, P1: float, P2: float, directions, image: torch.Tensor | None,
                            p2_alpha: float, penalty_step: float, s: int, p2: np.ndarray | None = None) -> np.ndarray:
    """The 16-bit kernel of :func:`sgm_aggregate_hwd` for one uint8 ``(H, W, D)`` cost (guide ``image``
    :math:`(C, H, W)` or None) whose values and penalties :func:`fixed_point_scale_for` accepted with ``s``:
    int16 ``(H, W, D)`` = ``s * S`` exactly. ``p2``: given float32 (R, H, W) penalty maps on the grid, at most
    ``P2`` (:func:`p2_maps_array`), instead of the image rule."""
    from stereonet.kernels.sgm import p2_maps_fixed, sgm_fixed_hwd

    dirs = np.asarray(directions, dtype=np.int64)
    P1, P2 = quantize_penalty(P1, penalty_step), quantize_penalty(P2, penalty_step)
    if p2 is not None:
        return sgm_fixed_hwd(cost_hwd, np.float32(P1), p2, dirs, s)
    h, w = cost_hwd.shape[:2]
    alpha = 0.0 if image is None else p2_alpha
    grey = np.zeros((h, w), np.float32) if image is None else grey_numpy(image)
    p2 = p2_maps_fixed(grey, np.float32(P1), np.float32(P2), np.float32(alpha), dirs, s)
    return sgm_fixed_hwd(cost_hwd, np.float32(P1), p2, dirs, s)
