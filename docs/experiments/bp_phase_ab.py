"""bp vs opencv-sgbm on KITTI 2015 in one process, calls alternating with and without the malloc_trim that the bench's
PeakMemory does before each call; 10 rounds, medians (see bp_phases.txt).

    [THP_MEM_ALLOC_ENABLE=1] python docs/experiments/bp_phase_ab.py
"""
import os
import time

import numpy as np
import torch

from stereonet.data import load_dataset
from stereonet.evaluation import expand_data_specs
from stereonet.matchers import get_matcher
from stereonet.measure import release_free_memory, reuse_freed_memory


def main():
    torch.set_num_threads(2)
    reuse_freed_memory()  # as the bench
    bp, sgbm = get_matcher("bp"), get_matcher("opencv-sgbm")
    spec = [s for s in expand_data_specs("real") if s.startswith("kitti2015")][0]
    item = load_dataset(spec)[0]
    left, right, max_disp = item["left"][None], item["right"][None], item["max_disp"]
    bp(left, right, max_disp)
    times: dict[str, list[float]] = {}
    for _ in range(10):
        for mode in ("warm", "trim"):
            for name, fn in (("bp", bp), ("sgbm", sgbm)):
                if mode == "trim":
                    release_free_memory()
                t = time.perf_counter()
                fn(left, right, max_disp)
                times.setdefault(f"{name}-{mode}", []).append(time.perf_counter() - t)
    med = {k: float(np.median(v)) for k, v in times.items()}
    print(f"THP_MEM_ALLOC_ENABLE={os.environ.get('THP_MEM_ALLOC_ENABLE')} "
          + " ".join(f"{k} {v:.3f}" for k, v in med.items())
          + f"  ratio warm {med['bp-warm'] / med['sgbm-warm']:.2f} trim {med['bp-trim'] / med['sgbm-trim']:.2f}")


if __name__ == "__main__":
    main()
