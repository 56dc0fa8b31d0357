"""Numba kernels of the disparity filters (:mod:`stereonet.select.filters`): the 3x3 median by a sorting
network (larger windows by sorting) over valid pixels, and the speckle filter's connected components."""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(inline="always", fastmath=False)
def _sort2(a, b):
    """Compare-exchange written as two selects (no branch: LLVM vectorises the loops that use it);
    ``a <= b`` false (b smaller, or a NaN) swaps, as ``(a, b) if a <= b else (b, a)`` does."""
    lo = a if a <= b else b
    hi = b if a <= b else a
    return lo, hi


@numba.njit(inline="always", fastmath=False)
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
    """Lower median of the valid samples of each size x size window (replicated border).

    3x3: one branch-free pass of the sorting network :func:`_median9` over every interior pixel (vectorised
    over the row; the same value as sorting nine samples), then, where a window holds ``m`` invalid pixels,
    the network again with ``j = 4 - (8 - m) // 2`` of them set to -inf and the rest to +inf, so that its 5th
    smallest is the ``(n - 1) // 2``-th of the ``n = 9 - m`` valid ones (the lower median). Windows across
    the border, and other sizes, sort their valid samples.
    """
    h, w = disp.shape
    r = size // 2
    out = np.empty_like(disp)
    net = size == 3 and h >= 3 and w >= 3
    if net:
        for y in numba.prange(1, h - 1):
            a, b, c = disp[y - 1], disp[y], disp[y + 1]
            o = out[y]
            for x in range(1, w - 1):
                o[x] = _median9(a[x - 1], a[x], a[x + 1], b[x - 1], b[x], b[x + 1], c[x - 1], c[x], c[x + 1])
    for y in numba.prange(h):
        buf = np.empty(size * size, disp.dtype)
        for x in range(w):
            if net and 0 < y < h - 1 and 0 < x < w - 1:
                m = 0
                for k in range(9):
                    m += not valid[y - 1 + k // 3, x - 1 + k % 3]
                if m == 0:
                    continue  # the network's value stands
                if m < 9:
                    j = 4 - (8 - m) // 2  # invalid samples sent to -inf; the other m - j to +inf
                    for k in range(9):
                        yy, xx = y - 1 + k // 3, x - 1 + k % 3
                        if valid[yy, xx]:
                            buf[k] = disp[yy, xx]
                        elif j > 0:
                            buf[k] = -np.inf
                            j -= 1
                        else:
                            buf[k] = np.inf
                    out[y, x] = _median9(buf[0], buf[1], buf[2], buf[3], buf[4], buf[5], buf[6], buf[7], buf[8])
                else:
                    out[y, x] = disp[y, x]
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


WMF_MIN_LOG_WEIGHT = -45.0
"""The weighted median's log-weights are floored here (weights >= e^-45 ~ 3e-20), in every backend."""


@numba.njit(cache=True, fastmath=False, inline="always")
def exp_sq(x):
    """exp(x) for WMF_MIN_LOG_WEIGHT <= x <= 0 (x below is taken as the floor) as exp(x / 64) ** 64: a degree-13
    Taylor polynomial, then six squarings; relative error ~1e-11, and plain arithmetic, so the loops that call it
    vectorise (numba has no vector exp without SVML)."""
    r = max(x, WMF_MIN_LOG_WEIGHT) * (1.0 / 64.0)
    p = 1.0 / 6227020800.0
    p = p * r + 1.0 / 479001600.0
    p = p * r + 1.0 / 39916800.0
    p = p * r + 1.0 / 3628800.0
    p = p * r + 1.0 / 362880.0
    p = p * r + 1.0 / 40320.0
    p = p * r + 1.0 / 5040.0
    p = p * r + 1.0 / 720.0
    p = p * r + 1.0 / 120.0
    p = p * r + 1.0 / 24.0
    p = p * r + 1.0 / 6.0
    p = p * r + 0.5
    p = p * r + 1.0
    p = p * r + 1.0
    p = p * p
    p = p * p
    p = p * p
    p = p * p
    p = p * p
    return p * p


@numba.njit(parallel=True, cache=True, fastmath=False)  # exact comparisons: equal to the torch reference
def weighted_median_kernel(disp: np.ndarray, guide: np.ndarray, valid: np.ndarray, radius: int, sigma_color: float,
                           sigma_space: float, jump: float, stride: int, band: int) -> np.ndarray:
    """Joint weighted median of ``disp`` (H, W) float32 guided by ``guide`` (C, H, W) float32: see
    :func:`stereonet.select.filters.weighted_median_filter` (same rule; weights and sums in float64). The
    median is found without sorting the window: a histogram of 1 px bins finds the bin where the cumulative
    weight crosses half the total, 256 sub-bins of that bin narrow it down, and only the crossing sub-bin's
    samples are sorted (by value, ties in raster order), which gives the same value as sorting them all. The window's
    samples lie at offsets that are multiples of ``stride`` (``rk = radius // stride`` of them each way); a pixel is
    filtered when a discontinuity lies within ``band`` px (Chebyshev)."""
    C, H, W = guide.shape
    out = disp.copy()
    inv_c = -0.5 / (sigma_color * sigma_color)
    inv_s = -0.5 / (sigma_space * sigma_space)
    rk = radius // stride
    k = 2 * rk + 1
    space = np.empty(k * k, np.float64)
    for i in range(k):
        for j in range(k):
            space[i * k + j] = (((i - rk) * stride) ** 2 + ((j - rk) * stride) ** 2) * inv_s
    edge = np.zeros((H, W), np.bool_)
    for y in numba.prange(H):
        for x in range(W):
            if valid[y, x]:
                v = np.float64(disp[y, x])
                if x + 1 < W and valid[y, x + 1] and abs(np.float64(disp[y, x + 1]) - v) > jump:
                    edge[y, x] = True
                if y + 1 < H and valid[y + 1, x] and abs(np.float64(disp[y + 1, x]) - v) > jump:
                    edge[y, x] = True
    colhit = np.zeros((H, W), np.bool_)
    for y in numba.prange(H):
        for yy in range(max(y - band, 0), min(y + band, H - 1) + 1):
            for x in range(W):
                colhit[y, x] |= edge[yy, x]
    near = np.zeros((H, W), np.bool_)
    for y in numba.prange(H):
        for x in range(W):
            h = False
            for xx in range(max(x - band, 0), min(x + band, W - 1) + 1):
                h |= colhit[y, xx]
            near[y, x] = h
    gmin = np.inf
    gmax = -np.inf
    for y in range(H):
        for x in range(W):
            if valid[y, x]:
                gmin = min(gmin, np.float64(disp[y, x]))
                gmax = max(gmax, np.float64(disp[y, x]))
    if not gmax >= gmin:
        return out
    fmin = math.floor(gmin)
    n_bins = int(math.floor(gmax) - fmin) + 1
    binmap = np.empty((H, W), np.int64)
    for y in numba.prange(H):
        for x in range(W):
            binmap[y, x] = int(math.floor(np.float64(disp[y, x])) - fmin) if valid[y, x] else -1
    n_max = k * k
    for y in numba.prange(H):
        vals = np.empty(n_max, np.float32)
        wts = np.empty(n_max, np.float64)
        bins = np.empty(n_max, np.int64)
        hist = np.zeros(n_bins, np.float64)
        members = np.empty(n_max, np.int64)
        dcrow = np.empty(k, np.float64)
        wrow = np.empty(k, np.float64)
        fine = np.empty(256, np.float64)
        fidx = np.empty(n_max, np.int64)
        gc = np.empty(C, np.float64)
        for x in range(W):
            if not near[y, x]:
                continue
            jy0, jy1 = -min(rk, y // stride), min(rk, (H - 1 - y) // stride)  # window offsets / stride
            jx0, jx1 = -min(rk, x // stride), min(rk, (W - 1 - x) // stride)
            x0 = x + jx0 * stride
            m = jx1 - jx0 + 1
            for c in range(C):
                gc[c] = np.float64(guide[c, y, x])
            n = 0
            blo, bhi = n_bins, -1
            for jy in range(jy0, jy1 + 1):
                yy = y + jy * stride
                for i in range(m):
                    dcrow[i] = 0.0
                for c in range(C):
                    g0 = gc[c]
                    for i in range(m):
                        g = np.float64(guide[c, yy, x0 + i * stride]) - g0
                        dcrow[i] += g * g
                srow = (jy + rk) * k + (jx0 + rk)
                for i in range(m):
                    wrow[i] = exp_sq(dcrow[i] * inv_c + space[srow + i])
                for i in range(m):
                    b = binmap[yy, x0 + i * stride]
                    if b >= 0:
                        vals[n] = disp[yy, x0 + i * stride]
                        wts[n] = wrow[i]
                        bins[n] = b
                        blo = min(blo, b)
                        bhi = max(bhi, b)
                        n += 1
            if n == 0:
                continue
            for b in range(blo, bhi + 1):
                hist[b] = 0.0
            total = 0.0
            for i in range(n):
                hist[bins[i]] += wts[i]
            for b in range(blo, bhi + 1):
                total += hist[b]
            half = 0.5 * total
            acc = 0.0
            b = blo
            while b < bhi and acc + hist[b] < half:
                acc += hist[b]
                b += 1
            # within the crossing 1 px bin: 256 fine bins, then sort only the crossing fine bin's members
            for f in range(256):
                fine[f] = 0.0
            base = np.float64(b + fmin)
            for i in range(n):
                if bins[i] == b:
                    f = min(int((np.float64(vals[i]) - base) * 256.0), 255)
                    fidx[i] = f
                    fine[f] += wts[i]
            f = 0
            while f < 255 and acc + fine[f] < half:
                acc += fine[f]
                f += 1
            cnt = 0
            for i in range(n):
                if bins[i] == b and fidx[i] == f:
                    members[cnt] = i
                    cnt += 1
            for a in range(1, cnt):
                cur = members[a]
                j = a - 1
                while j >= 0 and vals[members[j]] > vals[cur]:
                    members[j + 1] = members[j]
                    j -= 1
                members[j + 1] = cur
            res = vals[members[cnt - 1]]
            for j in range(cnt):
                acc += wts[members[j]]
                if acc >= half:
                    res = vals[members[j]]
                    break
            out[y, x] = res
    return out
