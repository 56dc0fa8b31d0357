"""Numba CPU helpers of the cost volumes: the grey image, census codes and the
out-of-image fill of ``(H, W, D)`` and ``(H, D, W)`` volumes, the learned-feature cost and the mix of two volumes. The classical
volumes themselves, and the box means of planar images, are computed row by row by
:mod:`stereonet.kernels.block`. Rows (or columns) run in parallel with ``prange``.
"""

from __future__ import annotations

import numba
import numpy as np
from numba import prange, types
from numba.extending import intrinsic


@numba.njit(parallel=True, cache=True, fastmath=False)
def fill_invalid_hwd(vol, fill):
    """vol[y, x, d] = fill for x < d."""
    H, W, D = vol.shape
    for y in prange(H):
        for x in range(W):
            for d in range(x + 1, D):
                vol[y, x, d] = fill


@numba.njit(parallel=True, cache=True, fastmath=False)
def fill_invalid_hdw(vol, fill):
    """vol[y, d, x] = fill for x < d (the ``(H, D, W)`` layout)."""
    H, D, W = vol.shape
    for y in prange(H):
        for d in range(1, D):
            row = vol[y, d]
            for x in range(min(d, W)):
                row[x] = fill


# one signature for any strides (a photo's (C, H, W) tensor is usually a view of its (H, W, C) pixels), compiled when
# the module is imported (from numba's cache after the first time), so no layout waits for the compiler at a first call
@numba.njit("float32[:, ::1](float32[:, :, :])", parallel=True, cache=True, fastmath=False)
def grey_planar(img):
    """BT.601 luma (H, W) of a colour image (3, H, W) float32: ``(r * 0.299 + g * 0.587) + b * 0.114`` in float32, the
    operations and order of :func:`stereonet.cost.census.to_grey` (no fused multiply-add: the same bits), rows in
    parallel. Channels past the third are ignored, as by ``to_grey``; fewer than three raise (numba does not check
    indices, so the kernel itself guards the reads of ``img[2]``)."""
    C, H, W = img.shape
    if C < 3:
        raise ValueError("img: expected at least 3 channels")
    out = np.empty((H, W), np.float32)
    kr, kg, kb = np.float32(0.299), np.float32(0.587), np.float32(0.114)
    for y in prange(H):
        r, g, b, o = img[0, y], img[1, y], img[2, y], out[y]
        for x in range(W):
            o[x] = (r[x] * kr + g[x] * kg) + b[x] * kb
    return out


@numba.njit(parallel=True, cache=True, fastmath=False)
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


@intrinsic
def float32_from_bits(typingctx, x):
    """The float32 whose IEEE-754 bits are the low 32 bits of the integer ``x`` (a register bitcast, vectorisable;
    numba widens integer arithmetic to 64 bits, so the value is truncated first)."""
    if not (isinstance(x, types.Integer) and x.bitwidth in (32, 64)):
        return None

    def codegen(context, builder, signature, args):
        v = args[0]
        if signature.args[0].bitwidth == 64:
            v = builder.trunc(v, context.get_value_type(types.int32))
        return builder.bitcast(v, context.get_value_type(types.float32))

    return types.float32(x), codegen


_LOG2E = np.float32(1.44269504088896341)
_LN2_HI = np.float32(0.693359375)  # ln 2 = _LN2_HI + _LN2_LO; _LN2_HI has few bits, so k * _LN2_HI is exact
_LN2_LO = np.float32(-2.12194440e-4)
_EXP_P = (np.float32(1.9875691500e-4), np.float32(1.3981999507e-3), np.float32(8.3334519073e-3),
          np.float32(4.1665795894e-2), np.float32(1.6666665459e-1), np.float32(5.0000001201e-1))
_EXP_MIN, _EXP_MAX, _HALF, _ONE = np.float32(-87.0), np.float32(88.0), np.float32(0.5), np.float32(1.0)


@numba.njit(cache=True, fastmath=False, inline="always")
def exp_f32(x):  # pragma: no cover - compiled
    """``exp(x)`` of a float32 in float32 without a library call, so a loop over it vectorises (numba has no
    vector ``exp`` without Intel's SVML): ``x = k ln 2 + r``, ``|r| <= ln 2 / 2``, a degree-7 polynomial for
    ``e^r`` (the coefficients of Moshier's Cephes ``expf``, about 1 ulp) and ``2^k`` put into the exponent bits.
    ``x`` is clamped to [-87, 88] (float32's normal range): below, the result is ``e^-87`` ~ 1.6e-38 instead
    of a subnormal or 0."""
    x = _EXP_MIN if x < _EXP_MIN else x
    x = _EXP_MAX if x > _EXP_MAX else x
    k = np.floor(x * _LOG2E + _HALF)
    r = (x - k * _LN2_HI) - k * _LN2_LO
    p = _EXP_P[0] * r + _EXP_P[1]
    p = p * r + _EXP_P[2]
    p = p * r + _EXP_P[3]
    p = p * r + _EXP_P[4]
    p = p * r + _EXP_P[5]
    p = (p * (r * r) + r) + _ONE
    return p * float32_from_bits((np.int64(k) + 127) << 23)


@intrinsic
def popcount64(typingctx, x):
    """Set bits of a uint64 as LLVM's ``ctpop`` (one POPCNT, or a vectorised nibble-table count inside a
    vectorised loop: about twice the speed of the shift-and-mask SWAR count it replaced, the same value)."""
    if not (isinstance(x, types.Integer) and x.bitwidth == 64 and not x.signed):
        return None

    def codegen(context, builder, signature, args):
        return builder.ctpop(args[0])

    return types.uint64(x), codegen


@numba.njit(parallel=True, cache=True, fastmath=False)  # integer kernel: fastmath would change nothing
def census_hamming_hwd_u8(codes_l, codes_r, n_disp):
    """Pixelwise census cost ``(H, W, D)`` uint8 of codes ``(K, H, W)`` uint64: ``vol[y, x, d]`` = Hamming
    distance of left (y, x) and right (y, x - d) for ``d <= x``; the positions ``x < d`` are left for
    :func:`fill_triangle_u8` (their value, ``max + 1``, is known only after every row). Also returns the
    per-row maxima (H,) int64. Rows in parallel; per pixel one loop over a contiguous slice of the reversed
    right row (vectorised). Distances must fit in uint8 (at most 254 bits, i.e. census windows <= 15)."""
    K, H, W = codes_l.shape
    D = n_disp
    vol = np.empty((H, W, D), np.uint8)
    row_max = np.zeros(H, np.int64)
    for y in prange(H):
        rev = np.empty((K, W), np.uint64)  # rev[k, j] = codes_r[k, y, W - 1 - j]: right[x - d] = rev[W - 1 - x + d]
        for k in range(K):
            for j in range(W):
                rev[k, j] = codes_r[k, y, W - 1 - j]
        m = np.uint8(0)
        for x in range(W):
            nv = min(x + 1, D)
            base = W - 1 - x
            o = vol[y, x, :nv]
            cl = codes_l[0, y, x]
            r0 = rev[0, base:base + nv]
            for d in range(nv):  # one word (census windows <= 9): straight into the uint8 row
                o[d] = np.uint8(popcount64(cl ^ r0[d]))
            for k in range(1, K):  # the sum of K words stays below 255 bits
                cl = codes_l[k, y, x]
                rk = rev[k, base:base + nv]
                for d in range(nv):
                    o[d] += np.uint8(popcount64(cl ^ rk[d]))
            for d in range(nv):
                m = max(m, o[d])
        row_max[y] = m
    return vol, row_max


@numba.njit(parallel=True, cache=True, fastmath=False)  # integer kernel: fastmath would change nothing
def fill_triangle_u8(vol, fill):
    """vol[y, x, d] = fill for x < d (uint8)."""
    H, W, D = vol.shape
    for y in prange(H):
        for x in range(min(W, D)):
            for d in range(x + 1, D):
                vol[y, x, d] = fill


# fastmath: only reassociation and contraction (FMA), so the dot product over features vectorises; no
# 'nnan'/'ninf', so NaN and inf inputs keep their meaning. It changes the sum's rounding (~1e-7), nothing else.
@numba.njit(parallel=True, cache=True, fastmath={"reassoc", "contract"})
def feature_cost_hwd(feat_l, feat_r, n_disp, invalid):
    """Learned matching cost ``(H, W, D)`` float32 of features ``(H, W, F)`` float32: ``vol[y, x, d] =
    1 - sum_f feat_l[y, x, f] * feat_r[y, x - d, f]`` for ``d <= x``, ``invalid`` for ``x < d``. Rows in
    parallel; each dot product runs over the contiguous feature axis (vectorised)."""
    H, W, F = feat_l.shape
    D = n_disp
    vol = np.empty((H, W, D), np.float32)
    one = np.float32(1.0)
    for y in prange(H):
        for x in range(W):
            nv = min(x + 1, D)
            a = feat_l[y, x]
            o = vol[y, x]
            for d in range(nv):
                b = feat_r[y, x - d]
                acc = np.float32(0.0)
                for f in range(F):
                    acc += a[f] * b[f]
                o[d] = one - acc
            for d in range(nv, D):
                o[d] = invalid
    return vol


@numba.njit(parallel=True, cache=True, fastmath=False)  # no fastmath: the sentinels stay exact
def mix_costs_hwd(own, other, w_own, w_other):
    """``w_own * own + w_other * other`` of two ``(H, W, D)`` volumes (own: any numeric dtype, e.g. the uint8
    census volume; other: float32), as float32 (the same numbers as the float32 torch expression)."""
    H, W, D = own.shape
    out = np.empty((H, W, D), np.float32)
    for y in prange(H):
        for x in range(W):
            for d in range(D):
                out[y, x, d] = w_own * np.float32(own[y, x, d]) + w_other * other[y, x, d]
    return out


@numba.njit(parallel=True, cache=True, fastmath=False)  # no fastmath: rint and the range test stay exact
def mix_costs_u8_hwd(own, other, w_own, w_other, q):
    """:func:`mix_costs_hwd` times ``q`` (a power of two, so the product is exact) rounded half to even, as
    uint8 ``(H, W, D)``: the mixed cost on the ``1 / q`` grid in units of ``1 / q``. Returns ``(vol, fits)``;
    ``fits`` is False when a value (NaN included) falls outside 0..255, and ``vol`` is then not to be used."""
    H, W, D = own.shape
    out = np.empty((H, W, D), np.uint8)
    ok = np.ones(H, np.bool_)
    lo, hi = np.float32(0.0), np.float32(255.0)
    for y in prange(H):
        good = True
        for x in range(W):
            o = out[y, x]
            a = own[y, x]
            b = other[y, x]
            for d in range(D):
                v = np.rint((w_own * np.float32(a[d]) + w_other * b[d]) * q)
                good &= (v >= lo) & (v <= hi)
                o[d] = np.uint8(min(max(v, lo), hi)) if v == v else np.uint8(0)
        ok[y] = good
    return out, bool(ok.all())
