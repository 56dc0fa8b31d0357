"""eval.py: every registered method on the same datasets, one table of standard metrics.

    python eval.py --methods A,B,...|all --data SPEC[,SPEC...] [--max-disp N] [--json FILE] [--plots DIR]
                   [--fill] [--shard i/n] [--budget SECONDS]

SPEC is ``synthetic[:N]``, ``middlebury2001:DIR``, ``middlebury2003:DIR``, ``middlebury2006:DIR`` (2005 and
2006 scenes, full/half/third size), ``middlebury2014:DIR``, ``kitti2012:DIR``, ``kitti2015:DIR``, ``eth3d:DIR``
(two-view training), ``sceneflow[-clean|-final][-train|-test]:DIR`` (FlyingThings3D, Monkaa, Driving; final
pass and every pair by default, ``-clean`` the clean pass, ``-train``/``-test`` FlyingThings3D's official
split, e.g. ``sceneflow-clean-test:DIR``), ``folder:DIR``, or ``real`` (every dataset in ../shared/data, one
table row per dataset). The engine is :mod:`stereonet.evaluation` (this module parses arguments). Datasets come from :func:`stereonet.data.load_dataset`, metrics from
:func:`stereonet.metrics.evaluate`; a missing, truncated or corrupt dataset file is bad input (exit 2, one
line naming the file).

What the numbers mean:
- Rates (bad-1/2/4, D1, density) are percentages 0-100. EPE is in pixels. Every metric is computed per pair
  over the pixels with ground truth and then averaged over the pairs (per-image averaging, as the Middlebury
  tables do; KITTI's devkit pools the pixels of all images instead, so a KITTI row here is comparable with
  published KITTI numbers only for a single pair).
- bad-t and D1 count the pixels a method leaves invalid as errors; EPE and SEE have no value for them and
  average the predicted pixels only, so read them with ``density`` (the share of GT pixels predicted), as
  :mod:`stereonet.metrics` defines. ``*_noc`` (non-occluded) and ``*_occ`` metrics appear when the dataset
  has an occlusion mask; the table shows EPE-noc and bad-2-noc, the JSON every key. ``--fill`` applies one
  shared filling (:func:`stereonet.select.fill.fill_occlusions`) to every method's invalid pixels for a
  dense comparison.
- SEE (soft edge error, SMD-Nets) is computed for every method from its disparity on the ground truth's
  depth-discontinuity pixels (not only for methods with a mixture head), so edge sharpness compares across
  all methods alike.
- ``seconds`` is the wall time per pair of the matcher call alone (not loading, filling or metrics), after one
  untimed warm-up call per method on a small crop (JIT compilation and weight loading excluded).
- ``peak_mib`` is the largest extra resident memory of one matcher call over the pairs (see
  :mod:`stereonet.measure` for how it is measured and its limits).

``--methods all`` leaves out learned methods whose trained weights are missing (a note says which); naming
one explicitly is an error. ``--budget S`` bounds slow methods: once a method has spent S seconds on one
dataset, its remaining pairs there are skipped (``skipped`` in the row). ``--shard i/n`` keeps the pairs
whose index is i modulo n.

A method that raises on a pair does not stop the run: the pair is counted in the row's ``failed`` key, the
first error message is kept in ``error``, the metrics average the pairs that worked, and the table marks the
row with ``!`` and prints the errors below it. The exit code is 0 when every method ran on every pair, 1 when
any failed, 2 for bad input (unknown method, missing dataset...), which is reported as one line.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from pathlib import Path

from stereonet.checks import StereoInputError
from stereonet.cli.common import USER_ERRORS, OneLineParser, check_output_path, fail
from stereonet.evaluation import (  # noqa: F401 - the engine (a library module), re-exported for callers
    METRICS,
    Evaluation,
    PairResult,
    apply_fill,
    dataset_label,
    expand_data_specs,
    format_table,
    parse_methods,
    parse_shard,
    run_evaluation,
    write_json,
)
from stereonet.measure import reuse_freed_memory

PROG = "eval.py"


# ------------------------------------------------------------------------------------------------ main

def build_parser() -> OneLineParser:
    p = OneLineParser(prog=PROG, description="Evaluate stereo methods on datasets with ground truth: one table.")
    p.add_argument("--methods", required=True, help="comma-separated registered names, or 'all'")
    p.add_argument("--data", required=True,
                   help="SPEC[,SPEC...]: synthetic[:N], middlebury2001:DIR, middlebury2003:DIR, middlebury2006:DIR, "
                        "middlebury2014:DIR, kitti2012:DIR, kitti2015:DIR, eth3d:DIR, "
                        "sceneflow[-clean|-final][-train|-test]:DIR (default final pass, all pairs), folder:DIR, "
                        "or real (every dataset in ../shared/data)")
    p.add_argument("--max-disp", type=int, default=None, help="disparity range (default: each pair's own)")
    p.add_argument("--json", type=Path, default=None, help="write the rows as a JSON list to this file")
    p.add_argument("--plots", type=Path, default=None, help="write per-pair panels and a bad-2 bar chart here")
    p.add_argument("--fill", action="store_true", help="fill every method's invalid pixels the same way")
    p.add_argument("--shard", default=None, help="evaluate only pairs with index %% n == i (i/n)")
    p.add_argument("--budget", type=float, default=None,
                   help="seconds a method may spend on one dataset; its remaining pairs there are skipped")
    p.add_argument("--memory-budget", type=float, default=None, metavar="MIB",
                   help="extra memory one matcher call may use; larger pairs run in overlapping strips of rows "
                        "(default: whole pairs)")
    p.add_argument("--align", action="store_true",
                   help="remove a residual vertical offset of each pair's right view first, as infer.py does "
                        "(the left view and the ground truth are unchanged)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    reuse_freed_memory()  # large buffers from the heap, reused instead of mapped afresh (stereonet.measure)
    try:
        skipped: list[str] = []
        methods = parse_methods(args.methods, skipped)
        if skipped:
            print(f"{PROG}: note: skipping {', '.join(skipped)} (trained weights missing)", file=sys.stderr)
        notes: list[str] = []
        specs = expand_data_specs(args.data, notes=notes)
        for note in notes:
            print(f"{PROG}: note: {note}", file=sys.stderr)
        shard = parse_shard(args.shard)
        if args.max_disp is not None and args.max_disp <= 0:
            raise StereoInputError(f"--max-disp: expected a positive integer, got {args.max_disp}")
        if args.fill:
            import stereonet.select.fill  # noqa: F401 - fail now, not after the first pair
        if args.budget is not None and not args.budget > 0:
            raise StereoInputError(f"--budget: expected a positive number of seconds, got {args.budget}")
        if args.memory_budget is not None and not args.memory_budget > 0:
            raise StereoInputError(f"--memory-budget: expected a positive number of MiB, got {args.memory_budget}")
        if args.json is not None:  # checked now, not after the whole run
            check_output_path(args.json, "--json", folder=False)
        if args.plots is not None:
            check_output_path(args.plots, "--plots", folder=True)
        ev = run_evaluation(methods, specs, args.max_disp, args.fill, shard, args.plots, not args.no_progress,
                            budget=args.budget, memory_budget=args.memory_budget, align=args.align)
    except USER_ERRORS as e:
        return fail(PROG, e)
    except ImportError as e:
        return fail(PROG, f"{e} (this part of stereonet is not installed)")
    except KeyboardInterrupt:
        return fail(PROG, "interrupted", 130)
    for dataset, pair, offset in ev.aligned:
        print(f"{PROG}: note: {dataset}/{pair}: right view aligned (residual vertical offset up to {offset:.2f} px)",
              file=sys.stderr)
    scored = {p.dataset for p in ev.pairs if p.metrics and not math.isnan(p.metrics.get("bad2", math.nan))}
    for dataset in dict.fromkeys(p.dataset for p in ev.pairs if p.metrics is not None and p.dataset not in scored):
        print(f"{PROG}: note: {dataset} has no ground truth; only times and memory are reported", file=sys.stderr)
    print(format_table(ev.rows))
    if args.json is not None:
        write_json(args.json, ev.rows)
    return 1 if any(r["failed"] for r in ev.rows) else 0


if __name__ == "__main__":
    sys.exit(main())
