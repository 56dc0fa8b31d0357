"""Numba kernels of the disparity filters (:mod:`stereonet.select.filters`): the 3x3 median by a sorting
network (larger windows by sorting) over valid pixels, and the speckle filter's connected components."""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(inline="always", fastmath=False)
def _sort2(a, b):
    return (a, b) if a <= b else (b, a)


@numba.njit(cache=True, fastmath=False)
def _median9(p0, p1, p2, p3, p4, p5, p6, p7, p8):
    """Median of nine values by the 19-exchange network (Paeth's opt_med9): the 5th smallest, the value the
    insertion sort of :func:`median_kernel` picks for nine samples."""
    p1, p2 = _sort2(p1, p2)
    p4, p5 = _sort2(p4, p5)
    p7, p8 = _sort2(p7, p8)
    p0, p1 = _sort2(p0, p1)
    p3, p4 = _sort2(p3, p4)
    p6, p7 = _sort2(p6, p7)
    p1, p2 = _sort2(p1, p2)
    p4, p5 = _sort2(p4, p5)
    p7, p8 = _sort2(p7, p8)
    p0, p3 = _sort2(p0, p3)
    p5, p8 = _sort2(p5, p8)
    p4, p7 = _sort2(p4, p7)
    p3, p6 = _sort2(p3, p6)
    p1, p4 = _sort2(p1, p4)
    p2, p5 = _sort2(p2, p5)
    p4, p7 = _sort2(p4, p7)
    p4, p2 = _sort2(p4, p2)
    p6, p4 = _sort2(p6, p4)
    p4, p2 = _sort2(p4, p2)
    return p4


# fastmath=False: comparisons only (exact), and NaN disparities must not be assumed away
@numba.njit(parallel=True, cache=True, fastmath=False)
def median_kernel(disp: np.ndarray, valid: np.ndarray, size: int) -> np.ndarray:
    """Lower median of the valid samples of each size x size window (replicated border). Interior 3x3
    windows with nine valid samples take the sorting network :func:`_median9` (the same value)."""
    h, w = disp.shape
    r = size // 2
    out = np.empty_like(disp)
    for y in numba.prange(h):
        buf = np.empty(size * size, disp.dtype)
        for x in range(w):
            if size == 3 and 0 < y < h - 1 and 0 < x < w - 1 and (
                    valid[y - 1, x - 1] & valid[y - 1, x] & valid[y - 1, x + 1] & valid[y, x - 1] & valid[y, x]
                    & valid[y, x + 1] & valid[y + 1, x - 1] & valid[y + 1, x] & valid[y + 1, x + 1]):
                out[y, x] = _median9(disp[y - 1, x - 1], disp[y - 1, x], disp[y - 1, x + 1], disp[y, x - 1],
                                     disp[y, x], disp[y, x + 1], disp[y + 1, x - 1], disp[y + 1, x],
                                     disp[y + 1, x + 1])
                continue
            n = 0
            for yy in range(y - r, y + r + 1):
                yc = min(max(yy, 0), h - 1)
                for xx in range(x - r, x + r + 1):
                    xc = min(max(xx, 0), w - 1)
                    if valid[yc, xc]:
                        v = disp[yc, xc]
                        j = n  # insertion sort
                        while j > 0 and buf[j - 1] > v:
                            buf[j] = buf[j - 1]
                            j -= 1
                        buf[j] = v
                        n += 1
            out[y, x] = buf[(n - 1) // 2] if n > 0 else disp[y, x]
    return out


@numba.njit(cache=True, fastmath=False)  # integer labels and exact comparisons
def speckle_kernel(disp: np.ndarray, valid: np.ndarray, max_size: int, max_diff: float) -> np.ndarray:
    """Flood fill of 4-connected regions of valid pixels whose neighbours differ by <= max_diff."""
    h, w = disp.shape
    label = np.zeros((h, w), dtype=np.int32)
    out = valid.copy()
    stack = np.empty(h * w, dtype=np.int64)
    members = np.empty(h * w, dtype=np.int64)
    current = 0
    for y0 in range(h):
        for x0 in range(w):
            if not valid[y0, x0] or label[y0, x0] != 0:
                continue
            current += 1
            label[y0, x0] = current
            top = 0
            stack[top] = y0 * w + x0
            top += 1
            count = 0
            while top > 0:
                top -= 1
                p = stack[top]
                members[count] = p
                count += 1
                y = p // w
                x = p - y * w
                dp = disp[y, x]
                for k in range(4):
                    ny, nx = y, x
                    if k == 0:
                        ny = y - 1
                    elif k == 1:
                        ny = y + 1
                    elif k == 2:
                        nx = x - 1
                    else:
                        nx = x + 1
                    if ny < 0 or ny >= h or nx < 0 or nx >= w:
                        continue
                    if not valid[ny, nx] or label[ny, nx] != 0:
                        continue
                    if abs(disp[ny, nx] - dp) <= max_diff:
                        label[ny, nx] = current
                        stack[top] = ny * w + nx
                        top += 1
            if count < max_size:
                for i in range(count):
                    p = members[i]
                    out[p // w, p - (p // w) * w] = False
    return out
