"""Row-sliding numba kernel of every numba cost volume and of fused block matching (CPU, float32 out).

One engine computes the window-aggregated cost row by row, the way OpenCV's block matcher does: per
image row it keeps the vertical window sums of the pixelwise cost for every ``(d, x)`` (updated from row
to row: add the row entering the window, subtract the one leaving it, kept in a ring of rows) and sums
each of them over the horizontal window by doubling, so each ``(d, x)`` costs O(log window). Rows are
``(D, W)``, contiguous along x: every pass (pixel cost per disparity, vertical update, horizontal sums,
post-processing, the selection's running minimum over d) is one loop along x that LLVM vectorises. The
finished ``(D, W)`` cost row then goes either

- into the ``(H, W, D)`` volume (``mode=0``, :func:`stereonet.cost.volume.numba_cost_volume`), or into an
  ``(H, D, W)`` volume as it is (``mode=2``, the same values row by row), or
- straight into the local selection (``mode=1``: WTA, uniqueness, sub-pixel, right-reference WTA and LR
  check of :mod:`stereonet.kernels.select`, :func:`~stereonet.kernels.select.select_row_t`), so block
  matching never materialises the volume.

Both modes run the same code on the same rows, so the selection of mode 1 equals the selection of the
volume of mode 0 (tested). Rows run in parallel in fixed blocks of :data:`ROW_BLOCK` rows (``prange``);
each block restarts its vertical sums from scratch, so results do not depend on the thread count, and the
float32 running sums drift over at most one block. Definitions are those of
:mod:`stereonet.cost.volume`: right pixels left of the image are the replicated border column, window
means are over the in-image part of the window, and positions with ``x < d`` finally cost
``max(volume) + 1`` (the selection of mode 1 resolves the few left-border pixels that depend on that
value once every row is done: :func:`finish_border_selection`).

Loops written for the vectoriser: shifted operands are slices indexed by the loop counter alone (an index
``i + k`` with a run-time ``k`` makes numba test it for wraparound on every element and the horizontal sums
measured 3x slower), and no loop reads and conditionally writes the same buffer (masked stores, see
:func:`stereonet.kernels.select._argmin_step`).

Inputs are planar: images ``(C, H, W)`` float32, census codes ``(K, H, W)`` uint64. Cost kinds:
:data:`KIND_ABS` (mean over channels of ``|l - r|``), :data:`KIND_SQ` (squared), :data:`KIND_PROD`
(``l * r`` on grey images, NCC), :data:`KIND_HAMMING` (census), :data:`KIND_CENSUS_AD`.
"""

from __future__ import annotations

import numba
import numpy as np
from numba import prange

from stereonet.kernels.cost import exp_f32, popcount64
from stereonet.kernels.select import (
    is_unique,
    lr_check_row,
    select_row_t,
    subpixel_offset,
)

ROW_BLOCK = 32
KIND_ABS, KIND_SQ, KIND_PROD, KIND_HAMMING, KIND_CENSUS_AD = 0, 1, 2, 3, 4
POST_NONE, POST_NCC, POST_MULTIWINDOW, POST_SHIFTABLE = 0, 1, 2, 3
MODE_VOLUME, MODE_SELECT, MODE_VOLUME_ROWS = 0, 1, 2


@numba.njit(cache=True, fastmath=False)
def _pixel_cost_row(kind, y, L, R, CL, CR, lam_c, lam_a, out, p0):
    """out[d, p0 + x] = pixelwise cost of left (y, x) against right (y, max(x - d, 0)) ((D, Wp) float32 rows).

    Per disparity one loop along x over contiguous slices of both image rows (vectorised, ~W long);
    colour costs are ``((c0 + c1) + c2) / 3`` (1 or 3 channels). AD-Census reads its census term from a table
    over the distances (the same float32 values, computed once per row) and its AD term from the vectorisable
    :func:`~stereonet.kernels.cost.exp_f32` (within 1 ulp of the library ``exp``, which kept the loop scalar and
    took two thirds of the volume's time). Positions x < d copy the cost at d = x (the right border column):
    the rows d' < d are finished by then."""
    D = out.shape[0]
    W = L.shape[2]
    C = L.shape[0]
    inv_c = np.float32(1.0 / C)
    if kind == KIND_CENSUS_AD:  # 2 - exp(-h / lambda_census) for every possible distance h, as computed per pixel
        census_term = np.empty(64 * CL.shape[0] + 1, dtype=np.float32)
        for h in range(census_term.shape[0]):
            census_term[h] = np.float32(2.0) - np.exp(-np.float32(h) / lam_c)
        hamming = np.empty(W, dtype=np.uint64)
    else:
        census_term = np.empty(0, dtype=np.float32)
        hamming = np.empty(0, dtype=np.uint64)
    for d in range(D):
        n = W - d  # x in [d, W): right pixel x - d inside the image
        if n > 0:
            t = out[d, p0 + d:p0 + W]
            if kind == KIND_PROD:
                lv = L[0, y, d:]
                rr = R[0, y, :n]
                for i in range(n):
                    t[i] = lv[i] * rr[i]
            elif kind == KIND_HAMMING:
                cl = CL[0, y, d:]
                cr = CR[0, y, :n]
                for i in range(n):
                    t[i] = np.float32(popcount64(cl[i] ^ cr[i]))
                for k in range(1, CL.shape[0]):
                    cl = CL[k, y, d:]
                    cr = CR[k, y, :n]
                    for i in range(n):
                        t[i] += np.float32(popcount64(cl[i] ^ cr[i]))
            else:
                l0 = L[0, y, d:]
                r0 = R[0, y, :n]
                if C == 1:
                    if kind == KIND_SQ:
                        for i in range(n):
                            v = l0[i] - r0[i]
                            t[i] = (v * v) * inv_c
                    else:
                        for i in range(n):
                            t[i] = abs(l0[i] - r0[i]) * inv_c
                else:
                    l1 = L[1, y, d:]
                    r1 = R[1, y, :n]
                    l2 = L[2, y, d:]
                    r2 = R[2, y, :n]
                    if kind == KIND_SQ:
                        for i in range(n):
                            v0 = l0[i] - r0[i]
                            v1 = l1[i] - r1[i]
                            v2 = l2[i] - r2[i]
                            t[i] = ((v0 * v0 + v1 * v1) + v2 * v2) * inv_c
                    else:
                        for i in range(n):
                            t[i] = ((abs(l0[i] - r0[i]) + abs(l1[i] - r1[i])) + abs(l2[i] - r2[i])) * inv_c
                if kind == KIND_CENSUS_AD:
                    hd = hamming[:n]
                    cl = CL[0, y, d:]
                    cr = CR[0, y, :n]
                    for i in range(n):
                        hd[i] = popcount64(cl[i] ^ cr[i])
                    for k in range(1, CL.shape[0]):
                        cl = CL[k, y, d:]
                        cr = CR[k, y, :n]
                        for i in range(n):
                            hd[i] += popcount64(cl[i] ^ cr[i])
                    for i in range(n):
                        t[i] = exp_f32(-t[i] / lam_a)
                    for i in range(n):
                        t[i] = census_term[hd[i]] - t[i]
        o = out[d]
        for x in range(min(d, W)):  # x - d < 0: the border column, the same as d = x
            o[p0 + x] = out[x, p0 + x]


@numba.njit(cache=True, fastmath=False)
def _slide_rows(colsum, kind, y_in, y_out, L, R, CL, CR, lam_c, lam_a, p0, buf_in, ring):
    """colsum += cost row y_in - cost row y_out (float32, elementwise over the flat (D, Wp) rows, whose zero
    pads stay zero); a row index < 0 = no such row.

    ``ring`` (window, D, Wp) holds the pixel-cost rows inside the window at slot ``y % window``: the
    leaving row is read from it (never recomputed) and the entering row, computed once, replaces it."""
    n = ring.shape[0]
    cs = colsum.reshape(-1)
    if y_in >= 0 and y_out >= 0:
        _pixel_cost_row(kind, y_in, L, R, CL, CR, lam_c, lam_a, buf_in, p0)
        old = ring[y_out % n]
        a = buf_in.reshape(-1)
        b = old.reshape(-1)
        for i in range(cs.shape[0]):
            cs[i] += a[i] - b[i]
            b[i] = a[i]
    elif y_in >= 0:
        new = ring[y_in % n]
        _pixel_cost_row(kind, y_in, L, R, CL, CR, lam_c, lam_a, new, p0)
        a = new.reshape(-1)
        for i in range(cs.shape[0]):
            cs[i] += a[i]
    elif y_out >= 0:
        b = ring[y_out % n].reshape(-1)
        for i in range(cs.shape[0]):
            cs[i] -= b[i]


@numba.njit(cache=True, fastmath=False)
def _pair_sums(src, size, n, dst):
    """dst[i] = src[i] + src[i + size] for i < n (one vectorised pass). The shifted operand is a slice
    indexed by the loop counter alone: ``src[i + size]`` with a run-time ``size`` makes numba test the index
    for wraparound on every element, which keeps LLVM from vectorising the loop (3x slower, measured)."""
    a = src[:n]
    b = src[size:size + n]
    o = dst[:n]
    for i in range(n):
        o[i] = a[i] + b[i]


@numba.njit(cache=True, fastmath=False)
def _add_into(a, off, n, dst, first):
    """dst[x] = a[off + x] (first) or dst[x] + a[off + x], x < n."""
    s = a[off:off + n]
    if first:
        for x in range(n):
            dst[x] = s[x]
    else:
        for x in range(n):
            dst[x] = dst[x] + s[x]


@numba.njit(cache=True, fastmath=False)
def _tap_row(c, window, inv, o):
    """o[x] = (c[x] + c[x + 1] + ... + c[x + window - 1]) * inv[x] written out for the common windows 3..11
    (every tap a constant offset: one vectorised pass, no scratch row; ~1.7x faster than the doubling of
    :func:`_box_row`, measured on window 9). Returns False, doing nothing, for other windows."""
    n = o.shape[0]
    if window == 3:
        for x in range(n):
            o[x] = ((c[x] + c[x + 1]) + c[x + 2]) * inv[x]
    elif window == 5:
        for x in range(n):
            o[x] = ((((c[x] + c[x + 1]) + c[x + 2]) + c[x + 3]) + c[x + 4]) * inv[x]
    elif window == 7:
        for x in range(n):
            s = (((c[x] + c[x + 1]) + c[x + 2]) + c[x + 3]) + c[x + 4]
            o[x] = ((s + c[x + 5]) + c[x + 6]) * inv[x]
    elif window == 9:
        for x in range(n):
            s = (((c[x] + c[x + 1]) + c[x + 2]) + c[x + 3]) + c[x + 4]
            o[x] = ((((s + c[x + 5]) + c[x + 6]) + c[x + 7]) + c[x + 8]) * inv[x]
    elif window == 11:
        for x in range(n):
            s = (((c[x] + c[x + 1]) + c[x + 2]) + c[x + 3]) + c[x + 4]
            s = (((s + c[x + 5]) + c[x + 6]) + c[x + 7]) + c[x + 8]
            o[x] = ((s + c[x + 9]) + c[x + 10]) * inv[x]
    else:
        return False
    return True


@numba.njit(cache=True, fastmath=False)
def _box_row(colsum, window, ny, pa, pb, inv, out):
    """out[d, x] = (sum of colsum[d, x - r .. x + r] in the image) / (ny * in-image width), float32.

    ``colsum`` (D, W + 2r) has zero pads of r columns on both sides, so every window sums ``window``
    entries. Sums of 2^k neighbours by doubling (``s_k[i] = s_(k-1)[i] + s_(k-1)[i + 2^(k-1)]``, each level
    one vectorised pass along x); level k is added into ``out`` (at the offset of the lower set bits) when
    bit k of ``window`` is set, lowest first. Only the current level is needed, so the levels alternate
    between the two scratch rows ``pa``/``pb`` (W + 2r,); ``inv`` (W,) is scratch. Windows 3..11 take the written-out sums of :func:`_tap_row` instead."""
    D, Wp = colsum.shape
    W = out.shape[1]
    r = window // 2
    for x in range(W):
        inv[x] = np.float32(1.0 / (ny * (min(x + r, W - 1) - max(x - r, 0) + 1)))
    for d in range(D):
        base = colsum[d]
        o = out[d]
        if _tap_row(base, window, inv, o):
            continue
        if window & 1:
            _add_into(base, 0, W, o, True)
        off = window & 1
        cur = base
        n = Wp
        k = 1
        while (1 << k) <= window:
            size = 1 << (k - 1)
            dst = pa if k & 1 else pb
            _pair_sums(cur, size, n - size, dst)
            n -= size
            if (window >> k) & 1:
                _add_into(dst, off, W, o, off == 0)
                off += 1 << k
            cur = dst
            k += 1
        for x in range(W):
            o[x] = o[x] * inv[x]


@numba.njit(cache=True, fastmath=False)
def _ncc_row(row, y, mu_l, isd_l, mu_r, isd_r):
    """In place on a (D, W) row of window means E[l r]: ``1 - clip((E[l r] - mu_l mu_r) * isd_l * isd_r, -1, 1)``
    with ``isd = 1 / sqrt(var)`` (0 where the variance is too small: NCC := 0, cost 1); contiguous along x."""
    D, W = row.shape
    m0 = mu_r[y, 0]
    i0 = isd_r[y, 0]
    for d in range(D):
        e = row[d]
        n = W - d
        if n > 0:
            t = e[d:]
            ml = mu_l[y, d:]
            il = isd_l[y, d:]
            mr = mu_r[y, :n]
            ir = isd_r[y, :n]
            for i in range(n):
                ncc = (t[i] - ml[i] * mr[i]) * (il[i] * ir[i])
                t[i] = np.float32(1.0) - min(max(ncc, np.float32(-1.0)), np.float32(1.0))
        for x in range(min(d, W)):  # x - d < 0: the border column
            ncc = (e[x] - mu_l[y, x] * m0) * (isd_l[y, x] * i0)
            e[x] = np.float32(1.0) - min(max(ncc, np.float32(-1.0)), np.float32(1.0))


@numba.njit(cache=True, fastmath=False)
def _multiwindow_px(a, b, c, e, mid):
    """(mid + the two smallest of the four corner means a, b, c, e) / 3 (float32), as compare-selects (the
    same values as ``min``/``max`` for the finite means here)."""
    lo1 = a if a < b else b
    hi1 = b if a < b else a
    lo2 = c if c < e else e
    hi2 = e if c < e else c
    best = lo1 if lo1 < lo2 else lo2
    other = lo2 if lo1 < lo2 else lo1
    hi = hi1 if hi1 < hi2 else hi2
    second = other if other < hi else hi
    return (mid + (best + second)) * np.float32(1.0 / 3.0)  # a product, not a division: 2x faster, <= 1 ulp


@numba.njit(cache=True, fastmath=False)
def _multiwindow_row(a_top, a_mid, a_bot, r, out):
    """(centre + the two best of the four corner windows at (±r, ±r)) / 3 of window-mean rows (D, W); corner
    columns are clamped to the image. The interior columns r <= x < W - r run as one loop over contiguous
    slices (vectorised), the 2r border columns clamp one by one."""
    D, W = out.shape
    n = W - 2 * r
    for d in range(D):
        o = out[d]
        if n > 0:
            t0 = a_top[d, :n]
            t1 = a_top[d, 2 * r:]
            b0 = a_bot[d, :n]
            b1 = a_bot[d, 2 * r:]
            m = a_mid[d, r:r + n]
            oi = o[r:r + n]
            for i in range(n):
                oi[i] = _multiwindow_px(t0[i], t1[i], b0[i], b1[i], m[i])
        for j in range(2 * r if n > 0 else W):
            x = j if j < r or n <= 0 else j + n
            x0 = max(x - r, 0)
            x1 = min(x + r, W - 1)
            o[x] = _multiwindow_px(a_top[d, x0], a_top[d, x1], a_bot[d, x0], a_bot[d, x1], a_mid[d, x])


@numba.njit(cache=True, fastmath=False)
def _shiftable_row(ring, y0, y1, R_post, vmin, tmp, out):
    """min over the rows y0..y1 of the ring and over x - R_post .. x + R_post (in the image) of (D, W) rows;
    every minimum is written to a buffer it is not read from (no in-place select: see _row_max)."""
    D, W = out.shape
    n = ring.shape[0]
    src = ring[y0 % n]
    for yy in range(y0 + 1, y1 + 1):
        a = src.reshape(-1)
        b = ring[yy % n].reshape(-1)
        dst = vmin if (yy - y0) & 1 else tmp
        c = dst.reshape(-1)
        for i in range(c.shape[0]):
            c[i] = min(a[i], b[i])
        src = dst
    for d in range(D):
        s = src[d]
        for x in range(W):
            m = s[x]
            for k in range(max(x - R_post, 0), min(x + R_post, W - 1) + 1):
                m = min(m, s[k])
            out[d, x] = m


@numba.njit(cache=True, fastmath=False)
def _row_max(row, acc):
    """max of a (D, W) row: elementwise maxima over d into the two-row buffer acc (2, W) (vectorised; read
    from one row and written to the other, see :func:`stereonet.kernels.select._argmin_step`), then over x."""
    D, W = row.shape
    acc[0] = row[0]
    for d in range(1, D):
        r = row[d]
        src = acc[(d - 1) & 1]
        dst = acc[d & 1]
        for x in range(W):
            v = r[x]
            a = src[x]
            dst[x] = v if v > a else a
    last = acc[(D - 1) & 1]
    m = last[0]
    for x in range(1, W):
        m = last[x] if last[x] > m else m
    return m


BOX_MEAN, BOX_ZERO_MEAN, BOX_SCALED = 0, 1, 2


@numba.njit(parallel=True, cache=True, fastmath=False)
def box_planes(img, window, op, eps):
    """Per pixel of planar ``img`` (C, H, W) float32, with ``m`` the mean over the in-image part of its ``window``
    x ``window`` square (the engine's own vertical running sums, float64 here so nothing drifts, and
    :func:`_box_row` along x; rows in blocks of :data:`ROW_BLOCK`, ``prange``), a new float32 array of
    ``m`` (``op`` = :data:`BOX_MEAN`), ``img - m`` (:data:`BOX_ZERO_MEAN`, ZSAD's input) or ``img / (m + eps)``
    (:data:`BOX_SCALED`, LS-SAD's): each in float32, as numpy computes them from the mean, in one pass."""
    C, H, W = img.shape
    r = window // 2
    Wp = W + 2 * r
    out = np.empty((C, H, W), np.float32)
    n_blocks = (H + ROW_BLOCK - 1) // ROW_BLOCK
    for job in prange(C * n_blocks):
        c = job // n_blocks
        a = (job % n_blocks) * ROW_BLOCK
        b = min(a + ROW_BLOCK, H)
        acc = np.zeros(W, np.float64)
        row = np.zeros((1, Wp), np.float32)
        pa = np.empty(Wp, np.float32)
        pb = np.empty(Wp, np.float32)
        inv = np.empty(W, np.float32)
        plane = img[c]
        for yy in range(max(a - r, 0), min(a + r, H - 1) + 1):
            src = plane[yy]
            for x in range(W):
                acc[x] += src[x]
        for y in range(a, b):
            if y > a:
                if y + r < H:
                    src = plane[y + r]
                    for x in range(W):
                        acc[x] += src[x]
                if y - r - 1 >= 0:
                    src = plane[y - r - 1]
                    for x in range(W):
                        acc[x] -= src[x]
            dst = row[0, r:r + W]
            for x in range(W):
                dst[x] = np.float32(acc[x])
            _box_row(row, window, min(y + r, H - 1) - max(y - r, 0) + 1, pa, pb, inv, out[c, y:y + 1])
            o = out[c, y]
            src = plane[y]
            if op == BOX_ZERO_MEAN:
                for x in range(W):
                    o[x] = src[x] - o[x]
            elif op == BOX_SCALED:
                for x in range(W):
                    o[x] = src[x] / (o[x] + eps)
    return out


@numba.njit(parallel=True, cache=True, fastmath=False)
def ncc_window_stats(grey, window, min_variance):
    """NCC's window statistics of a grey (H, W) float32 image, the same float32 values as numpy's composition
    ``mu = box(g)``, ``var = maximum(box(g * g) - mu * mu, 0)``, ``isd = 1 / sqrt(var)`` where ``var >
    min_variance`` else 0, in two passes (both box means in one :func:`box_planes` call). Returns (mu, isd)."""
    H, W = grey.shape
    planes = np.empty((2, H, W), np.float32)
    for y in prange(H):
        for x in range(W):
            g = grey[y, x]
            planes[0, y, x] = g
            planes[1, y, x] = g * g
    means = box_planes(planes, window, BOX_MEAN, np.float32(0.0))
    isd = np.empty((H, W), np.float32)
    for y in prange(H):
        mu = means[0, y]
        m2 = means[1, y]
        o = isd[y]
        for x in range(W):
            var = max(m2[x] - mu[x] * mu[x], np.float32(0.0))
            o[x] = np.float32(1.0) / np.sqrt(var) if var > min_variance else np.float32(0.0)
    return means[0], isd


@numba.njit(parallel=True, cache=True, fastmath=False)
def block_cost_rows(mode, kind, L, R, CL, CR, n_disp, window, post, post_window, lam_c, lam_a,
                    mu_l, isd_l, mu_r, isd_r, method, ratio, lr_tol, vol):
    """The engine (see the module doc). Returns
    ``(vol, row_max, disp, min_cost, unique, disp_right, lr_ok, strip)``; ``vol`` (H, W, D) for ``mode=0``,
    (H, D, W) for ``mode=2`` (else (1, 1, 1)), the selection arrays (H, W) only for ``mode=1`` (else (1, 1)).

    Args:
        mode: 0 = volume (H, W, D), 1 = selection, 2 = volume (H, D, W).
        kind: pixel cost (``KIND_*``); L, R: (C, H, W) float32 (grey for KIND_PROD); CL, CR: (K, H, W)
            uint64 census codes (K >= 1; unused ones may be (1, 1, 1)).
        n_disp: D; window: odd box window (1 = pixelwise).
        post: ``POST_*`` applied to the window means (NCC normalisation with the window means mu and
            ``isd = 1/sqrt(variance)`` (0 below the variance floor) (H, W) float32 maps, or a multi/shiftable
            window of size post_window).
        method, ratio, lr_tol: selection as :func:`stereonet.kernels.select.select_hwd`.
        vol: the output volume, float32 (H, W, D) for ``mode=0``, (H, D, W) for ``mode=2``, any (1, 1, 1) array
            for ``mode=1`` (allocated by the caller: numpy gives large buffers transparent huge pages, so the
            volume's first touch costs a few hundred page faults instead of one per 4 KiB), returned as ``vol``.
    """
    C, H, W = L.shape
    D = n_disp
    r = window // 2
    Wp = W + 2 * r  # pixel-cost rows and vertical sums with r zero columns on both sides
    R_post = post_window // 2 if post == POST_MULTIWINDOW or post == POST_SHIFTABLE else 0
    n_ring = 2 * R_post + 1
    sel = mode == MODE_SELECT
    hv, wv = (H, W) if sel else (1, 1)
    rows_out = mode == MODE_VOLUME_ROWS
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
        colsum = np.zeros((D, Wp), np.float32)
        pa = np.empty(Wp, np.float32)
        pb = np.empty(Wp, np.float32)
        inv = np.empty(W, np.float32)
        acc = np.empty((2, W), np.float32)
        buf_in = np.zeros((D, Wp), np.float32)
        pring = np.zeros((window if r > 0 else 1, D, Wp), np.float32)  # pixel-cost rows in the window
        ring = np.empty((n_ring, D, W), np.float32)
        out = np.empty((D, W), np.float32)
        vmin = np.empty((D, W), np.float32)
        tmp = np.empty((D, W), np.float32)
        dint = np.empty(W, np.float32)
        best = np.empty((2, W), np.float32)
        second = np.empty((2, W), np.float32)
        best_r = np.empty((2, W), np.float32)
        bi, ri = np.empty((2, W), np.int32), np.empty((2, W), np.int32)
        s = max(a - R_post, 0)
        e = min(b + R_post, H)
        for ya in range(s, e):
            agg = ring[ya % n_ring]
            if r == 0:
                _pixel_cost_row(kind, ya, L, R, CL, CR, lam_c, lam_a, agg, 0)
            elif ya == s:
                colsum[:] = 0.0
                for yy in range(max(ya - r, 0), min(ya + r, H - 1) + 1):
                    _slide_rows(colsum, kind, yy, -1, L, R, CL, CR, lam_c, lam_a, r, buf_in, pring)
            else:
                _slide_rows(colsum, kind, ya + r if ya + r < H else -1, ya - r - 1, L, R, CL, CR, lam_c, lam_a,
                            r, buf_in, pring)
            if r > 0:
                _box_row(colsum, window, min(ya + r, H - 1) - max(ya - r, 0) + 1, pa, pb, inv, agg)
            if post == POST_NCC:
                _ncc_row(agg, ya, mu_l, isd_l, mu_r, isd_r)
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
                        _shiftable_row(ring, y0, y1, R_post, vmin, tmp, out)
                    row = out
                else:
                    row = ring[y % n_ring]
                row_max[y] = _row_max(row, acc)
                if sel:
                    select_row_t(row, y, method, keep, ratio > 0, True, disp, min_cost, unique, dint, strip,
                                 disp_right, best, bi, second, best_r, ri)
                    if lr_tol >= 0:
                        lr_check_row(dint, disp_right[y], lr_ok[y], lr_tol)
                elif rows_out:
                    vy = vol[y]
                    for d in range(D):
                        src = row[d]
                        dst = vy[d]
                        for x in range(W):
                            dst[x] = src[x]
                else:
                    vy = vol[y]
                    for x in range(W):
                        v = vy[x]
                        for d in range(D):
                            v[d] = row[d, x]
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
