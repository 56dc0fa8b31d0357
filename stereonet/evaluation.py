"""The evaluation engine behind ``eval.py``, ``make bench`` and the experiment scripts: every method on the same
datasets, pair by pair in one process, one row of standard metrics per method and dataset.

:func:`run_evaluation` is the entry point (what the numbers mean: :mod:`stereonet.cli.eval`'s docstring);
``eval.py`` only parses its arguments and prints :func:`format_table`.
"""

from __future__ import annotations

import json
import math
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from stereonet.checks import StereoInputError
from stereonet.matchers import weights_available
from stereonet.measure import PeakMemory, Stopwatch
from stereonet.types import StereoOutput

METRICS = ("epe", "bad1", "bad2", "bad4", "d1", "density")


# ----------------------------------------------------------------------------------------------- parsing

def parse_methods(text: str, skipped: list[str] | None = None) -> list[str]:
    """``"all"`` or a comma-separated list of registered names -> names.

    ``all`` leaves out learned methods whose weights are missing (their names are appended to ``skipped``);
    naming such a method explicitly, or an unknown name, raises a ValueError.
    """
    from stereonet import matchers

    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise StereoInputError("--methods: expected a comma-separated list of method names or 'all', got nothing")
    out: list[str] = []
    for n in names:
        if n == "all":
            chosen = [m for m in matchers.available() if weights_available(m)]
            if skipped is not None:
                skipped += [m for m in matchers.available() if m not in chosen and m not in skipped]
        else:
            chosen = [matchers.spec(n).name]
            if not weights_available(n):
                raise FileNotFoundError(f"--methods: {n} needs trained weights and they are missing "
                                        "(see stereonet/weights/README.md, or train them with train.py)")
        out += [m for m in chosen if m not in out]
    return out


def expand_data_specs(text: str, shared: Path | None = None, notes: list[str] | None = None) -> list[str]:
    """Split ``SPEC[,SPEC...]`` and expand ``real`` into one spec per dataset folder in ../shared/data (or,
    without one, in the bundled pairs: :func:`stereonet.data.real_data_dir`).

    ``real`` is optional data: when the folder is missing and other specs are given, it is left out and a
    note is appended to ``notes`` (so ``make demo`` runs on a machine without it); alone, it is an error.
    """
    parts = [s.strip() for s in text.split(",") if s.strip()]
    specs: list[str] = []
    for s in parts:
        if s == "real":
            if shared is None:
                from stereonet.data import real_data_dir

                shared, source = real_data_dir()
                if source == "bundled" and notes is not None:
                    notes.append(f"real: no ../shared/data (or STEREONET_SHARED_DATA); the Middlebury pairs "
                                 f"bundled in {shared} are used")
            if not shared.is_dir():
                missing = f"no shared real data folder ({shared or '../shared/data'}; set STEREONET_SHARED_DATA)"
                if parts == ["real"]:
                    raise FileNotFoundError(f"--data real: {missing}")
                if notes is not None:
                    notes.append(f"real left out: {missing}")
                continue
            from stereonet.data import REAL_KINDS  # the kinds ``real`` expands to, in table order

            specs += [f"{k}:{shared / k}" for k in REAL_KINDS if (shared / k).is_dir()]
        else:
            specs.append(s)
    if not specs:
        raise StereoInputError("--data: expected SPEC[,SPEC...], got nothing")
    return specs


def dataset_label(spec: str) -> str:
    """Short name for a table row: ``kitti2015:/a/b/kitti2015`` -> ``kitti2015``; ``folder:/x/y`` -> ``folder:y``;
    ``sceneflow-clean-test:/d/sceneflow`` -> ``sceneflow-clean-test`` (the folder named as the kind before its
    options)."""
    kind, _, arg = spec.partition(":")
    if not arg or kind == "synthetic":
        return spec
    name = Path(arg.rstrip("/")).name
    return kind if name in (kind, kind.split("-")[0]) else f"{kind}:{name}"


def parse_shard(text: str | None) -> tuple[int, int]:
    """``"i/n"`` -> (i, n) with 0 <= i < n; None -> (0, 1)."""
    if text is None:
        return 0, 1
    try:
        i, n = (int(x) for x in text.split("/"))
    except ValueError:
        raise StereoInputError(f"--shard: expected i/n with integers, e.g. 0/4, got {text!r}") from None
    if n < 1 or not 0 <= i < n:
        raise StereoInputError(f"--shard: expected 0 <= i < n, got {text!r}")
    return i, n


# --------------------------------------------------------------------------------------------- running

@dataclass
class PairResult:
    """One method on one pair: metrics (None when the method failed or was skipped), time, memory, error.

    ``metrics`` are measured after ``--fill`` when it is on; ``raw_metrics`` always before it.
    """

    method: str
    dataset: str
    pair: str
    metrics: dict[str, float] | None
    raw_metrics: dict[str, float] | None
    seconds: float
    peak_mib: float
    error: str | None = None
    skipped: bool = False
    run: int = 0  # which benchmark run measured it (scripts/bench.py --merge keeps several)
    work: float = 0.0  # W x H x (max_disp + 1): disparity evaluations of the pair (for Mde/s)


@dataclass
class Evaluation:
    """Everything a run measured: per-pair results and the aggregated rows (one per method and dataset)."""

    pairs: list[PairResult] = field(default_factory=list)
    rows: list[dict] = field(default_factory=list)
    # (dataset, pair, largest offset in px) of each pair whose right view was aligned (run_evaluation's align)
    aligned: list[tuple[str, str, float]] = field(default_factory=list)


def _batch(x: torch.Tensor) -> torch.Tensor:
    return x if x.dim() == 4 else x[None]


def apply_fill(out: StereoOutput) -> StereoOutput:
    """The shared filling of ``--fill``: invalid pixels get :func:`fill_occlusions`' values, all valid."""
    from stereonet.select.fill import fill_occlusions

    disp = fill_occlusions(out.disparity, out.valid)
    valid = torch.isfinite(disp)
    return StereoOutput(torch.where(valid, disp, torch.zeros_like(disp)), valid, out.confidence,
                        out.uncertainty, None, out.extras)


def pair_metrics(out: StereoOutput, item: dict) -> dict[str, float]:
    """:func:`stereonet.metrics.evaluate` of one prediction against the item's ground truth (with SEE)."""
    from stereonet import metrics

    gt = _batch(item["disparity"]).to(out.disparity.device)  # its own dtype: metrics compute in float64
    occ = item.get("occlusion")
    with torch.no_grad():
        res = metrics.evaluate(out.disparity, gt, _batch(item["valid"]).bool(), pred_valid=out.valid,
                               occlusion=None if occ is None else _batch(occ).bool(), see=True)
        if out.uncertainty is not None or out.confidence is not None:
            # sparsification by the method's own uncertainty (preferred) or confidence
            rank = {"uncertainty": out.uncertainty} if out.uncertainty is not None else {"confidence": out.confidence}
            res["ause"] = metrics.sparsification_ause(out.disparity, gt, _batch(item["valid"]).bool(),
                                                      pred_valid=out.valid, **rank)
    return {k: float(v) for k, v in res.items()}


def _warm_up(fn: Callable, item: dict, max_disp: int) -> None:
    """One untimed call on a small crop (JIT compilation, weight loading); errors surface in the real call."""
    left, right = _batch(item["left"]).float(), _batch(item["right"]).float()
    h, w = left.shape[-2:]
    md = min(max_disp, 16)
    hh, ww = min(h, 32), min(w, md + 48)
    try:
        with torch.no_grad():
            fn(left[..., :hh, :ww].contiguous(), right[..., :hh, :ww].contiguous(), md)
    except Exception:  # noqa: BLE001 - the timed call reports it
        pass


def run_evaluation(methods: Sequence[str], specs: Sequence[str], max_disp: int | None = None, fill: bool = False,
                   shard: tuple[int, int] = (0, 1), plots: Path | None = None, progress: bool = True,
                   options: dict[str, dict] | None = None, load: Callable | None = None,
                   budget: float | None = None, pair_cap: float | None = None,
                   memory_budget: float | None = None, repeats: int = 1, align: bool = False) -> Evaluation:
    """Run every method on every pair of every dataset spec; return per-pair results and table rows.

    ``load`` (default :func:`stereonet.data.load_dataset`) maps a spec to a dataset of item dicts; it is
    called for every spec before anything runs, so a bad spec fails fast. ``options[name]`` are keyword
    options bound to matcher ``name``. ``budget``: once a method has used this many seconds on one dataset,
    its remaining pairs there are skipped (counted in the row's ``skipped`` key) - for benchmarks that must
    finish in bounded time. ``pair_cap``: a pair is skipped when the method's projected time for it exceeds
    this many seconds, projected from its median time per unit of work (H x W x (max_disp + 1)) so far.
    ``memory_budget`` (MiB): each matcher call runs within it, in overlapping strips when the pair needs more
    (:func:`stereonet.tiling.match_with_budget`); None = whole pairs.
    ``repeats``: each pair's calls are timed this many times, the methods interleaved round by round (a load burst
    then hits one sample of each method, not all samples of one), and the pair's ``seconds`` is the median; the
    metrics, output and peak memory come from the first round, and the caps count that median once per pair.
    ``align``: each pair's right view first goes through :func:`stereonet.geometry.align.auto_align` (a residual
    vertical offset removed, as infer.py does; the left view and its ground truth are unchanged), once for every
    method; ``Evaluation.aligned`` lists the pairs it corrected.
    """
    if isinstance(repeats, bool) or not isinstance(repeats, int) or repeats < 1:
        raise StereoInputError(f"repeats: expected an integer >= 1, got {repeats!r}")
    from tqdm import tqdm

    from stereonet import matchers

    if load is None:
        from stereonet.data import load_dataset as load
    datasets = [(dataset_label(s), load(s)) for s in specs]
    fns = {m: matchers.get_matcher(m, **(options or {}).get(m, {})) for m in methods}
    if memory_budget is not None:
        import functools

        from stereonet.tiling import match_with_budget

        fns = {m: functools.partial(match_with_budget, fn, budget_mib=memory_budget) for m, fn in fns.items()}
    i_shard, n_shard = shard
    indices = {label: [i for i in range(len(ds)) if i % n_shard == i_shard] for label, ds in datasets}
    total = sum(len(v) for v in indices.values()) * len(methods)
    result = Evaluation()
    warmed: set[str] = set()
    spent: dict[tuple[str, str], float] = {}
    rates: dict[str, list[float]] = {}  # seconds per H*W*(max_disp+1) of each method's runs so far
    with tqdm(total=total, desc="eval", unit="run", disable=not progress, file=sys.stderr,
              dynamic_ncols=True) as bar:
        for label, ds in datasets:
            for idx in indices[label]:
                try:
                    item = ds[idx]
                except BaseException:
                    bar.leave = False  # a bad file ends the run: its one-line error stands alone on stderr
                    bar.close()
                    raise
                name = str(item.get("name", idx))
                md = int(max_disp if max_disp is not None else item["max_disp"])
                if max_disp is not None and md >= item["left"].shape[-1]:  # the caller's range, not a method's fault
                    bar.leave = False
                    bar.close()
                    raise StereoInputError(f"--max-disp: expected less than the width of {label}/{name} "
                                           f"({item['left'].shape[-1]} px), got {md}")
                left, right = _batch(item["left"]).float(), _batch(item["right"]).float()
                if align:
                    from stereonet.geometry.align import auto_align

                    right, model, corrected = auto_align(left, right, md)
                    if corrected:
                        result.aligned.append((label, name, model.largest(right.shape[-1], right.shape[-2])))
                outs: dict[str, StereoOutput | None] = {}
                work = float(left.shape[-2] * left.shape[-1] * (md + 1))
                pending: list[tuple[str, tuple | None]] = []  # (method, _run_one's result or None = skipped)
                for m in methods:
                    bar.set_postfix_str(f"{label}/{name} {m}", refresh=False)
                    projected = float(np.median(rates[m])) * work if rates.get(m) else 0.0
                    if (budget is not None and spent.get((m, label), 0.0) > budget) or \
                            (pair_cap is not None and projected > pair_cap):
                        pending.append((m, None))
                        outs[m] = None
                        bar.update(1)
                        continue
                    if m not in warmed:
                        _warm_up(fns[m], item, md)
                        warmed.add(m)
                    res, out = _run_one(fns[m], left, right, md, item, fill)
                    pending.append((m, res))
                    outs[m] = out
                    bar.update(1)
                seconds = {m: [res[2]] for m, res in pending if res is not None and not math.isnan(res[2])}
                for r in range(1, repeats):  # timing rounds, methods interleaved
                    bar.set_postfix_str(f"{label}/{name} timing round {r + 1}/{repeats}", refresh=True)
                    for m in seconds:
                        seconds[m].append(_time_one(fns[m], left, right, md))
                for m, res in pending:
                    if res is None:
                        result.pairs.append(PairResult(m, label, name, None, None, math.nan, math.nan, skipped=True))
                        continue
                    if m in seconds:
                        res = (res[0], res[1], float(np.median(seconds[m])), *res[3:])
                        spent[(m, label)] = spent.get((m, label), 0.0) + res[2]
                        rates.setdefault(m, []).append(res[2] / work)
                    result.pairs.append(PairResult(m, label, name, *res, work=work))
                if plots is not None:
                    _plot_pair(plots / safe_name(label) / f"{safe_name(name)}.png", item, outs, md)
    result.rows = aggregate(result.pairs, methods, [label for label, _ in datasets])
    if plots is not None:
        plot_bad2(result.rows, plots / "bad2.png")
    return result


def _run_one(fn: Callable, left: torch.Tensor, right: torch.Tensor, max_disp: int, item: dict,
             fill: bool) -> tuple[tuple, StereoOutput | None]:
    """Run and measure one matcher call; failures come back as an error message, never an exception.

    Returns ``((metrics, raw_metrics, seconds, peak_mib, error), output)``.
    """
    try:
        with torch.no_grad(), PeakMemory() as mem, Stopwatch() as clock:
            out = fn(left, right, max_disp)
        raw = pair_metrics(out, item)
        if fill:
            out = apply_fill(out)
        return (pair_metrics(out, item) if fill else raw, raw, clock.seconds, mem.peak_mib, None), out
    except Exception as e:  # noqa: BLE001 - one failing method must not stop the comparison
        from stereonet.tiling import MemoryBudgetError

        if isinstance(e, MemoryBudgetError):  # the run's own argument, not the method: stop with one line
            raise
        msg = " ".join(str(e).split()) or "no message"
        return (None, None, math.nan, math.nan, f"{type(e).__name__}: {msg}"), None


def _time_one(fn: Callable, left: torch.Tensor, right: torch.Tensor, max_disp: int) -> float:
    """Seconds of one more call, measured as :func:`_run_one` measures the first (same memory hand-back)."""
    with torch.no_grad(), PeakMemory(), Stopwatch() as clock:
        fn(left, right, max_disp)
    return clock.seconds


def _mean(values: list[float]) -> float | None:
    values = [v for v in values if v is not None and not math.isnan(v)]
    return float(np.mean(values)) if values else None


def aggregate(pairs: Sequence[PairResult], methods: Sequence[str], datasets: Sequence[str]) -> list[dict]:
    """One row per (method, dataset): per-pair means of every metric, mean seconds, max peak MiB.

    With ``--fill`` the rows also carry ``density_raw`` and ``bad2_raw`` (before filling).
    """
    rows = []
    for d in datasets:
        for m in methods:
            sel = [p for p in pairs if p.method == m and p.dataset == d]
            ok = [p for p in sel if p.metrics is not None]
            keys = sorted({k for p in ok for k in p.metrics}, key=_key_order)
            row: dict = {"method": m, "dataset": d, "pairs": len(ok)}
            for k in keys:
                row[k] = _mean([p.metrics.get(k) for p in ok])
            for k in METRICS:
                row.setdefault(k, None)
            if any(p.raw_metrics is not p.metrics for p in ok):
                for k in ("density", "bad2"):
                    row[f"{k}_raw"] = _mean([p.raw_metrics.get(k) for p in ok])
            row["seconds"] = _mean([p.seconds for p in ok])
            peaks = [p.peak_mib for p in ok]
            row["peak_mib"] = float(max(peaks)) if peaks else None
            row["failed"] = sum(1 for p in sel if p.error)
            row["skipped"] = sum(1 for p in sel if p.skipped)
            errors = [p.error for p in sel if p.error]
            if errors:
                row["error"] = errors[0]
            rows.append(row)
    return rows


def _key_order(k: str) -> tuple[int, str]:
    base = k.split("_")[0]
    return (METRICS.index(base) if base in METRICS else len(METRICS), k)


# ---------------------------------------------------------------------------------------------- output

COLUMNS = (("EPE", "epe", "{:.2f}"), ("bad-1", "bad1", "{:.1f}"), ("bad-2", "bad2", "{:.1f}"),
           ("bad-4", "bad4", "{:.1f}"), ("D1", "d1", "{:.1f}"), ("dens", "density", "{:.1f}"),
           ("EPE-noc", "epe_noc", "{:.2f}"), ("bad-2-noc", "bad2_noc", "{:.1f}"), ("SEE", "see", "{:.2f}"),
           ("AUSE", "ause", "{:.2f}"), ("s/pair", "seconds", "{:.3f}"), ("MiB", "peak_mib", "{:.1f}"))


def format_table(rows: Sequence[dict]) -> str:
    """Plain-text table, one line per method and dataset; columns that no row has are dropped."""
    cols = [c for c in COLUMNS if any(r.get(c[1]) is not None for r in rows)]
    header = ["method", "dataset", "pairs"] + [c[0] for c in cols]
    lines = []
    for r in rows:
        mark = "!" if r.get("failed") else ""
        cells = [r["method"] + mark, r["dataset"], str(r["pairs"])]
        cells += ["-" if r.get(k) is None else fmt.format(r[k]) for _, k, fmt in cols]
        lines.append(cells)
    widths = [max(len(x) for x in col) for col in zip(header, *lines)]
    out = [" ".join(h.ljust(w) if i < 2 else h.rjust(w) for i, (h, w) in enumerate(zip(header, widths)))]
    out.append(" ".join("-" * w for w in widths))
    for cells in lines:
        out.append(" ".join(c.ljust(w) if i < 2 else c.rjust(w) for i, (c, w) in enumerate(zip(cells, widths))))
    notes = []
    for m in dict.fromkeys(r["method"] for r in rows if r.get("failed")):
        bad = [r for r in rows if r["method"] == m and r.get("failed")]
        where = ", ".join(f"{r['dataset']} ({r['failed']})" for r in bad)
        notes.append(f"! {m} failed on {where}: {bad[0].get('error', '')}")
    skipped = [f"{r['method']} on {r['dataset']} ({r['skipped']})" for r in rows if r.get("skipped")]
    if skipped:
        notes.append("pairs skipped (time budget): " + ", ".join(skipped))
    legend = ("EPE/SEE in px over predicted pixels; bad-t = % of GT pixels with error > t px, D1 = KITTI "
              "(>3 px and >5 %), both counting missing predictions as errors; dens = % of GT pixels predicted; "
              "-noc = non-occluded pixels only; per-pair means; s/pair and MiB = matcher call only.")
    return "\n".join(out + notes + [legend])


def safe_name(name: str) -> str:
    """A file-name-safe version of a dataset or pair name (what --plots uses for folders and files)."""
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in name).strip("_") or "pair"


def pair_panel(item: dict, outs: dict[str, StereoOutput | None], max_disp: int, per_row: int = 3) -> np.ndarray:
    """Picture of one pair: left | GT, then per method its colour disparity | its error map, ``per_row``
    such couples per row (rows stacked). Disparities share one colour scale (0..max_disp). uint8 (H', W', 3)."""
    from stereonet import viz
    from stereonet.io import to_uint8_rgb

    img = to_uint8_rgb(_batch(item["left"])[0])
    img = np.repeat(img[:, :, None], 3, axis=2) if img.ndim == 2 else img
    gt = _batch(item["disparity"])[0, 0].cpu().numpy()
    gt_valid = _batch(item["valid"])[0, 0].cpu().numpy().astype(bool)
    blank = np.full_like(img, 255)
    couples = [((img, "left"), (viz.colorize_disparity(gt, max_disp, gt_valid), "ground truth"))]
    for m, out in outs.items():
        if out is None:
            couples.append(((blank, f"{m}: failed/skipped"), (blank, "")))
            continue
        d = out.disparity[0, 0].float().cpu().numpy()
        v = out.valid[0, 0].cpu().numpy()
        couples.append(((viz.colorize_disparity(d, max_disp, v), m),
                        (viz.error_map(np.where(v, d, 0.0), gt, gt_valid, pred_valid=v), f"{m} error")))
    rows = []
    for i in range(0, len(couples), per_row):
        tiles = [t for c in couples[i:i + per_row] for t in c]
        tiles += [(blank, "")] * (2 * per_row - len(tiles)) if i else []
        rows.append(viz.panel([t[0] for t in tiles], [t[1] for t in tiles]))
    width = max(r.shape[1] for r in rows)
    rows = [np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0)), constant_values=255) for r in rows]
    return np.concatenate(rows, axis=0)


def _plot_pair(path: Path, item: dict, outs: dict[str, StereoOutput | None], max_disp: int) -> None:
    from stereonet import viz

    viz.save_png(path, pair_panel(item, outs, max_disp))


def plot_bad2(rows: Sequence[dict], path: Path, key: str = "bad2") -> None:
    """Grouped bar chart of ``key`` (bad-2 by default) per method, one bar per dataset (:func:`viz.plot_bars`)."""
    from stereonet import viz

    methods = list(dict.fromkeys(r["method"] for r in rows))
    value = {(r["method"], r["dataset"]): r.get(key) for r in rows}
    series = {d: [value.get((m, d)) for m in methods] for d in dict.fromkeys(r["dataset"] for r in rows)}
    viz.plot_bars(path, methods, series, ylabel=f"{key} (% of GT pixels, lower is better)",
                  title=f"{key} per method")


def write_json(path: Path, rows: Sequence[dict]) -> None:
    from stereonet.io.atomic import atomic_write_text

    atomic_write_text(path, json.dumps(list(rows), indent=2) + "\n")
