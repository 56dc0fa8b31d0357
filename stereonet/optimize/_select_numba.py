"""Numba kernel of the local selection on an ``(H, W, D)`` float32 volume: WTA, uniqueness, sub-pixel
refinement and the right-reference WTA in one pass (same rules as :mod:`stereonet.optimize.wta`,
:mod:`stereonet.optimize.subpixel` and :func:`stereonet.optimize.lr_check.wta_right`, tested equal)."""

from __future__ import annotations

import numba
import numpy as np
from numba import prange


@numba.njit(fastmath={"nnan", "nsz", "reassoc"}, inline="always")
def _min_range(c, lo, hi):
    """min of c[lo:hi] (+inf when empty); vectorised (the volume holds no NaN)."""
    m = np.float32(3.4e38)
    for d in range(max(lo, 0), hi):
        m = min(m, c[d])
    return m if hi > max(lo, 0) else np.float32(np.inf)


@numba.njit(inline="always")
def _wta_right_row(row, out):
    """Right-reference WTA of one row (W, D) into out (W,), ties to the smallest disparity."""
    W, D = row.shape
    best = np.empty(W, np.float32)
    for x in range(W):
        best[x] = row[x, 0]
        out[x] = 0
    for x in range(W):
        for d in range(1, min(D, x + 1)):
            v = row[x, d]
            if v < best[x - d]:
                best[x - d] = v
                out[x - d] = d


@numba.njit(parallel=True, cache=True)
def select_hwd(vol, method, ratio, lr_tol):
    """Args: vol (H, W, D) float32; method 0 = none, 1 = parabola, 2 = equiangular; ratio in [0, 1);
    lr_tol: LR-check tolerance (< 0 = no check).

    Returns: disp (H, W) float32 (refined), min_cost (H, W) float32, unique (H, W) bool,
    disp_right (H, W) float32 (integer-valued right-reference WTA, ties to the smallest disparity),
    lr_ok (H, W) bool (:func:`stereonet.optimize.lr_check.left_right_check` of the integer WTA disparity
    and disp_right, i.e. before sub-pixel refinement).
    """
    H, W, D = vol.shape
    disp = np.empty((H, W), np.float32)
    disp_int = np.empty((H, W), np.float32)
    min_cost = np.empty((H, W), np.float32)
    unique = np.ones((H, W), np.bool_)
    disp_right = np.zeros((H, W), np.float32)
    lr_ok = np.ones((H, W), np.bool_)
    keep = np.float32(1.0 - ratio)
    for y in prange(H):
        for x in range(W):
            c = vol[y, x]
            best = _min_range(c, 0, D)
            bi = 0
            while c[bi] != best:  # first index of the minimum (ties to the smallest d)
                bi += 1
            if ratio > 0:
                second = min(_min_range(c, 0, bi - 1), _min_range(c, bi + 2, D))
                unique[y, x] = best <= keep * second
            min_cost[y, x] = best
            off = np.float32(0.0)
            if method > 0 and 0 < bi < D - 1:
                cm = c[bi - 1]
                cp = c[bi + 1]
                if method == 1:
                    den = np.float32(2.0) * (cm - np.float32(2.0) * best + cp)
                else:
                    den = np.float32(2.0) * max(cm - best, cp - best)
                if den > 0:
                    off = (cm - cp) / den
                    off = min(max(off, np.float32(-0.5)), np.float32(0.5))
            disp[y, x] = np.float32(bi) + off
            disp_int[y, x] = bi
        _wta_right_row(vol[y], disp_right[y])
        if lr_tol >= 0:
            for x in range(W):
                xr = x - int(disp_int[y, x])
                if xr < 0:
                    lr_ok[y, x] = False
                else:
                    lr_ok[y, x] = abs(disp_int[y, x] - disp_right[y, xr]) <= lr_tol
    return disp, min_cost, unique, disp_right, lr_ok


@numba.njit(parallel=True, cache=True)
def wta_right_hwd(vol):
    """Right-reference WTA (H, W) float32 of a left-reference (H, W, D) volume, ties to the smallest d."""
    H, W, D = vol.shape
    disp_right = np.zeros((H, W), np.float32)
    for y in prange(H):
        _wta_right_row(vol[y], disp_right[y])
    return disp_right
