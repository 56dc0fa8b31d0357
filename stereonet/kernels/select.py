"""Numba kernel of the local selection on an ``(H, W, D)`` float32 volume: WTA, uniqueness, sub-pixel
refinement and the right-reference WTA in one pass (same rules as :mod:`stereonet.select.wta`,
:mod:`stereonet.select.subpixel` and :func:`stereonet.select.lr_check.wta_right`, tested equal).

Every kernel is compiled with ``fastmath=False``: the minima start at +inf sentinels and NaN costs must
never win, which fastmath's no-inf/no-NaN assumptions would let the compiler break."""

from __future__ import annotations

import numba
import numpy as np
from numba import prange

from stereonet.kernels.confidence import clipped_margin


@numba.njit(inline="always", fastmath=False)
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


@numba.njit(inline="always", fastmath=False)
def is_unique(best, second, keep):
    """The uniqueness rule of :func:`stereonet.select.wta.uniqueness_mask`: best <= (1 - ratio) * second."""
    return best <= keep * second


@numba.njit(inline="always", fastmath=False)
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


@numba.njit(inline="always", fastmath=False)
def lr_check_row(disp_int, disp_right, lr_ok, lr_tol):
    """LR check of one row: integer left disparities (W,) against the right-reference row (W,)."""
    for x in range(disp_int.shape[0]):
        xr = x - int(disp_int[x])
        if xr < 0:
            lr_ok[x] = False
        else:
            lr_ok[x] = abs(disp_int[x] - disp_right[xr]) <= lr_tol


def select_hwd(vol, method, ratio, lr_tol):
    """Args: vol (H, W, D) float32; method 0 = none, 1 = parabola, 2 = equiangular; ratio in [0, 1);
    lr_tol: LR-check tolerance (< 0 = no check).

    Returns: disp (H, W) float32 (refined), min_cost (H, W) float32, unique (H, W) bool,
    disp_right (H, W) float32 (integer-valued right-reference WTA, ties to the smallest disparity),
    lr_ok (H, W) bool (:func:`stereonet.select.lr_check.left_right_check` of the integer WTA disparity
    and disp_right, i.e. before sub-pixel refinement). Each row is transposed to (D, W) and selected by
    :func:`select_row_t` (:func:`_select_kernel` without the confidence).
    """
    return _select_kernel(vol, method, ratio, lr_tol, np.float32(0.0), False, np.float32(1.0))[:5]


def select_confidence_hwd(vol, method, ratio, lr_tol, eps, inv_scale=1.0):
    """:func:`select_hwd` plus the cost-margin confidence (H, W) float32 of
    :func:`stereonet.select.confidence.cost_margin_confidence` with ``exclude=1``, from the same pass:
    its best cost is the WTA minimum and its competitor the uniqueness test's second best (both over
    ``|d - best| > 1``). Pixels whose best or second is not finite get the general rule
    (:func:`_margin_scalar`), so the confidence equals the separate kernel's on any volume.

    ``vol`` may also be a fixed-point int16 volume (:func:`stereonet.kernels.sgm.sgm_fixed_hwd`) with
    ``inv_scale`` = 1 / s: each cost row is converted (``float32(v) * inv_scale``, exact for a power-of-two
    scale) as it is transposed, so the result equals the selection of the float32 volume.

    Returns: ``(disp, min_cost, unique, disp_right, lr_ok, confidence)``.
    """
    if vol.dtype == np.int16 and vol.shape[2] >= 4:
        return _select_kernel_i16(vol, method, ratio, lr_tol, np.float32(eps), np.float32(inv_scale))
    return _select_kernel(vol, method, ratio, lr_tol, np.float32(eps), True, np.float32(inv_scale))


@numba.njit(cache=True, fastmath=False)
def _margin_scalar(c, exclude, eps):
    """:func:`stereonet.kernels.confidence.cost_margin_hwd` of one cost curve (D,): the general
    rule (NaN and +inf never win), for the rare pixels where the selection's best or second is not finite."""
    inf = np.float32(np.inf)
    c1 = inf
    i1 = -1
    for d in range(c.shape[0]):
        if c[d] < c1:
            c1 = c[d]
            i1 = d
    if i1 < 0:
        return np.float32(0.0)
    c2 = inf
    for d in range(c.shape[0]):
        if abs(d - i1) > exclude and c[d] < c2:
            c2 = c[d]
    if c2 == inf:
        return np.float32(1.0)
    return clipped_margin(c1, c2, eps)


@numba.njit(inline="always")
def _selection_outputs(H, W):
    """The (H, W) outputs of both selection kernels: disp, min_cost (filled by every pixel), unique and lr_ok
    (True until a test fails), disp_right (0 = the WTA start), confidence (0 unless computed)."""
    return (np.empty((H, W), np.float32), np.empty((H, W), np.float32), np.ones((H, W), np.bool_),
            np.zeros((H, W), np.float32), np.ones((H, W), np.bool_), np.zeros((H, W), np.float32))


# fastmath=False: +inf is the "no competitor" sentinel and NaN must never win (see stereonet.kernels.confidence)
@numba.njit(parallel=True, cache=True, fastmath=False)
def _select_kernel(vol, method, ratio, lr_tol, eps, with_conf, inv_scale):
    """The one selection pass of :func:`select_hwd` and (``with_conf``) :func:`select_confidence_hwd`;
    returns ``(disp, min_cost, unique, disp_right, lr_ok, confidence)`` (confidence zeros without it).
    The costs are ``vol * inv_scale`` (1 for a float32 volume: the same bits)."""
    H, W, D = vol.shape
    disp, min_cost, unique, disp_right, lr_ok, conf = _selection_outputs(H, W)
    keep = np.float32(1.0 - ratio)
    inf = np.float32(np.inf)
    n_chunks = min(H, 64)  # row chunks (per-chunk buffers), plenty for any thread count
    for chunk in prange(n_chunks):
        T = np.empty((D, W), np.float32)
        dint = np.empty(W, np.float32)
        best = np.empty((2, W), np.float32)
        second = np.empty((2, W), np.float32)
        best_r = np.empty((2, W), np.float32)
        bi, ri = np.empty((2, W), np.int32), np.empty((2, W), np.int32)
        strip = np.zeros((1, 1, 4), np.float32)
        for y in range(chunk * H // n_chunks, (chunk + 1) * H // n_chunks):
            transpose_row_scaled(vol[y], T, inv_scale)
            # the second best is needed for the confidence even without a uniqueness test
            select_row_t(T, y, method, keep, ratio > 0 or with_conf, False, disp, min_cost, unique, dint, strip,
                         disp_right, best, bi, second, best_r, ri)
            if with_conf and ratio <= 0:
                unique[y] = True
            if lr_tol >= 0:
                lr_check_row(dint, disp_right[y], lr_ok[y], lr_tol)
            if not with_conf:
                continue
            for x in range(W):
                c1 = best[0, x]
                c2 = second[0, x]
                if not (np.isfinite(c1) and (np.isfinite(c2) or c2 == inf)):
                    conf[y, x] = _margin_scalar(T[:, x], 1, eps)  # T[:, x] = this pixel's costs
                elif c2 == inf:
                    conf[y, x] = 1.0
                else:
                    conf[y, x] = clipped_margin(c1, c2, eps)
    return disp, min_cost, unique, disp_right, lr_ok, conf


@numba.njit(parallel=True, cache=True, fastmath=False)
def wta_right_hwd(vol):
    """Right-reference WTA (H, W) float32 of a left-reference (H, W, D) volume, ties to the smallest d."""
    H, W, D = vol.shape
    disp_right = np.zeros((H, W), np.float32)
    for y in prange(H):
        wta_right_row(vol[y], disp_right[y])
    return disp_right


@numba.njit(cache=True, fastmath=False)
def transpose_row_scaled(row, T, inv_scale):
    """T[d, x] = float32(row[x, d]) * inv_scale for a (W, D) cost row (strided stores that stay in L1; a
    float32 row with inv_scale = 1: the same bits)."""
    W, D = row.shape
    for x in range(W):
        r = row[x]
        for d in range(D):
            T[d, x] = np.float32(r[d]) * inv_scale


@numba.njit(inline="always", fastmath=False)
def _argmin_step(t, sb, si, db, di, dd):
    """One disparity of a running first minimum: ``(db, di) = (t, dd) where t < sb else (sb, si)``, elementwise.

    Read from one row of a two-row buffer and written to the other (callers alternate them): the in-place form
    ``b[x] = v if v < b[x] else b[x]`` compiles to a masked store (``vmaskmovps``), microcoded on the AMD cores
    measured and ~4x slower than this; every value is loaded before the select, so no arm holds a conditional
    load either. Strict ``<``: ties keep the smaller d, and a NaN never wins."""
    for x in range(t.shape[0]):
        v = t[x]
        b = sb[x]
        s = si[x]
        take = v < b
        db[x] = v if take else b
        di[x] = dd if take else s


@numba.njit(inline="always", fastmath=False)
def _second_step(t, sb, bi, lo_d, hi_d, db):
    """One disparity of the running second best: ``db = min(sb, t)`` where the best ``bi`` is outside
    ``[lo_d, hi_d]`` (|d - bi| > 1), else ``sb`` (two-row buffers as :func:`_argmin_step`)."""
    for x in range(t.shape[0]):
        v = t[x]
        s = sb[x]
        k = bi[x]
        far = (k > hi_d) | (k < lo_d)
        db[x] = min(s, v) if far else s


@numba.njit(cache=True, fastmath=False)
def select_row_t(T, y, method, keep, use_unique, in_image_only, disp, min_cost, unique, disp_int, strip,
                 disp_right, best, bi, second, best_r, ri):
    """Selection of one cost row given transposed, ``T`` (D, W): every loop runs along x (contiguous,
    branch-free, vectorised). Rules of :func:`select_hwd` (first minimum, uniqueness over |d - bi| > 1,
    sub-pixel fit) and :func:`wta_right_row`.

    ``in_image_only``: only d <= x are candidates (the costs at d > x, outside the right image, are not
    final yet): pixels x < D - 1 get their uniqueness/sub-pixel inputs in ``strip[y, x]`` (second best in
    the image, c(bi - 1), c(bi + 1) if in the image, bi) for a later pass; otherwise (a filled volume)
    every d is a candidate and every pixel is final. disp_int (W,) and the two-row scratch buffers best,
    second, best_r (2, W) float32 and bi, ri (2, W) int32 are per-thread (:func:`_argmin_step`); on return
    ``best[0]``, ``bi[0]`` and ``second[0]`` hold the row's best cost, its disparity and the second best.
    """
    D, W = T.shape
    best[0] = T[0]
    bi[0] = 0
    for d in range(1, D):
        p, q = (d - 1) & 1, d & 1
        lo = d if in_image_only else 0
        best[q, :lo] = best[p, :lo]
        bi[q, :lo] = bi[p, :lo]
        _argmin_step(T[d, lo:], best[p, lo:], bi[p, lo:], best[q, lo:], bi[q, lo:], np.int32(d))
    f = (D - 1) & 1
    if f:
        best[0] = best[1]
        bi[0] = bi[1]
    b0 = best[0]
    k0 = bi[0]
    if use_unique:
        second[0] = np.float32(np.inf)
        for d in range(D):
            p, q = d & 1, (d + 1) & 1
            lo = d if in_image_only else 0
            second[q, :lo] = second[p, :lo]
            _second_step(T[d, lo:], second[p, lo:], k0[lo:], np.int32(d - 1), np.int32(d + 1), second[q, lo:])
        if D & 1:
            second[0] = second[1]
    s0 = second[0]
    for x in range(W):
        nv = min(x + 1, D) if in_image_only else D
        bx = np.int64(k0[x])
        bv = b0[x]
        min_cost[y, x] = bv
        disp_int[x] = bx
        cm = T[bx - 1, x] if bx > 0 else np.float32(0.0)
        cp = T[bx + 1, x] if bx + 1 < nv else np.float32(0.0)
        if nv == D:
            if use_unique:
                unique[y, x] = is_unique(bv, s0[x], keep)
            off = np.float32(0.0)
            if method > 0 and 0 < bx < D - 1:
                off = subpixel_offset(bv, cm, cp, method)
            disp[y, x] = np.float32(bx) + off
        else:
            strip[y, x, 0] = s0[x]
            strip[y, x, 1] = cm
            strip[y, x, 2] = cp
            strip[y, x, 3] = bx
    _wta_right_t(T, best_r, ri, disp_right[y])


@numba.njit(inline="always", fastmath=False)
def _wta_right_t(T, best_r, ri, out):
    """Right-reference WTA of a transposed row ``T`` (D, W) into out (W,) float32: the candidates of right pixel
    xr are ``T[d, xr + d]`` (contiguous in xr); two-row buffers best_r (float32) and ri (int32)."""
    D, W = T.shape
    best_r[0] = T[0]
    ri[0] = 0
    n = min(D, W)
    for d in range(1, n):
        p, q = (d - 1) & 1, d & 1
        m = W - d
        best_r[q, m:] = best_r[p, m:]
        ri[q, m:] = ri[p, m:]
        _argmin_step(T[d, d:], best_r[p, :m], ri[p, :m], best_r[q, :m], ri[q, :m], np.int32(d))
    f = (n - 1) & 1
    for xr in range(W):
        out[xr] = np.float32(ri[f, xr])


@numba.njit(inline="always", fastmath=False)
def _lane_mask(take):
    """All bits set (int16 -1) where ``take``, else 0: the blend ``(a & m) | (b & ~m)`` that LLVM vectorises
    16 lanes wide, where the same ``a if take else b`` on int16 stays scalar (measured: ~7x slower)."""
    return np.int16(-1) if take else np.int16(0)


@numba.njit(cache=True, fastmath=False)
def _argmin_rows_i16(T, lo_shift, best, idx):
    """First minimum over d of ``T[d, x + d * lo_shift]`` (lo_shift 0: the left WTA; 1: the right-reference
    diagonal) into ``best`` and ``idx`` (W,) int16; strict ``<``, so ties go to the smallest d."""
    D, W = T.shape
    best[:] = T[0]
    idx[:] = 0
    for d in range(1, min(D, W) if lo_shift else D):
        t = T[d, d * lo_shift:]
        dd = np.int16(d)
        for x in range(W - d * lo_shift):
            v = t[x]
            b = best[x]
            m = _lane_mask(v < b)
            best[x] = min(v, b)
            idx[x] = (dd & m) | (idx[x] & ~m)


# fastmath=False as everywhere here; int16 has no NaN or infinity, so the blends below are exact
@numba.njit(parallel=True, cache=True, fastmath=False)
def _select_kernel_i16(vol, method, ratio, lr_tol, eps, inv_scale):
    """:func:`_select_kernel` (with the confidence) of a fixed-point int16 ``(H, W, D)`` volume, D >= 4,
    working in int16 until the selected values: the transposed row is int16 (half the bytes), the WTA,
    second-best and right-reference minima are int16 min/blend loops (16 lanes), and only the best, its two
    neighbours and the second best are converted (``float32(v) * inv_scale``, exact for a power-of-two
    scale). The same numbers as :func:`_select_kernel`: integers compare as their exact float32 images do,
    and with D >= 4 every pixel has a second best at |d - best| > 1 (no +inf case)."""
    H, W, D = vol.shape
    disp, min_cost, unique, disp_right, lr_ok, conf = _selection_outputs(H, W)
    keep = np.float32(1.0 - ratio)
    big = np.int16(32767)
    n_chunks = min(H, 64)
    for chunk in prange(n_chunks):
        T = np.empty((D, W), np.int16)
        dint = np.empty(W, np.float32)
        best = np.empty(W, np.int16)
        bi = np.empty(W, np.int16)
        second = np.empty(W, np.int16)
        best_r = np.empty(W, np.int16)
        ri = np.empty(W, np.int16)
        for y in range(chunk * H // n_chunks, (chunk + 1) * H // n_chunks):
            row = vol[y]
            for x in range(W):
                r = row[x]
                for d in range(D):
                    T[d, x] = r[d]
            _argmin_rows_i16(T, 0, best, bi)
            second[:] = big
            for d in range(D):
                t = T[d]
                lo = np.int16(d - 1)
                hi = np.int16(d + 1)
                for x in range(W):
                    k = bi[x]
                    m = _lane_mask((k > hi) | (k < lo))  # |d - best| > 1
                    second[x] = min(second[x], (t[x] & m) | (big & ~m))
            for x in range(W):
                bx = np.int64(bi[x])
                bv = np.float32(best[x]) * inv_scale
                c2 = np.float32(second[x]) * inv_scale
                min_cost[y, x] = bv
                dint[x] = bx
                if ratio > 0:
                    unique[y, x] = is_unique(bv, c2, keep)
                off = np.float32(0.0)
                if method > 0 and 0 < bx < D - 1:
                    cm = np.float32(T[bx - 1, x]) * inv_scale
                    cp = np.float32(T[bx + 1, x]) * inv_scale
                    off = subpixel_offset(bv, cm, cp, method)
                disp[y, x] = np.float32(bx) + off
                conf[y, x] = clipped_margin(bv, c2, eps)
            _argmin_rows_i16(T, 1, best_r, ri)
            out = disp_right[y]
            for x in range(W):
                out[x] = np.float32(ri[x])
            if lr_tol >= 0:
                lr_check_row(dint, out, lr_ok[y], lr_tol)
    return disp, min_cost, unique, disp_right, lr_ok, conf
