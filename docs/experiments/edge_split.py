"""Issue 14, twenty-ninth session: bad-2 after eval.py's fill near ground-truth depth edges and far from them.

"Near" = within RADIUS px (Chebyshev) of a depth discontinuity (stereonet.metrics.depth_discontinuities, jumps of
more than 1 px, dilated by a (2 RADIUS + 1) box), "far" = every other pixel with ground truth. Per set: the share of
near pixels and the mean over pairs of each region's bad-2 (% of that region's ground-truth pixels). The twenty-eighth
session measured the same split as a one-off probe (docs/experiments/siamese_edges.txt); this is it as a script.
Reports, decides nothing.
    python docs/experiments/edge_split.py "label=method@weights.pt,..." "val2u;val4u" [RADIUS]
"""
import statistics
import sys

import torch

sys.path.insert(0, "docs/experiments")
from val_sets import expand, items  # noqa: E402

from stereonet import matchers  # noqa: E402
from stereonet.evaluation import _batch, apply_fill  # noqa: E402
from stereonet.metrics import bad_pixel_rate, depth_discontinuities  # noqa: E402

methods = [matchers.register_checkpoint_variant(arg) for arg in sys.argv[1].split(",")]
specs = expand(sys.argv[2])
radius = int(sys.argv[3]) if len(sys.argv) > 3 else 4
torch.set_num_threads(2)
rows = {}
for spec, item in items(specs):
    gt, gv = _batch(item["disparity"]).float(), _batch(item["valid"]).bool()
    near = depth_discontinuities(gt, gv, threshold=1.0, dilation=2 * radius + 1) & gv
    far = gv & ~near
    for m in methods:
        with torch.no_grad():
            out = apply_fill(matchers.match(m, _batch(item["left"]).float(), _batch(item["right"]).float(),
                                            int(item["max_disp"])))
        r = rows.setdefault((m, spec), {"near": [], "far": [], "share": [], "all": []})
        for region, mask in (("near", near), ("far", far), ("all", gv)):
            if bool(mask.any()):
                r[region].append(bad_pixel_rate(out.disparity, gt, gv, 2.0, out.valid, mask))
        r["share"].append(100.0 * float(near.sum()) / max(1.0, float(gv.sum())))
print(f"bad-2 after fill, mean over pairs; near = within {radius} px of a depth edge")
print("| method | set | pairs | near-edge share of pixels | bad-2 near | bad-2 far | bad-2 all |")
print("|---|---|---|---|---|---|---|")
for (m, spec), r in rows.items():
    print(f"| {m} | {spec} | {len(r['all'])} | {statistics.fmean(r['share']):.1f} % | {statistics.fmean(r['near']):.2f} | "
          f"{statistics.fmean(r['far']):.2f} | {statistics.fmean(r['all']):.2f} |")
