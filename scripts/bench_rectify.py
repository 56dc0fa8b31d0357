"""Rectification benchmark on data_gen's unrectified rigs: ours vs OpenCV, one process, same rigs and matches.

    python scripts/bench_rectify.py [--rigs 50] [--seed 0] [--rendered 3] [--sigma 0.5] [--outliers 0.2]
                                    [--json FILE]

1. ``--rigs`` rigs of ``data_gen.sample_rig`` (the rigs of ``render_pair(seed, index, rectified=False)``),
   ground-truth correspondences projected by data_gen's own camera model; calibrated: ours
   (``stereonet.geometry.stereo_rectify``) and ``cv2.stereoRectify``; uncalibrated from "SIFT-like" matches
   (GT + Gaussian noise ``--sigma`` px + ``--outliers`` random matches): ours (RANSAC F + Hartley) and
   ``cv2.findFundamentalMat(FM_RANSAC)`` + ``cv2.stereoRectifyUncalibrated``. The table reports the row error
   ``|y_left - y_right|`` of the GT correspondences after rectification: pooled median, 95th percentile, max,
   the worst per-rig median and seconds per rig; separately for rigs with and without lens distortion.
2. ``--rendered`` fully rendered pairs: every valid, non-occluded pixel's GT correspondence, real SIFT matches
   on the rendered images for the uncalibrated methods, and our triangulation against the rendered depth.

Targets (issue 4): calibrated median < 0.1 px and max < 0.5 px; uncalibrated median < 0.5 px; triangulation
< 0.1 % relative depth error.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))  # the benchmark's library beside this script
from rectify_bench_lib import format_table, rendered_benchmark, rig_benchmark, summarize  # noqa: E402

from stereonet.io.atomic import atomic_write_text

REPO = Path(__file__).resolve().parents[1]  # stereonet itself comes from the (editable) install


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--rigs", type=int, default=50, help="number of data_gen rigs (default 50)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--rendered", type=int, default=3, help="number of fully rendered pairs (0 = skip)")
    p.add_argument("--sigma", type=float, default=0.5, help="match noise in px for the rig benchmark")
    p.add_argument("--outliers", type=float, default=0.2, help="fraction of random matches")
    p.add_argument("--json", type=Path, default=None, help="write the per-method summaries here")
    args = p.parse_args(argv)
    if args.rigs < 1:
        p.error(f"--rigs: expected a positive integer, got {args.rigs}")
    torch.set_num_threads(1)  # thousands of tiny tensor ops: one thread avoids contention
    logging.getLogger("stereonet.geometry.rectify").setLevel(logging.ERROR)  # per-pair "dominant plane" notes

    t0 = time.perf_counter()
    rows = rig_benchmark(rigs=args.rigs, seed=args.seed, sigma=args.sigma, outliers=args.outliers)
    report: dict = {"rigs": args.rigs, "seed": args.seed, "sigma": args.sigma, "outliers": args.outliers}
    for title, subset in (
        ("all rigs", rows),
        ("undistorted rigs", [r for r in rows if not r["distorted"]]),
        ("rigs with lens distortion", [r for r in rows if r["distorted"]]),
    ):
        if not subset:
            continue
        summary = summarize(subset)
        print(format_table(summary, f"\n== data_gen rigs (seed {args.seed}): {title} ==  |dy| in px"))
        report[title] = summary
    tri = max(r["triangulation_rel_err"] for r in rows)
    print(
        f"\ntriangulation (DLT) of the exact correspondences vs data_gen depth: max relative error {tri:.2e}"
    )
    report["triangulation_max_rel_err"] = tri
    if args.rendered > 0:
        rendered, tri_r = rendered_benchmark(pairs=args.rendered, seed=args.seed)
        summary = summarize(rendered)
        print(
            format_table(
                summary,
                f"\n== {args.rendered} rendered unrectified pairs: all valid non-occluded pixels, "
                f"real SIFT matches for the uncalibrated rows ==",
            )
        )
        print(
            f"triangulation vs rendered depth: max relative error {tri_r['max_rel_depth_err']:.2e}, "
            f"median {tri_r['median_rel_depth_err']:.2e}"
        )
        report["rendered"] = summary
        report["rendered_triangulation"] = tri_r
    print(f"\n({time.perf_counter() - t0:.1f} s)")
    if args.json is not None:
        atomic_write_text(args.json, json.dumps(report, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
