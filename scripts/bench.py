"""The fixed benchmark behind ``make bench``: every registered method on the real pairs of ../shared/data and a
seeded synthetic set, written to ``BENCHMARKS.md`` with plots under ``docs/bench/``.

    python scripts/bench.py [--methods all] [--synthetic N] [--budget SECONDS] [--repeats 3] [--out BENCHMARKS.md]

All methods run in this one process through :func:`stereonet.evaluation.run_evaluation`, pair by pair, so
their times and the ratios to ``opencv-sgbm`` are measured under the same load. Every number in the tables
is the **median over pairs** (robust to one odd pair); the shared filling of ``eval.py --fill`` is applied
to every method (dense comparison) and the raw bad-2 and density before filling are reported beside it.
``--budget`` bounds the run: once a method has used that many seconds on one dataset its remaining pairs
there are skipped, and ``--pair-cap`` skips a pair whose projected time (from the method's speed per pixel
and disparity so far) is above it; the tables count the skipped pairs. ``--repeats`` times every call that many
times per pair, the methods interleaved round by round, and reports the median (one call's time swings with
the machine's other work; a single slow sample used to decide a method's worst pair).
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import json
import math
import os
import platform
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from stereonet.checks import StereoInputError
from stereonet.cli.common import USER_ERRORS, OneLineParser, fail
from stereonet.evaluation import (
    Evaluation,
    PairResult,
    expand_data_specs,
    parse_methods,
    plot_bad2,
    run_evaluation,
    safe_name,
)
from stereonet.measure import reuse_freed_memory

PROG = "scripts/bench.py"
REPO = Path(__file__).resolve().parents[1]
REFERENCE = "opencv-sgbm"
SYNTHETIC_PAIRS = 8
PANEL_DATASETS = ("middlebury2003", "kitti2015")  # + the synthetic set: one picture of each in the report


def median_of(pairs: Sequence[PairResult], key: str, raw: bool = False) -> float | None:
    """Median over pairs of one metric (``seconds``/``peak_mib`` or a metrics key); None when nothing ran."""
    if key in ("seconds", "peak_mib"):
        vals = [getattr(p, key) for p in pairs if p.metrics is not None]
    else:
        vals = [(p.raw_metrics if raw else p.metrics).get(key) for p in pairs if p.metrics is not None]
    vals = [v for v in vals if v is not None and not math.isnan(v)]
    return float(np.median(vals)) if vals else None


def _latest_run(pairs: Sequence[PairResult], method: str) -> list[PairResult]:
    """The results of ``method`` from the last run (see ``--merge``) that includes it."""
    runs = [getattr(p, "run", 0) for p in pairs if p.method == method]
    last = max(runs) if runs else 0
    return [p for p in pairs if p.method == method and getattr(p, "run", 0) == last]


def summarize(ev: Evaluation, groups: dict[str, list[str]]) -> list[dict]:
    """Median rows per (method, group of datasets) with ratios to :data:`REFERENCE` in the same group.

    The time ratio is the median over pairs of ``seconds / seconds of opencv-sgbm on the same pair in the same
    run`` (same process, same moment's machine load); the bad-2 ratio compares the two medians.
    """
    methods = list(dict.fromkeys(p.method for p in ev.pairs))
    rows = []
    for group, datasets in groups.items():
        for m in methods:
            sel = [p for p in _latest_run(ev.pairs, m) if p.dataset in datasets]
            if not sel:
                continue
            run = getattr(sel[0], "run", 0)
            ref = {(p.dataset, p.pair): p for p in ev.pairs if p.method == REFERENCE and p.dataset in datasets
                   and getattr(p, "run", 0) == run and p.metrics is not None}
            ratios = [p.seconds / ref[(p.dataset, p.pair)].seconds for p in sel
                      if p.metrics is not None and (p.dataset, p.pair) in ref and ref[(p.dataset, p.pair)].seconds > 0]
            row = {"method": m, "group": group, "pairs": sum(p.metrics is not None for p in sel),
                   "failed": sum(p.error is not None for p in sel), "skipped": sum(p.skipped for p in sel)}
            for k in ("epe", "bad1", "bad2", "bad4", "d1", "see", "epe_noc", "bad2_noc", "seconds", "peak_mib"):
                row[k] = median_of(sel, k)
            row["bad2_raw"] = median_of(sel, "bad2", raw=True)
            row["density_raw"] = median_of(sel, "density", raw=True)
            row["time_ratio"] = float(np.median(ratios)) if ratios else None
            rates = [p.work / p.seconds / 1e6 for p in sel
                     if p.metrics is not None and getattr(p, "work", 0) and p.seconds > 0]
            row["mdes"] = float(np.median(rates)) if rates else None  # million disparity evaluations per s
            same = [ref[(p.dataset, p.pair)] for p in sel if p.metrics is not None and (p.dataset, p.pair) in ref]
            ref_b2 = median_of(same, "bad2")  # the reference on the same pairs this method ran on
            row["bad2_ratio"] = row["bad2"] / ref_b2 if row["bad2"] is not None and ref_b2 else None
            row["complete"] = row["pairs"] == len(sel) and len(sel) > 0
            rows.append(row)
    return rows


def _fmt(v: float | None, spec: str) -> str:
    return "–" if v is None else format(v, spec)


def markdown_table(rows: Sequence[dict], group: str) -> str:
    head = ("| method | pairs | EPE | bad-1 | bad-2 | bad-4 | D1 | SEE | bad-2 noc | bad-2 raw | density raw | "
            "s/pair | Mde/s | × sgbm time | ÷ sgbm bad-2 | peak MiB |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    sel = sorted((r for r in rows if r["group"] == group),  # methods that ran on every pair first
                 key=lambda r: (not r["complete"], r["bad2"] is None, r["bad2"] if r["bad2"] is not None else 0))
    for r in sel:
        note = "".join([f" ({r['failed']} failed)" if r["failed"] else "",
                        f" ({r['skipped']} skipped: time cap)" if r["skipped"] else ""])
        lines.append("| " + " | ".join([
            f"`{r['method']}`{note}", str(r["pairs"]), _fmt(r["epe"], ".2f"), _fmt(r["bad1"], ".1f"),
            _fmt(r["bad2"], ".1f"), _fmt(r["bad4"], ".1f"), _fmt(r["d1"], ".1f"), _fmt(r["see"], ".2f"),
            _fmt(r["bad2_noc"], ".1f"), _fmt(r["bad2_raw"], ".1f"), _fmt(r["density_raw"], ".1f"),
            _fmt(r["seconds"], ".3f"), _fmt(r.get("mdes"), ".0f"), _fmt(r["time_ratio"], ".1f"), _fmt(r["bad2_ratio"], ".2f"),
            _fmt(r["peak_mib"], ".0f")]) + " |")
    return "\n".join(lines)


def headline(rows: Sequence[dict], groups: Sequence[str]) -> list[str]:
    """Markdown lines: per group, the best method of each kind by median bad-2 (after fill), with EPE, SEE,
    time and the ratios to opencv-sgbm."""
    from stereonet import matchers

    lines = ["## Headline: best of each kind (median bad-2 after fill, lower is better)", "",
             "Only methods that ran on every pair of the group compete here (a method that skipped the large "
             "pairs would be judged on the easy ones).", "",
             "| data | kind | method | bad-2 | EPE | SEE | s/pair | ÷ sgbm bad-2 | × sgbm time |",
             "|---|---|---|---|---|---|---|---|---|"]
    for group in groups:
        sel = [r for r in rows if r["group"] == group and r["bad2"] is not None and r["complete"]]
        for kind in dict.fromkeys(matchers.spec(r["method"]).kind for r in sel):
            best = min((r for r in sel if matchers.spec(r["method"]).kind == kind), key=lambda r: r["bad2"])
            lines.append(f"| {group} | {kind} | `{best['method']}` | {_fmt(best['bad2'], '.1f')} | "
                         f"{_fmt(best['epe'], '.2f')} | {_fmt(best['see'], '.2f')} | {_fmt(best['seconds'], '.3f')} | "
                         f"{_fmt(best['bad2_ratio'], '.2f')} | {_fmt(best['time_ratio'], '.1f')} |")
    return lines + [""]


BLOCK_REFERENCE = "opencv-bm"  # the counterpart of the local block matchers (bm-*); every other method: REFERENCE


def counterpart(method: str) -> str:
    """The OpenCV method a method's time is held against: ``opencv-bm`` for the block matchers, else opencv-sgbm."""
    return BLOCK_REFERENCE if method.startswith("bm-") else REFERENCE


def counterpart_ratios(ev: Evaluation, groups: dict[str, list[str]]) -> list[dict]:
    """Per (method, group): the median and the largest over pairs of ``seconds / seconds of its counterpart``
    (:func:`counterpart`) on the same pair in the same run (one process, the same moment's load)."""
    methods = [m for m in dict.fromkeys(p.method for p in ev.pairs) if m not in (REFERENCE, BLOCK_REFERENCE)]
    rows = []
    for group, datasets in groups.items():
        for m in methods:
            sel = [p for p in _latest_run(ev.pairs, m) if p.dataset in datasets and p.metrics is not None]
            if not sel:
                continue
            ref_name, run = counterpart(m), getattr(sel[0], "run", 0)
            ref = {(p.dataset, p.pair): p.seconds for p in ev.pairs if p.method == ref_name and p.dataset in datasets
                   and getattr(p, "run", 0) == run and p.metrics is not None and p.seconds > 0}
            ratios = [p.seconds / ref[(p.dataset, p.pair)] for p in sel if (p.dataset, p.pair) in ref]
            if ratios:
                rows.append({"method": m, "group": group, "reference": ref_name, "pairs": len(ratios),
                             "median": float(np.median(ratios)), "worst": float(max(ratios))})
    return rows


def counterpart_table(rows: Sequence[dict], groups: Sequence[str]) -> list[str]:
    """Markdown lines of :func:`counterpart_ratios`: one row per method, median and worst pair per group."""
    if not rows:
        return []
    head = "| method | against | " + " | ".join(f"{g}: median × | {g}: worst pair ×" for g in groups) + " |"
    lines = ["## Time against the OpenCV counterpart", "",
             "Wall-clock time of each call (the run's torch threads, see the header) over its OpenCV counterpart's on the "
             "same pair in the same run: "
             f"`{BLOCK_REFERENCE}` for the block matchers (`bm-*`), `{REFERENCE}` for the others; the median over "
             "pairs and the worst pair.", "", head, "|" + "---|" * (head.count("|") - 1)]
    by = {(r["method"], r["group"]): r for r in rows}
    for m in dict.fromkeys(r["method"] for r in rows):
        cells = []
        for g in groups:
            r = by.get((m, g))
            cells += [_fmt(r and r["median"], ".2f"), _fmt(r and r["worst"], ".2f")]
        lines.append(f"| `{m}` | `{counterpart(m)}` | " + " | ".join(cells) + " |")
    return lines + [""]


def plot_speed_accuracy(rows: Sequence[dict], group: str, path: Path) -> None:
    """Scatter: median seconds per pair (log) vs median bad-2, one labelled point per method."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from stereonet.io.atomic import atomic_path

    sel = [r for r in rows if r["group"] == group and r["seconds"] and r["bad2"] is not None]
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for r in sel:  # hollow markers: the method skipped pairs (time cap), so its median is over fewer pairs
        colour = "tab:red" if r["method"] == REFERENCE else "tab:blue"
        ax.scatter(r["seconds"], r["bad2"], edgecolors=colour, facecolors=colour if r["complete"] else "none")
        label = r["method"] if r["complete"] else f"{r['method']} ({r['pairs']} pairs only)"
        ax.annotate(label, (r["seconds"], r["bad2"]), fontsize=8, xytext=(3, 3), textcoords="offset points")
    ax.set_xscale("log")
    ax.set_xlabel("seconds per pair (median, log scale)")
    ax.set_ylabel("bad-2 % after fill (median, lower is better)")
    ax.set_title(f"speed vs accuracy: {group}")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=100)
    plt.close(fig)


def shrink_copy(src: Path, dst: Path, max_width: int = 1600) -> bool:
    """Copy a picture (format by ``dst``'s extension), shrunk to ``max_width`` (area interpolation);
    False when ``src`` is absent."""
    import cv2

    from stereonet.io import read_array, write_image

    if not src.is_file():
        return False
    img = read_array(src)
    if img.shape[1] > max_width:
        s = max_width / img.shape[1]
        img = cv2.resize(img, (max_width, round(img.shape[0] * s)), interpolation=cv2.INTER_AREA)
    write_image(dst, img)
    return True


def _load_average() -> float | None:
    try:
        return os.getloadavg()[0]
    except (OSError, AttributeError):
        return None


def _environment() -> str:
    import cv2
    import torch

    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True,
                                text=True, timeout=10).stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        commit = "unknown"
    return (f"{_dt.datetime.now(_dt.timezone.utc).strftime('%Y-%m-%d %H:%M UTC')}, commit `{commit}`, "
            f"{platform.machine()} {os.cpu_count()} CPU cores (torch threads: {torch.get_num_threads()}), "
            f"Python {platform.python_version()}, torch {torch.__version__}, OpenCV {cv2.__version__}")


def save_pairs(path: Path, pairs: Sequence[PairResult]) -> None:
    """Per-pair results as JSON (what ``--merge`` reads back)."""
    from stereonet.io.atomic import atomic_write_text

    atomic_write_text(path, json.dumps([dataclasses.asdict(p) for p in pairs], indent=1, allow_nan=True) + "\n")


def load_pairs(path: Path) -> list[PairResult]:
    if not path.is_file():
        raise FileNotFoundError(f"--merge: no earlier per-pair results at {path}")
    return [PairResult(**d) for d in json.loads(path.read_text())]


def dataset_pairs(ev: Evaluation, datasets: Sequence[str]) -> dict[str, list[str]]:
    """Per dataset, the names of the pairs the benchmark has (any method), in first-seen order."""
    out: dict[str, list[str]] = {d: [] for d in datasets}
    for p in ev.pairs:
        if p.dataset in out and p.pair not in out[p.dataset]:
            out[p.dataset].append(p.pair)
    return out


def pairs_line(ev: Evaluation, datasets: Sequence[str]) -> str:
    """'N pairs: dataset k (names), ...' -- what a group's medians stand on."""
    per = dataset_pairs(ev, datasets)
    total = sum(len(v) for v in per.values())
    return (f"Each row's median is over **{total} pairs**: "
            + "; ".join(f"{d} {len(v)} ({', '.join(v)})" if len(v) <= 6 else f"{d} {len(v)}"
                        for d, v in per.items()) + ".")


def write_report(ev: Evaluation, groups: dict[str, list[str]], out: Path, docs: Path, plots_tmp: Path,
                 synthetic_spec: str, seconds_total: float, skipped: Sequence[str] = (),
                 load: tuple[float, float] | None = None, caps: str = "", environment: str | None = None) -> None:
    from stereonet import matchers
    from stereonet.io.atomic import atomic_write_text

    rows = summarize(ev, groups)
    per_dataset = summarize(ev, {d: [d] for ds in groups.values() for d in ds})
    from stereonet.data import real_data_dir

    real_source = ("`../shared/data` (Middlebury 2001/2003, KITTI 2012/2015" if real_data_dir()[1] == "shared"
                   else "`stereonet/data/bundled` (the four Middlebury 2001/2003 pairs shipped with the package")
    docs.mkdir(parents=True, exist_ok=True)
    rel = os.path.relpath(docs, out.parent)
    parts = [
        "# Benchmarks",
        "",
        "Generated by `make bench` (`python scripts/bench.py`); do not edit by hand. "
        f"Run: {environment or _environment()}; the whole benchmark took {seconds_total / 60:.1f} min"
        + (f"; 1-min load average {load[0]:.1f} at the start and {load[1]:.1f} at the end (on a shared "
           "machine absolute times are noisy: the ratios to opencv-sgbm, measured pair by pair in the same "
           "process, are the robust numbers)" if load else "") + ".",
        "",
        "Every method ran in the same process on the same pairs: the real pairs with ground truth in "
        f"{real_source}; never used for training) and the seeded "
        f"synthetic set `{synthetic_spec}` of data_gen. Numbers are **medians over pairs**. All methods get the "
        "same occlusion filling (`eval.py --fill`), so the main columns compare dense maps; `bad-2 raw` and "
        "`density raw` are before filling. bad-τ and D1 are % of ground-truth pixels (missing predictions count "
        "as errors), EPE and SEE (SMD-Nets soft edge error on depth discontinuities) are in pixels; `noc` = "
        "non-occluded pixels (datasets with an occlusion mask). `Mde/s` is million disparity evaluations (W x H x (max_disp + 1)) per second, the median over pairs; `× sgbm time` and `÷ sgbm bad-2` are ratios to "
        f"`{REFERENCE}` medians on the same pairs; peak MiB is the extra resident memory of one call (see "
        f"`stereonet/measure.py`; freed memory is handed back before each call, and glibc keeps large freed buffers "
        f"for reuse inside it, as in infer.py: `reuse_freed_memory`). Rows are sorted by bad-2, methods that ran on every pair first; the bad-2 "
        f"ratio of a method that skipped pairs compares it with opencv-sgbm on the pairs it ran. {caps}",
        "",
    ]
    parts += headline(rows, list(groups))
    parts += counterpart_table(counterpart_ratios(ev, groups), list(groups))
    for group in groups:
        parts += [f"## {group}: median over pairs", "", pairs_line(ev, groups[group]), "",
                  markdown_table(rows, group), ""]
        path = docs / f"speed_accuracy_{group}.png"
        plot_speed_accuracy(rows, group, path)
        parts += [f"![speed vs accuracy on {group}]({rel}/{path.name})", ""]
    plot_bad2([dict(r, dataset=r["group"]) for r in per_dataset], docs / "bad2_per_dataset.png")
    parts += ["## Per dataset", "", f"![bad-2 per method and dataset]({rel}/bad2_per_dataset.png)", ""]
    for d in (d for ds in groups.values() for d in ds):
        n = len(dataset_pairs(ev, [d])[d])
        parts += [f"### {d} ({n} pair{'s' if n != 1 else ''})", "", markdown_table(per_dataset, d), ""]
    run = max((p.run for p in ev.pairs), default=0)
    if run == 0 and any(plots_tmp.iterdir()):  # a fresh benchmark with new pictures: the earlier ones go
        for old in docs.glob("panel_*.jpg"):
            old.unlink()
    for d in (d for ds in groups.values() for d in ds if d in PANEL_DATASETS or d.startswith("synthetic")):
        folder = plots_tmp / safe_name(d)
        for src in sorted(folder.glob("*.png"))[:1] if folder.is_dir() else []:
            shrink_copy(src, docs / f"panel_{folder.name}_{src.stem}{f'_run{run}' if run else ''}.jpg")
    shown = sorted(docs.glob("panel_*.jpg"))
    if shown:
        parts += ["## What the maps look like", "",
                  "Left image, ground truth, then each method's disparity and error map (same colour scale); "
                  "`_runN` pictures show the methods added by a later `--merge` run.", ""]
        for dst in shown:
            parts += [f"**{dst.stem.removeprefix('panel_')}**", "", f"![{dst.stem}]({rel}/{dst.name})", ""]
    failures = [p for p in ev.pairs if p.error]
    if failures:
        parts += ["## Failures", ""]
        seen = set()
        for p in failures:
            if (p.method, p.error) not in seen:
                seen.add((p.method, p.error))
                parts.append(f"- `{p.method}` on {p.dataset}/{p.pair}: {p.error}")
        parts.append("")
    if skipped:
        parts += ["## Not run", "", "Registered but left out because their trained weights are missing: "
                  + ", ".join(f"`{n}`" for n in skipped) + ".", ""]
    kinds = {n: matchers.spec(n).kind for n in dict.fromkeys(p.method for p in ev.pairs)}
    parts += ["## Methods", "", "| method | kind | description |", "|---|---|---|"]
    parts += [f"| `{n}` | {k} | {matchers.spec(n).description} |" for n, k in kinds.items()]
    atomic_write_text(out, "\n".join(parts) + "\n")


def build_parser() -> OneLineParser:
    p = OneLineParser(prog=PROG, description="Run the fixed benchmark and write BENCHMARKS.md + docs/bench/.")
    p.add_argument("--methods", default="all", help="comma-separated names or 'all' (default)")
    p.add_argument("--synthetic", type=int, default=SYNTHETIC_PAIRS, help="synthetic pairs (default %(default)s)")
    p.add_argument("--no-real", action="store_true", help="skip ../shared/data")
    p.add_argument("--budget", type=float, default=45.0,
                   help="seconds a method may spend per dataset before its remaining pairs are skipped")
    p.add_argument("--pair-cap", type=float, default=40.0,
                   help="skip a pair when a method's projected time for it (from its speed so far) exceeds this")
    p.add_argument("--repeats", type=int, default=3,
                   help="timed calls per method and pair, methods interleaved round by round; the median is "
                        "reported (default %(default)s)")
    p.add_argument("--out", type=Path, default=REPO / "BENCHMARKS.md")
    p.add_argument("--docs", type=Path, default=REPO / "docs" / "bench")
    p.add_argument("--merge", action="store_true",
                   help="add these methods to the last benchmark (docs/bench/pairs.json) instead of starting over; "
                        f"{REFERENCE} is re-run for the ratios")
    p.add_argument("--report-only", action="store_true",
                   help="rewrite BENCHMARKS.md from docs/bench/pairs.json without running anything")
    p.add_argument("--no-progress", action="store_true")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    import time

    args = build_parser().parse_args(argv)
    reuse_freed_memory()  # as infer.py and eval.py do (stereonet.measure)
    try:
        skipped: list[str] = []
        methods = parse_methods(args.methods, skipped)
        if args.repeats < 1:
            raise StereoInputError(f"--repeats: expected a count >= 1, got {args.repeats}")
        if args.synthetic < 0:
            raise StereoInputError(f"--synthetic: expected a count >= 0, got {args.synthetic}")
        real = [] if args.no_real else expand_data_specs("real")
        synthetic = f"synthetic:{args.synthetic}" if args.synthetic else None
        specs = real + ([synthetic] if synthetic else [])
        if not specs:
            raise StereoInputError("nothing to run: no real data and --synthetic 0")
        from stereonet.evaluation import dataset_label

        groups = {}
        if real:
            groups["real"] = [dataset_label(s) for s in real]
        if synthetic:
            groups["synthetic"] = [dataset_label(synthetic)]
        pairs_json, run_json = args.docs.resolve() / "pairs.json", args.docs.resolve() / "run.json"
        if args.report_only:  # rewrite BENCHMARKS.md from the saved results (e.g. after a change to the report)
            meta = json.loads(run_json.read_text()) if run_json.is_file() else {}
            ev = Evaluation(load_pairs(pairs_json))
            with tempfile.TemporaryDirectory() as tmp:
                write_report(ev, groups, args.out.resolve(), args.docs.resolve(), Path(tmp),
                             meta.get("synthetic", synthetic or "none"), meta.get("seconds", 0.0),
                             meta.get("skipped", skipped), meta.get("load"), meta.get("caps", ""),
                             meta.get("environment"))
            print(f"rewrote {args.out} from {pairs_json}")
            return 0
        earlier = load_pairs(pairs_json) if args.merge else []
        if args.merge and REFERENCE not in methods:
            methods.append(REFERENCE)
        t0, load0 = time.perf_counter(), _load_average()
        with tempfile.TemporaryDirectory(prefix="stereonet-bench-") as tmp:
            ev = run_evaluation(methods, specs, fill=True, plots=Path(tmp), progress=not args.no_progress,
                                budget=args.budget, pair_cap=args.pair_cap, repeats=args.repeats)
            if earlier:
                run = max(p.run for p in earlier) + 1
                for p in ev.pairs:
                    p.run = run
                ev = Evaluation(earlier + ev.pairs)
                skipped = [n for n in skipped if n not in {p.method for p in ev.pairs}]
            save_pairs(pairs_json, ev.pairs)
            load = None if load0 is None else (load0, _load_average() or load0)
            caps = (f"Time caps: a method's remaining pairs on a dataset are skipped after {args.budget:g} s there, "
                    f"and a pair is skipped when its projected time exceeds {args.pair_cap:g} s; skipped pairs are "
                    "counted in the method column."
                    + (f" Times: each method's median of {args.repeats} timed calls per pair, the methods interleaved "
                       "round by round on the pair (a load burst hits one sample of each, not every sample of one); "
                       "metrics and peak memory from the first call." if args.repeats > 1 else ""))
            meta = {"synthetic": synthetic or "none", "seconds": time.perf_counter() - t0, "skipped": skipped,
                    "load": load, "caps": caps, "environment": _environment()}
            if earlier and run_json.is_file():
                meta["seconds"] += json.loads(run_json.read_text()).get("seconds", 0.0)
            from stereonet.io.atomic import atomic_write_text

            atomic_write_text(run_json, json.dumps(meta, indent=1) + "\n")
            write_report(ev, groups, args.out.resolve(), args.docs.resolve(), Path(tmp), meta["synthetic"],
                         meta["seconds"], skipped, load, caps, meta["environment"])
    except USER_ERRORS as e:
        return fail(PROG, e)
    except ImportError as e:
        return fail(PROG, f"{e} (this part of stereonet is not installed)")
    print(f"wrote {args.out} and plots in {args.docs}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
