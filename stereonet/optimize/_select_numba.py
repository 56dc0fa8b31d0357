"""Numba kernel of the local selection on an ``(H, W, D)`` float32 volume: WTA, uniqueness, sub-pixel
refinement and the right-reference WTA in one pass (same rules as :mod:`stereonet.optimize.wta`,
:mod:`stereonet.optimize.subpixel` and :func:`stereonet.optimize.lr_check.wta_right`, tested equal)."""

from __future__ import annotations

import numba
import numpy as np
from numba import prange


@numba.njit(fastmath={"nnan", "nsz", "reassoc"}, inline="always")
def min_range(c, lo, hi):
    """min of c[lo:hi] (+inf when empty); vectorised (the volume holds no NaN)."""
    m = np.float32(3.4e38)
    for d in range(max(lo, 0), hi):
        m = min(m, c[d])
    return m if hi > max(lo, 0) else np.float32(np.inf)


@numba.njit(inline="always")
def wta_right_row(row, out):
    """Right-reference WTA of one row (W, D) into out (W,), ties to the smallest disparity.

    Disparity-outer loop over the diagonal ``row[xr + d, d]`` (a strided slice of the flat row), branch-free
    inner loop over xr (vectorised)."""
    W, D = row.shape
    flat = row.ravel()
    best = row[:, 0].copy()
    out[:] = 0
    for d in range(1, min(D, W)):
        diag = flat[d * (D + 1)::D]  # diag[xr] = row[xr + d, d]
        fd = np.float32(d)
        for xr in range(W - d):
            v = diag[xr]
            b = best[xr]
            take = v < b
            best[xr] = v if take else b
            out[xr] = fd if take else out[xr]


@numba.njit(inline="always")
def first_argmin(c, n):
    """(min of c[:n], first index of it); ties resolve to the smallest index."""
    best = min_range(c, 0, n)
    bi = 0
    while c[bi] != best:
        bi += 1
    return best, bi


@numba.njit(inline="always")
def is_unique(best, second, keep):
    """The uniqueness rule of :func:`stereonet.optimize.wta.uniqueness_mask`: best <= (1 - ratio) * second."""
    return best <= keep * second


@numba.njit(inline="always")
def subpixel_offset(best, cm, cp, method):
    """Offset in [-0.5, 0.5] of the parabola (method 1) or equiangular (2) fit through c(d-1), c(d), c(d+1);
    0 for a degenerate fit."""
    if method == 1:
        den = np.float32(2.0) * (cm - np.float32(2.0) * best + cp)
    else:
        den = np.float32(2.0) * max(cm - best, cp - best)
    off = np.float32(0.0)
    if den > 0:
        off = (cm - cp) / den
        off = min(max(off, np.float32(-0.5)), np.float32(0.5))
    return off


@numba.njit(inline="always")
def lr_check_row(disp_int, disp_right, lr_ok, lr_tol):
    """LR check of one row: integer left disparities (W,) against the right-reference row (W,)."""
    for x in range(disp_int.shape[0]):
        xr = x - int(disp_int[x])
        if xr < 0:
            lr_ok[x] = False
        else:
            lr_ok[x] = abs(disp_int[x] - disp_right[xr]) <= lr_tol


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
            best, bi = first_argmin(c, D)
            if ratio > 0:
                unique[y, x] = is_unique(best, min(min_range(c, 0, bi - 1), min_range(c, bi + 2, D)), keep)
            min_cost[y, x] = best
            off = np.float32(0.0)
            if method > 0 and 0 < bi < D - 1:
                off = subpixel_offset(best, c[bi - 1], c[bi + 1], method)
            disp[y, x] = np.float32(bi) + off
            disp_int[y, x] = bi
        wta_right_row(vol[y], disp_right[y])
        if lr_tol >= 0:
            lr_check_row(disp_int[y], disp_right[y], lr_ok[y], lr_tol)
    return disp, min_cost, unique, disp_right, lr_ok


@numba.njit(parallel=True, cache=True)
def wta_right_hwd(vol):
    """Right-reference WTA (H, W) float32 of a left-reference (H, W, D) volume, ties to the smallest d."""
    H, W, D = vol.shape
    disp_right = np.zeros((H, W), np.float32)
    for y in prange(H):
        wta_right_row(vol[y], disp_right[y])
    return disp_right
