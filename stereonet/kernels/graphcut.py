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
