"""Row-sliding numba kernel of every numba cost volume and of fused block matching (CPU, float32 out).

One engine computes the window-aggregated cost row by row, the way OpenCV's block matcher does: per
image row it keeps the vertical window sums of the pixelwise cost for every ``(x, d)`` (updated from row
to row: add the row entering the window, subtract the one leaving it, kept in a ring of rows) and slides a horizontal window sum
along the row, so each ``(x, d)`` costs O(1) whatever the window. The finished ``(W, D)`` cost row then
goes either

- into the ``(H, W, D)`` volume (``mode=0``, :func:`stereonet.cost.volume.numba_cost_volume`), or
- straight into the local selection (``mode=1``: WTA, uniqueness, sub-pixel, right-reference WTA and LR
  check of :mod:`stereonet.kernels.select`), so block matching never materialises the volume.

Both modes run the same code on the same rows, so the selection of mode 1 equals the selection of the
volume of mode 0 (tested). Rows run in parallel in fixed blocks of :data:`ROW_BLOCK` rows (``prange``);
each block restarts its vertical sums from scratch, so results do not depend on the thread count, and the
float32 running sums drift over at most one block. Definitions are those of
:mod:`stereonet.cost.volume`: right pixels left of the image are the replicated border column, window
means are over the in-image part of the window, and positions with ``x < d`` finally cost
``max(volume) + 1`` (the selection of mode 1 resolves the few left-border pixels that depend on that
value once every row is done: :func:`finish_border_selection`).

Inputs are planar: images ``(C, H, W)`` float32, census codes ``(K, H, W)`` uint64. Cost kinds:
:data:`KIND_ABS` (mean over channels of ``|l - r|``), :data:`KIND_SQ` (squared), :data:`KIND_PROD`
(``l * r`` on grey images, NCC), :data:`KIND_HAMMING` (census), :data:`KIND_CENSUS_AD`.
"""

from __future__ import annotations

import numba
import numpy as np
from numba import prange

from stereonet.kernels.cost import popcount64
from stereonet.kernels.select import (
    is_unique,
    lr_check_row,
    select_row_t,
    subpixel_offset,
    transpose_row_scaled,
)

ROW_BLOCK = 32
KIND_ABS, KIND_SQ, KIND_PROD, KIND_HAMMING, KIND_CENSUS_AD = 0, 1, 2, 3, 4
POST_NONE, POST_NCC, POST_MULTIWINDOW, POST_SHIFTABLE = 0, 1, 2, 3
MODE_VOLUME, MODE_SELECT = 0, 1


@numba.njit(cache=True, fastmath=False)
def _reverse_row(src, y, dst):
    """dst[c, j] = src[c, y, W - 1 - j]: then right[x - d] = dst[W - 1 - x + d], contiguous in d."""
    C, _, W = src.shape
    for c in range(C):
        for j in range(W):
            dst[c, j] = src[c, y, W - 1 - j]


@numba.njit(cache=True, fastmath=False)
def _pixel_cost_row(kind, y, L, R, CL, CR, lam_c, lam_a, rrev, crev, out):
    """out[x, d] = pixelwise cost of left (y, x) against right (y, max(x - d, 0)) (float32 (W, D)).

    Per pixel one loop over contiguous slices of the reversed right row (non-negative indices: no
    wraparound code, so it vectorises); colour costs are ``((c0 + c1) + c2) / 3`` (1 or 3 channels)."""
    if kind == KIND_HAMMING or kind == KIND_CENSUS_AD:
        _reverse_row(CR, y, crev)
    if kind != KIND_HAMMING:
        _reverse_row(R, y, rrev)
    W, D = out.shape
    C = L.shape[0]
    inv_c = np.float32(1.0 / C)
    for x in range(W):
        nv = min(x + 1, D)  # d < nv: right pixel inside the image
        base = W - 1 - x
        t = out[x, :nv]
        if kind == KIND_PROD:
            lv = L[0, y, x]
            rr = rrev[0, base:base + nv]
            for d in range(nv):
                t[d] = lv * rr[d]
        elif kind == KIND_HAMMING:
            cr = crev[0, base:base + nv]
            cv = CL[0, y, x]
            for d in range(nv):
                t[d] = np.float32(popcount64(cv ^ cr[d]))
            for k in range(1, CL.shape[0]):
                cv = CL[k, y, x]
                cr = crev[k, base:base + nv]
                for d in range(nv):
                    t[d] += np.float32(popcount64(cv ^ cr[d]))
        else:
            r0 = rrev[0, base:base + nv]
            l0 = L[0, y, x]
            if C == 1:
                if kind == KIND_SQ:
                    for d in range(nv):
                        v = l0 - r0[d]
                        t[d] = (v * v) * inv_c
                else:
                    for d in range(nv):
                        t[d] = abs(l0 - r0[d]) * inv_c
            else:
                r1 = rrev[1, base:base + nv]
                r2 = rrev[2, base:base + nv]
                l1 = L[1, y, x]
                l2 = L[2, y, x]
                if kind == KIND_SQ:
                    for d in range(nv):
                        v0 = l0 - r0[d]
                        v1 = l1 - r1[d]
                        v2 = l2 - r2[d]
                        t[d] = ((v0 * v0 + v1 * v1) + v2 * v2) * inv_c
                else:
                    for d in range(nv):
                        t[d] = ((abs(l0 - r0[d]) + abs(l1 - r1[d])) + abs(l2 - r2[d])) * inv_c
            if kind == KIND_CENSUS_AD:
                for d in range(nv):
                    n = np.uint64(0)
                    for k in range(CL.shape[0]):
                        n += popcount64(CL[k, y, x] ^ crev[k, base + d])
                    t[d] = (np.float32(2.0) - np.exp(-np.float32(n) / lam_c)) - np.exp(-t[d] / lam_a)
        o = out[x]
        last = o[nv - 1]
        for d in range(nv, D):  # x - d < 0: the border column, the same as d = x
            o[d] = last


@numba.njit(cache=True, fastmath=False)
def _slide_rows(colsum, kind, y_in, y_out, L, R, CL, CR, lam_c, lam_a, rrev, crev, buf_in, ring):
    """colsum += cost row y_in - cost row y_out (float32, elementwise); a row index < 0 = no such row.

    ``ring`` (window, W, D) holds the pixel-cost rows inside the window at slot ``y % window``: the
    leaving row is read from it (never recomputed) and the entering row, computed once, replaces it."""
    W, D = colsum.shape
    n = ring.shape[0]
    if y_in >= 0 and y_out >= 0:
        _pixel_cost_row(kind, y_in, L, R, CL, CR, lam_c, lam_a, rrev, crev, buf_in)
        old = ring[y_out % n]
        for x in range(W):
            cs = colsum[x]
            a = buf_in[x]
            b = old[x]
            for d in range(D):
                cs[d] += a[d] - b[d]
                b[d] = a[d]
    elif y_in >= 0:
        new = ring[y_in % n]
        _pixel_cost_row(kind, y_in, L, R, CL, CR, lam_c, lam_a, rrev, crev, new)
        for x in range(W):
            cs = colsum[x]
            a = new[x]
            for d in range(D):
                cs[d] += a[d]
    elif y_out >= 0:
        old = ring[y_out % n]
        for x in range(W):
            cs = colsum[x]
            b = old[x]
            for d in range(D):
                cs[d] -= b[d]


@numba.njit(cache=True, fastmath=False)
def _box_row(colsum, r, ny, hs, out):
    """out[x, d] = (sum of colsum[x - r .. x + r, d] in the image) / (ny * in-image width), float32."""
    W, D = colsum.shape
    hs[:] = 0.0
    for x in range(min(r, W)):
        cs = colsum[x]
        for d in range(D):
            hs[d] += cs[d]
    for x in range(W):
        if x + r < W and x - r - 1 >= 0:
            ca = colsum[x + r]
            cb = colsum[x - r - 1]
            for d in range(D):
                hs[d] += ca[d] - cb[d]
        elif x + r < W:
            ca = colsum[x + r]
            for d in range(D):
                hs[d] += ca[d]
        elif x - r - 1 >= 0:
            cb = colsum[x - r - 1]
            for d in range(D):
                hs[d] -= cb[d]
        inv = np.float32(1.0 / (ny * (min(x + r, W - 1) - max(x - r, 0) + 1)))
        o = out[x]
        for d in range(D):
            o[d] = hs[d] * inv


@numba.njit(cache=True, fastmath=False)
def _ncc_row(row, y, mu_l, isd_l, mu_r, isd_r, rev):
    """In place: window means E[l r] -> ``1 - clip((E[l r] - mu_l mu_r) * isd_l * isd_r, -1, 1)`` with
    ``isd = 1 / sqrt(var)`` (0 where the variance is too small: NCC := 0, cost 1). rev: (2, W) scratch for
    the reversed right maps (contiguous in d, vectorised)."""
    W, D = row.shape
    for j in range(W):
        rev[0, j] = mu_r[y, W - 1 - j]
        rev[1, j] = isd_r[y, W - 1 - j]
    for x in range(W):
        nv = min(x + 1, D)
        base = W - 1 - x
        ml = mu_l[y, x]
        il = isd_l[y, x]
        mr = rev[0, base:base + nv]
        ir = rev[1, base:base + nv]
        e = row[x]
        for d in range(nv):
            ncc = (e[d] - ml * mr[d]) * (il * ir[d])
            e[d] = np.float32(1.0) - min(max(ncc, np.float32(-1.0)), np.float32(1.0))
        m0 = mu_r[y, 0]
        i0 = isd_r[y, 0]
        for d in range(nv, D):  # x - d < 0: the border column
            ncc = (e[d] - ml * m0) * (il * i0)
            e[d] = np.float32(1.0) - min(max(ncc, np.float32(-1.0)), np.float32(1.0))


@numba.njit(cache=True, fastmath=False)
def _multiwindow_row(a_top, a_mid, a_bot, r, out):
    """(centre + the two best of the four corner windows at (±r, ±r)) / 3 of window-mean rows."""
    W, D = out.shape
    for x in range(W):
        x0 = max(x - r, 0)
        x1 = min(x + r, W - 1)
        for d in range(D):
            a = a_top[x0, d]
            b = a_top[x1, d]
            c = a_bot[x0, d]
            e = a_bot[x1, d]
            lo1 = min(a, b)
            hi1 = max(a, b)
            lo2 = min(c, e)
            hi2 = max(c, e)
            best = min(lo1, lo2)
            second = min(max(lo1, lo2), min(hi1, hi2))
            out[x, d] = (a_mid[x, d] + (best + second)) / np.float32(3.0)


@numba.njit(cache=True, fastmath=False)
def _row_max(row, acc):
    """max of a (W, D) row: elementwise maxima over x into the two-row buffer acc (2, D) (vectorised; read
    from one row and written to the other, see :func:`stereonet.kernels.select._argmin_step`), then over d."""
    W, D = row.shape
    acc[0] = row[0]
    for x in range(1, W):
        r = row[x]
        src = acc[(x - 1) & 1]
        dst = acc[x & 1]
        for d in range(D):
            v = r[d]
            a = src[d]
            dst[d] = v if v > a else a
    last = acc[(W - 1) & 1]
    m = last[0]
    for d in range(1, D):
        m = last[d] if last[d] > m else m
    return m


@numba.njit(parallel=True, cache=True, fastmath=False)
def block_cost_rows(mode, kind, L, R, CL, CR, n_disp, window, post, post_window, lam_c, lam_a,
                    mu_l, isd_l, mu_r, isd_r, method, ratio, lr_tol):
    """The engine (see the module doc). Returns
    ``(vol, row_max, disp, min_cost, unique, disp_right, lr_ok, strip)``; ``vol`` (H, W, D) only for
    ``mode=0`` (else (1, 1, 1)), the selection arrays (H, W) only for ``mode=1`` (else (1, 1)).

    Args:
        mode: 0 = volume, 1 = selection.
        kind: pixel cost (``KIND_*``); L, R: (C, H, W) float32 (grey for KIND_PROD); CL, CR: (K, H, W)
            uint64 census codes (K >= 1; unused ones may be (1, 1, 1)).
        n_disp: D; window: odd box window (1 = pixelwise).
        post: ``POST_*`` applied to the window means (NCC normalisation with the window means mu and
            ``isd = 1/sqrt(variance)`` (0 below the variance floor) (H, W) float32 maps, or a multi/shiftable
            window of size post_window).
        method, ratio, lr_tol: selection as :func:`stereonet.kernels.select.select_hwd`.
    """
    C, H, W = L.shape
    D = n_disp
    r = window // 2
    R_post = post_window // 2 if post == POST_MULTIWINDOW or post == POST_SHIFTABLE else 0
    n_ring = 2 * R_post + 1
    sel = mode == MODE_SELECT
    hv, wv = (H, W) if sel else (1, 1)
    vol = np.empty((H, W, D) if not sel else (1, 1, 1), np.float32)
    disp = np.empty((hv, wv), np.float32)
    min_cost = np.empty((hv, wv), np.float32)
    unique = np.ones((hv, wv), np.bool_)
    disp_right = np.zeros((hv, wv), np.float32)
    lr_ok = np.ones((hv, wv), np.bool_)
    strip = np.zeros((hv, max(min(D - 1, wv), 1), 4), np.float32)
    row_max = np.empty(H, np.float32)
    keep = np.float32(1.0 - ratio)
    n_blocks = (H + ROW_BLOCK - 1) // ROW_BLOCK
    for blk in prange(n_blocks):
        a = blk * ROW_BLOCK
        b = min(a + ROW_BLOCK, H)
        colsum = np.zeros((W, D), np.float32)
        hs = np.empty(D, np.float32)
        acc = np.empty((2, D), np.float32)
        rrev = np.empty((C, W), np.float32)
        nrev = np.empty((2, W), np.float32)
        crev = np.empty((CL.shape[0], W), np.uint64)
        buf_in = np.empty((W, D), np.float32)
        pring = np.empty((window if r > 0 else 1, W, D), np.float32)  # pixel-cost rows in the window
        ring = np.empty((n_ring, W, D), np.float32)
        out = np.empty((W, D), np.float32)
        vmin = np.empty((W, D), np.float32)
        dint = np.empty(W, np.float32)
        T = np.empty((D, W) if sel else (1, 1), np.float32)
        best = np.empty((2, W), np.float32)
        second = np.empty((2, W), np.float32)
        best_r = np.empty((2, W), np.float32)
        bi, ri = np.empty((2, W), np.int32), np.empty((2, W), np.int32)
        s = max(a - R_post, 0)
        e = min(b + R_post, H)
        for ya in range(s, e):
            agg = ring[ya % n_ring]
            if r == 0:
                _pixel_cost_row(kind, ya, L, R, CL, CR, lam_c, lam_a, rrev, crev, agg)
            elif ya == s:
                colsum[:] = 0.0
                for yy in range(max(ya - r, 0), min(ya + r, H - 1) + 1):
                    _slide_rows(colsum, kind, yy, -1, L, R, CL, CR, lam_c, lam_a, rrev, crev, buf_in, pring)
            else:
                _slide_rows(colsum, kind, ya + r if ya + r < H else -1, ya - r - 1, L, R, CL, CR, lam_c, lam_a,
                            rrev, crev, buf_in, pring)
            if r > 0:
                _box_row(colsum, r, min(ya + r, H - 1) - max(ya - r, 0) + 1, hs, agg)
            if post == POST_NCC:
                _ncc_row(agg, ya, mu_l, isd_l, mu_r, isd_r, nrev)
            # output rows whose last needed window-mean row is ya
            y_lo = ya - R_post if ya < H - 1 else max(ya - R_post, a)
            y_hi = ya - R_post if ya < H - 1 else b - 1
            for y in range(max(y_lo, a), min(y_hi, b - 1) + 1):
                if post == POST_MULTIWINDOW or post == POST_SHIFTABLE:
                    y0 = max(y - R_post, 0)
                    y1 = min(y + R_post, H - 1)
                    if post == POST_MULTIWINDOW:
                        _multiwindow_row(ring[y0 % n_ring], ring[y % n_ring], ring[y1 % n_ring], R_post, out)
                    else:
                        vmin[:] = ring[y0 % n_ring]
                        for yy in range(y0 + 1, y1 + 1):
                            src = ring[yy % n_ring]
                            for x in range(W):
                                for d in range(D):
                                    vmin[x, d] = min(vmin[x, d], src[x, d])
                        for x in range(W):
                            for d in range(D):
                                m = vmin[x, d]
                                for k in range(max(x - R_post, 0), min(x + R_post, W - 1) + 1):
                                    m = min(m, vmin[k, d])
                                out[x, d] = m
                    row = out
                else:
                    row = ring[y % n_ring]
                row_max[y] = _row_max(row, acc)
                if sel:
                    transpose_row_scaled(row, T, np.float32(1.0))
                    select_row_t(T, y, method, keep, ratio > 0, True, disp, min_cost, unique, dint, strip,
                                 disp_right, best, bi, second, best_r, ri)
                    if lr_tol >= 0:
                        lr_check_row(dint, disp_right[y], lr_ok[y], lr_tol)
                else:
                    vol[y] = row
    return vol, row_max, disp, min_cost, unique, disp_right, lr_ok, strip


@numba.njit(parallel=True, cache=True, fastmath=False)
def finish_border_selection(disp, min_cost, unique, strip, n_disp, fill, method, ratio):
    """Uniqueness and sub-pixel offset of the pixels x < D - 1 once the out-of-image cost ``fill`` is
    known (in place), exactly as the selection of the filled volume would give them."""
    H, S = strip.shape[0], min(strip.shape[1], disp.shape[1])
    D = n_disp
    keep = np.float32(1.0 - ratio)
    for y in prange(H):
        for x in range(S):
            nv = x + 1
            bi = int(strip[y, x, 3])
            best = min_cost[y, x]
            if ratio > 0:
                second = strip[y, x, 0]
                if D - 1 >= max(nv, bi + 2):  # an out-of-image d with |d - bi| > 1
                    second = min(second, fill)
                unique[y, x] = is_unique(best, second, keep)
            off = np.float32(0.0)
            if method > 0 and bi > 0:
                cp = strip[y, x, 2] if bi + 1 < nv else fill
                off = subpixel_offset(best, strip[y, x, 1], cp, method)
            disp[y, x] = np.float32(bi) + off
