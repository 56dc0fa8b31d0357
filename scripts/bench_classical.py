"""Benchmark of the classical local matchers against OpenCV, in one process, under the same load.

    python scripts/bench_classical.py [--repeats 5] [--methods sgm,bm-sad,...] [--accuracy sgm,opencv-sgbm]
                                      [--json FILE] [--cpu]

1. Speed and memory on Middlebury 2003 Cones (450x375, 64 disparities = max_disp 63): every method runs
   ``--repeats`` times, the methods interleaved round by round (so a load change hits all of them), after
   one untimed warm-up call each (numba compilation). Reported: median wall seconds, the ratio to the OpenCV
   reference (``sgm`` -> ``opencv-sgbm``, ``bm-*`` -> ``opencv-bm``) and the peak extra resident memory of
   one call (:class:`stereonet.cli.common.PeakMemory`). ``--cpu``: CPU seconds with one thread everywhere
   (work ratios, for a machine busy with other jobs).
2. Accuracy on every real pair of ../shared/data (``stereonet.data.load_dataset("real")``, each pair's own
   ``max_disp``): bad-2 over all pixels with ground truth after the shared textbook filling of invalid pixels
   (:func:`stereonet.select.fill.fill_occlusions`, as ``eval.py --fill``), plus the density before filling.

Not a test: timings depend on the machine and its load; the targets (``sgm`` <= 3x ``opencv-sgbm``,
``bm-*`` <= 3x ``opencv-bm``, ``sgm`` bad-2 <= ``opencv-sgbm`` bad-2 on every pair) are read off the output.
"""

from __future__ import annotations

import json
import statistics
import sys
import time
from pathlib import Path

import torch

from stereonet import matchers, metrics
from stereonet.checks import StereoInputError
from stereonet.cli.common import OneLineParser, PeakMemory, add_malloc_argument, apply_malloc_argument
from stereonet.io.atomic import atomic_write_text
from stereonet.select.fill import fill_occlusions

BM = ["bm-sad", "bm-ssd", "bm-zsad", "bm-lssad", "bm-ncc", "bm-census", "bm-adaptive"]
REFERENCE = {"sgm": "opencv-sgbm", **{m: "opencv-bm" for m in BM}}


def reference(method: str) -> str | None:
    """The OpenCV method a method's time is divided by: opencv-bm for bm-*, opencv-sgbm for the others."""
    if method.startswith("opencv-"):
        return None
    return REFERENCE.get(method, "opencv-sgbm")


def load_cones() -> tuple[torch.Tensor, torch.Tensor]:
    from stereonet.data import load_dataset, real_data_dir

    ds = load_dataset(f"middlebury2003:{real_data_dir()[0] / 'middlebury2003'}")
    item = next(ds[i] for i in range(len(ds)) if "cones" in str(ds[i]["name"]))
    return item["left"][None].float(), item["right"][None].float()


def time_methods(methods: list[str], left: torch.Tensor, right: torch.Tensor, max_disp: int,
                 repeats: int, clock=time.perf_counter) -> dict[str, dict]:
    """Median seconds of ``clock`` (interleaved rounds) and peak MiB of one call per method."""
    res: dict[str, dict] = {}
    for m in methods:  # warm-up (JIT) and memory
        matchers.match(m, left, right, max_disp)
        with PeakMemory() as pm:
            matchers.match(m, left, right, max_disp)
        res[m] = {"times": [], "peak_mib": pm.peak_mib}
    for _ in range(repeats):
        for m in methods:
            t = clock()
            matchers.match(m, left, right, max_disp)
            res[m]["times"].append(clock() - t)
    for r in res.values():
        r["seconds"] = statistics.median(r.pop("times"))
    for m, r in res.items():
        ref = reference(m)
        r["ratio"] = r["seconds"] / res[ref]["seconds"] if ref in res else None
    return res


def bad2_filled(name: str, item: dict) -> dict[str, float]:
    left, right = item["left"][None].float(), item["right"][None].float()
    out = matchers.match(name, left, right, int(item["max_disp"]))
    disp = fill_occlusions(out.disparity, out.valid)
    gt, gt_valid = item["disparity"][None], item["valid"][None].bool()
    with torch.no_grad():
        filled = metrics.evaluate(disp, gt, gt_valid, pred_valid=torch.ones_like(out.valid))
        raw = metrics.evaluate(out.disparity, gt, gt_valid, pred_valid=out.valid)
    return {"bad2": filled["bad2"], "density": raw["density"], "bad2_raw": raw["bad2"]}


def main(argv: list[str] | None = None) -> int:
    p = OneLineParser(prog="scripts/bench_classical.py", description=__doc__.split("\n\n")[0])
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--methods", default=",".join(["opencv-sgbm", "sgm", "opencv-bm", *BM]),
                   help="methods to time on Cones (OpenCV references are added when needed); "
                        "LABEL=METHOD@CHECKPOINT times a learned matcher with other weights")
    p.add_argument("--accuracy", default="opencv-sgbm,sgm", help="methods for bad-2 on the real pairs ('' = skip)")
    p.add_argument("--json", type=Path, default=None)
    p.add_argument("--cpu", action="store_true",
                   help="one thread everywhere (torch, numba, OpenCV) and CPU seconds (process_time) instead of "
                        "wall seconds: work ratios that a busy machine distorts much less than wall-time ratios")
    add_malloc_argument(p)
    args = p.parse_args(argv)
    apply_malloc_argument(args)
    torch.set_num_threads(1 if args.cpu else 2)
    clock = time.perf_counter
    if args.cpu:
        import cv2
        import numba

        numba.set_num_threads(1)
        cv2.setNumThreads(1)
        clock = time.process_time

    acc = [m for m in args.accuracy.split(",") if m]
    try:  # every name checked before anything runs: a typo is one line, not a traceback after the timings
        methods = [matchers.register_checkpoint_variant(m) for m in args.methods.split(",") if m]
        for m in methods + acc:
            matchers.spec(m)
    except (StereoInputError, FileNotFoundError) as e:
        p.error(f"--methods/--accuracy: {e}")
    for m in list(methods):
        ref = reference(m)
        if ref and ref not in methods:
            methods.insert(0, ref)
    report: dict = {"speed": {}, "accuracy": {}}
    if methods:
        left, right = load_cones()
        report["speed"] = time_methods(methods, left, right, 63, args.repeats, clock)
        print(f"Cones 450x375, 64 disparities, median of {args.repeats} interleaved runs, "
              f"torch threads {torch.get_num_threads()}" + (", CPU seconds, one thread everywhere" if args.cpu else ""))
        print(f"{'method':18s} {'seconds':>9s} {'x ref':>7s} {'ref':>12s} {'peak MiB':>9s}")
        for m, r in report["speed"].items():
            ratio = "" if r["ratio"] is None else f"{r['ratio']:.2f}"
            print(f"{m:18s} {r['seconds']:9.4f} {ratio:>7s} {reference(m) or '':>12s} {r['peak_mib']:9.1f}")

    if acc:
        from stereonet.data import load_dataset

        ds = load_dataset("real")
        print("\nbad-2 (%, all GT pixels, after the textbook fill) / density before filling (%)")
        print(f"{'pair':28s} " + " ".join(f"{m:>20s}" for m in acc))
        for i in range(len(ds)):
            item = ds[i]
            row = {m: bad2_filled(m, item) for m in acc}
            report["accuracy"][str(item["name"])] = row
            print(f"{str(item['name']):28s} " + " ".join(
                f"{row[m]['bad2']:11.2f} / {row[m]['density']:5.1f}" for m in acc))
    if args.json:
        atomic_write_text(args.json, json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
