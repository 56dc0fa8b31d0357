"""Where bp's time goes on KITTI 2012 (2 threads, 7 calls, medians per part; see bp_phases.txt).

    python docs/experiments/bp_parts.py
"""
import time

import numpy as np
import torch

import stereonet.aggregate.bp as bp_module
import stereonet.kernels.bp as kernels
import stereonet.matchers.energy as energy
from stereonet.data import load_dataset
from stereonet.evaluation import expand_data_specs
from stereonet.matchers import get_matcher

spent: dict[str, float] = {}


def timed(module, name):
    """Replace ``module.name`` by a wrapper adding its wall time to ``spent[name]``."""
    fn = getattr(module, name)

    def wrapper(*args, **kwargs):
        t = time.perf_counter()
        out = fn(*args, **kwargs)
        spent[name] = spent.get(name, 0.0) + time.perf_counter() - t
        return out

    setattr(module, name, wrapper)


def main():
    torch.set_num_threads(2)
    for name in ("bp_finest", "bp_level", "pool_sum2", "round_rows", "upsample2"):
        timed(kernels, name)
    timed(bp_module, "grid_energy")
    for name in ("belief_propagation", "_mrf_problem", "_occlusion_filled"):
        timed(energy, name)
    bp = get_matcher("bp")
    spec = [s for s in expand_data_specs("real") if s.startswith("kitti2012")][0]
    item = load_dataset(spec)[0]
    left, right, max_disp = item["left"][None], item["right"][None], item["max_disp"]
    bp(left, right, max_disp)
    rows = []
    for _ in range(7):
        spent.clear()
        t = time.perf_counter()
        bp(left, right, max_disp)
        spent["total"] = time.perf_counter() - t
        rows.append(dict(spent))
    for name in rows[0]:
        print(f"{name:20s} {np.median([r[name] for r in rows]):.3f} s")


if __name__ == "__main__":
    main()
