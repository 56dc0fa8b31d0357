"""Benchmark of the global matchers (dp, bp, graphcut) beside opencv-sgbm, all in this one process.

    python scripts/bench_global.py [--methods dp,bp,graphcut,opencv-sgbm] [--data middlebury]
                                   [--repeat 1] [--json FILE]

Runs :func:`stereonet.evaluation.run_evaluation` with the shared filling of ``eval.py --fill`` (dense
comparison; raw bad-2 and density before filling are reported too) and prints, per method, the **median
over pairs** of bad-2 (all pixels with ground truth), wall seconds per pair with its ratio to opencv-sgbm
(measured under the same load, so comparable on a shared machine) and peak MiB.
``--repeat N`` runs the whole evaluation N times and keeps each pair's median time. ``--data middlebury``
means the Middlebury 2001 and 2003 pairs of ../shared/data (tsukuba, venus, cones, teddy); any
``eval.py`` spec list works too (e.g. ``real``).
"""

from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path

from stereonet.evaluation import expand_data_specs, run_evaluation
from stereonet.io.atomic import atomic_write_text

REPO = Path(__file__).resolve().parents[1]

SHARED = REPO.parent / "shared" / "data"
REFERENCE = "opencv-sgbm"


def _specs(text: str) -> list[str]:
    if text == "middlebury":
        return [f"middlebury2001:{SHARED / 'middlebury2001'}", f"middlebury2003:{SHARED / 'middlebury2003'}"]
    return expand_data_specs(text)


def _median(values: list[float]) -> float:
    values = [v for v in values if v == v]
    return statistics.median(values) if values else float("nan")


def summarize(runs: list, methods: list[str]) -> list[dict]:
    """Rows per method: medians over pairs (times: median over repeats first), ratio to the reference."""
    per_pair: dict[tuple[str, str, str], list] = {}
    for ev in runs:
        for p in ev.pairs:
            per_pair.setdefault((p.method, p.dataset, p.pair), []).append(p)
    rows = []
    for m in methods:
        pairs = [v for k, v in per_pair.items() if k[0] == m]
        ok = [v for v in pairs if v[0].metrics is not None]
        row = {"method": m, "pairs": len(ok),
               "bad2": _median([v[0].metrics["bad2"] for v in ok]),
               "bad2_raw": _median([v[0].raw_metrics["bad2"] for v in ok]),
               "density_raw": _median([v[0].raw_metrics["density"] for v in ok]),
               "seconds": _median([_median([p.seconds for p in v]) for v in ok]),
               "peak_mib": _median([max(p.peak_mib for p in v) for v in ok]),
               "per_pair": {f"{v[0].dataset}/{v[0].pair}": {"bad2": round(v[0].metrics["bad2"], 2),
                                                            "seconds": round(_median([p.seconds for p in v]), 3)}
                            for v in ok},
               "errors": [v[0].error for v in pairs if v[0].error]}
        rows.append(row)
    ref = next((r for r in rows if r["method"] == REFERENCE), None)
    for r in rows:
        r["time_ratio_to_sgbm"] = r["seconds"] / ref["seconds"] if ref and ref["seconds"] > 0 else float("nan")
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python scripts/bench_global.py", description=__doc__.split("\n\n")[0])
    p.add_argument("--methods", default="dp,bp,graphcut,opencv-sgbm")
    p.add_argument("--data", default="middlebury", help="'middlebury' or an eval.py spec list")
    p.add_argument("--repeat", type=int, default=1, help="timing repeats (median per pair)")
    p.add_argument("--json", type=Path, default=None, help="write the rows as JSON (atomically)")
    args = p.parse_args(argv)
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    if REFERENCE not in methods:
        methods.append(REFERENCE)
    specs = _specs(args.data)
    runs = [run_evaluation(methods, specs, fill=True, progress=False) for _ in range(max(1, args.repeat))]
    rows = summarize(runs, methods)
    print(f"{'method':<12} {'pairs':>5} {'bad2':>7} {'bad2_raw':>8} {'dens_raw':>8} {'sec/pair':>9} {'x sgbm':>7} {'MiB':>7}")
    for r in rows:
        print(f"{r['method']:<12} {r['pairs']:>5} {r['bad2']:>7.2f} {r['bad2_raw']:>8.2f} {r['density_raw']:>8.1f} "
              f"{r['seconds']:>9.3f} {r['time_ratio_to_sgbm']:>7.1f} {r['peak_mib']:>7.0f}")
        for pair, v in r["per_pair"].items():
            print(f"    {pair:<28} bad2 {v['bad2']:>6.2f}  {v['seconds']:>8.3f} s")
        for e in r["errors"]:
            print(f"    error: {e}")
    if args.json is not None:
        atomic_write_text(args.json, json.dumps(rows, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
