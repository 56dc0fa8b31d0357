"""Compiled CPU kernel (numba) of the graph of one α-expansion move of :mod:`stereonet.aggregate.graphcut`.

One pass over the pixels computes what the move's graph needs: the capacity of each edge to the right and down
neighbour and the two terminal capacities of each node (Kolmogorov & Zabih's construction, see the module doc of
:mod:`stereonet.aggregate.graphcut`). The float64 operations are the ones the vectorised numpy construction did,
in the same order for every pixel (its ``alpha_cost`` gets ``+ (C - A)`` as the left end of its right edge, ``- C``
as the right end of its left edge, then the same for its down and up edges), so the graph is the same to the bit
(tested); it replaces a dozen full-size numpy temporaries per move.
"""

from __future__ import annotations

from numba import njit


@njit(cache=True, fastmath=False, inline="always")
def _edge(s, lp, lq, alpha, T, to_p):  # pragma: no cover - compiled
    """One edge p -> q of slope ``s``: (``C - A``, the edge capacity ``max(B + C - A, 0)``) with ``A = V(f_p, f_q)``,
    ``B = V(f_p, α)`` (``s * to_p``), ``C = V(α, f_q)``."""
    e00 = s * min(float(abs(lp - lq)), T)
    e01 = s * to_p
    e10 = s * min(float(abs(lq - alpha)), T)
    return e10 - e00, max(e01 + e10 - e00, 0.0)


@njit(cache=True, fastmath=False)
def expansion_terms(cost, labels, alpha, s_right, s_down, truncation, cap_right, cap_down, source, sink):  # pragma: no cover
    """The α-expansion graph of ``labels`` (H, W) int64 on ``cost`` (D, H, W) float64 with slopes λ·w
    ``s_right``/``s_down`` (H, W) float64, written into the (H, W) float64 outputs: ``cap_right[y, x]`` the capacity
    of the edge (y, x) -> (y, x + 1) (0 in the last column), ``cap_down`` the same downwards, ``source`` and ``sink``
    the terminal capacities (a node in the source set, x = 0, keeps its label and pays its sink capacity).
    """
    H, W = labels.shape
    T = truncation
    for y in range(H):
        for x in range(W):
            lp = labels[y, x]
            a = cost[alpha, y, x]
            to_p = min(float(abs(lp - alpha)), T)
            if x + 1 < W:
                delta, cap_right[y, x] = _edge(s_right[y, x], lp, labels[y, x + 1], alpha, T, to_p)
                a += delta
            else:
                cap_right[y, x] = 0.0
            if x > 0:
                s = s_right[y, x - 1]
                a -= s * to_p
            if y + 1 < H:
                delta, cap_down[y, x] = _edge(s_down[y, x], lp, labels[y + 1, x], alpha, T, to_p)
                a += delta
            else:
                cap_down[y, x] = 0.0
            if y > 0:
                s = s_down[y - 1, x]
                a -= s * to_p
            keep = cost[lp, y, x]
            low = keep if keep < a else a
            source[y, x] = a - low
            sink[y, x] = keep - low


@njit(cache=True, fastmath=False)
def restricted_expansion_graph(cost, labels, alpha, s_right, s_down, truncation, seeds, radius, stamp, move,
                               index, nodes, source, sink, edge_i, edge_j, edge_cap):  # pragma: no cover
    """The graph of one α-expansion move restricted to the pixels within ``radius`` (Chebyshev) of a seed pixel;
    every other pixel keeps its label (a fixed ``x = 0``). Returns ``(n, m)``: the free pixels' node count and the
    edge count.

    ``seeds`` (S,) flat pixel indices whose candidate labels include ``alpha``; ``stamp`` (H, W) int64 marks the free
    pixels of this move with ``move`` (a number no earlier call used, so the array is never cleared); ``index``
    (H, W) int64 gets each free pixel's node number. Written: ``nodes[:n]`` the free pixels' flat indices,
    ``source[:n]``/``sink[:n]`` their terminal capacities, ``edge_i/edge_j/edge_cap[:m]`` the edges ``i -> j`` with
    positive capacity (outputs sized ``H*W``, and ``2*H*W`` for the edges). Pixels already labelled ``alpha``
    stay fixed (either side of the cut gives them the same label).

    The terms are :func:`expansion_terms`' (the same float64 operations in the same order for a free pixel), with
    the edges to fixed neighbours folded in: an edge ``p -> q`` costs its capacity when ``x_p = 0`` and
    ``x_q = 1``, so a free ``q`` behind a fixed ``p`` adds it to its source capacity, and a free ``p`` before a
    fixed ``q`` pays nothing for it; the linear parts of the fixed ends are constants of the move.
    """
    H, W = labels.shape
    T = truncation
    n = 0
    for k in range(seeds.shape[0]):
        sy, sx = seeds[k] // W, seeds[k] % W
        for y in range(max(sy - radius, 0), min(sy + radius + 1, H)):
            for x in range(max(sx - radius, 0), min(sx + radius + 1, W)):
                if stamp[y, x] != move and labels[y, x] != alpha:
                    stamp[y, x] = move
                    index[y, x] = n
                    nodes[n] = y * W + x
                    n += 1
    m = 0
    for i in range(n):
        y, x = nodes[i] // W, nodes[i] % W
        lp = labels[y, x]
        a = cost[alpha, y, x]
        to_p = min(float(abs(lp - alpha)), T)
        extra = 0.0  # capacities of edges from fixed neighbours into this pixel
        if x + 1 < W:
            delta, cap = _edge(s_right[y, x], lp, labels[y, x + 1], alpha, T, to_p)
            a += delta
            if cap > 0.0 and stamp[y, x + 1] == move:
                edge_i[m], edge_j[m], edge_cap[m] = i, index[y, x + 1], cap
                m += 1
        if x > 0:
            s = s_right[y, x - 1]
            a -= s * to_p
            if stamp[y, x - 1] != move:
                extra += _edge(s, labels[y, x - 1], lp, alpha, T, min(float(abs(labels[y, x - 1] - alpha)), T))[1]
        if y + 1 < H:
            delta, cap = _edge(s_down[y, x], lp, labels[y + 1, x], alpha, T, to_p)
            a += delta
            if cap > 0.0 and stamp[y + 1, x] == move:
                edge_i[m], edge_j[m], edge_cap[m] = i, index[y + 1, x], cap
                m += 1
        if y > 0:
            s = s_down[y - 1, x]
            a -= s * to_p
            if stamp[y - 1, x] != move:
                extra += _edge(s, labels[y - 1, x], lp, alpha, T, min(float(abs(labels[y - 1, x] - alpha)), T))[1]
        a += extra
        keep = cost[lp, y, x]
        low = keep if keep < a else a
        source[i] = a - low
        sink[i] = keep - low
    return n, m
