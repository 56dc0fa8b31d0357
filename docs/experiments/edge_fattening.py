"""Issue 14, thirty-first session: what kind of error each method makes near depth edges (reports, decides nothing).

Within RADIUS px of a ground-truth depth discontinuity (stereonet.models.siamese.edge_maps, as the depth-edge
training samples use): bad-2 after eval.py's fill, the share of those errors that took the other side's disparity
(within 2 px of the window's farthest disparity: the edge bled across) and the share larger than the truth (the
nearer surface bled into the farther one: foreground fattening). Pooled over each set's pairs.
    python docs/experiments/edge_fattening.py "sgm,siamese-census-sgm,sgm-refine" "real;val2aa;val4aa" [RADIUS]
"""
import sys

import torch

sys.path.insert(0, "docs/experiments")
from val_sets import expand, items  # noqa: E402

from stereonet import matchers  # noqa: E402
from stereonet.evaluation import _batch, apply_fill  # noqa: E402
from stereonet.models.siamese import edge_maps  # noqa: E402

methods = [matchers.register_checkpoint_variant(arg) for arg in sys.argv[1].split(",")]
groups = sys.argv[2].split(";")
radius = int(sys.argv[3]) if len(sys.argv) > 3 else 4
torch.set_num_threads(2)
print("| set | method | near-edge pixels | near-edge bad-2 | of which the other side's value | of which larger than truth |")
for group in groups:
    specs = expand(group)
    counts = {m: [0, 0, 0, 0] for m in methods}
    for _, item in items(specs):
        left, right = _batch(item["left"]).float(), _batch(item["right"]).float()
        gt, gv = _batch(item["disparity"]).float(), _batch(item["valid"]).bool()
        near, other = edge_maps(gt, gv, radius)
        for m in methods:
            d = apply_fill(matchers.match(m, left, right, int(item["max_disp"]))).disparity
            wrong = ((d - gt).abs() > 2) & near
            c = counts[m]
            c[0] += int(near.sum())
            c[1] += int(wrong.sum())
            c[2] += int((wrong & ((d - other).abs() <= 2)).sum())
            c[3] += int((wrong & (d > gt)).sum())
    for m, (n, w, o, f) in counts.items():
        print(f"| {group} | {m} | {n} | {100 * w / max(n, 1):.1f} | {100 * o / max(w, 1):.1f} | {100 * f / max(w, 1):.1f} |",
              flush=True)
