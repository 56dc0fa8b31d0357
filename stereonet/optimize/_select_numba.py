"""Numba kernel of the local selection on an ``(H, W, D)`` float32 volume: WTA, uniqueness, sub-pixel
refinement and the right-reference WTA in one pass (same rules as :mod:`stereonet.optimize.wta`,
:mod:`stereonet.optimize.subpixel` and :func:`stereonet.optimize.lr_check.wta_right`, tested equal)."""

from __future__ import annotations

import numba
import numpy as np
from numba import prange


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
        right_best = np.empty(W, np.float32)
        for x in range(W):
            right_best[x] = vol[y, x, 0]  # d = 0
        for x in range(W):
            c = vol[y, x]
            best = c[0]
            bi = 0
            for d in range(1, D):
                v = c[d]
                if v < best:
                    best = v
                    bi = d
                xr = x - d  # the right-reference WTA: x ascending visits d ascending for a fixed xr
                if xr >= 0 and v < right_best[xr]:
                    right_best[xr] = v
                    disp_right[y, xr] = d
            if ratio > 0:
                second = np.float32(np.inf)
                for d in range(D):
                    if abs(d - bi) > 1 and c[d] < second:
                        second = c[d]
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
        best = np.empty(W, np.float32)
        for x in range(W):
            best[x] = vol[y, x, 0]
        for x in range(W):
            for d in range(1, min(D, x + 1)):
                v = vol[y, x, d]
                if v < best[x - d]:
                    best[x - d] = v
                    disp_right[y, x - d] = d
    return disp_right
