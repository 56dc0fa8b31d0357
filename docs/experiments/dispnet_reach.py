"""Where `dispnet`'s bad-2 pixels come from (a diagnostic; no decision, no training).

For every pair of the given sets: the shipped census DispNet's final map (pixels off by > 2 px, valid ground truth),
split into pixels near a ground-truth depth jump (within ``EDGE`` px of a jump > 1 px) and interior pixels; the
interior ones further by the error of the 1/4 stage's prediction ``d2`` (bilinear to full size) at that pixel:
``> REACH`` px means the fine stages could not have reached the answer by their local searches (the 1/2 stage
searches +-2 of its pixels = +-4 input px, the 1/1 stage +-2 px), ``<= REACH`` means the answer was within reach.

    python docs/experiments/dispnet_reach.py "val2ai;val4ai"

Prints per pair and in sum: bad-2 of d0, of d2 (upsampled), shares of the bad-2 pixels, and on how many of the
unreachable pixels `sgm` (filled as eval.py --fill) is within 2 px.
"""
import sys

import torch
import torch.nn.functional as F
import val_sets

from stereonet.matchers import get_matcher
from stereonet.matchers.learned import _downscale_to_range, load_network
from stereonet.metrics import depth_discontinuities
from stereonet.models.dispnet import run_padded
from stereonet.select.fill import fill_occlusions

EDGE = 4
REACH = 6.0


def main(arg: str, checkpoint: str | None = None):
    graph = load_network("dispnet", checkpoint).eval()
    totals = torch.zeros(7)
    for spec, item in val_sets.items(val_sets.expand(arg)):
        left, right = item["left"][None], item["right"][None]
        gt, valid = item["disparity"][None], item["valid"][None]
        h, w = left.shape[-2:]
        small_l, small_r, scale = _downscale_to_range(left, right, item["max_disp"], graph.max_disp)
        with torch.no_grad():
            out, padder = run_padded(graph, small_l, small_r)
        d0 = padder.unpad(out.disparity)
        hp, wp = out.disparity.shape[-2:]
        d2 = F.interpolate(out.pyramid[2], size=(hp, wp), mode="bilinear", align_corners=False)
        d2 = padder.unpad(d2)
        if scale < 1.0:
            d0 = F.interpolate(d0, size=(h, w), mode="bilinear", align_corners=False) / scale
            d2 = F.interpolate(d2, size=(h, w), mode="bilinear", align_corners=False) / scale
        err0, err2 = (d0 - gt).abs(), (d2 - gt).abs()
        edge = depth_discontinuities(gt, valid, threshold=1.0, dilation=2 * EDGE + 1)
        bad = (err0 > 2) & valid
        sgm = get_matcher("sgm")(left, right, item["max_disp"])
        sgm_ok = (fill_occlusions(sgm.disparity, sgm.valid) - gt).abs() <= 2
        unreachable = bad & ~edge & (err2 > REACH)
        row = torch.tensor([valid.sum(), bad.sum(), (bad & edge).sum(), unreachable.sum(),
                            ((err2 > 2) & valid).sum(), (unreachable & sgm_ok).sum(),
                            (unreachable & (err2 <= 2 * REACH)).sum()], dtype=torch.float64)
        totals += row
        n = row[0]
        print(f"{spec:10s} {item['name']:24s} bad2 {100 * row[1] / n:6.2f}  d2 bad2 {100 * row[4] / n:6.2f}  "
              f"of bad: edge {100 * row[2] / row[1]:5.1f}%  interior unreachable {100 * row[3] / row[1]:5.1f}%  "
              f"interior reachable {100 * (row[1] - row[2] - row[3]) / row[1]:5.1f}%  "
              f"sgm right on {100 * row[5] / row[3]:5.1f}% of the unreachable", flush=True)
    n = totals[0]
    print(f"ALL bad2 {100 * totals[1] / n:.2f}  d2 bad2 {100 * totals[4] / n:.2f}  of bad: edge "
          f"{100 * totals[2] / totals[1]:.1f}%  interior unreachable {100 * totals[3] / totals[1]:.1f}%  "
          f"interior reachable {100 * (totals[1] - totals[2] - totals[3]) / totals[1]:.1f}%  "
          f"sgm right on {100 * totals[5] / totals[3]:.1f}% of the unreachable; "
          f"{100 * totals[6] / totals[3]:.1f}% of the unreachable within {2 * REACH:g} px")


if __name__ == "__main__":
    main(*sys.argv[1:])
