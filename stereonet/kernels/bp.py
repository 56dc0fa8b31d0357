"""Compiled CPU kernels (numba) for one level of :mod:`stereonet.aggregate.bp`, and its pyramid steps.

Row-major layout ``(B, H, D, W)``: one grid row ``(b, y)`` is ``D`` contiguous runs of ``W`` pixels, so every
step is an elementwise loop along ``x`` that LLVM vectorises (8 float32 lanes on AVX2): the distance
transform's forward pass ``f[d] = min(h[d], f[d-1] + s)`` and backward pass run over ``d`` with all the
row's pixels at once. The iterations of a level run as a wavefront over the rows (see :func:`bp_level`), so
the grid streams from memory once per level rather than once per iteration; two threads sweep two strips of rows
towards each other and wait for each other only where they meet. It mirrors the torch reference
``bp._run_level`` (synchronous updates, linear distance transform, truncation, min-normalisation) in the
cost's dtype (float32 scratch for float32 costs).

Vectoriser notes (measured): inner loops index 1-d C-contiguous slices by the loop counter alone (``a[i + k]``
with a run-time ``k`` adds a wraparound check per element, and a 2-d ``[:, :n]`` slice is layout 'A' with a
run-time stride: both stay scalar); minima are compare-selects (``a if a < b else b``); and no loop reads and
select-writes the same buffer (an in-place running minimum becomes a masked store and stays scalar, about 3x
slower): running minima ping-pong between two rows.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange, types
from numba.extending import overload

ROWS_PER_STEP = 1
"""Rows per block of :func:`bp_level`'s wavefront (its default ``rows_per_step``)."""


def _narrow(value, like):
    """``value`` in the dtype of the array ``like`` (in compiled code the overload below, which leaves floats as
    they are: a float value of a float array's dtype is unchanged by the cast)."""
    return like.dtype.type(value)


@overload(_narrow, inline="always")
def _narrow_overload(value, like):
    """Integer arrays: ``value`` cast back to their element type; float arrays: ``value`` unchanged.

    numba computes ``int16 + int16`` in int64 (machine-width integer arithmetic), and LLVM cannot narrow a
    comparison of int64 sums back to 16 bits (the int64 sum does not wrap, the int16 one would), so without the
    cast the fixed-point kernels run on 64-bit lanes (8 per AVX-512 register instead of 32; measured in the
    generated code: ``vpmovsxwq``/``vpminsq``). Every value the kernels compute fits int16 by the fixed-point
    plan's bound (:func:`stereonet.aggregate.bp.fixed_point_plan`), so the cast changes no value."""
    if isinstance(like.dtype, types.Integer):
        return lambda value, like: like.dtype.type(value)
    return lambda value, like: value


@njit(cache=True, fastmath=False)
def _send_row(total, exclude, y_src, k_src, slopes, k, dest, y_dest, k_dest, out, lowest, row, b, y, x0, x_dest, n):  # pragma: no cover
    """One outgoing message of the ``n`` pixels ``x0 .. x0+n-1`` of row ``(b, y)``, written shifted into ``dest``.

    ``dest[y_dest, k_dest, :, x_dest + i] = DT(total[:, x0 + i] - exclude[y_src, k_src, :, x0 + i])`` normalised to min 0,
    DT the truncated-linear distance transform: forward pass ``f[d] = min(h[d], f[d-1] + s)``, backward
    pass ``g[d] = min(f[d], g[d+1] + s, lowest + s·T)`` (the cap folded in: ``min(g[d+1], cap) + s`` only
    differs from ``g[d+1] + s`` where both are above the cap), ``lowest = min_d h = min_d f`` (s >= 0),
    which is also the minimum of the message: the normalisation subtracts it.

    total, out: ``(D, W)`` row scratch (``out`` gets the forward pass); exclude, dest: ``(rows, 4, D, W)`` message
    sets (a whole grid or a ring of rows, indexed by the caller's row numbers ``y_src`` and ``y_dest``, slots
    ``k_src`` and ``k_dest``); slopes ``(B, 8, H, W)`` with s at channel ``k`` and s·T at ``k + 4``; lowest, row: ``(2, W)``
    ping-pong scratch. Every inner loop runs over ``i`` on 1-d C-contiguous slices indexed by ``i`` alone, and
    no loop reads and select-writes the same buffer (LLVM turns that into a masked store and stays scalar).
    """
    D = out.shape[0]
    s = slopes[b, k, y, x0:x0 + n]
    sT = slopes[b, k + 4, y, x0:x0 + n]
    t = total[0, x0:x0 + n]
    e = exclude[y_src, k_src, 0, x0:x0 + n]
    cur = out[0, :n]
    lo = lowest[0, :n]
    for i in range(n):
        v = _narrow(t[i] - e[i], out)
        cur[i] = v
        lo[i] = v
    for d in range(1, D):
        t = total[d, x0:x0 + n]
        e = exclude[y_src, k_src, d, x0:x0 + n]
        prev = out[d - 1, :n]
        cur = out[d, :n]
        lo_old = lowest[(d - 1) % 2, :n]
        lo = lowest[d % 2, :n]
        for i in range(n):
            h = _narrow(t[i] - e[i], out)
            v = _narrow(prev[i] + s[i], out)
            c = v if v < h else h
            cur[i] = c
            m = lo_old[i]
            lo[i] = c if c < m else m
    lo = lowest[(D - 1) % 2, :n]
    cp = lowest[D % 2, :n]  # the other half of the ping-pong: now the cap
    for i in range(n):
        cp[i] = _narrow(lo[i] + sT[i], out)
    f = out[D - 1, :n]
    g = row[(D - 1) % 2, :n]
    dst = dest[y_dest, k_dest, D - 1, x_dest:x_dest + n]
    for i in range(n):
        c = f[i]
        q = cp[i]
        c = q if q < c else c
        g[i] = c
        dst[i] = _narrow(c - lo[i], out)
    for d in range(D - 2, -1, -1):
        f = out[d, :n]
        nxt = row[(d + 1) % 2, :n]
        g = row[d % 2, :n]
        dst = dest[y_dest, k_dest, d, x_dest:x_dest + n]
        for i in range(n):
            c = f[i]
            v = _narrow(nxt[i] + s[i], out)
            c = v if v < c else c
            q = cp[i]
            c = q if q < c else c
            g[i] = c
            dst[i] = _narrow(c - lo[i], out)


def ring_shape(iterations: int, rows_per_step: int, depth: int, width: int) -> tuple[int, int, int, int, int]:
    """Shape of :func:`bp_level`'s ``rings`` scratch: per intermediate iteration, one ring of ``R = 4 K`` rows of the
    four message slots for each of the two strips of rows (``2 R`` rows; at least one set, so the shape is never
    empty)."""
    return (max(iterations - 1, 1), 2 * 4 * max(1, rows_per_step), 4, depth, width)


@njit(cache=True, fastmath=False)
def _strips(H, K):  # pragma: no cover - compiled
    """The two strips of :func:`bp_level`'s wavefront: ``(n_blocks, nA, nB, M)``: ``n_blocks`` blocks of ``K`` rows,
    the top strip blocks ``0 .. nA - 1`` (rows ``0 .. M - 1``, swept downwards), the bottom strip the other ``nB``
    (swept upwards from the last block), ``nA - nB`` 0 or 1."""
    n_blocks = (H + K - 1) // K
    nA = (n_blocks + 1) // 2
    return n_blocks, nA, n_blocks - nA, min(nA * K, H)


@njit(cache=True, fastmath=False)
def _strip_block(t, j, strip, n_blocks, nA, nB):  # pragma: no cover - compiled
    """The block that iteration (stage) ``j`` of ``strip`` (0 top, 1 bottom) updates at step ``t``, or -1: the strip's
    ``t - 2 j``-th block in its own sweep order."""
    local = t - 2 * j
    if strip == 0:
        return local if 0 <= local < nA else -1
    return n_blocks - 1 - local if 0 <= local < nB else -1


@njit(parallel=True, cache=True, fastmath=False)
def bp_level(cost, start, final, rings, slopes, iterations, rows_per_step=ROWS_PER_STEP):  # pragma: no cover - compiled
    """Run ``iterations`` synchronous min-sum updates from the messages in ``start``; the result lands in ``final``.

    cost ``(B, H, D, W)`` row-major, C-contiguous; ``start`` the incoming messages ``(B, H, 4, D, W)``
    [from left, from right, from up, from down], a row's four slots side by side, zero in the border slots that
    receive no message; ``final`` the same shape, and with ``iterations >= 2`` it may be ``start`` itself (then updated in place; with one
    iteration it must be another buffer); ``rings`` scratch of :func:`ring_shape` (any content); ``slopes (B, 8,
    H, W)`` = λ·w to the right, left, down, up neighbour, then the same four times the truncation ``T``.

    Iteration ``j`` reads the message set ``S_j`` and writes ``S_{j+1}``, row by row: ``S_0 = start``,
    ``S_J = final`` (``J = iterations``), and the sets in between live in the rings: row ``y`` of ``S_j`` at
    row ``y % R`` of ring ``j - 1`` (``R = 4 K``). The iterations run as a wavefront over blocks of
    ``K = rows_per_step`` rows: at step ``t`` iteration ``j`` updates block ``t - 2j``. A row's update reads only
    its own incoming messages and writes its own row and the two next to it (and zeroes the border slots it
    owns), so the lag of two blocks keeps it exactly synchronous for any ``K >= 1``: iteration ``j`` at block
    ``b`` needs iteration ``j - 1``'s writes into the block, made from blocks ``b - 1 .. b + 1`` (done at steps up
    to ``t - 1``), and what it writes (the block and one row either side) never meets a row that another
    iteration reads or writes in the same step; so the blocks of one step could run in parallel, and every ``K``
    gives the same bits. The same lag bounds what a ring must hold: when iteration ``j`` writes rows up to
    ``(b + 1) K``, iteration ``j + 1`` has consumed every row before ``(b - 2) K``, so ``3 K + 1 <= R`` rows are
    live; and ``final`` can overwrite ``start`` because iteration ``J - 1`` writes rows that iteration 0 read at
    least one step earlier (``J >= 2``). So one whole set of messages is held instead of two, and the sets in
    between stay in cache. ``K = 1`` keeps the most in cache.

    Threads: the blocks are split into two strips (:func:`_strips`) swept towards each other, the top one downwards
    and the bottom one upwards (the lag argument holds in either direction), each with its own half of every ring.
    Until a strip reaches its last block no row it touches neighbours the other strip, so each strip runs its steps
    alone, without a barrier; the last ``~2 J`` steps, where the two meet, run one step at a time (a barrier per
    step). The block counts differ by at most one, so the meeting rows' writes precede their reads by at least one
    step, as within a strip. One thread per strip: on a shared machine a thread that loses its core delays the
    other only where they meet, instead of at every row (a barrier per row cost bp up to 23x its idle time beside
    another two-thread job; docs/experiments/bp_phases.txt).
    """
    B, H, D, W = cost.shape
    K = max(1, rows_per_step)
    R = rings.shape[1] // 2
    n_blocks, nA, nB, M = _strips(H, K)
    split = max(0, min(nA, nB) - 1)  # steps before either strip's last block: the strips never meet
    for b in range(B):
        for strip in prange(2):  # each strip alone: no barrier until its last block
            for t in range(split):
                for j in range(iterations):
                    _level_block(cost, start, final, rings, R, M, slopes, iterations, b, j,
                                 _strip_block(t, j, strip, n_blocks, nA, nB), K)
        for t in range(split, nA + 2 * (iterations - 1)):  # the meeting rows: one barrier per step
            for item in prange(2 * iterations):
                j = item % iterations
                _level_block(cost, start, final, rings, R, M, slopes, iterations, b, j,
                             _strip_block(t, j, item // iterations, n_blocks, nA, nB), K)


@njit(cache=True, fastmath=False)
def _level_block(cost, start, final, rings, R, M, slopes, iterations, b, j, blk, K):  # pragma: no cover - compiled
    """Iteration ``j`` of :func:`bp_level` on block ``blk`` (nothing when ``blk < 0``): rows ``blk K .. blk K + K - 1``
    read ``start`` or ring ``j - 1`` and write ring ``j`` or ``final`` (the rings of the strip each row is in: rows
    from ``M`` on use the second half)."""
    if blk < 0:
        return
    H = cost.shape[1]
    last = iterations - 1
    for y in range(blk * K, min(blk * K + K, H)):
        if j == 0 and j == last:
            _update_row(cost, start[b], H, H, final[b], H, H, slopes, b, y)
        elif j == 0:
            _update_row(cost, start[b], H, H, rings[0], R, M, slopes, b, y)
        elif j == last:
            _update_row(cost, rings[j - 1], R, M, final[b], H, H, slopes, b, y)
        else:
            _update_row(cost, rings[j - 1], R, M, rings[j], R, M, slopes, b, y)


@njit(cache=True, fastmath=False)
def _row_index(y, rows, split):  # pragma: no cover - compiled
    """Where grid row ``y`` lives in a set of ``rows`` rows: ``y`` itself in a whole grid (``rows = split = H``); in
    a pair of rings of ``rows`` rows each, ``y % rows`` in the first (rows above ``split``) or the second."""
    return y % rows + (rows if y >= split else 0)


@njit(cache=True, fastmath=False)
def _update_row(cost, src, src_rows, src_split, dst, dst_rows, dst_split, slopes, b, y):  # pragma: no cover - compiled
    """One synchronous update of row ``(b, y)``: read its incoming messages in ``src``, write the four
    outgoing ones into ``dst`` (``src``/``dst`` ``(rows, 4, D, W)``, [from left, right, up, down]; grid row ``y``
    is row :func:`_row_index` ``(y, src_rows, src_split)`` / ``(y, dst_rows, dst_split)``: a whole grid, or a pair
    of rings).

    Row ``y`` writes ``dst`` from-left/from-right of its own row, from-up of row ``y + 1`` and from-down of
    row ``y - 1``: no two rows write the same slot. It also zeroes the slots of its own row that no neighbour
    writes (from-left at ``x = 0``, from-right at ``x = W - 1``, from-up in row 0, from-down in row ``H - 1``).
    """
    B, H, D, W = cost.shape
    total = np.empty((D, W), dtype=cost.dtype)
    out = np.empty((D, W), dtype=cost.dtype)
    lowest = np.empty((2, W), dtype=cost.dtype)
    scratch = np.empty((2, W), dtype=cost.dtype)
    ys = _row_index(y, src_rows, src_split)
    yd = _row_index(y, dst_rows, dst_split)
    for d in range(D):
        t = total[d]
        cd = cost[b, y, d]
        ld = src[ys, 0, d]
        rd = src[ys, 1, d]
        ud = src[ys, 2, d]
        dd = src[ys, 3, d]
        for x in range(W):
            t[x] = _narrow(cd[x] + ld[x] + rd[x] + ud[x] + dd[x], total)
    zero = total.dtype.type(0)
    for d in range(D):
        dst[yd, 0, d, 0] = zero
        dst[yd, 1, d, W - 1] = zero
    if y == 0:
        dst[yd, 2] = zero
    if y == H - 1:
        dst[yd, 3] = zero
    if W > 1:  # to the right neighbour (0..W-2 send to 1..W-1), to the left (1..W-1 send to 0..W-2)
        _send_row(total, src, ys, 1, slopes, 0, dst, yd, 0, out, lowest, scratch, b, y, 0, 1, W - 1)
        _send_row(total, src, ys, 0, slopes, 1, dst, yd, 1, out, lowest, scratch, b, y, 1, 0, W - 1)
    if y + 1 < H:
        _send_row(total, src, ys, 3, slopes, 2, dst, _row_index(y + 1, dst_rows, dst_split), 2, out, lowest, scratch,
                  b, y, 0, 0, W)
    if y >= 1:
        _send_row(total, src, ys, 2, slopes, 3, dst, _row_index(y - 1, dst_rows, dst_split), 3, out, lowest, scratch,
                  b, y, 0, 0, W)


@njit(parallel=True, cache=True, fastmath=False)
def upsample2(coarse, out):  # pragma: no cover - compiled
    """Each coarse pixel's values copied to its 2x2 children: row-major ``(N, h, D, w) -> out (N, H, D, W)``.

    ``out[n, y, d, x] = coarse[n, y // 2, d, x // 2]`` with ``H <= 2h``, ``W <= 2w`` (the torch
    ``repeat_interleave(2)`` twice, cropped), in one pass.
    """
    N, height, D, width = out.shape
    for row in prange(N * height):
        n = row // height
        y = row % height
        _upsample_row(coarse[n, y // 2], out[n, y])


@njit(cache=True, fastmath=False)
def _upsample_row(src, dst):  # pragma: no cover - compiled
    """``dst[c, x] = src[c, x // 2]``: one row of :func:`upsample2`, ``(C, w) -> (C, W)``, ``W <= 2w``."""
    C, W = dst.shape
    half = W // 2
    for c in range(C):
        a = src[c]
        b = dst[c]
        for i in range(half):
            v = a[i]
            b[2 * i] = v
            b[2 * i + 1] = v
        if W % 2:
            b[W - 1] = a[half]


@njit(parallel=True, cache=True, fastmath=False)
def pool_sum2(fine):  # pragma: no cover - compiled
    """Sums over 2x2 blocks, odd sizes replicated: row-major ``(B, H, D, W) -> (B, ceil(H/2), D, ceil(W/2))``.

    ``out[b, y, d, x] = f[2y, d, 2x] + f[2y, d, 2x+1] + f[2y+1, d, 2x] + f[2y+1, d, 2x+1]`` (indices past
    the border replaced by the last row/column, as ``F.pad(mode="replicate")`` does for ``bp._pool_sum``).
    """
    B, H, D, W = fine.shape
    h = (H + 1) // 2
    w = (W + 1) // 2
    out = np.empty((B, h, D, w), dtype=fine.dtype)
    half = W // 2
    for row in prange(B * h):
        b = row // h
        y = row % h
        y1 = min(2 * y + 1, H - 1)
        for d in range(D):
            top = fine[b, 2 * y, d]
            bottom = fine[b, y1, d]
            dst = out[b, y, d]
            for i in range(half):
                dst[i] = top[2 * i] + top[2 * i + 1] + bottom[2 * i] + bottom[2 * i + 1]
            if W % 2:
                dst[w - 1] = top[W - 1] + top[W - 1] + bottom[W - 1] + bottom[W - 1]
    return out


@njit(parallel=True, cache=True, fastmath=False)
def round_rows(cost, scale, out):  # pragma: no cover - compiled
    """``out = rint(cost * scale)`` as int16 (round half to even, as ``np.rint``): the finest level in fixed point,
    read from any strided ``(B, H, D, W)`` float32 view (a permuted cost volume) in one pass, row by row."""
    B, H, D, W = out.shape
    for row in prange(B * H):
        b = row // H
        y = row % H
        for d in range(D):
            src = cost[b, y, d]
            dst = out[b, y, d]
            for x in range(W):
                dst[x] = np.int16(np.rint(src[x] * scale))


def beliefs_view(messages: np.ndarray, dtype) -> np.ndarray:
    """The ``(B, H, D, W)`` beliefs of :func:`beliefs_argmin` as a strided view of its ``messages`` buffer: row
    ``(b, y)``'s beliefs take the first ``D·W`` values of ``dtype`` of that row's four message slots."""
    B, H, _, D, W = messages.shape
    raw = messages.reshape(B, H, -1).view(np.uint8)
    return raw[:, :, :D * W * np.dtype(dtype).itemsize].view(dtype).reshape(B, H, D, W)


@njit(cache=True, fastmath=False)
def _beliefs_row(cost, m, b, y, s, bel, best, lab, dst):  # pragma: no cover - compiled
    """Row ``(b, y)`` of :func:`beliefs_argmin`: ``bel (D, W) = (cost[b, y] + m[0] + m[1] + m[2] + m[3]) * s`` from
    the row's incoming messages ``m (4, D, W)``, and its first argmin over d into ``dst (W,)``; ``best``/``lab``
    ``(2, W)`` ping-pong scratch."""
    D = bel.shape[0]
    W = bel.shape[1]
    for d in range(D):
        c = cost[b, y, d]
        a0 = m[0, d]
        a1 = m[1, d]
        a2 = m[2, d]
        a3 = m[3, d]
        out = bel[d]
        for x in range(W):
            out[x] = _narrow(c[x] + a0[x] + a1[x] + a2[x] + a3[x], cost) * s
        if d == 0:
            b0 = best[0]
            l0 = lab[0]
            for x in range(W):
                b0[x] = out[x]
                l0[x] = 0
        else:
            old = best[(d - 1) % 2]
            new = best[d % 2]
            lab_old = lab[(d - 1) % 2]
            lab_new = lab[d % 2]
            for x in range(W):
                v = out[x]
                o = old[x]
                better = v < o
                new[x] = v if better else o
                lab_new[x] = d if better else lab_old[x]
    final = lab[(D - 1) % 2]
    for x in range(W):
        dst[x] = final[x]


@njit(cache=True, fastmath=False)
def _near_row(bel, lab, lo, mid, hi):  # pragma: no cover - compiled
    """Beliefs ``bel (D, W)`` of one row at each pixel's label ``lab (W,)`` and its two neighbours, into ``lo``,
    ``mid``, ``hi (W,)``; a neighbour outside ``0 .. D - 1`` takes the label's own value."""
    D = bel.shape[0]
    for x in range(bel.shape[1]):
        d = lab[x]
        c0 = bel[d, x]
        mid[x] = c0
        lo[x] = bel[d - 1, x] if d > 0 else c0
        hi[x] = bel[d + 1, x] if d < D - 1 else c0


@njit(parallel=True, cache=True, fastmath=False)
def beliefs_argmin(cost, messages, labels, scale):  # pragma: no cover - compiled
    """``beliefs = (cost + m0 + m1 + m2 + m3) * scale`` (summed left to right), written over the messages, and
    ``labels`` its first argmin over d, row-major.

    cost ``(B, H, D, W)`` and messages ``(B, H, 4, D, W)`` of one dtype (float, or int16 in fixed point), C-contiguous;
    ``scale`` a 1-element array of the beliefs' dtype (1 for float costs: the same bits; ``1/s`` in fixed point, a
    power of two, so the int16 sums come back exactly); (output) labels ``(B, H, W)`` int64. Each row's beliefs are computed into a
    scratch row and then copied over the row's own message slots (a row's four slots hold at least one row of
    beliefs of ``scale``'s dtype: float32 over int16 or float32 slots, float64 over float64), so no separate
    volume is allocated; :func:`beliefs_view` reads them back. The running minimum ping-pongs between two rows (no
    select-write in place: that stays scalar).
    """
    B, H, D, W = cost.shape
    s = scale[0]
    for row in prange(B * H):
        b = row // H
        y = row % H
        bel = np.empty((D, W), dtype=scale.dtype)
        best = np.empty((2, W), dtype=bel.dtype)
        lab = np.empty((2, W), dtype=np.int64)
        m = messages[b, y]
        _beliefs_row(cost, m, b, y, s, bel, best, lab, labels[b, y])
        flat = bel.reshape(D * W)
        into = m.reshape(4 * D * W).view(bel.dtype)
        for i in range(D * W):
            into[i] = flat[i]


@njit(parallel=True, cache=True, fastmath=False)
def bp_finest(cost, coarse, rings, slopes, iterations, beliefs, near, labels, scale, rows_per_step=ROWS_PER_STEP):  # pragma: no cover
    """The finest level of the pyramid without its full message sets: :func:`bp_level` started from the coarse
    level's messages, then :func:`beliefs_argmin`, in one wavefront.

    Iteration 0 reads row ``y``'s incoming messages from the coarse level's row ``y // 2`` (``coarse (B, h, 4, D,
    w)``), upsampled into a scratch row exactly as :func:`upsample2` copies each coarse pixel to its 2x2 children;
    every iteration, the last one too, writes into a ring (``rings`` of :func:`ring_shape` with ``iterations + 1``);
    and one step behind the last iteration's lag a last stage computes each row's beliefs ``(cost + four messages) *
    scale[0]`` into ``beliefs (B, H, D, W)`` (``scale``'s dtype) and their first argmin into ``labels (B, H, W)``
    int64. The beliefs of row ``y`` need the last iteration's writes from rows ``y - 1 .. y + 1``, the same
    dependency as an iteration's on the one before, so the same two-block lag keeps it exact and the ring bound
    holds. The same numbers as upsampling into a full message set, :func:`bp_level` and :func:`beliefs_argmin`;
    what it saves is the two full message sets' traffic (the upsampled start and the final set).

    ``near (B, 3, H, W)`` (``scale``'s dtype) receives each pixel's beliefs at ``label - 1``, ``label``, ``label + 1``
    (the label's own value where a neighbour lies outside ``0 .. D - 1``): all a sub-pixel fit reads. A ``beliefs``
    array with no rows (shape ``(B, 0, D, W)``) keeps no belief volume: each row's beliefs go to a scratch row.
    """
    B, H, D, W = cost.shape
    K = max(1, rows_per_step)
    R = rings.shape[1] // 2
    n_blocks, nA, nB, M = _strips(H, K)
    J = iterations
    split = max(0, min(nA, nB) - 1)  # as bp_level: the strips run alone until their last blocks
    for b in range(B):
        for strip in prange(2):
            for t in range(split):
                for j in range(J + 1):
                    _finest_block(cost, coarse, rings, R, M, slopes, J, beliefs, near, labels, scale, b, j,
                                  _strip_block(t, j, strip, n_blocks, nA, nB), K)
        for t in range(split, nA + 2 * J):
            for item in prange(2 * (J + 1)):
                j = item % (J + 1)
                _finest_block(cost, coarse, rings, R, M, slopes, J, beliefs, near, labels, scale, b, j,
                              _strip_block(t, j, item // (J + 1), n_blocks, nA, nB), K)


@njit(cache=True, fastmath=False)
def _finest_block(cost, coarse, rings, R, M, slopes, J, beliefs, near, labels, scale, b, j, blk, K):  # pragma: no cover
    """Stage ``j`` of :func:`bp_finest` on block ``blk`` (nothing when ``blk < 0``): an iteration (``j < J``; the
    first one reads the upsampled coarse messages), or the beliefs, labels and ``near`` values (``j == J``)."""
    if blk < 0:
        return
    H, D, W = cost.shape[1], cost.shape[2], cost.shape[3]
    for y in range(blk * K, min(blk * K + K, H)):
        if j == J:
            bel = beliefs[b, y] if beliefs.shape[1] > 0 else np.empty((D, W), dtype=scale.dtype)
            best = np.empty((2, W), dtype=bel.dtype)
            lab = np.empty((2, W), dtype=np.int64)
            _beliefs_row(cost, rings[J - 1][_row_index(y, R, M)], b, y, scale[0], bel, best, lab, labels[b, y])
            _near_row(bel, labels[b, y], near[b, 0, y], near[b, 1, y], near[b, 2, y])
        elif j == 0:
            src = np.empty((1, 4, D, W), dtype=cost.dtype)
            _upsample_row(coarse[b, y // 2].reshape(4 * D, coarse.shape[4]), src[0].reshape(4 * D, W))
            _update_row(cost, src, 1, H, rings[0], R, M, slopes, b, y)
        else:
            _update_row(cost, rings[j - 1], R, M, rings[j], R, M, slopes, b, y)
