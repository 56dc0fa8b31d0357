"""bp's wavefront kernels on one or two numba threads, timed the way ``make bench`` times them (wall clock, torch on 2
threads, each call beside an opencv-sgbm call on the same pair in the same process, rounds interleaved), on Cones,
KITTI 2012 and KITTI 2015; CPU seconds of the process beside. Same bits either way (the wavefront is exact for any
schedule). Twenty-first session; question: does the two-thread wavefront (a barrier per block of rows) pay for itself
on a 2-core VM?
    python docs/experiments/bp_threads.py [rounds]
"""
import statistics
import sys
import time

import numba
import torch

from stereonet import matchers
from stereonet.data import load_dataset
from stereonet.measure import reuse_freed_memory

reuse_freed_memory()
torch.set_num_threads(2)
rounds = int(sys.argv[1]) if len(sys.argv) > 1 else 5
ds = load_dataset("real")
items = [ds[i] for i in range(len(ds)) if any(k in str(ds[i]["name"]) for k in ("cones", "kitti"))]
threads = (2, 1)


def timed(name, item):
    left, right = item["left"][None], item["right"][None]
    t, c = time.perf_counter(), time.process_time()
    out = matchers.match(name, left, right, int(item["max_disp"]))
    return time.perf_counter() - t, time.process_time() - c, out


for item in items:  # compile and warm every path first
    for n in threads:
        numba.set_num_threads(n)
        timed("bp", item)
walls = {}
for _ in range(rounds):
    for item in items:
        for n in threads:
            numba.set_num_threads(2)
            ref, _, _ = timed("opencv-sgbm", item)
            numba.set_num_threads(n)
            wall, cpu, out = timed("bp", item)
            walls.setdefault((item["name"], n), []).append((wall, cpu, wall / ref))
numba.set_num_threads(2)
print(f"{rounds} rounds; bp with numba on n threads (torch 2 threads); medians")
print("| pair | numba threads | bp wall s | bp CPU s | wall / opencv-sgbm wall |")
print("|---|---|---|---|---|")
for (name, n), rows in walls.items():
    print(f"| {name} | {n} | {statistics.median(r[0] for r in rows):.3f} | {statistics.median(r[1] for r in rows):.3f} | "
          f"{statistics.median(r[2] for r in rows):.2f} |")
