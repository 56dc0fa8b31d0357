"""Issue 14, thirty-second session: the image-guided weighted median (stereonet.select.filters.weighted_median_filter)
after a matcher's filled map, on data_gen sets (the rule of docs/experiments/wmf.txt) or on the real pairs
(evaluation only). Each method runs once per pair; every filter setting is applied to that filled map and scored with
eval.py's metrics. Prints, per set, the mean bad-2 / EPE / SEE of each (method, setting), and the near-edge bad-2
(within 4 px of a ground-truth depth edge) with the share of those errors larger than the truth (fattening).
For sgm-refine the filter under test replaces the matcher's own (run with wmf_radius=0, the choice itself), so
"off" is the choice alone, as in the runs recorded in docs/experiments/wmf.txt (made before the matcher had a filter).
Run: python docs/experiments/wmf_probe.py "sgm,sgm-refine" "val2;val4" "off,5:0.1,9:0.1,9:0.2:2:5"
(radius:sigma_color, or radius:sigma_color:stride:band; see weighted_median_filter)"""
import statistics
import sys

import torch

sys.path.insert(0, "docs/experiments")
from val_sets import expand, items  # noqa: E402

from stereonet import matchers  # noqa: E402
from stereonet.evaluation import apply_fill, pair_metrics  # noqa: E402
from stereonet.metrics import depth_discontinuities  # noqa: E402
from stereonet.select.filters import weighted_median_filter  # noqa: E402
from stereonet.types import StereoOutput  # noqa: E402

methods = [matchers.register_checkpoint_variant(a) for a in sys.argv[1].split(",")]
specs = expand(sys.argv[2])
settings = sys.argv[3].split(",")
rows, pairs = {}, {}
for spec, item in items(specs):
    left, right = item["left"][None], item["right"][None]
    md = int(item["max_disp"])
    gt, gv = item["disparity"][None], item["valid"][None]
    near = torch.nn.functional.max_pool2d(depth_discontinuities(gt, gv).float(), 9, 1, 4) > 0
    near &= gv
    for m in methods:
        with torch.no_grad():
            # sgm-refine's own filter off: the settings are applied to its choice, as when they were selected
            out = apply_fill(matchers.match(m, left, right, md, **({"wmf_radius": 0} if m == "sgm-refine" else {})))
        for s in settings:
            if s == "off":
                d = out.disparity
            else:
                r, sc, *more = s.split(":")  # radius:sigma_color[:stride:band]
                extra = dict(stride=int(more[0]), band=int(more[1])) if more else {}
                d = weighted_median_filter(out.disparity, left, radius=int(r), sigma_color=float(sc), **extra)
            res = StereoOutput(d, torch.ones_like(d, dtype=torch.bool))
            met = pair_metrics(res, item)
            err = d - gt
            bad = near & (err.abs() > 2)
            fat = float((bad & (err > 0)).sum()) / max(1, int(bad.sum()))
            pairs.setdefault((m, s), []).append((spec, item.get("name", "?"), met["bad2"]))
            rows.setdefault((m, s, spec), []).append((met["bad2"], met["epe"], met["see"],
                                                      100.0 * float(bad.sum()) / max(1, int(near.sum())), 100 * fat))
print("| method | wmf | set | pairs | mean bad-2 | mean EPE | mean SEE | near-edge bad-2 | fattening share |")
print("|---|---|---|---|---|---|---|---|---|")
for (m, s, spec), vals in rows.items():
    see = [v[2] for v in vals if v[2] == v[2]]
    print(f"| {m} | {s} | {spec} | {len(vals)} | {statistics.fmean(v[0] for v in vals):.2f} | "
          f"{statistics.fmean(v[1] for v in vals):.3f} | {statistics.fmean(see) if see else float('nan'):.3f} | "
          f"{statistics.fmean(v[3] for v in vals):.1f} | {statistics.fmean(v[4] for v in vals):.1f} |")
print("| method | wmf | each pair's bad-2 (in order) | median |")
for (m, s), vals in pairs.items():
    print(f"| {m} | {s} | {' / '.join(f'{v[2]:.2f}' for v in vals)} | {statistics.median(v[2] for v in vals):.2f} |")
