"""Issue 14 item 3(b), a second reading (evaluation only): does SMD's uncertainty rank SMD's own errors better than
a classical confidence computed for the same map would?

For each real pair: SMD's disparity, ranked (1) by its own uncertainty (the chosen mode's Laplacian scale, what
eval.py's AUSE column uses) and (2) by the left-right disagreement of the same network, |d_L(x) - d_R(round(x -
d_L(x)))| with d_R from SMD run on the mirrored, swapped pair (stereonet.select.left_right_difference, the
quantity the left-right check thresholds; outside the right image = least trusted). ``dispnet`` (no uncertainty) gets (2) as a
reference. Bad-2 sparsification AUSE (stereonet.metrics.sparsification_ause), all GT pixels.

    python docs/experiments/smd_ause_lr.py > docs/experiments/smd_ause_lr.txt
"""
import statistics

import torch

from stereonet import matchers, metrics
from stereonet.data import load_dataset
from stereonet.select import left_right_difference


def main() -> None:
    torch.set_num_threads(2)
    ds = load_dataset("real")
    rows = {}
    for i in range(len(ds)):
        item = ds[i]
        left, right = item["left"][None], item["right"][None]
        gt, valid, max_disp = item["disparity"][None], item["valid"][None].bool(), int(item["max_disp"])
        name = str(item["name"])
        for method in ("smd", "dispnet"):
            plain = {"lr_check": False, "wmf_radius": 0}  # as recorded: no check, no filter
            out = matchers.match(method, left, right, max_disp, **plain)
            mirrored = matchers.match(method, right.flip(-1), left.flip(-1), max_disp, **plain)
            disp_right = mirrored.disparity.flip(-1)
            lr = left_right_difference(out.disparity, disp_right)
            r = rows.setdefault(method, {})
            r[name] = {"bad2": metrics.bad_pixel_rate(out.disparity, gt, valid, 2.0),
                       "lr": metrics.sparsification_ause(out.disparity, gt, valid, uncertainty=lr)}
            if out.uncertainty is not None:
                r[name]["own"] = metrics.sparsification_ause(out.disparity, gt, valid, uncertainty=out.uncertainty)
    names = list(rows["smd"])
    print("| method, ranking | " + " | ".join(names) + " | median |")
    print("|---|" + "---|" * (len(names) + 1))
    for method, key, label in (("smd", "bad2", "smd bad-2"), ("smd", "own", "smd AUSE, own uncertainty"),
                               ("smd", "lr", "smd AUSE, left-right disagreement"), ("dispnet", "bad2", "dispnet bad-2"),
                               ("dispnet", "lr", "dispnet AUSE, left-right disagreement")):
        vals = [rows[method][n][key] for n in names]
        print(f"| {label} | " + " | ".join(f"{v:.2f}" for v in vals) + f" | {statistics.median(vals):.2f} |")


if __name__ == "__main__":
    main()
