"""Graph cuts: α-expansion (Boykov, Veksler & Zabih, PAMI 2001) with PyMaxflow's Boykov–Kolmogorov max-flow.

Minimises the 4-connected MRF energy of :mod:`stereonet.aggregate.mrf`
(data cost + ``λ·w_pq·min(|f_p - f_q|, T)``; ``T = 1`` is Potts). Truncated linear is a metric, so every
expansion move is an exactly solvable binary problem: each pixel either keeps its label (``x = 0``) or
switches to ``α`` (``x = 1``). A pairwise term ``E(x_p, x_q)`` with values ``A, B, C, D`` at
``00, 01, 10, 11`` is written (Kolmogorov & Zabih, PAMI 2004) as
``A + (C - A)·x_p + (D - C)·x_q + (B + C - A - D)·(1 - x_p)·x_q``; the last coefficient is >= 0 by the
triangle inequality and becomes the capacity of the edge ``p -> q``, the linear parts go to the terminal
edges. The minimum cut is the optimal move; a move is kept only when it lowers the energy, so the energy
never increases (a guard against float rounding; in exact arithmetic it cannot increase anyway).

Complexity: ``cycles · D`` max-flow problems on a grid graph of ``H·W`` nodes and ``2·H·W`` edges, each
near-linear in practice for BK's algorithm on such grids (worst case O(E·V²·|C|)); each move's capacities come
from one compiled pass (:func:`stereonet.kernels.graphcut.expansion_terms`). Pass ``init`` (e.g. the WTA
disparity) to start close to the optimum.
"""

from __future__ import annotations

from typing import NamedTuple

import maxflow
import numpy as np
import torch

from stereonet.aggregate.mrf import check_edge_weights, check_smoothness, grid_energy
from stereonet.checks import StereoInputError, check_cost_volume, check_finite, check_shape

_RIGHT = np.array([[0, 0, 0], [0, 0, 1], [0, 0, 0]])
_DOWN = np.array([[0, 0, 0], [0, 0, 0], [0, 1, 0]])


class GraphCutResult(NamedTuple):
    """Output of :func:`alpha_expansion`.

    disparity: :math:`(B, 1, H, W)` float, integer-valued labels.
    energy: :math:`(B,)` float64 final energy.
    history: per batch item, the energy before the first move and after every expansion move (non-increasing).
    """

    disparity: torch.Tensor
    energy: torch.Tensor
    history: list[list[float]]


def _energy(cost: np.ndarray, labels: np.ndarray, s_right: np.ndarray, s_down: np.ndarray,
            truncation: float) -> float:
    """Energy of one item: ``cost`` (D, H, W), ``labels`` (H, W), slopes λ·w (H, W)."""
    data = np.take_along_axis(cost, labels[None], axis=0).sum()
    horiz = np.minimum(np.abs(labels[:, 1:] - labels[:, :-1]), truncation) * s_right[:, :-1]
    vert = np.minimum(np.abs(labels[1:, :] - labels[:-1, :]), truncation) * s_down[:-1, :]
    return float(data + horiz.sum() + vert.sum())


def _expansion_move(cost: np.ndarray, labels: np.ndarray, alpha: int, s_right: np.ndarray,
                    s_down: np.ndarray, truncation: float) -> np.ndarray:
    """Optimal α-expansion of ``labels`` (H, W) by one min cut; returns the new labels."""
    from stereonet.kernels.graphcut import expansion_terms

    h, w = labels.shape
    cap_right, cap_down, source, sink = (np.empty((h, w)) for _ in range(4))
    expansion_terms(cost, labels, int(alpha), s_right, s_down, float(truncation), cap_right, cap_down, source, sink)
    graph = maxflow.GraphFloat(h * w, 2 * h * w)
    nodes = graph.add_grid_nodes((h, w))
    graph.add_grid_edges(nodes, weights=cap_right, structure=_RIGHT, symmetric=False)
    graph.add_grid_edges(nodes, weights=cap_down, structure=_DOWN, symmetric=False)
    # a node in the source set (x = 0) pays its sink capacity, in the sink set (x = 1) its source capacity
    graph.add_grid_tedges(nodes, source, sink)
    graph.maxflow()
    take_alpha = graph.get_grid_segments(nodes)
    return np.where(take_alpha, alpha, labels)


class _RestrictedMoves:
    """The α-expansion moves of one item restricted to candidate pixels (see :func:`alpha_expansion`'s
    ``candidates``): per label, the pixels that list it (a bucket sort of the candidates, once); per move, the
    graph of the pixels within ``radius`` of them (:func:`stereonet.kernels.graphcut.restricted_expansion_graph`)."""

    def __init__(self, candidates: np.ndarray, n_labels: int, radius: int):
        k, h, w = candidates.shape
        flat = candidates.reshape(k, h * w)
        pixel = np.broadcast_to(np.arange(h * w), (k, h * w))
        order = np.argsort(flat, axis=None, kind="stable")
        self.pixels = pixel.reshape(-1)[order]
        self.starts = np.searchsorted(flat.reshape(-1)[order], np.arange(n_labels + 1))
        self.radius = radius
        self.stamp = np.zeros((h, w), np.int64)
        self.index = np.empty((h, w), np.int64)
        self.nodes = np.empty(h * w, np.int64)
        self.source, self.sink = np.empty(h * w), np.empty(h * w)
        self.edge_i, self.edge_j = np.empty(2 * h * w, np.int64), np.empty(2 * h * w, np.int64)
        self.edge_cap = np.empty(2 * h * w)
        self.moves = 0

    def move(self, cost: np.ndarray, labels: np.ndarray, alpha: int, s_right: np.ndarray, s_down: np.ndarray,
             truncation: float, tolerance: float) -> float:
        """Apply the optimal restricted move to ``labels`` in place; returns its energy change (<= 0: keeping
        every label is one of the cuts). A move that does not lower the energy by more than ``tolerance`` (float
        rounding) is not applied and returns 0."""
        from stereonet.kernels.graphcut import restricted_expansion_graph

        seeds = self.pixels[self.starts[alpha]:self.starts[alpha + 1]]
        if seeds.size == 0:
            return 0.0
        self.moves += 1
        n, m = restricted_expansion_graph(cost, labels, int(alpha), s_right, s_down, float(truncation), seeds,
                                          self.radius, self.stamp, self.moves, self.index, self.nodes, self.source,
                                          self.sink, self.edge_i, self.edge_j, self.edge_cap)
        if n == 0:
            return 0.0
        graph = maxflow.GraphFloat(n, m)
        ids = graph.add_nodes(n)  # 0..n-1
        graph.add_edges(self.edge_i[:m], self.edge_j[:m], self.edge_cap[:m], np.zeros(m))
        graph.add_grid_tedges(ids, self.source[:n], self.sink[:n])
        # the cut where every free pixel keeps its label pays the sum of their sink capacities
        change = graph.maxflow() - float(self.sink[:n].sum())
        if change >= -tolerance:
            return 0.0
        take = graph.get_grid_segments(ids)
        labels.reshape(-1)[self.nodes[:n][take]] = alpha
        return change


def alpha_expansion(cost: torch.Tensor, smoothness: float, truncation: float = 2.0, cycles: int = 2,
                    init: torch.Tensor | None = None, weights_right: torch.Tensor | None = None,
                    weights_down: torch.Tensor | None = None, candidates: torch.Tensor | None = None,
                    candidate_radius: int = 2) -> GraphCutResult:
    """α-expansion over all labels ``0..D-1``, ``cycles`` times (stops early when a cycle changes nothing).

    With ``candidates`` (label pruning) the move for ``α`` frees only the pixels within ``candidate_radius``
    (Chebyshev distance) of a pixel that lists ``α`` among its candidate labels; every other pixel keeps its
    label, and a label no pixel lists is not expanded. Each such move is still the optimal one over the pixels it
    frees (a min cut on their graph, the edges to fixed pixels folded into the terminals), so the energy still
    never increases; it is no longer the optimal expansion move over the whole image, so the result can differ
    from the unrestricted one (either way: the moves see a different sequence of labellings). The graphs shrink
    from ``H·W`` nodes to about ``K·(2r + 1)²/D`` of that, which is what makes the method usable on large pairs and
    ranges. Which candidates matters (``docs/experiments/graphcut_pruning.txt``): the top labels of an SGM
    aggregation of the same energy alone lose 2-3 points of bad-2 on data_gen's low-texture renders, where the
    unpruned moves flip whole regions to a label none of their pixels ranks high; adding ``sgm``'s census proposals
    (``graphcut``'s default) makes the pruned result better than the unpruned one there.

    Args:
        cost: :math:`(B, D, H, W)` finite data costs, lower = better.
        smoothness: ``λ >= 0``.
        truncation: ``T > 0`` of ``min(|d - d'|, T)`` (``1`` = Potts).
        cycles: passes over all labels (>= 1).
        init: optional :math:`(B, 1, H, W)` integer-valued start labels (default: winner-takes-all).
        weights_right, weights_down: optional :math:`(B, 1, H, W)` edge weights (see ``_global_mrf``).
        candidates: optional :math:`(B, K, H, W)` integer candidate labels in ``[0, D-1]`` per pixel (see above);
            None = every move over the whole image (exact expansion moves).
        candidate_radius: ``r >= 0``, the spatial reach of a candidate.
    Returns:
        :class:`GraphCutResult`. Not differentiable; inputs are detached.
    """
    cost = check_cost_volume(cost, "cost")
    check_finite(cost, "cost")  # (skipped for a volume the caller built from checked images: inputs_checked)
    smoothness, truncation = check_smoothness(smoothness, truncation)
    if isinstance(cycles, bool) or not isinstance(cycles, int) or cycles < 1:
        raise StereoInputError(f"cycles: expected an integer >= 1, got {cycles!r}")
    b, n, h, w = cost.shape
    weights_right = check_edge_weights(weights_right, cost, "weights_right")
    weights_down = check_edge_weights(weights_down, cost, "weights_down")
    if init is None:
        init = cost.argmin(dim=1, keepdim=True)
    else:
        check_shape(init, [str(b), "1", str(h), str(w)], "init")
        if bool((init < 0).any()) or bool((init > n - 1).any()) or bool((init != init.round()).any()):
            raise StereoInputError(f"init: expected integer labels in [0, {n - 1}]")
    if candidates is not None:
        if not isinstance(candidates, torch.Tensor) or candidates.dim() != 4 or candidates.shape[0] != b \
                or tuple(candidates.shape[2:]) != (h, w) or candidates.shape[1] < 1:
            raise StereoInputError(f"candidates: expected a ({b}, K, {h}, {w}) tensor of labels, K >= 1, got "
                                   f"{tuple(candidates.shape) if isinstance(candidates, torch.Tensor) else candidates!r}")
        if candidates.is_floating_point() or bool((candidates < 0).any()) or bool((candidates > n - 1).any()):
            raise StereoInputError(f"candidates: expected integer labels in [0, {n - 1}]")
    if isinstance(candidate_radius, bool) or not isinstance(candidate_radius, int) or candidate_radius < 0:
        raise StereoInputError(f"candidate_radius: expected an integer >= 0, got {candidate_radius!r}")
    truncation_eff = min(truncation, float(n))
    cost_np = cost.detach().double().cpu().numpy()
    ones = np.ones((b, h, w))
    s_right = smoothness * (ones if weights_right is None else weights_right.detach().double().cpu().numpy()[:, 0])
    s_down = smoothness * (ones if weights_down is None else weights_down.detach().double().cpu().numpy()[:, 0])
    out, history = [], []
    for i in range(b):
        labels = init[i, 0].detach().round().long().cpu().numpy().copy()  # the pruned moves write into it
        energy = _energy(cost_np[i], labels, s_right[i], s_down[i], truncation_eff)
        trace = [energy]
        restricted = None if candidates is None else _RestrictedMoves(
            candidates[i].detach().long().cpu().numpy(), n, candidate_radius)
        for _ in range(cycles):
            changed = False
            for alpha in range(n):
                if restricted is not None:
                    change = restricted.move(cost_np[i], labels, alpha, s_right[i], s_down[i], truncation_eff,
                                             1e-9 * max(1.0, abs(energy)))
                    energy, changed = energy + change, changed or change < 0.0
                    trace.append(energy)
                    continue
                proposal = _expansion_move(cost_np[i], labels, alpha, s_right[i], s_down[i], truncation_eff)
                new_energy = _energy(cost_np[i], proposal, s_right[i], s_down[i], truncation_eff)
                if new_energy < energy - 1e-9 * max(1.0, abs(energy)):
                    labels, energy, changed = proposal, new_energy, True
                trace.append(energy)
            if not changed:
                break
        out.append(torch.from_numpy(labels))
        history.append(trace)
    labels_t = torch.stack(out)[:, None].to(cost.device)
    energy_t = grid_energy(cost.detach(), labels_t, smoothness, truncation, weights_right, weights_down)
    return GraphCutResult(labels_t.to(cost.dtype), energy_t, history)
