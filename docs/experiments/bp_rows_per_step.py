"""bp's wavefront block size (``stereonet.kernels.bp.ROWS_PER_STEP``, any value gives the same bits): wall time of
``bp`` against ``opencv-sgbm`` the way ``make bench`` measures it (eval's PeakMemory + Stopwatch, 2 threads, the
methods interleaved pair by pair with ``sgm``), on Cones and KITTI 2015, and one-thread CPU seconds on Cones.
    python docs/experiments/bp_rows_per_step.py [K,K,...] [rounds]
Rule (written before the idle run, in bp_rows_per_step.txt): the default becomes the K with the lowest median
bp/opencv-sgbm wall ratio over both pairs and all rounds; a K within 5 % of the best loses to a smaller K (more of
the wavefront stays in cache when the machine is quiet).
"""
import statistics
import sys
import time

import numba
import torch

from stereonet import matchers
from stereonet.data import load_dataset
from stereonet.evaluation import expand_data_specs
from stereonet.kernels import bp as kernels
from stereonet.measure import PeakMemory, reuse_freed_memory

reuse_freed_memory()
blocks = [int(k) for k in (sys.argv[1] if len(sys.argv) > 1 else "1,2,4,8").split(",")]
rounds = int(sys.argv[2]) if len(sys.argv) > 2 else 5
pairs = []
for key, name in (("middlebury2003", "cones"), ("kitti2015", "000000_10")):
    ds = load_dataset(next(s for s in expand_data_specs("real") if key in s))
    item = next(ds[i] for i in range(len(ds)) if name in str(ds[i]["name"]))
    pairs.append((f"{key}/{name}", item["left"][None], item["right"][None], int(item["max_disp"])))


def timed(method, left, right, md):
    with torch.no_grad(), PeakMemory():
        t = time.perf_counter()
        matchers.match(method, left, right, md)
        return time.perf_counter() - t


for _, left, right, md in pairs:  # compile and warm every method once
    for m in ("opencv-sgbm", "bp", "sgm"):
        timed(m, left, right, md)
ratios = {k: [] for k in blocks}
for r in range(rounds):
    for k in blocks:
        kernels.ROWS_PER_STEP = k
        for label, left, right, md in pairs:
            ref = timed("opencv-sgbm", left, right, md)
            t = timed("bp", left, right, md)
            timed("sgm", left, right, md)
            ratios[k].append(t / ref)
            print(f"round {r} K={k} {label}: bp {t:.3f} s, opencv-sgbm {ref:.4f} s, ratio {t / ref:.1f}", flush=True)
print("\nmedian bp / opencv-sgbm wall ratio (2 threads, both pairs, all rounds):")
for k in blocks:
    print(f"K={k}: {statistics.median(ratios[k]):.2f}")
numba.set_num_threads(1)
torch.set_num_threads(1)
_, left, right, md = pairs[0]
print("\none thread, CPU seconds on Cones (median of 5):")
for k in blocks:
    kernels.ROWS_PER_STEP = k
    ts = []
    for _ in range(5):
        t = time.process_time()
        matchers.match("bp", left, right, md)
        ts.append(time.process_time() - t)
    print(f"K={k}: {statistics.median(ts):.3f}")
