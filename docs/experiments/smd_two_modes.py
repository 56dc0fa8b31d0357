"""Issue 14 item 3(a), twenty-eighth session probe (no training): do the shipped SMD head's two modes hold sharper
edges than the mode it picks? Per pair, bad-2 / SEE of dispnet (the backbone), smd, smd with the mode picked by the
pixelwise census 7x7 cost at each mode where they differ by more than 1 px ("census-pick"), and the oracle that
picks the mode closer to the ground truth (a bound, not a method). Results in smd_two_modes.txt.

    python docs/experiments/smd_two_modes.py val2o|real
"""
import statistics
import sys

import torch
from val_sets import load

from stereonet.cost.volume import build_cost_volume
from stereonet.data import load_dataset
from stereonet.evaluation import expand_data_specs
from stereonet.matchers import get_matcher
from stereonet.metrics import soft_edge_error


def lookup(vol, d):
    """The cost volume (B, D, H, W) at continuous disparities d (B, 1, H, W), linearly interpolated."""
    d = d.clamp(0, vol.shape[1] - 1)
    lo = d.floor().long()
    hi = (lo + 1).clamp(max=vol.shape[1] - 1)
    f = d - lo
    return vol.gather(1, lo) * (1 - f) + vol.gather(1, hi) * f


def items(spec):
    if spec == "real":
        for s in expand_data_specs("real"):
            ds = load_dataset(s)
            for i in range(len(ds)):
                yield f"{s.split(':')[0]}/{i}", ds[i]
    else:
        ds = load(spec)
        for i in range(len(ds)):
            yield f"{spec}/{i}", ds[i]


def main():
    torch.set_num_threads(2)
    smd, dispnet = (get_matcher(m, lr_check=False, wmf_radius=0) for m in ("smd", "dispnet"))  # disparity only
    totals = {}
    for name, it in items(sys.argv[1]):
        left, right, md = it["left"][None].float(), it["right"][None].float(), int(it["max_disp"])
        gt, valid = it["disparity"][None], it["valid"][None].bool()
        out = smd(left, right, md)
        mu1, mu2 = out.extras["mu1"], out.extras["mu2"]
        vol = build_cost_volume(left, right, md, "census", window=1, census_window=7)
        c1, c2 = lookup(vol, mu1), lookup(vol, mu2)
        census_pick = torch.where((mu1 - mu2).abs() > 1, torch.where(c1 <= c2, mu1, mu2), out.disparity)
        oracle = torch.where((mu1 - gt).abs() <= (mu2 - gt).abs(), mu1, mu2)
        res = {}
        for k, d in [("dispnet", dispnet(left, right, md).disparity), ("smd", out.disparity),
                     ("census-pick", census_pick), ("oracle", oracle)]:
            res[k] = (float(((d - gt).abs() > 2)[valid].float().mean() * 100), soft_edge_error(d, gt, valid))
            totals.setdefault(k, []).append(res[k])
        print(name, " ".join(f"{k} {b:.1f}/{s:.2f}" for k, (b, s) in res.items()), flush=True)
    for k, vals in totals.items():
        print("MEAN", k, f"bad2 {statistics.fmean(b for b, _ in vals):.2f} "
              f"SEE {statistics.fmean(s for _, s in vals if s == s):.3f}")


if __name__ == "__main__":
    main()
