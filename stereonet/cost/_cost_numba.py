"""Numba CPU helpers of the cost volumes: box means of ``(H, W, C)`` float32 images, census codes and the
out-of-image fill of ``(H, W, D)`` volumes. The volumes themselves are computed row by row by
:mod:`stereonet.cost._block_numba`. Rows (or columns) run in parallel with ``prange``.
"""

from __future__ import annotations

import numba
import numpy as np
from numba import prange


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
def fill_invalid_hwd(vol, fill):
    """vol[y, x, d] = fill for x < d."""
    H, W, D = vol.shape
    for y in prange(H):
        for x in range(W):
            for d in range(x + 1, D):
                vol[y, x, d] = fill


@numba.njit(parallel=True, cache=True)
def census_khw(grey, window, bits_per_word):
    """Census codes (K, H, W) uint64 of a grey (H, W) image: same bit order as
    :func:`stereonet.cost.census.census_transform` (row-major neighbours, centre skipped, border replicated).
    The inner loop runs along x over a border-padded copy of the neighbour row, one neighbour offset at a
    time (contiguous, vectorised)."""
    H, W = grey.shape
    r = window // 2
    n_bits = window * window - 1
    K = (n_bits + bits_per_word - 1) // bits_per_word
    out = np.zeros((K, H, W), np.uint64)
    for y in prange(H):
        padded = np.empty(W + 2 * r, grey.dtype)
        centre = grey[y]
        bit = 0
        for dy in range(window):
            src = grey[min(max(y + dy - r, 0), H - 1)]
            padded[r:r + W] = src
            padded[:r] = src[0]
            padded[r + W:] = src[W - 1]
            for dx in range(window):
                if dy == r and dx == r:
                    continue
                k = bit // bits_per_word
                sh = np.uint64(bit - k * bits_per_word)
                wk = out[k, y]
                seg = padded[dx:dx + W]
                for x in range(W):
                    wk[x] |= np.uint64(seg[x] < centre[x]) << sh
                bit += 1
    return out
