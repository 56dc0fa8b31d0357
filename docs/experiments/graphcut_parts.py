"""Issue 15 item 3, twenty-sixth session: where graphcut's time goes on Cones (alpha-expansion from WTA, one cycle over
the 65 labels), and whether an exact persistency pre-pass shrinks the max-flow work.

Part 1 splits each move into the capacities (the numba kernel), building PyMaxflow's grid graph, its max-flow and
reading the segments (measured: 0.27 / 0.65 / 2.65 / 0.04 s). Part 2 fixes, before each max-flow, every node whose
unary gap exceeds the capacities of its edges (in either direction: it keeps its side in some optimal cut), folds the
fixed ends of edges into the free nodes' terminal capacities and cuts only the free nodes (measured: 0.8 % of the nodes
fixed, the max-flow as slow, the same labels). Not kept in the library.

    python docs/experiments/graphcut_parts.py
"""
import time

import maxflow
import numpy as np
import torch

from stereonet.aggregate import graphcut as G
from stereonet.data import load_dataset
from stereonet.evaluation import expand_data_specs
from stereonet.kernels.graphcut import expansion_terms
from stereonet.matchers.energy import _mrf_problem


def grid_cut(cap_right, cap_down, source, sink):
    """PyMaxflow on the full grid, as stereonet.aggregate.graphcut does; returns (take_alpha, flow seconds, timings)."""
    t0 = time.perf_counter()
    h, w = source.shape
    graph = maxflow.GraphFloat(h * w, 2 * h * w)
    nodes = graph.add_grid_nodes((h, w))
    graph.add_grid_edges(nodes, weights=cap_right, structure=G._RIGHT, symmetric=False)
    graph.add_grid_edges(nodes, weights=cap_down, structure=G._DOWN, symmetric=False)
    graph.add_grid_tedges(nodes, source, sink)
    t1 = time.perf_counter()
    graph.maxflow()
    t2 = time.perf_counter()
    take = graph.get_grid_segments(nodes)
    return take, t2 - t1, (t1 - t0, time.perf_counter() - t2)


def reduced_cut(cap_right, cap_down, source, sink):
    """The same cut after fixing the dominated nodes; returns (take_alpha, flow seconds, fraction of free nodes)."""
    h, w = source.shape
    out_cap = cap_right + cap_down
    in_cap = np.zeros((h, w))
    in_cap[:, 1:] += cap_right[:, :-1]
    in_cap[1:, :] += cap_down[:-1, :]
    keep = source - sink >= out_cap  # x = 0 is at least as good whatever the neighbours do
    alpha = sink - source >= in_cap
    free = ~(keep | alpha)
    index = -np.ones((h, w), np.int64)
    n = int(free.sum())
    index[free] = np.arange(n)
    src, snk = source.copy(), sink.copy()
    edges = ((cap_right, (slice(0, h), slice(0, w - 1)), (slice(0, h), slice(1, w))),
             (cap_down, (slice(0, h - 1), slice(0, w)), (slice(1, h), slice(0, w))))
    for cap, p, q in edges:  # an edge p -> q costs cap when x_p = 0 and x_q = 1
        c = cap[p]
        snk[p] += np.where(free[p] & alpha[q], c, 0.0)  # q fixed to alpha: p pays when it keeps
        src[q] += np.where(keep[p] & free[q], c, 0.0)  # p fixed to keep: q pays when it takes alpha
    graph = maxflow.GraphFloat(n, 2 * n)
    graph.add_nodes(n)
    for cap, p, q in edges:
        m = free[p] & free[q] & (cap[p] > 0)
        graph.add_edges(index[p][m], index[q][m], cap[p][m], np.zeros(int(m.sum())))
    graph.add_grid_tedges(np.arange(n), src[free], snk[free])
    t0 = time.perf_counter()
    graph.maxflow()
    flow = time.perf_counter() - t0
    take = alpha.copy()
    take[free] = graph.get_grid_segments(np.arange(n))
    return take, flow, n / (h * w)


def main() -> None:
    torch.set_num_threads(2)
    cones = next(s for s in expand_data_specs("real") if s.startswith("middlebury2003:"))
    item = load_dataset(cones)[0]
    left, right, max_disp = item["left"][None].float(), item["right"][None].float(), int(item["max_disp"])
    volume, wr, wd = _mrf_problem(left, right, max_disp, "census_ad", 3, None, 0.03, 3.0)
    cost = volume.double().numpy()[0]
    s_right, s_down = 0.3 * wr.double().numpy()[0, 0], 0.3 * wd.double().numpy()[0, 0]
    for reduced in (False, True):
        labels = cost.argmin(0)
        h, w = labels.shape
        totals = {"capacities": 0.0, "build": 0.0, "flow": 0.0, "segments": 0.0}
        free = []
        for a in range(max_disp + 1):
            t0 = time.perf_counter()
            caps = [np.empty((h, w)) for _ in range(4)]
            expansion_terms(cost, labels, a, s_right, s_down, 2.0, *caps)
            totals["capacities"] += time.perf_counter() - t0
            if reduced:
                take, flow, frac = reduced_cut(*caps)
                free.append(frac)
            else:
                take, flow, (build, seg) = grid_cut(*caps)
                totals["build"] += build
                totals["segments"] += seg
            totals["flow"] += flow
            labels = np.where(take, a, labels)
        extra = f", free nodes {100 * np.mean(free):.1f} %" if reduced else ""
        print("reduced" if reduced else "full   ", {k: round(v, 3) for k, v in totals.items()}, extra,
              "labels checksum", int(labels.sum()))


if __name__ == "__main__":
    main()
