"""Numba kernels of the SGM path recurrence (see :mod:`stereonet.optimize.sgm` for the maths).

Layout ``(H, W, D)`` float32 so the inner loop over disparities is contiguous (and vectorised). The
directions are computed in two sweeps over the rows, top-down (left-to-right, and every direction with
dy > 0) and bottom-up (the rest), so each sweep reads every cost row once and writes every S row once;
the two sweeps run concurrently on two threads without any barrier (which matters on a busy 2-core
machine), each into its own buffer, and are added at the end. Every path cost is computed with the
same float32 operations as the torch reference (``C + (t - m)``), so the per-path costs are identical and
the sums differ only by the order of additions.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np
from numba import prange

_INF = np.float32(np.inf)


@numba.njit(fastmath=True, inline="always")
def _step(c_row, prev, m, P1, pen2, out, s_row):
    """out = c + (min(prev[d], prev[d±1] + P1, m + pen2) - m); s += out; returns min_d out.

    ``prev``/``out`` are padded: index ``d + 1`` holds disparity ``d``, indices 0 and D + 1 hold +inf, so
    the loop is branch-free and vectorises (min is exact, so fastmath changes no result bit here except
    through ``c + (t - m)``, which stays as written)."""
    n = c_row.shape[0]
    big = m + pen2
    for d in range(n):
        t = min(min(prev[d + 1], prev[d] + P1), min(prev[d + 2] + P1, big))
        out[d + 1] = c_row[d] + (t - m)
    o = out[1:n + 1]
    for d in range(n):
        s_row[d] += o[d]
    return min_of(o)


@numba.njit(fastmath=True, inline="always")
def min_of(a):
    """min of a 1-D float array with eight independent accumulators (no serial dependency chain; min is
    exact, so the result equals the plain loop's)."""
    n = a.shape[0]
    m0 = m1 = m2 = m3 = m4 = m5 = m6 = m7 = _INF
    i = 0
    while i + 8 <= n:
        m0 = min(m0, a[i])
        m1 = min(m1, a[i + 1])
        m2 = min(m2, a[i + 2])
        m3 = min(m3, a[i + 3])
        m4 = min(m4, a[i + 4])
        m5 = min(m5, a[i + 5])
        m6 = min(m6, a[i + 6])
        m7 = min(m7, a[i + 7])
        i += 8
    while i < n:
        m0 = min(m0, a[i])
        i += 1
    return min(min(min(m0, m1), min(m2, m3)), min(min(m4, m5), min(m6, m7)))


@numba.njit(fastmath=True, nogil=True, cache=True)
def _sweep(C, S, P1, p2, dirs, downward):
    """One sweep over the rows (top-down if ``downward`` else bottom-up) computing every direction of
    ``dirs`` (G, 2) at once: each pixel's cost row is read once and its S row written once.

    Directions with ``dy != 0`` must point along the sweep; a horizontal one must point along the column
    order of the sweep (left-to-right top-down, right-to-left bottom-up). ``L``/``M`` keep three rows of
    padded path costs and their minima per direction (enough for the |dy| = 2 knight moves)."""
    H, W, D = C.shape
    G = dirs.shape[0]
    L = np.full((G, 3, W, D + 2), _INF, np.float32)
    M = np.empty((G, 3, W), np.float32)
    for step in range(H):
        y = step if downward else H - 1 - step
        slot = y % 3
        for k in range(W):
            x = k if downward else W - 1 - k
            c_row = C[y, x]
            s_row = S[y, x]
            for g in range(G):
                dx = dirs[g, 0]
                dy = dirs[g, 1]
                yp = y - dy
                xp = x - dx
                out = L[g, slot, x]
                if 0 <= yp < H and 0 <= xp < W:
                    ps = yp % 3
                    M[g, slot, x] = _step(c_row, L[g, ps, xp], M[g, ps, xp], P1, p2[g, y, x], out, s_row)
                else:
                    for d in range(D):
                        v = c_row[d]
                        out[d + 1] = v
                        s_row[d] += v
                    M[g, slot, x] = min_of(c_row)


@numba.njit(parallel=True, cache=True)
def _add_into(a, b):
    H = a.shape[0]
    for y in prange(H):
        a[y] += b[y]


def sweep_groups(dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the directions of the top-down sweep (dy > 0, or dy = 0 and dx > 0) and the bottom-up one."""
    down = (dirs[:, 1] > 0) | ((dirs[:, 1] == 0) & (dirs[:, 0] > 0))
    return np.nonzero(down)[0], np.nonzero(~down)[0]


CONCURRENT_MAX_BYTES = 256 * 2**20  # above this volume size the two sweeps share one buffer (sequential)


def sgm_numba_hwd(cost_hwd: np.ndarray, P1: np.float32, p2: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Aggregated cost ``S`` (H, W, D) float32 of a cost ``(H, W, D)`` float32.

    The directions split into a top-down and a bottom-up sweep that run concurrently on two threads
    (numba releases the GIL), each into its own buffer, added at the end; for volumes above
    :data:`CONCURRENT_MAX_BYTES` (e.g. KITTI at 192 disparities) they run one after the other into a single
    buffer, so the peak memory stays at two volumes (cost + aggregate).

    Args:
        cost_hwd: C-contiguous float32 (H, W, D).
        P1: float32 scalar.
        p2: float32 (R, H, W) per-direction P2 maps.
        dirs: int64 (R, 2) ``(dx, dy)`` directions.
    """
    P1 = np.float32(P1)
    p2 = np.ascontiguousarray(p2, dtype=np.float32)
    down, up = sweep_groups(dirs)
    groups = [(np.ascontiguousarray(p2[g]), np.ascontiguousarray(dirs[g]), flag)
              for g, flag in ((down, True), (up, False)) if g.size]
    if len(groups) == 1 or numba.get_num_threads() == 1 or cost_hwd.nbytes > CONCURRENT_MAX_BYTES:
        total = np.zeros(cost_hwd.shape, np.float32)  # one buffer, the sweeps one after the other
        for p2g, dg, flag in groups:
            _sweep(cost_hwd, total, P1, p2g, dg, flag)
        return total
    buffers = [np.zeros(cost_hwd.shape, np.float32) for _ in groups]  # calloc: zero pages on first touch
    with ThreadPoolExecutor(max_workers=len(groups)) as pool:
        list(pool.map(lambda job: _sweep(cost_hwd, job[0], P1, *job[1]), zip(buffers, groups)))
    total = buffers[0]
    for other in buffers[1:]:
        _add_into(total, other)
    return total
