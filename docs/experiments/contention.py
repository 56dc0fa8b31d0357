"""Matchers on KITTI 2012 (2 threads, medians of 3) -- run it once on an idle machine and once beside another
two-thread job (here: a training run) to see how each degrades when the cores are shared (see bp_phases.txt).

    python docs/experiments/contention.py
"""
import time

import numpy as np
import torch

from stereonet.data import load_dataset
from stereonet.evaluation import expand_data_specs
from stereonet.matchers import get_matcher


def main():
    torch.set_num_threads(2)
    spec = [s for s in expand_data_specs("real") if s.startswith("kitti2012")][0]
    item = load_dataset(spec)[0]
    left, right, max_disp = item["left"][None], item["right"][None], item["max_disp"]
    for name in ("opencv-sgbm", "sgm", "bp", "dp"):
        fn = get_matcher(name)
        fn(left, right, max_disp)
        times = []
        for _ in range(3):
            t = time.perf_counter()
            fn(left, right, max_disp)
            times.append(time.perf_counter() - t)
        print(f"{name:12s} {float(np.median(times)):.3f} s")


if __name__ == "__main__":
    main()
