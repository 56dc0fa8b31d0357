"""Numba kernel of the local selection on an ``(H, W, D)`` float32 volume: WTA, uniqueness, sub-pixel
refinement and the right-reference WTA in one pass (same rules as :mod:`stereonet.optimize.wta`,
:mod:`stereonet.optimize.subpixel` and :func:`stereonet.optimize.lr_check.wta_right`, tested equal)."""

from __future__ import annotations

import numba
import numpy as np
from numba import prange


@numba.njit(parallel=True, cache=True)
def select_hwd(vol, method, ratio):
    """Args: vol (H, W, D) float32; method 0 = none, 1 = parabola, 2 = equiangular; ratio in [0, 1).

    Returns: disp (H, W) float32 (refined), min_cost (H, W) float32, unique (H, W) bool,
    disp_right (H, W) float32 (integer-valued right-reference WTA).
    """
    H, W, D = vol.shape
    disp = np.empty((H, W), np.float32)
    min_cost = np.empty((H, W), np.float32)
    unique = np.empty((H, W), np.bool_)
    disp_right = np.empty((H, W), np.float32)
    keep = np.float32(1.0 - ratio)
    for y in prange(H):
        for x in range(W):
            c = vol[y, x]
            best = c[0]
            bi = 0
            for d in range(1, D):
                if c[d] < best:
                    best = c[d]
                    bi = d
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
        for xr in range(W):
            best = vol[y, xr, 0]
            bi = 0
            for d in range(1, min(D, W - xr)):
                v = vol[y, xr + d, d]
                if v < best:
                    best = v
                    bi = d
            disp_right[y, xr] = bi
    return disp, min_cost, unique, disp_right
