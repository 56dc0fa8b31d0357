"""Compiled CPU kernel (numba, parallel over rows) for one level of :mod:`stereonet.aggregate.bp`.

Pixel-major layout ``(B, H, W, D)`` so each pixel's labels are contiguous. It mirrors the torch
reference ``bp._run_level`` (synchronous updates, linear distance transform, truncation, min-normalisation).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange


@njit(cache=True, fastmath=False)
def _send(h, slope, truncation, out):  # pragma: no cover - compiled
    """out[d] = min_d' h[d'] + slope·min(|d - d'|, T), normalised to min 0 (two-pass distance transform)."""
    D = h.shape[0]
    lowest = h[0]
    for d in range(D):
        out[d] = h[d]
        if h[d] < lowest:
            lowest = h[d]
    for d in range(1, D):
        v = out[d - 1] + slope
        if v < out[d]:
            out[d] = v
    for d in range(D - 2, -1, -1):
        v = out[d + 1] + slope
        if v < out[d]:
            out[d] = v
    cap = lowest + slope * truncation
    m = np.inf
    for d in range(D):
        if cap < out[d]:
            out[d] = cap
        if out[d] < m:
            m = out[d]
    for d in range(D):
        out[d] -= m


@njit(cache=True, fastmath=False)
def bp_level(cost, from_left, from_right, from_up, from_down, slopes, truncation, iterations):  # pragma: no cover
    """Run ``iterations`` synchronous min-sum updates; returns the four final message arrays.

    cost and messages ``(B, H, W, D)``; ``slopes (B, H, W, 4)`` = λ·w to the right, left, down, up neighbour.
    The message arrays passed in are reused as buffers (overwritten).
    """
    # two buffer sets, swapped each iteration; border slots that receive no message stay 0
    new_left = np.zeros_like(from_left)
    new_right = np.zeros_like(from_right)
    new_up = np.zeros_like(from_up)
    new_down = np.zeros_like(from_down)
    for _ in range(iterations):
        _bp_iteration(cost, from_left, from_right, from_up, from_down, new_left, new_right, new_up, new_down,
                      slopes, truncation)
        from_left, new_left = new_left, from_left
        from_right, new_right = new_right, from_right
        from_up, new_up = new_up, from_up
        from_down, new_down = new_down, from_down
    return from_left, from_right, from_up, from_down


@njit(parallel=True, cache=True, fastmath=False)
def _bp_iteration(cost, from_left, from_right, from_up, from_down, new_left, new_right, new_up, new_down,
                  slopes, truncation):  # pragma: no cover - compiled
    """One synchronous update: read the incoming messages ``from_*``, write the next ones into ``new_*``."""
    B, H, W, D = cost.shape
    for row in prange(B * H):
        b = row // H
        y = row % H
        total = np.empty(D)
        h = np.empty(D)
        for x in range(W):
            for d in range(D):
                total[d] = (cost[b, y, x, d] + from_left[b, y, x, d] + from_right[b, y, x, d]
                            + from_up[b, y, x, d] + from_down[b, y, x, d])
            if x + 1 < W:
                for d in range(D):
                    h[d] = total[d] - from_right[b, y, x, d]
                _send(h, slopes[b, y, x, 0], truncation, new_left[b, y, x + 1])
            if x >= 1:
                for d in range(D):
                    h[d] = total[d] - from_left[b, y, x, d]
                _send(h, slopes[b, y, x, 1], truncation, new_right[b, y, x - 1])
            if y + 1 < H:
                for d in range(D):
                    h[d] = total[d] - from_down[b, y, x, d]
                _send(h, slopes[b, y, x, 2], truncation, new_up[b, y + 1, x])
            if y >= 1:
                for d in range(D):
                    h[d] = total[d] - from_up[b, y, x, d]
                _send(h, slopes[b, y, x, 3], truncation, new_down[b, y - 1, x])
