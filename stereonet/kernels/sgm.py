"""Numba kernels of the SGM path recurrence (see :mod:`stereonet.aggregate.sgm` for the maths).

Layout ``(H, W, D)`` float32 so the inner loop over disparities is contiguous (and vectorised). The
directions are computed in two sweeps over the rows, top-down (left-to-right, and every direction with
dy > 0) and bottom-up (the rest), so each sweep reads every cost row once and writes every S row once;
the two sweeps run concurrently on two threads without any barrier (which matters on a busy 2-core
machine), each into its own buffer, and are added at the end. Every path cost is computed with the
same float32 operations as the torch reference (``C + (t - m)``), so the per-path costs are identical and
the sums differ only by the order of additions (tested bit for bit per path). The cost may be float32 or
uint8 (census distances: :func:`stereonet.cost.volume.census_pixel_volumes_u8`).

Fixed point (:func:`_sweep_i16`): for uint8 costs with penalties on a grid ``1 / s`` (``s = 2^k``,
:func:`stereonet.aggregate.sgm.quantize_penalty`) every path cost is an integer multiple of ``1 / s``; the
kernel computes ``s * L`` in int16 (16 SIMD lanes instead of 8, half the memory traffic), which is exact as
long as ``paths * s * (max C + max P2)`` fits int16 (checked; otherwise the float32 kernel runs). The float32
sums of such multiples are exact too, so both kernels give the same bits. Its two sweeps share one int16
buffer even when they run concurrently (rows handed over in the middle: :func:`sgm_fixed_hwd`), so at any
size the memory is the uint8 cost plus one int16 volume, on two threads.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np
from numba import prange

_INF = np.float32(np.inf)


# fastmath=False on every kernel here: the padding of the path rows and the start of the minima are +inf
# sentinels (so no "ninf"/"nnan"), and "reassoc" would let the compiler rewrite ``c + (t - m)`` as
# ``(c + t) - m``, which changes result bits against the torch reference (the old fastmath=True did, by
# ~1e-4 on Cones' aggregated costs). Nothing here needs fastmath to vectorise: the recurrence is
# elementwise, and the minimum over disparities is an integer min reduction over the float bits
# (:func:`min_key`), which the compiler vectorises without fast-math flags.


@numba.njit(fastmath=False, inline="always")
def _min(a, b):
    """``a if a < b else b``: a compare and a select (the builtin ``min`` adds NaN tests without fastmath,
    which stop the loops from vectorising)."""
    return a if a < b else b


@numba.njit(fastmath=False, inline="always")
def _step(c_row, prev, m, P1, pen2, out, s_row, assign):
    """out = c + (min(prev[d], prev[d±1] + P1, m + pen2) - m); s += out.

    ``prev``/``out`` are padded: index ``d + 1`` holds disparity ``d``, indices 0 and D + 1 hold +inf, so
    the loop is branch-free and vectorises. The minimum of ``out`` is taken by :func:`min_key` afterwards."""
    n = c_row.shape[0]
    big = m + pen2
    for d in range(n):
        t = _min(_min(prev[d + 1], prev[d] + P1), _min(prev[d + 2] + P1, big))
        out[d + 1] = np.float32(c_row[d]) + (t - m)
    if assign:  # the first direction into a fresh (uninitialised) S: S = L (0 + L would give the same)
        for d in range(n):
            s_row[d] = out[d + 1]
    else:
        for d in range(n):
            s_row[d] += out[d + 1]


@numba.njit(fastmath=False, inline="always")
def _key(k):
    """Order-preserving int32 key of a float32's bits (an involution): non-negative floats keep their bits,
    negative ones get the lower 31 bits flipped, so signed integer order = float order (-0 < +0, NaN above
    +inf)."""
    return k ^ ((k >> np.int32(31)) & np.int32(0x7FFFFFFF))


@numba.njit(fastmath=False, inline="always")
def min_key(bits):
    """Key of the minimum of float32 values given as their int32 bits (1-D, non-empty): an integer min
    reduction, which vectorises without fastmath (a float min reduction would need "nnan")."""
    mi = np.int32(0x7FFFFFFF)
    for d in range(bits.shape[0]):
        mi = min(mi, _key(bits[d]))
    return mi


@numba.njit(fastmath=False, inline="always")
def min_of(a):
    """min of a 1-D float array with eight independent accumulators (no serial dependency chain; min is
    exact, so the result equals the plain loop's for non-NaN input)."""
    n = a.shape[0]
    m0 = m1 = m2 = m3 = m4 = m5 = m6 = m7 = _INF
    i = 0
    while i + 8 <= n:
        m0 = _min(m0, np.float32(a[i]))
        m1 = _min(m1, np.float32(a[i + 1]))
        m2 = _min(m2, np.float32(a[i + 2]))
        m3 = _min(m3, np.float32(a[i + 3]))
        m4 = _min(m4, np.float32(a[i + 4]))
        m5 = _min(m5, np.float32(a[i + 5]))
        m6 = _min(m6, np.float32(a[i + 6]))
        m7 = _min(m7, np.float32(a[i + 7]))
        i += 8
    while i < n:
        m0 = _min(m0, np.float32(a[i]))
        i += 1
    return _min(_min(_min(m0, m1), _min(m2, m3)), _min(_min(m4, m5), _min(m6, m7)))


@numba.njit(fastmath=False, inline="always")
def _row_bases(y, H, W, dirs, row_ok, out_base, prev_base):
    """Per direction g for image row y: whether the predecessor row exists, and the flat ring-buffer row
    bases of this row's path costs (slot y % 3) and of the predecessor's (shifted by -dx, so that pixel x's
    predecessor is at ``prev_base[g] + x``)."""
    for g in range(dirs.shape[0]):
        yp = y - dirs[g, 1]
        row_ok[g] = 0 <= yp < H
        out_base[g] = (g * 3 + y % 3) * W
        prev_base[g] = (g * 3 + (yp % 3 if row_ok[g] else 0)) * W - dirs[g, 0]


@numba.njit(fastmath=False, nogil=True, cache=True)
def _sweep(C, S, P1, p2, dirs, downward, fresh):
    """One sweep over the rows (top-down if ``downward`` else bottom-up) computing every direction of
    ``dirs`` (G, 2) at once: each pixel's cost row is read once and its S row written once.

    Directions with ``dy != 0`` must point along the sweep; a horizontal one must point along the column
    order of the sweep (left-to-right top-down, right-to-left bottom-up). ``L``/``M`` keep three rows of
    padded path costs and their minima per direction (enough for the |dy| = 2 knight moves)."""
    H, W, D = C.shape
    G = dirs.shape[0]
    # path rows and minima as flat (G * 3 * W) rows: row (g * 3 + slot) * W + x holds pixel x of the path
    # row in ring slot ``slot`` (one 2-D index per access instead of 3-D ones, bases hoisted per image row)
    L = np.full((G * 3 * W, D + 2), _INF, np.float32)
    M = np.empty(G * 3 * W, np.float32)
    L_bits = L.view(np.int32)  # the same memory, for the integer minimum
    box = np.empty(1, np.int32)
    box_f = box.view(np.float32)
    C2 = C.reshape(H * W, D)
    S2 = S.reshape(H * W, D)
    out_base = np.empty(G, np.int64)
    prev_base = np.empty(G, np.int64)
    row_ok = np.empty(G, np.bool_)
    for step in range(H):
        y = step if downward else H - 1 - step
        _row_bases(y, H, W, dirs, row_ok, out_base, prev_base)
        for k in range(W):
            x = k if downward else W - 1 - k
            c_row = C2[y * W + x]
            s_row = S2[y * W + x]
            for g in range(G):
                xp = x - dirs[g, 0]
                o = out_base[g] + x
                out = L[o]
                if row_ok[g] and 0 <= xp < W:
                    q = prev_base[g] + x
                    _step(c_row, L[q], M[q], P1, p2[g, y, x], out, s_row, fresh and g == 0)
                    box[0] = _key(min_key(L_bits[o, 1:D + 1]))
                    M[o] = box_f[0]
                else:
                    for d in range(D):
                        v = np.float32(c_row[d])
                        out[d + 1] = v
                        s_row[d] = v if fresh and g == 0 else s_row[d] + v
                    M[o] = min_of(c_row)


@numba.njit(parallel=True, cache=True, fastmath=False)  # exact float32 (or in-range int16) adds
def _add_into(a, b):
    H = a.shape[0]
    for y in prange(H):
        a[y] += b[y]


def sweep_groups(dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the directions of the top-down sweep (dy > 0, or dy = 0 and dx > 0) and the bottom-up one."""
    down = (dirs[:, 1] > 0) | ((dirs[:, 1] == 0) & (dirs[:, 0] > 0))
    return np.nonzero(down)[0], np.nonzero(~down)[0]


_I16_SENTINEL = np.int16(0x3FFF)  # "no disparity here" in the padded int16 path rows: above every valid s*L
# (<= 32767 / paths <= 8191) plus s*P1, and sentinel + s*P1 <= 32767 stays in range
_I16_MAX = 32767


def sweep_state_i16(G: int, W: int, D: int) -> tuple[np.ndarray, np.ndarray]:
    """The ring of padded path-cost rows ``L`` and their minima ``M`` that :func:`_sweep_i16` carries from
    one chunk of rows to the next (``L`` starts at the sentinel)."""
    return np.full((G * 3 * W, D + 2), _I16_SENTINEL, np.int16), np.empty(G * 3 * W, np.int16)


@numba.njit(fastmath=False, inline="always")
def _add4(s_row, o0, o1, o2, o3, assign):
    """``s_row (+)= o0 + o1 + o2 + o3`` over the padded path rows' disparities (index ``d + 1``). Every path
    cost is non-negative and every partial sum is at most the full sum, which the caller's bound keeps in
    int16, so the order of these integer additions does not change a bit."""
    D = s_row.shape[0]
    if assign:
        for d in range(D):
            s_row[d] = np.int16(np.int16(o0[d + 1] + o1[d + 1]) + np.int16(o2[d + 1] + o3[d + 1]))
    else:
        for d in range(D):
            s_row[d] = np.int16(s_row[d] + np.int16(np.int16(o0[d + 1] + o1[d + 1]) + np.int16(o2[d + 1] + o3[d + 1])))


@numba.njit(fastmath=False, nogil=True, cache=True)
def _sweep_i16(C, S, scale, P1, p2, dirs, downward, assign, L, M, step0, step1):
    """Steps ``step0 .. step1 - 1`` of :func:`_sweep` in 16-bit fixed point (step = row index top-down, or
    ``H - 1 - row`` bottom-up): ``C`` uint8 (H, W, D), ``S`` int16 (H, W, D) receives ``s * sum L`` of these
    rows (``assign``: written by the first direction instead of added), ``scale`` = s, ``P1`` = s * P1 and
    ``p2`` (G, H, W) = s * P2 maps, all int16; ``L``, ``M`` the state of :func:`sweep_state_i16`, carried
    between calls. Every value stays below :data:`_I16_SENTINEL` (the caller checks the bound), so no
    operation wraps."""
    H, W, D = C.shape
    G = dirs.shape[0]
    C2 = C.reshape(H * W, D)
    S2 = S.reshape(H * W, D)
    cs = np.empty(D, np.int16)
    out_base = np.empty(G, np.int64)
    prev_base = np.empty(G, np.int64)
    row_ok = np.empty(G, np.bool_)
    for step in range(step0, step1):
        y = step if downward else H - 1 - step
        _row_bases(y, H, W, dirs, row_ok, out_base, prev_base)
        for k in range(W):
            x = k if downward else W - 1 - k
            c_row = C2[y * W + x]
            s_row = S2[y * W + x]
            for d in range(D):
                cs[d] = np.int16(c_row[d]) * scale
            for g in range(G):
                xp = x - dirs[g, 0]
                o = out_base[g] + x
                out = L[o]
                mi = _I16_SENTINEL
                if row_ok[g] and 0 <= xp < W:
                    q = prev_base[g] + x
                    prev = L[q]
                    m = M[q]
                    big = np.int16(m + p2[g, y, x])
                    for d in range(D):
                        t = _min(_min(prev[d + 1], np.int16(prev[d] + P1)),
                                   _min(np.int16(prev[d + 2] + P1), big))
                        v = np.int16(cs[d] + np.int16(t - m))
                        out[d + 1] = v
                        mi = _min(mi, v)
                else:
                    for d in range(D):
                        out[d + 1] = cs[d]
                        mi = _min(mi, cs[d])
                M[o] = mi
                if G != 4:
                    if assign and g == 0:
                        for d in range(D):
                            s_row[d] = out[d + 1]
                    else:
                        for d in range(D):
                            s_row[d] += out[d + 1]
            if G == 4:  # 8 paths: the sweep's four path costs added in one pass (s_row read and written once)
                _add4(s_row, L[out_base[0] + x], L[out_base[1] + x], L[out_base[2] + x], L[out_base[3] + x],
                      assign)


def grid_scale(penalty_step: float | None) -> int | None:
    """``s = 1 / penalty_step`` if it is an integer power of two (the grids fixed point can use), else None."""
    if penalty_step is None:
        return None
    s = 1.0 / float(penalty_step)
    if s < 1 or s != round(s) or int(round(s)) & (int(round(s)) - 1):
        return None
    return int(round(s))


def fits_int16(s: int, cost_max: float, P1: float, p2_max: float, paths: int) -> bool:
    """Whether ``s * L`` (0 <= L <= max C + max P2) summed over ``paths`` fits int16, with the padding
    sentinel above every ``s * L + s * P1``."""
    l_max = s * (float(cost_max) + float(p2_max))
    return paths * l_max <= _I16_MAX and l_max + s * float(P1) < int(_I16_SENTINEL)


def fixed_point_scale(cost_hwd: np.ndarray, P1: float, p2: np.ndarray, paths: int,
                      penalty_step: float | None, cost_max: int | None = None) -> int | None:
    """``s = 1 / penalty_step`` when the 16-bit kernel is exact for this uint8 cost and these penalties
    (``s`` an integer power of two, ``P1`` and ``p2`` multiples of ``1 / s``, :func:`fits_int16`; ``cost_max``
    a known bound of the cost, else its maximum is taken), else None (the float32 kernel runs)."""
    s = grid_scale(penalty_step)
    if s is None or cost_hwd.dtype != np.uint8 or cost_hwd.size == 0:
        return None
    p2s = p2.astype(np.float64) * s
    if not (np.array_equal(p2s, np.round(p2s)) and float(P1) * s == round(float(P1) * s)):
        return None
    c_max = int(cost_hwd.max()) if cost_max is None else cost_max
    return s if fits_int16(s, c_max, P1, float(p2.max()) if p2.size else 0.0, paths) else None


@numba.njit(parallel=True, cache=True, fastmath=False)
def p2_maps_fixed(grey, P1, P2, alpha, dirs, s):
    """``s *`` :func:`stereonet.aggregate.sgm.p2_maps_numpy` (penalty step ``1 / s``) as int16 (R, H, W), in
    one parallel pass: the same float32 operations, ``max(P2 / (1 + alpha |dI|), P1)`` rounded half to even
    to the grid (``P1``, ``P2`` float32, already on it); ``P2`` where there is no predecessor."""
    R = dirs.shape[0]
    H, W = grey.shape
    out = np.empty((R, H, W), np.int16)
    sf = np.float32(s)
    p2c = np.int16(np.rint(P2 * sf))
    one = np.float32(1.0)
    for y in prange(H):
        for r in range(R):
            dx, dy = dirs[r, 0], dirs[r, 1]
            yp = y - dy
            o = out[r, y]
            if alpha == 0 or not 0 <= yp < H:
                o[:] = p2c
                continue
            for x in range(W):
                xp = x - dx
                if 0 <= xp < W:
                    v = P2 / (one + alpha * abs(grey[y, x] - grey[yp, xp]))
                    v = v if v > P1 else P1
                    o[x] = np.int16(np.rint(v * sf))
                else:
                    o[x] = p2c
    return out


def sgm_fixed_hwd(cost_hwd: np.ndarray, P1: float, p2: np.ndarray, dirs: np.ndarray, s: int) -> np.ndarray:
    """``s * S`` as int16 (H, W, D) for a uint8 cost and penalties on the ``1 / s`` grid, where
    :func:`fixed_point_scale` returned ``s`` (exact: ``S`` = the float32 kernel's result times ``s``).
    ``p2`` float (R, H, W) penalties, or int16 ones already times ``s`` (:func:`p2_maps_fixed`).

    The two sweeps share one int16 buffer and run concurrently on two threads (numba releases the GIL):
    the top-down sweep writes the upper half of the rows first and the bottom-up sweep the lower half, and
    each adds its share to a row of the other half only after the other sweep has finished that row (rows
    are handed over in chunks of :data:`SWEEP_CHUNK`, so the threads meet once, in the middle). Memory: the
    cost and one int16 volume whatever the size; one thread runs the sweeps one after the other."""
    P1s = np.int16(round(float(P1) * s))
    p2s = p2 if p2.dtype == np.int16 else np.round(p2.astype(np.float64) * s).astype(np.int16)
    H, W, D = cost_hwd.shape
    down, up = sweep_groups(dirs)
    groups = [(np.ascontiguousarray(p2s[g]), np.ascontiguousarray(dirs[g]), flag)
              for g, flag in ((down, True), (up, False)) if g.size]
    acc = np.empty(cost_hwd.shape, np.int16)
    if len(groups) == 1 or numba.get_num_threads() == 1 or H < 2:
        for i, (p2g, dg, flag) in enumerate(groups):
            L, M = sweep_state_i16(dg.shape[0], W, D)
            _sweep_i16(cost_hwd, acc, np.int16(s), P1s, p2g, dg, flag, i == 0, L, M, 0, H)
        return acc
    _shared_sweeps(cost_hwd, acc, np.int16(s), P1s, groups)
    return acc


SWEEP_CHUNK = 16  # rows per hand-over between the two concurrent sweeps


def _shared_sweeps(C: np.ndarray, acc: np.ndarray, s: np.int16, P1s: np.int16, groups: list) -> None:
    """Run the top-down and bottom-up sweep concurrently into one buffer (see :func:`sgm_fixed_hwd`).

    Rows ``y < half`` (``half = (H + 1) // 2``) belong to the top-down sweep first, the others to the
    bottom-up one: a sweep assigns the rows it owns and, before adding to a row it does not own, waits until
    the owner has finished it. Each owner reaches its last owned row before it needs a row of the other half,
    so neither waits for long and there is no deadlock."""
    import threading

    H, W, D = C.shape
    half = (H + 1) // 2
    done = [0, 0]  # rows finished: top-down from row 0, bottom-up from row H - 1
    cond = threading.Condition()
    errors: list[BaseException] = []

    def run(k: int) -> None:
        p2g, dg, downward = groups[k]
        L, M = sweep_state_i16(dg.shape[0], W, D)
        owned = half if downward else H - half  # steps 0 .. owned - 1 are this sweep's own rows
        other = 1 - k
        try:
            step = 0
            while step < H:
                end = min(step + SWEEP_CHUNK, owned if step < owned else H)
                if step >= owned:  # the other sweep's rows: wait until it has finished them
                    need = H - step  # rows [step, end) of this sweep are the other's steps < H - step
                    with cond:
                        cond.wait_for(lambda need=need: done[other] >= need or bool(errors))
                    if errors:
                        return
                _sweep_i16(C, acc, s, P1s, p2g, dg, downward, step < owned, L, M, step, end)
                with cond:
                    done[k] = end
                    cond.notify_all()
                step = end
        except BaseException as e:  # noqa: BLE001 - re-raised in the caller's thread
            with cond:
                errors.append(e)
                cond.notify_all()

    threads = [threading.Thread(target=run, args=(k,)) for k in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    if errors:
        raise errors[0]


def fixed_to_float(acc: np.ndarray, s: int) -> np.ndarray:
    """float32 ``acc / s`` (exact) of an :func:`sgm_fixed_hwd` result."""
    return np.multiply(acc, np.float32(1.0 / s), dtype=np.float32)


CONCURRENT_MAX_BYTES = 256 * 2**20  # above this float32 volume size the two sweeps share one buffer (sequential)


def sgm_numba_hwd(cost_hwd: np.ndarray, P1: np.float32, p2: np.ndarray, dirs: np.ndarray,
                  penalty_step: float | None = None) -> np.ndarray:
    """Aggregated cost ``S`` (H, W, D) float32 of a cost ``(H, W, D)`` float32 or uint8 (integer costs such
    as census Hamming distances: a quarter of the memory traffic, the same float32 path costs; with
    ``penalty_step`` = 1 / 2^k and penalties on that grid, the 16-bit kernel when it is exact:
    :func:`fixed_point_scale`).

    The directions split into a top-down and a bottom-up sweep that run concurrently on two threads
    (numba releases the GIL), each into its own buffer, added at the end; for volumes above
    :data:`CONCURRENT_MAX_BYTES` (e.g. KITTI at 192 disparities) they run one after the other into a single
    buffer, so the peak memory stays at two volumes (cost + aggregate).

    Args:
        cost_hwd: C-contiguous float32 or uint8 (H, W, D).
        P1: float32 scalar.
        p2: float32 (R, H, W) per-direction P2 maps.
        dirs: int64 (R, 2) ``(dx, dy)`` directions.
    """
    P1 = np.float32(P1)
    p2 = np.ascontiguousarray(p2, dtype=np.float32)
    s = fixed_point_scale(cost_hwd, P1, p2, dirs.shape[0], penalty_step)
    if s is not None:
        return fixed_to_float(sgm_fixed_hwd(cost_hwd, P1, p2, dirs, s), s)
    down, up = sweep_groups(dirs)
    groups = [(np.ascontiguousarray(p2[g]), np.ascontiguousarray(dirs[g]), flag)
              for g, flag in ((down, True), (up, False)) if g.size]
    if len(groups) == 1 or numba.get_num_threads() == 1 or 4 * cost_hwd.size > CONCURRENT_MAX_BYTES:
        total = np.empty(cost_hwd.shape, np.float32)  # one buffer, the sweeps one after the other
        for i, (p2g, dg, flag) in enumerate(groups):
            _sweep(cost_hwd, total, P1, p2g, dg, flag, i == 0)
        return total
    buffers = [np.empty(cost_hwd.shape, np.float32) for _ in groups]  # each written first by its sweep
    with ThreadPoolExecutor(max_workers=len(groups)) as pool:
        list(pool.map(lambda job: _sweep(cost_hwd, job[0], P1, *job[1], True), zip(buffers, groups)))
    total = buffers[0]
    for other in buffers[1:]:
        _add_into(total, other)
    return total
