"""Large pairs: ``sgm`` against OpenCV's SGBM in wall time (2 threads) and peak memory, as ``infer.py`` runs it.

    python scripts/bench_large.py [--cases kitti,6mp,16mp] [--repeats 3] [--budget 2048] [--json FILE]

Cases: ``kitti`` = the KITTI 2015 pair of ../shared/data (1242x375, its ground truth's disparity range, as eval.py picks for
KITTI); ``6mp`` = a data_gen pair rendered at 2964x2000 with 256 disparities; ``16mp`` = 4608x3456 with 256
disparities (one run of sgm, to show it runs under the budget; SGBM beside it). Each method runs through
:func:`stereonet.tiling.match_with_budget` with ``--budget`` MiB (infer.py's default 2048, the 8 GB-laptop
default), torch/numba/OpenCV on 2 threads, in this one process, interleaved; the table gives the median wall
seconds, the ratio to ``opencv-sgbm`` on the same pair, Mde/s (W x H x (D + 1) per second) and the peak
extra resident memory of one call (:class:`stereonet.measure.PeakMemory`).
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import torch

from stereonet import matchers
from stereonet.cli.common import add_malloc_argument, apply_malloc_argument
from stereonet.io.atomic import atomic_write_text
from stereonet.measure import PeakMemory
from stereonet.tiling import DEFAULT_BUDGET_MIB, match_with_budget

SIZES = {"6mp": (2000, 2964, 255), "16mp": (3456, 4608, 255)}


def load_case(case: str) -> tuple[torch.Tensor, torch.Tensor, int]:
    if case == "kitti":
        from stereonet.data import load_dataset, real_data_dir

        ds = load_dataset(f"kitti2015:{real_data_dir()[0] / 'kitti2015'}")
        item = ds[0]
        return item["left"][None].float(), item["right"][None].float(), int(item.get("max_disp", 191))
    import data_gen

    h, w, max_disp = SIZES[case]
    pair = data_gen.render_pair(7, 0, difficulty=2, height=h, width=w, supersample=1, max_disp=max_disp)
    return pair["left"][None].float(), pair["right"][None].float(), max_disp


def run_case(case: str, methods: list[str], repeats: int, budget: float) -> dict:
    left, right, max_disp = load_case(case)
    h, w = left.shape[-2:]
    res: dict[str, dict] = {m: {"times": [], "peak_mib": 0.0} for m in methods}
    for r in range(repeats):
        for m in methods:
            if case == "16mp" and m != "opencv-sgbm" and r > 0:
                continue
            fn = matchers.get_matcher(m)
            info: dict = {}
            with PeakMemory() as pm:
                t0 = time.perf_counter()
                match_with_budget(fn, left, right, max_disp, budget, info=info)
                res[m]["times"].append(time.perf_counter() - t0)
            res[m]["peak_mib"] = max(res[m]["peak_mib"], pm.peak_mib)
            res[m]["strips"] = info.get("strips", 1)
            print(f"  {case} {m}: {res[m]['times'][-1]:.2f} s, peak {pm.peak_mib:.0f} MiB, "
                  f"{res[m]['strips']} strip(s)", flush=True)
    for r in res.values():
        r["seconds"] = statistics.median(r.pop("times"))
        r["mde_s"] = w * h * (max_disp + 1) / r["seconds"] / 1e6
    ref = res.get("opencv-sgbm", {}).get("seconds")
    for r in res.values():
        r["ratio"] = r["seconds"] / ref if ref else None
    return {"size": [int(w), int(h)], "max_disp": max_disp, "methods": res}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="scripts/bench_large.py", description=__doc__.split("\n\n")[0])
    p.add_argument("--cases", default="kitti,6mp,16mp")
    p.add_argument("--methods", default="opencv-sgbm,sgm")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--budget", type=float, default=DEFAULT_BUDGET_MIB, help="MiB, as infer.py --memory-budget")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--json", default=None)
    add_malloc_argument(p)
    args = p.parse_args(argv)
    apply_malloc_argument(args)
    import cv2
    import numba

    torch.set_num_threads(args.threads)
    numba.set_num_threads(min(args.threads, numba.config.NUMBA_NUM_THREADS))
    cv2.setNumThreads(args.threads)
    methods = [m for m in args.methods.split(",") if m]
    report = {}
    for case in [c for c in args.cases.split(",") if c]:
        report[case] = run_case(case, methods, args.repeats, args.budget)
    print(f"\nwall seconds, {args.threads} threads, budget {args.budget:g} MiB, median of {args.repeats} interleaved runs")
    print(f"{'case':6s} {'size':>11s} {'D':>4s} {'method':12s} {'seconds':>8s} {'x sgbm':>7s} {'Mde/s':>7s} "
          f"{'peak MiB':>9s} {'strips':>6s}")
    for case, rep in report.items():
        w, h = rep["size"]
        for m, r in rep["methods"].items():
            ratio = "" if r["ratio"] is None else f"{r['ratio']:.2f}"
            print(f"{case:6s} {f'{w}x{h}':>11s} {rep['max_disp'] + 1:4d} {m:12s} {r['seconds']:8.2f} {ratio:>7s} "
                  f"{r['mde_s']:7.0f} {r['peak_mib']:9.0f} {r['strips']:6d}")
    if args.json:
        atomic_write_text(args.json, json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
