"""Numba CPU kernels for cost volumes in ``(H, W, D)`` float32 layout (disparity innermost).

They compute exactly the definitions of :mod:`stereonet.cost.volume` (tested equal to the torch path):
right pixels left of the image are replaced by the border column while aggregating, box means are over
the in-image part of the window, and out-of-image matches get ``max(volume before filling) + 1`` at the end.
Rows (or columns) run in parallel with ``prange``.
"""

from __future__ import annotations

import numba
import numpy as np
from numba import prange

_M1 = np.uint64(0x5555555555555555)
_M2 = np.uint64(0x3333333333333333)
_M4 = np.uint64(0x0F0F0F0F0F0F0F0F)
_H01 = np.uint64(0x0101010101010101)


@numba.njit(inline="always")
def _popcount(x):
    x = x - ((x >> np.uint64(1)) & _M1)
    x = (x & _M2) + ((x >> np.uint64(2)) & _M2)
    x = (x + (x >> np.uint64(4))) & _M4
    return (x * _H01) >> np.uint64(56)


@numba.njit(parallel=True, cache=True)
def pixel_diff(left, right, n_disp, squared):
    """left/right (H, W, C) float32 -> (H, W, D): mean over channels of |l - r| (or (l - r)**2)."""
    H, W, C = left.shape
    out = np.empty((H, W, n_disp), np.float32)
    inv_c = np.float32(1.0 / C)
    for y in prange(H):
        for x in range(W):
            for d in range(n_disp):
                xr = x - d
                if xr < 0:
                    xr = 0
                acc = np.float32(0.0)
                for c in range(C):
                    v = left[y, x, c] - right[y, xr, c]
                    if squared:
                        acc += v * v
                    else:
                        acc += abs(v)
                out[y, x, d] = acc * inv_c
    return out


@numba.njit(parallel=True, cache=True)
def pixel_hamming(codes_left, codes_right, n_disp):
    """codes (H, W, K) uint64 -> (H, W, D) float32 Hamming distances."""
    H, W, K = codes_left.shape
    out = np.empty((H, W, n_disp), np.float32)
    for y in prange(H):
        for x in range(W):
            for d in range(n_disp):
                xr = x - d
                if xr < 0:
                    xr = 0
                n = np.uint64(0)
                for k in range(K):
                    n += _popcount(codes_left[y, x, k] ^ codes_right[y, xr, k])
                out[y, x, d] = np.float32(n)
    return out


@numba.njit(parallel=True, cache=True)
def pixel_product(left, right, n_disp):
    """grey left/right (H, W) float32 -> (H, W, D) products l * r(x - d)."""
    H, W = left.shape
    out = np.empty((H, W, n_disp), np.float32)
    for y in prange(H):
        for x in range(W):
            for d in range(n_disp):
                xr = x - d
                if xr < 0:
                    xr = 0
                out[y, x, d] = left[y, x] * right[y, xr]
    return out


@numba.njit(cache=True)
def _running_mean(src, dst, r):
    """dst[i, :] = mean of src[max(i - r, 0) : min(i + r, N - 1) + 1, :] (float64 running sums)."""
    N, D = src.shape
    acc = np.zeros(D, np.float64)
    for i in range(min(r, N)):
        for d in range(D):
            acc[d] += src[i, d]
    for i in range(N):
        if i + r < N:
            for d in range(D):
                acc[d] += src[i + r, d]
        if i - r - 1 >= 0:
            for d in range(D):
                acc[d] -= src[i - r - 1, d]
        n = min(i + r, N - 1) - max(i - r, 0) + 1
        for d in range(D):
            dst[i, d] = acc[d] / n


@numba.njit(parallel=True, cache=True)
def box_mean_hwd(vol, window):
    """In-place mean over the in-image part of a window x window square, per disparity."""
    H, W, D = vol.shape
    r = window // 2
    for x in prange(W):
        _running_mean(vol[:, x, :].copy(), vol[:, x, :], r)  # HxD column
    for y in prange(H):
        _running_mean(vol[y].copy(), vol[y], r)  # WxD row


@numba.njit(parallel=True, cache=True)
def ncc_finalize(vol, mu_l, var_l, mu_r, var_r, min_var):
    """In place: E[l r] -> 1 - NCC, NCC := 0 where a variance is <= min_var; clipped to [-1, 1]."""
    H, W, D = vol.shape
    for y in prange(H):
        for x in range(W):
            for d in range(D):
                xr = x - d
                if xr < 0:
                    xr = 0
                vr = var_r[y, xr]
                if var_l[y, x] > min_var and vr > min_var:
                    ncc = (vol[y, x, d] - mu_l[y, x] * mu_r[y, xr]) / np.sqrt(var_l[y, x] * vr)
                    if ncc > 1.0:
                        ncc = 1.0
                    elif ncc < -1.0:
                        ncc = -1.0
                else:
                    ncc = 0.0
                vol[y, x, d] = 1.0 - ncc


@numba.njit(parallel=True, cache=True)
def multiwindow_hwd(vol, window):
    """Five-window cost: (centre + two best of the four corner windows) / 3, corners at (±r, ±r)."""
    H, W, D = vol.shape
    r = window // 2
    out = np.empty_like(vol)
    for y in prange(H):
        y0 = max(y - r, 0)
        y1 = min(y + r, H - 1)
        for x in range(W):
            x0 = max(x - r, 0)
            x1 = min(x + r, W - 1)
            for d in range(D):
                a = vol[y0, x0, d]
                b = vol[y0, x1, d]
                c = vol[y1, x0, d]
                e = vol[y1, x1, d]
                # two smallest of four
                lo1 = min(a, b)
                hi1 = max(a, b)
                lo2 = min(c, e)
                hi2 = max(c, e)
                best = min(lo1, lo2)
                second = min(max(lo1, lo2), min(hi1, hi2))
                out[y, x, d] = (vol[y, x, d] + (best + second)) / np.float32(3.0)
    return out


@numba.njit(parallel=True, cache=True)
def min_filter_hwd(vol, window):
    """Minimum over the in-image part of a window x window square, per disparity (separable)."""
    H, W, D = vol.shape
    r = window // 2
    tmp = np.empty_like(vol)
    for y in prange(H):
        for x in range(W):
            for d in range(D):
                m = vol[y, x, d]
                for k in range(max(x - r, 0), min(x + r, W - 1) + 1):
                    if vol[y, k, d] < m:
                        m = vol[y, k, d]
                tmp[y, x, d] = m
    out = np.empty_like(vol)
    for y in prange(H):
        for x in range(W):
            for d in range(D):
                m = tmp[y, x, d]
                for k in range(max(y - r, 0), min(y + r, H - 1) + 1):
                    if tmp[k, x, d] < m:
                        m = tmp[k, x, d]
                out[y, x, d] = m
    return out


@numba.njit(parallel=True, cache=True)
def fill_invalid_hwd(vol, fill):
    """vol[y, x, d] = fill for x < d."""
    H, W, D = vol.shape
    for y in prange(H):
        for x in range(W):
            for d in range(x + 1, D):
                vol[y, x, d] = fill


@numba.njit(parallel=True, cache=True)
def census_hwk(grey, window, bits_per_word):
    """Census codes (H, W, K) uint64 of a grey (H, W) image: same bit order as
    :func:`stereonet.cost.census.census_transform` (row-major neighbours, centre skipped, border replicated).
    The inner loop runs along x for one neighbour offset at a time (vectorisable)."""
    H, W = grey.shape
    r = window // 2
    n_bits = window * window - 1
    K = (n_bits + bits_per_word - 1) // bits_per_word
    out = np.zeros((H, W, K), np.uint64)
    for y in prange(H):
        words = np.zeros((K, W), np.uint64)
        centre = grey[y]
        bit = 0
        for dy in range(window):
            src = grey[min(max(y + dy - r, 0), H - 1)]
            for dx in range(window):
                if dy == r and dx == r:
                    continue
                k = bit // bits_per_word
                sh = np.uint64(bit - k * bits_per_word)
                wk = words[k]
                for x in range(W):
                    xx = min(max(x + dx - r, 0), W - 1)
                    wk[x] |= np.uint64(src[xx] < centre[x]) << sh
                bit += 1
        for x in range(W):
            for k in range(K):
                out[y, x, k] = words[k, x]
    return out


@numba.njit(parallel=True, cache=True)
def pixel_census_ad(codes_left, codes_right, left, right, n_disp, lambda_census, lambda_ad):
    """AD-Census ``2 - exp(-hamming / lambda_census) - exp(-ad / lambda_ad)`` -> (H, W, D) float32."""
    H, W, K = codes_left.shape
    C = left.shape[2]
    out = np.empty((H, W, n_disp), np.float32)
    inv_c = np.float32(1.0 / C)
    for y in prange(H):
        for x in range(W):
            for d in range(n_disp):
                xr = x - d
                if xr < 0:
                    xr = 0
                n = np.uint64(0)
                for k in range(K):
                    n += _popcount(codes_left[y, x, k] ^ codes_right[y, xr, k])
                acc = np.float32(0.0)
                for c in range(C):
                    acc += abs(left[y, x, c] - right[y, xr, c])
                ham = np.float32(n)
                out[y, x, d] = (np.float32(2.0) - np.exp(-ham / lambda_census)) - np.exp(-(acc * inv_c) / lambda_ad)
    return out
