"""Probe (data_gen only, no training): how much would semi-global aggregation of the shipped dispnet.pt's 1/4
volume help its matching stage? For each pair of val2k / val4k (seeds 5172 / 5173, see val_sets.py) the network's 1/4
logits (census correlation + 3-D aggregation, what its soft-argmax reads) are taken as they are, or aggregated by
the project's hard SGM (4 paths, cost = -logits, a few fixed penalty pairs), and read out by WTA / soft-argmax;
each 1/4 map is upsampled to full resolution and scored (bad-2 / bad-8 %, mean over pairs), beside the network's
final output. Run: python docs/experiments/sga_probe.py [weights]"""
import sys

import torch
import torch.nn.functional as F

import stereonet.models.dispnet as dn
from stereonet.aggregate.sgm import sgm_aggregate
from stereonet.matchers.learned import _downscale_to_range
from stereonet.models.layers import resize_disparity
from stereonet.models.weights import load_weights

sys.path.insert(0, "docs/experiments")
from val_sets import load  # noqa: E402

PENALTIES = [(1.0, 4.0), (4.0, 16.0), (8.0, 32.0), (16.0, 64.0)]  # logit units (corr_scale ~ see output)


def score(d, padder, gt, valid):
    """d: a map of the padded input (any stride) in its input pixels -> bad-2 / bad-8 % at gt's resolution."""
    up = padder.unpad(F.interpolate(d, size=(padder.height + padder.pad_h, padder.width + padder.pad_w),
                                    mode="bilinear", align_corners=False))
    up = resize_disparity(up, *gt.shape[-2:])
    err = (up[0, 0] - gt).abs()[valid]
    return 100 * float((err > 2).float().mean()), 100 * float((err > 8).float().mean())


def main(path="docs/experiments/weights/dispnet_shipped22.pt"):
    net, _ = load_weights(path)
    captured = {}
    original = dn.soft_argmax

    def capture(logits, *a, **k):
        captured["logits"] = logits
        return original(logits, *a, **k)

    dn.soft_argmax = capture
    for spec in ("val2k", "val4k"):
        ds = load(spec)
        rows = {}
        for i in range(len(ds)):
            item = ds[i]
            l, r = item["left"][None], item["right"][None]
            sl, sr, _ = _downscale_to_range(l, r, item["max_disp"], net.max_disp)
            with torch.no_grad():
                out, padder = dn.run_padded(net, sl, sr)
            gt, valid = item["disparity"][0], item["valid"][0]
            logits = captured["logits"]
            maps = {"soft-argmax (the network's)": original(logits) * 4.0,
                    "WTA": logits.argmax(dim=1, keepdim=True).float() * 4.0}
            for p1, p2 in PENALTIES:
                agg = sgm_aggregate(-logits, p1, p2, paths=4)
                maps[f"SGM P1={p1} P2={p2} WTA"] = agg.argmin(dim=1, keepdim=True).float() * 4.0
            maps["final output"] = out.disparity
            for name, d in maps.items():
                rows.setdefault(name, []).append(score(d, padder, gt, valid))
        print(f"{spec} ({len(ds)} pairs): bad-2 / bad-8 % at full resolution, mean over pairs")
        for name, vals in rows.items():
            b2 = sum(v[0] for v in vals) / len(vals)
            b8 = sum(v[1] for v in vals) / len(vals)
            print(f"  {name:34s} {b2:5.1f} / {b8:5.1f}")


if __name__ == "__main__":
    main(*sys.argv[1:])
