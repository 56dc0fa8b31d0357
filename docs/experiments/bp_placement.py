"""Do bp's two speeds on this VM depend on where its buffers land? (twenty-first session probe; answer in the .txt: no)

In one process, Cones, 2 threads (as make bench): time bp three times, then keep a small array alive so that the
next calls' buffers land elsewhere in the heap (``reuse_freed_memory`` makes glibc hand the same addresses back call
after call, so a process otherwise stays in one mode), and repeat. Eight placements per process.
    python docs/experiments/bp_placement.py
"""
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))
from bench_classical import load_cones  # noqa: E402

from stereonet import matchers  # noqa: E402
from stereonet.measure import reuse_freed_memory  # noqa: E402

reuse_freed_memory()
torch.set_num_threads(2)
left, right = load_cones()
matchers.match("bp", left, right, 63)
keep, medians = [], []
for shift in range(8):
    times = []
    for _ in range(3):
        t = time.perf_counter()
        matchers.match("bp", left, right, 63)
        times.append(time.perf_counter() - t)
    medians.append(round(statistics.median(times), 3))
    keep.append(np.ones(1000 + 4096 * shift + 64 * shift, np.uint8))  # moves the later allocations
print("bp seconds per placement:", medians)
