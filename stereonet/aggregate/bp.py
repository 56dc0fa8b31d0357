"""Loopy belief propagation (min-sum) on the 4-connected grid, Felzenszwalb & Huttenlocher style.

Minimises the MRF energy of :mod:`stereonet.aggregate.mrf` (data cost + ``λ·w_pq·min(|f_p - f_q|, T)``)
approximately, following P. Felzenszwalb, D. Huttenlocher, "Efficient belief propagation for early vision",
IJCV 2006:

* message update ``m_{p→q}(d) = min_d' [h_p(d') + λ w_pq min(|d - d'|, T)]`` with
  ``h_p = C_p + Σ_{s ∈ N(p) \\ q} m_{s→p}``, computed in O(D) by the linear distance transform
  (:func:`~stereonet.aggregate.mrf.truncated_linear_min_convolution`), messages normalised to min 0;
* synchronous ("flooding") updates of all messages of the whole grid at once: on CPU (``backend="auto"``)
  numba kernels on a row-major ``(B, H, D, W)`` copy, vectorised along rows, the iterations of a level run
  as a wavefront over the rows (two strips swept towards each other, one thread each), tested equal to the vectorised torch
  reference (``backend="torch"``);
* coarse-to-fine: data costs summed over 2×2 blocks per level, messages of a coarse level initialise the
  four children at the next finer level, so few iterations per level propagate information far.

* ``precision="int16"`` (the ``bp`` matcher's default): the finest levels in 16-bit fixed point, costs and
  slopes rounded to a grid ``1/s`` (:func:`fixed_point_plan`), on which min-sum is exact integer arithmetic.

Cost: O(iterations · 4 · B·D·H·W) time per level (the coarse levels add a third). With more than one level the
finest one never holds a full message set (:func:`stereonet.kernels.bp.bp_finest`: its first iteration reads the
coarse level's messages row by row, every iteration writes into small rings of rows, the beliefs are computed in the
same wavefront), so its memory is about 3 volumes of ``B·D·H·W`` (cost, its row-major copy, beliefs; the row-major
copy half in fixed point) plus the next coarser level's messages (one volume); a single level keeps its 4 messages
(updated in place) and writes the beliefs over them.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import torch
import torch.nn.functional as F

from stereonet.aggregate.mrf import (
    check_edge_weights,
    check_smoothness,
    grid_energy,
    truncated_linear_min_convolution,
)
from stereonet.checks import StereoInputError, check_cost_volume, check_finite
from stereonet.kernels import empty_array, use_numba
from stereonet.select.subpixel import neighbour_costs


class BPResult(NamedTuple):
    """Output of :func:`belief_propagation`.

    disparity: :math:`(B, 1, H, W)` float, integer-valued argmin of the beliefs.
    beliefs: :math:`(B, D, H, W)` min-sum beliefs (lower = better), data cost plus incoming messages; None when
        :func:`belief_propagation` ran with ``keep_beliefs=False``.
    energy: :math:`(B,)` float64 MRF energy of ``disparity``.
    near: :math:`(B, 3, H, W)` the beliefs at ``disparity - 1``, ``disparity``, ``disparity + 1`` (the label's own
        value where a neighbour lies outside the range): what a sub-pixel fit reads
        (:func:`stereonet.select.subpixel.refine_from_neighbours`), kept in either case.
    """

    disparity: torch.Tensor
    beliefs: torch.Tensor | None
    energy: torch.Tensor
    near: torch.Tensor


def _near(beliefs: torch.Tensor, labels: torch.Tensor) -> torch.Tensor:
    """:attr:`BPResult.near` from a belief volume and its long labels :math:`(B, 1, H, W)`."""
    return torch.cat(neighbour_costs(beliefs, labels), dim=1)


def _shift(x: torch.Tensor, dy: int, dx: int) -> torch.Tensor:
    """Move content by (dy, dx) pixels (zeros shifted in): ``out[y, x] = x[y - dy, x - dx]``."""
    h, w = x.shape[-2:]
    out = torch.zeros_like(x)
    out[..., max(dy, 0):h + min(dy, 0), max(dx, 0):w + min(dx, 0)] = \
        x[..., max(-dy, 0):h - max(dy, 0), max(-dx, 0):w - max(dx, 0)]
    return out


def _run_level(cost: torch.Tensor, messages: list[torch.Tensor], slopes: list[torch.Tensor],
               truncation: float, iterations: int) -> list[torch.Tensor]:
    """Synchronous min-sum iterations at one level.

    ``messages`` = incoming at each pixel [from left, from right, from up, from down], each (B, D, H, W).
    ``slopes`` = λ·w for the edge to the [right, left, down, up] neighbour of each pixel, each (B, 1, H, W).
    """
    from_left, from_right, from_up, from_down = messages
    s_right, s_left, s_down, s_up = slopes
    for _ in range(iterations):
        total = cost + from_left + from_right + from_up + from_down
        outgoing = []
        for exclude, slope in ((from_right, s_right), (from_left, s_left), (from_down, s_down), (from_up, s_up)):
            msg = truncated_linear_min_convolution(total - exclude, slope, truncation)
            outgoing.append(msg - msg.amin(dim=1, keepdim=True))
        to_right, to_left, to_down, to_up = outgoing
        from_left, from_right = _shift(to_right, 0, 1), _shift(to_left, 0, -1)
        from_up, from_down = _shift(to_down, 1, 0), _shift(to_up, -1, 0)
    return [from_left, from_right, from_up, from_down]


def _slope_array(slopes: list[torch.Tensor], truncation: float) -> np.ndarray:
    """The kernel's ``(B, 8, H, W)`` slopes: λ·w to the right, left, down, up neighbour, then each times ``T``
    (the cap ``s·T``, computed in the cost's dtype as the reference does)."""
    return torch.cat(slopes + [s * truncation for s in slopes], dim=1).contiguous().numpy()


def _run_level_numba(cost: np.ndarray, start: np.ndarray, slope_array: np.ndarray, iterations: int) -> np.ndarray:
    """Same as :func:`_run_level` through the numba kernel, on *row-major* arrays; returns the final messages.

    cost ``(B, H, D, W)``; ``start`` the incoming messages ``(B, H, 4, D, W)`` [from left, right, up, down], updated
    in place when ``iterations >= 2``; ``slope_array`` from :func:`_slope_array` (all float32/float64, or all int16
    in fixed point).
    """
    from stereonet.kernels.bp import bp_level

    final = start if iterations >= 2 else empty_array(start.shape, start.dtype)
    rings, k = _wavefront_rings(iterations, cost.shape[2], cost.shape[3], cost.dtype)
    bp_level(cost, start, final, rings, slope_array, int(iterations), k)
    return final


def _wavefront_rings(sets: int, depth: int, width: int, dtype) -> tuple[np.ndarray, int]:
    """Scratch rings for a wavefront writing ``sets`` message sets (:func:`stereonet.kernels.bp.ring_shape`) and its
    block of rows, read here at call time from ``kernels.bp.ROWS_PER_STEP`` (any value gives the same bits)."""
    from stereonet.kernels import bp as kernels

    k = int(kernels.ROWS_PER_STEP)
    return empty_array(kernels.ring_shape(sets, k, depth, width), dtype), k


FIXED_POINT_LIMIT = 32000
"""Fixed point: every value a level's kernel computes stays below this (int16 holds 32767)."""
FIXED_POINT_MIN_SCALE = 128
"""Fixed point is used only when the finest level gets at least this many steps per unit of cost."""
FIXED_POINT_MAX_SCALE = 1024


def fixed_point_plan(maxima: list[float], slope_arrays: list[np.ndarray]) -> tuple[int, list[bool]]:
    """The scale ``s`` (a power of two) and which pyramid levels run in int16 for ``precision="int16"``.

    In min-sum BP with a truncated-linear DT every value a level computes is at most ``max C + 5 max(s·T)`` (the
    summed beliefs: the cost plus four messages, each normalised to min 0 and capped at ``min + s·T``; the cap adds
    one more ``s·T``). ``s`` is the largest power of two up to :data:`FIXED_POINT_MAX_SCALE` that keeps the finest
    level's bound under :data:`FIXED_POINT_LIMIT`; a level runs in int16 when its own bound (coarse costs are sums
    over 4^level pixels) fits too. Returns ``(0, [False] * levels)`` when ``s`` would be below
    :data:`FIXED_POINT_MIN_SCALE` (a smoothness far above the cost's range). ``maxima``: each level's largest
    cost; ``slope_arrays``: each level's :func:`_slope_array`.
    """
    bounds = [float(m) + 5.0 * float(a[:, 4:].max()) for m, a in zip(maxima, slope_arrays)]
    scale = FIXED_POINT_MAX_SCALE
    while scale >= FIXED_POINT_MIN_SCALE and scale * bounds[0] > FIXED_POINT_LIMIT:
        scale //= 2
    if scale < FIXED_POINT_MIN_SCALE:
        return 0, [False] * len(maxima)
    return scale, [scale * b <= FIXED_POINT_LIMIT for b in bounds]


def _largest(x: torch.Tensor) -> float:
    """``x.max()`` read in memory order: a reduction over a permuted view (the numba cost volume is a
    ``(B, D, H, W)`` view of ``(B, H, W, D)`` memory) is several times slower than over the same values in order."""
    for order in ((0, 1, 2, 3), (0, 2, 3, 1), (0, 2, 1, 3)):
        view = x.permute(*order)
        if view.is_contiguous():
            return float(view.max())
    return float(x.max())


def _to_fixed(x: np.ndarray, scale: int) -> np.ndarray:
    """``round(x · scale)`` as int16 (the caller has checked the range; float32 ``x`` of 4 or 5 dimensions), by the
    parallel kernel :func:`stereonet.kernels.bp.round_rows`: the same values as ``np.rint(x * np.float32(scale))``."""
    from stereonet.kernels.bp import round_rows

    out = empty_array(x.shape, np.int16)
    rows = (-1,) + x.shape[-3:]
    round_rows(x.reshape(rows), np.float32(scale), out.reshape(rows))
    return out


def _in_dtype(messages: np.ndarray, dtype, scale: int) -> np.ndarray:
    """A coarser level's messages as the next level needs them: as they are, or rounded to fixed point (a float
    level above an int16 one)."""
    return messages if messages.dtype == dtype else _to_fixed(messages, scale)


def _pool_sum(x: torch.Tensor) -> torch.Tensor:
    """Sum over 2x2 blocks (odd sizes padded by replication): (B, C, H, W) -> (B, C, ceil(H/2), ceil(W/2))."""
    h, w = x.shape[-2:]
    x = F.pad(x, (0, w % 2, 0, h % 2), mode="replicate") if (h % 2 or w % 2) else x
    return F.avg_pool2d(x, 2) * 4


def _slopes(smoothness: float, weights_right: torch.Tensor, weights_down: torch.Tensor) -> list[torch.Tensor]:
    """λ·w per pixel for its edges to the right, left, down and up neighbours (0 at the image border)."""
    wr = weights_right.clone()
    wr[..., :, -1] = 0
    wd = weights_down.clone()
    wd[..., -1, :] = 0
    return [smoothness * wr, smoothness * _shift(wr, 0, 1), smoothness * wd, smoothness * _shift(wd, 1, 0)]


def belief_propagation(cost: torch.Tensor, smoothness: float, truncation: float = 2.0, iterations: int = 5,
                       levels: int = 4, weights_right: torch.Tensor | None = None,
                       weights_down: torch.Tensor | None = None, backend: str = "auto",
                       precision: str = "float", keep_beliefs: bool = True) -> BPResult:
    """Coarse-to-fine min-sum loopy BP with truncated-linear smoothness (see the module docstring).

    Args:
        cost: :math:`(B, D, H, W)` finite data costs, lower = better.
        smoothness: ``λ >= 0``.
        truncation: ``T > 0`` of ``min(|d - d'|, T)`` (``1`` = Potts).
        iterations: message-passing iterations per level (>= 1).
        levels: pyramid levels (>= 1; 1 = single scale); capped so the coarsest level is at least 2×2.
        weights_right, weights_down: optional :math:`(B, 1, H, W)` edge weights (see ``_global_mrf``).
        backend: ``"auto"`` (numba on CPU), ``"numba"`` or ``"torch"`` (the vectorised reference).
        precision: ``"float"`` (the cost's dtype) or ``"int16"``: on the numba path with a float32 cost, the
            finest levels run in 16-bit fixed point (:func:`fixed_point_plan`: costs and slopes rounded to a grid
            ``1/s``, ``s`` up to 1024; on that grid min-sum is exact integer arithmetic, so the result is the float
            kernel's on the rounded inputs), with half the message memory; coarser levels, a float64 cost and
            the torch backend stay in floating point.
        keep_beliefs: return the belief volume (``False``: ``beliefs`` is None, and on the numba path with more than
            one level the volume is never allocated, each row's beliefs live in a scratch row: ~30 % less memory
            touched on a KITTI pair; ``near`` keeps what a sub-pixel fit needs). The labels are the same either way.
    Returns:
        :class:`BPResult`. Not differentiable (``argmin``); the inputs are detached.
    """
    cost = check_cost_volume(cost, "cost")
    check_finite(cost, "cost")  # (skipped for a volume the caller built from checked images: inputs_checked)
    smoothness, truncation = check_smoothness(smoothness, truncation)
    if precision not in ("float", "int16"):
        raise StereoInputError(f"precision: expected 'float' or 'int16', got {precision!r}")
    for name, v in (("iterations", iterations), ("levels", levels)):
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise StereoInputError(f"{name}: expected an integer >= 1, got {v!r}")
    weights_right = check_edge_weights(weights_right, cost, "weights_right")
    weights_down = check_edge_weights(weights_down, cost, "weights_down")
    numba_path = use_numba(cost.detach(), backend=backend, float32_only=False)  # bp detaches the cost
    cost = cost.detach()
    ones = torch.ones_like(cost[:, :1])
    wr = ones if weights_right is None else weights_right.detach().to(cost.dtype)
    wd = ones if weights_down is None else weights_down.detach().to(cost.dtype)
    h, w = cost.shape[-2:]
    levels = max(1, min(levels, int(math.log2(max(1, min(h, w) // 2))) + 1))

    weights = [(wr, wd)]
    for _ in range(levels - 1):
        r, d = weights[-1]
        weights.append((F.avg_pool2d(F.pad(r, (0, r.shape[-1] % 2, 0, r.shape[-2] % 2), mode="replicate"), 2),
                        F.avg_pool2d(F.pad(d, (0, d.shape[-1] % 2, 0, d.shape[-2] % 2), mode="replicate"), 2)))
    truncation_eff = min(truncation, float(cost.shape[1]))
    if numba_path:
        from stereonet.kernels.bp import (
            beliefs_argmin,
            beliefs_view,
            bp_finest,
            pool_sum2,
            round_rows,
            upsample2,
        )

        # the kernels work row-major (B, H, D, W): each grid row is D contiguous runs of W pixels
        B, D, H, W = cost.shape
        rows = cost.permute(0, 2, 1, 3).numpy()  # a strided (B, H, D, W) view, no copy
        slope_arrays = [_slope_array(_slopes(smoothness, r.to("cpu"), d.to("cpu")), truncation_eff) for r, d in weights]
        costs: list[np.ndarray] = [rows]
        for _ in range(levels - 1):  # the same sums whether the finest level is read strided or copied
            costs.append(pool_sum2(costs[-1]))
        scale, fixed = 0, [False] * levels
        if precision == "int16" and rows.dtype == np.float32:
            maxima = [_largest(cost)] + [float(c.max()) for c in costs[1:]]
            scale, fixed = fixed_point_plan(maxima, slope_arrays)
        if fixed[0]:  # rounded straight from the strided view: no float row-major copy of the finest level
            costs[0] = empty_array((B, H, D, W), np.int16)
            round_rows(rows, np.float32(scale), costs[0])
        else:
            costs[0] = empty_array((B, H, D, W), rows.dtype)
            torch.from_numpy(costs[0]).copy_(cost.permute(0, 2, 1, 3))
        del rows
        for level in range(levels):
            if fixed[level]:
                if level > 0:
                    costs[level] = _to_fixed(costs[level], scale)
                slope_arrays[level] = _to_fixed(slope_arrays[level], scale)
        # each level's messages (B, h, 4, D, w) are updated in place; the coarser level's result initialises them
        # (each coarse pixel's messages copied to its 2x2 children: the four slots of a row are one (4D, w) block)
        # and is then dropped
        result = None
        for level in range(levels - 1, 0, -1):
            c = costs[level]
            shape = c.shape[:2] + (4,) + c.shape[2:]
            if result is None:
                start = empty_array(shape, c.dtype, zero=True)
            else:
                start = empty_array(shape, c.dtype)
                src = _in_dtype(result, c.dtype, scale)
                upsample2(src.reshape(src.shape[:2] + (-1, src.shape[-1])), start.reshape(shape[:2] + (-1, shape[-1])))
                del src
                result = None
            result = _run_level_numba(c, start, slope_arrays[level], iterations)
            del start
        # fixed point: beliefs back in cost units (1/s is a power of two: exact)
        out_dtype = np.dtype(np.float32) if fixed[0] else costs[0].dtype
        belief_scale = np.array([1.0 / scale if fixed[0] else 1.0], dtype=out_dtype)
        labels_rows = empty_array((B, H, W), np.int64)
        near = None
        if result is None:  # one level: from zero messages, the beliefs written over the final messages (a view)
            zero = empty_array((B, H, 4, D, W), costs[0].dtype, zero=True)
            result = _run_level_numba(costs[0], zero, slope_arrays[0], iterations)
            beliefs_argmin(costs[0], result, labels_rows, belief_scale)
            beliefs_rows = beliefs_view(result, out_dtype)
            del result
        else:  # the finest level in one wavefront from the coarse messages to the beliefs (kernels.bp.bp_finest)
            coarse = _in_dtype(result, costs[0].dtype, scale)
            del result
            rings, k = _wavefront_rings(iterations + 1, D, W, costs[0].dtype)
            beliefs_rows = empty_array((B, H if keep_beliefs else 0, D, W), out_dtype)
            near_np = empty_array((B, 3, H, W), out_dtype)
            bp_finest(costs[0], coarse, rings, slope_arrays[0], int(iterations), beliefs_rows, near_np,
                      labels_rows, belief_scale, k)
            near = torch.from_numpy(near_np).to(cost.device)
            del coarse, rings
        del costs
        beliefs = torch.from_numpy(beliefs_rows).permute(0, 2, 1, 3).to(cost.device)  # BxDxHxW view
        labels = torch.from_numpy(labels_rows).unsqueeze(1).to(cost.device)
        if near is None:
            near = _near(beliefs, labels)
    else:
        pyramid = [cost]
        for _ in range(levels - 1):
            pyramid.append(_pool_sum(pyramid[-1]))
        messages_t: list[torch.Tensor] | None = None
        for level in range(levels - 1, -1, -1):
            c = pyramid[level]
            if messages_t is None:
                messages_t = [torch.zeros_like(c) for _ in range(4)]
            else:  # each coarse pixel's messages initialise its 2x2 children
                hh, ww = c.shape[-2:]
                messages_t = [m.repeat_interleave(2, dim=2).repeat_interleave(2, dim=3)
                              .narrow(2, 0, hh).narrow(3, 0, ww).contiguous() for m in messages_t]
            r, d = weights[level]
            messages_t = _run_level(c, messages_t, _slopes(smoothness, r, d), truncation_eff, iterations)
        beliefs = c + messages_t[0]
        for m in messages_t[1:]:
            beliefs += m
        del messages_t
        labels = beliefs.argmin(dim=1, keepdim=True)
        near = _near(beliefs, labels)
    energy = grid_energy(cost, labels, smoothness, truncation, weights_right, weights_down)
    return BPResult(labels.to(cost.dtype), beliefs if keep_beliefs else None, energy, near)
