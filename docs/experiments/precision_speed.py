"""CPU seconds of the Siamese matchers on Cones (450x375, 64 disparities), one thread, float32 against bfloat16
towers, with opencv-sgbm in the same process for the ratio (median of 7 interleaved runs, thread_time).

    python docs/experiments/precision_speed.py
"""
import statistics
import time
from pathlib import Path

import cv2
import numba
import torch

from stereonet import matchers
from stereonet.measure import reuse_freed_memory
from stereonet.models.siamese import native_bfloat16

reuse_freed_memory()  # as infer.py and eval.py
torch.set_num_threads(1)
numba.set_num_threads(1)
cv2.setNumThreads(1)
root = Path(__file__).resolve().parents[3] / "shared" / "data" / "middlebury2003" / "cones"
images = [cv2.imread(str(root / name)) for name in ("im2.png", "im6.png")]
left, right = (torch.from_numpy(im[..., ::-1].copy()).permute(2, 0, 1)[None].float() / 255 for im in images)
runs = {"opencv-sgbm": lambda: matchers.match("opencv-sgbm", left, right, 63)}
for method in ("siamese-census-sgm", "siamese-sgm"):
    for precision in ("float32", "bfloat16"):
        runs[f"{method} {precision}"] = (lambda m=method, p=precision: matchers.match(m, left, right, 63, precision=p))
times = {name: [] for name in runs}
for fn in runs.values():
    fn()  # warm-up (kernels, weights, the bfloat16 copy)
for _ in range(7):
    for name, fn in runs.items():
        t = time.thread_time()
        fn()
        times[name].append(time.thread_time() - t)
ref = statistics.median(times["opencv-sgbm"])
print(f"{'method':32s} {'CPU s':>7s} {'x sgbm':>7s}")
for name, ts in times.items():
    print(f"{name:32s} {statistics.median(ts):7.4f} {statistics.median(ts) / ref:7.2f}")
print("torch", torch.__version__, "native bfloat16:", native_bfloat16())
