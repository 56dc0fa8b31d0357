"""SMD's continuous output resolution on real pairs (issue 14, item 3c): the pair downscaled 2x, then
- smd-half-query2x: the head queried on a grid 2x the input (upsample=2) -> back at full resolution;
- smd-half-nearest / smd-half-bilinear: the same network at 1x, the disparity map upsampled 2x afterwards;
- smd (full): the full-resolution pair at 1x (the reference the half-size runs try to reach).
All without smd's left-right check (its default since the thirty-sixth session) and its weighted median (since the
thirty-seventh), as this table was recorded; ``--now`` runs smd as it runs by default (check, fill, filter: every
pixel valid). Each scored at full resolution against the full-resolution ground truth (bad-2 after the shared fill,
SEE).

    python docs/experiments/smd_output_scale.py [--now] [SPECS]     (default: real)
"""
import statistics
import sys

import torch
import torch.nn.functional as F

from stereonet import matchers
from stereonet.evaluation import expand_data_specs, run_evaluation
from stereonet.matchers import register
from stereonet.types import StereoOutput

NOW = "--now" in sys.argv[1:]
ARGS = [a for a in sys.argv[1:] if a != "--now"]
OPTS = {} if NOW else {"lr_check": False, "wmf_radius": 0}  # as recorded, or as smd runs by default


def _half(left, right):
    h, w = left.shape[-2:]
    size = (round(h / 2), round(w / 2))
    return F.interpolate(left, size=size, mode="area"), F.interpolate(right, size=size, mode="area")


def query2x(left, right, max_disp):
    sl, sr = _half(left, right)
    out = matchers.match("smd", sl, sr, max(1, max_disp // 2), upsample=2.0, **OPTS)
    h, w = left.shape[-2:]
    d = out.disparity
    if d.shape[-2:] != (h, w):  # odd sizes: one row/column of rounding
        ratio = w / d.shape[-1]
        d = F.interpolate(d, size=(h, w), mode="nearest") * ratio
    return StereoOutput(d, torch.ones_like(d, dtype=torch.bool))


def upsampled(mode):
    def fn(left, right, max_disp):
        sl, sr = _half(left, right)
        out = matchers.match("smd", sl, sr, max(1, max_disp // 2), **OPTS)
        h, w = left.shape[-2:]
        ratio = w / out.disparity.shape[-1]
        kw = {} if mode == "nearest" else {"align_corners": False}
        d = F.interpolate(out.disparity, size=(h, w), mode=mode, **kw) * ratio
        return StereoOutput(d, torch.ones_like(d, dtype=torch.bool))
    return fn


register("smd-half-query2x", kind="learned", description="exp")(query2x)
register("smd-half-nearest", kind="learned", description="exp")(upsampled("nearest"))
register("smd-half-bilinear", kind="learned", description="exp")(upsampled("bilinear"))
register("smd-full", kind="learned", description="exp")(lambda left, right, max_disp: matchers.match(
    "smd", left, right, max_disp, **OPTS))
methods = ["smd-full", "smd-half-query2x", "smd-half-nearest", "smd-half-bilinear"]
specs = expand_data_specs(ARGS[0] if ARGS else "real")
ev = run_evaluation(methods, specs, fill=True, progress=False)
rows = {}
for p in ev.pairs:
    rows.setdefault(p.method, {})[f"{p.dataset}/{p.pair}"] = p.metrics
pairs = list(rows["smd-full"])
for key in ("bad2", "see"):
    print(f"\n{key} per pair")
    print("| method | " + " | ".join(pairs) + " | median |")
    print("|---|" + "---|" * (len(pairs) + 1))
    for m in methods:
        vals = [rows[m][k][key] for k in pairs]
        finite = [v for v in vals if v == v]  # SEE is nan on a pair without measurable depth edges
        print(f"| {m} | " + " | ".join(f"{v:.2f}" for v in vals) + f" | {statistics.median(finite):.2f} |")
