"""Compiled CPU kernels (numba, parallel over scanlines) for :mod:`stereonet.aggregate.dp`.

Both kernels read the cost volume ``cost[B, D, H, W]`` in place (any float dtype, no copy: scanline
``r = b·H + h`` is the strided view ``cost[b, :, h, :]``; float32 costs are widened to float64 exactly as
they are added) and mirror the plain torch references in ``dp.py`` step for step (same recurrences, same
tie-breaking, float64 sums), so the two agree exactly on costs that are exactly representable.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

MATCH, LEFT_OCCLUDED, RIGHT_OCCLUDED = 0, 1, 2


@njit(parallel=True, cache=True, fastmath=False)
def scanline_dp_three_case(cost, occlusion_cost):  # pragma: no cover - compiled
    """Cox-style three-case DP with the ordering constraint, per scanline.

    States ``(i, d)``: ``i`` left pixels and ``j = i - d`` right pixels consumed. Moves into ``(i, d)``:
    match left ``i-1`` with right ``i-1-d`` (from ``(i-1, d)``, cost ``cost[d, i-1]``), left-occluded
    (from ``(i-1, d-1)``), right-occluded (from ``(i, d+1)``), both at ``occlusion_cost``. Start ``(0, 0)``;
    end ``(W, d)`` for any ``d`` (right pixels beyond the last left pixel are free).

    Returns ``disp (R, W) int32`` (occluded pixels filled from the nearest matched pixel on their left,
    else on their right), ``occluded (R, W) bool`` and ``energy (R,) float64``.
    """
    B, D, H, W = cost.shape
    R = B * H
    disp = np.zeros((R, W), dtype=np.int32)
    occluded = np.zeros((R, W), dtype=np.bool_)
    energy = np.zeros(R, dtype=np.float64)
    inf = np.inf
    for r in prange(R):
        c = cost[r // H, :, r % H, :]  # (D, W) view of scanline r
        table = np.full((W + 1, D), inf)
        back = np.zeros((W + 1, D), dtype=np.int8)
        table[0, 0] = 0.0
        for i in range(1, W + 1):
            dmax = min(i, D - 1)
            for d in range(dmax + 1):
                best = inf
                arg = MATCH
                if d <= i - 1:
                    v = table[i - 1, d] + np.float64(c[d, i - 1])
                    if v < best:
                        best = v
                        arg = MATCH
                if d >= 1:
                    v = table[i - 1, d - 1] + occlusion_cost
                    if v < best:
                        best = v
                        arg = LEFT_OCCLUDED
                table[i, d] = best
                back[i, d] = arg
            for d in range(dmax - 1, -1, -1):
                v = table[i, d + 1] + occlusion_cost
                if v < table[i, d]:
                    table[i, d] = v
                    back[i, d] = RIGHT_OCCLUDED
        d = 0
        for k in range(1, D):
            if table[W, k] < table[W, d]:
                d = k
        energy[r] = table[W, d]
        i = W
        while i > 0:
            b = back[i, d]
            if b == MATCH:
                disp[r, i - 1] = d
                i -= 1
            elif b == LEFT_OCCLUDED:
                occluded[r, i - 1] = True
                i -= 1
                d -= 1
            else:
                d += 1
        _fill_row(disp[r], occluded[r])
    return disp, occluded, energy


@njit(cache=True, fastmath=False)
def _fill_row(disp, occluded):  # pragma: no cover - compiled
    """Occluded pixels take the disparity of the nearest non-occluded pixel on their left (else right)."""
    W = disp.shape[0]
    first = -1
    for x in range(W):
        if not occluded[x]:
            first = x
            break
    if first < 0:
        return
    last = disp[first]
    for x in range(W):
        if not occluded[x]:
            last = disp[x]
        else:
            disp[x] = last


@njit(parallel=True, cache=True, fastmath=False)
def scanline_viterbi(cost, weights, smoothness, truncation):  # pragma: no cover - compiled
    """Per-scanline energy DP: ``sum_x cost[d_x, x] + smoothness·weights[x]·min(|d_x - d_{x+1}|, T)`` of each
    scanline ``r = b·H + h`` of ``cost (B, D, H, W)``.

    The min over the previous disparity uses the O(D) two-pass distance transform with argmin tracking.
    ``weights (R, W)`` holds the weight of edge ``(x, x+1)`` at ``x``. Returns ``disp (R, W) int32`` and
    ``energy (R,) float64``.
    """
    B, D, H, W = cost.shape
    R = B * H
    disp = np.zeros((R, W), dtype=np.int32)
    energy = np.zeros(R, dtype=np.float64)
    for r in prange(R):
        c = cost[r // H, :, r % H, :]  # (D, W) view of scanline r
        acc = np.empty(D)
        f = np.empty(D)
        arg = np.empty(D, dtype=np.int32)
        back = np.zeros((W, D), dtype=np.int32)
        for d in range(D):
            acc[d] = np.float64(c[d, 0])
        for x in range(1, W):
            s = smoothness * weights[r, x - 1]
            best = 0
            for d in range(D):
                f[d] = acc[d]
                arg[d] = d
                if acc[d] < acc[best]:
                    best = d
            for d in range(1, D):
                if f[d - 1] + s < f[d]:
                    f[d] = f[d - 1] + s
                    arg[d] = arg[d - 1]
            for d in range(D - 2, -1, -1):
                if f[d + 1] + s < f[d]:
                    f[d] = f[d + 1] + s
                    arg[d] = arg[d + 1]
            cap = acc[best] + s * truncation
            for d in range(D):
                if cap < f[d]:
                    f[d] = cap
                    arg[d] = best
                acc[d] = f[d] + np.float64(c[d, x])
                back[x, d] = arg[d]
        d = 0
        for k in range(1, D):
            if acc[k] < acc[d]:
                d = k
        energy[r] = acc[d]
        for x in range(W - 1, -1, -1):
            disp[r, x] = d
            d = back[x, d]
    return disp, energy
