"""Numba kernels of the SGM path recurrence (see :mod:`stereonet.optimize.sgm` for the maths).

Layout ``(H, W, D)`` float32 so the inner loop over disparities is contiguous. For each direction the
image splits into disjoint chains (straight lines of the walk, starting where the predecessor leaves the
image); the chains run in parallel with ``prange``, one parallel region per direction (no per-row
barriers, which matter on a busy 2-core machine). Every path cost is computed with the
same float32 operations as the torch reference (``C + (t - m)``), so the per-path costs are identical and
the sums differ only by the order of additions.
"""

from __future__ import annotations

import numba
import numpy as np
from numba import prange

_INF = np.float32(np.inf)


@numba.njit(inline="always")
def _step(c_row, prev, m, P1, pen2, out, s_row):
    """out[d] = c[d] + (min(prev[d], prev[d±1] + P1, m + pen2) - m); s += out; returns min_d out."""
    n = prev.shape[0]
    big = m + pen2
    new_min = _INF
    for d in range(n):
        t = prev[d]
        if d > 0:
            a = prev[d - 1] + P1
            if a < t:
                t = a
        if d < n - 1:
            a = prev[d + 1] + P1
            if a < t:
                t = a
        if big < t:
            t = big
        v = c_row[d] + (t - m)
        out[d] = v
        s_row[d] += v
        if v < new_min:
            new_min = v
    return new_min


@numba.njit(parallel=True, cache=True)
def _direction(C, S, P1, p2, dx, dy, starts):
    """All paths of one direction: chains start at the pixels without predecessor (``starts`` (N, 2) as
    (y, x)) and walk ``+ (dx, dy)``; chains are disjoint, so they run in parallel without races."""
    H, W, D = C.shape
    for i in prange(starts.shape[0]):
        prev = np.empty(D, np.float32)
        cur = np.empty(D, np.float32)
        y = starts[i, 0]
        x = starts[i, 1]
        m = _INF
        for d in range(D):
            v = C[y, x, d]
            prev[d] = v
            S[y, x, d] += v
            if v < m:
                m = v
        y += dy
        x += dx
        while 0 <= y < H and 0 <= x < W:
            m = _step(C[y, x], prev, m, P1, p2[y, x], cur, S[y, x])
            prev, cur = cur, prev
            y += dy
            x += dx


def chain_starts(h: int, w: int, dx: int, dy: int) -> np.ndarray:
    """(N, 2) int64 (y, x) of the pixels whose predecessor ``(y - dy, x - dx)`` is outside the image."""
    y, x = np.mgrid[0:h, 0:w]
    yp, xp = y - dy, x - dx
    outside = (yp < 0) | (yp >= h) | (xp < 0) | (xp >= w)
    return np.ascontiguousarray(np.stack([y[outside], x[outside]], axis=1).astype(np.int64))


def sgm_numba_hwd(cost_hwd: np.ndarray, P1: np.float32, p2: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Aggregated cost ``S`` (H, W, D) float32 of a cost ``(H, W, D)`` float32.

    Args:
        cost_hwd: C-contiguous float32 (H, W, D).
        P1: float32 scalar.
        p2: float32 (R, H, W) per-direction P2 maps.
        dirs: int64 (R, 2) ``(dx, dy)`` directions.
    """
    h, w, _ = cost_hwd.shape
    S = np.zeros_like(cost_hwd)
    P1 = np.float32(P1)
    p2 = np.ascontiguousarray(p2, dtype=np.float32)
    for i in range(dirs.shape[0]):
        dx, dy = int(dirs[i, 0]), int(dirs[i, 1])
        _direction(cost_hwd, S, P1, p2[i], dx, dy, chain_starts(h, w, dx, dy))
    return S
