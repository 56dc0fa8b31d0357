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


def alpha_expansion(cost: torch.Tensor, smoothness: float, truncation: float = 2.0, cycles: int = 2,
                    init: torch.Tensor | None = None, weights_right: torch.Tensor | None = None,
                    weights_down: torch.Tensor | None = None) -> GraphCutResult:
    """α-expansion over all labels ``0..D-1``, ``cycles`` times (stops early when a cycle changes nothing).

    Args:
        cost: :math:`(B, D, H, W)` finite data costs, lower = better.
        smoothness: ``λ >= 0``.
        truncation: ``T > 0`` of ``min(|d - d'|, T)`` (``1`` = Potts).
        cycles: passes over all labels (>= 1).
        init: optional :math:`(B, 1, H, W)` integer-valued start labels (default: winner-takes-all).
        weights_right, weights_down: optional :math:`(B, 1, H, W)` edge weights (see ``_global_mrf``).
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
    truncation_eff = min(truncation, float(n))
    cost_np = cost.detach().double().cpu().numpy()
    ones = np.ones((b, h, w))
    s_right = smoothness * (ones if weights_right is None else weights_right.detach().double().cpu().numpy()[:, 0])
    s_down = smoothness * (ones if weights_down is None else weights_down.detach().double().cpu().numpy()[:, 0])
    out, history = [], []
    for i in range(b):
        labels = init[i, 0].detach().round().long().cpu().numpy()
        energy = _energy(cost_np[i], labels, s_right[i], s_down[i], truncation_eff)
        trace = [energy]
        for _ in range(cycles):
            changed = False
            for alpha in range(n):
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
