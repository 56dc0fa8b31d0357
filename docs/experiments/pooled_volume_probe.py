"""Probe (data_gen only, no training; decides only whether to build): is `dispnet`'s 1/4 matching evidence better when
the census is compared at full resolution and pooled to 1/4, instead of compared on the 1/4-downsampled image?

Why: the thirty-fourth session's diagnostic (docs/experiments/dispnet_reach.py) put 55 % of the shipped network's
bad-2 pixels on interior pixels whose 1/4 answer is off by more than 6 px, and the SGA probe (sga_probe.py) found the
1/4 census volume of the downsampled image to be the limit, not missing aggregation over it. At 1/4 a 5x5 census
compares cells of 4x4 px means: fine texture (what SGM matches on the photos) is averaged away before any comparison.

Volumes compared (each pair downscaled to the network's range first, as `dispnet` runs; same 4 census groups):
- ``coarse``: the network's own input, group correlation of 5x5 census signs of the grey image at 1/4 (levels of 4 px);
- ``pooled-max``: census signs at 1/1 compared at every integer disparity, each group's correlation averaged over the
  4x4 input pixels of each 1/4 cell, then the maximum over the 4 disparities of each level (4k-2 .. 4k+1);
- ``pooled-mean``: the same with the mean over those 4 disparities (its first run only: worse than max on both sets).
- ``both``: the two volumes' groups side by side (the mean over groups is the mean of the two; second run).
Each is read out raw (no aggregation), and after a k x k box of 1/4 cells (k = 3, 5, 7: the same spatial support added
to each, standing in for the network's aggregation), by WTA of the mean over groups at 1/4 (x4 input px), upsampled to the full
resolution and scored (bad-2 / bad-8 %, and the share off by more than 6 px, what the fine stages cannot reach),
mean over pairs. Also the time of building each volume (one thread). The network's 3-D aggregation would follow any
of them; this compares only the evidence it starts from.

Run: OMP_NUM_THREADS=1 python docs/experiments/pooled_volume_probe.py [specs, default "val2k;val4k"]
"""
import sys
import time

import torch
import torch.nn.functional as F

from stereonet.cost.census import census_signs, to_grey
from stereonet.cost.correlation import group_correlation_1d
from stereonet.matchers.learned import _downscale_to_range
from stereonet.models.dispnet import _mean2x2, pooled_group_correlation
from stereonet.models.layers import InputPadder, resize_disparity

sys.path.insert(0, "docs/experiments")
from val_sets import load  # noqa: E402

MAX_DISP, GROUPS, POOL = 96, 4, 4
AGG_WINDOWS = (3, 5, 7)


def score(d4, padder, gt, valid):
    d = F.interpolate(d4, scale_factor=4.0, mode="bilinear", align_corners=False)
    up = resize_disparity(padder.unpad(d), *gt.shape[-2:])
    err = (up[0, 0] - gt).abs()[valid]
    return [100 * float((err > t).float().mean()) for t in (2, 6, 8)]


def main(specs="val2k;val4k"):
    torch.set_grad_enabled(False)
    for spec in specs.split(";"):
        ds = load(spec)
        rows, secs = {}, {}
        for i in range(len(ds)):
            item = ds[i]
            l, r = item["left"][None], item["right"][None]
            sl, sr, _ = _downscale_to_range(l, r, item["max_disp"], MAX_DISP)
            padder = InputPadder(sl.shape[-2], sl.shape[-1], 16)
            sl, sr = padder.pad(sl, sr)
            both = torch.cat([sl, sr], 0)
            grey = to_grey(both)
            vols = {}
            t = time.perf_counter()
            n2 = census_signs(_mean2x2(_mean2x2(grey)), 5)
            vols["coarse"] = group_correlation_1d(n2[:1], n2[1:], MAX_DISP // 4, GROUPS)
            secs.setdefault("coarse", []).append(time.perf_counter() - t)
            n0 = census_signs(grey, 5)
            t = time.perf_counter()  # the network's own function (the first runs used a copy of it, with a mean variant)
            vols["pooled-max"] = pooled_group_correlation(n0[:1], n0[1:], MAX_DISP, GROUPS, POOL)
            secs.setdefault("pooled-max", []).append(time.perf_counter() - t)
            vols["both"] = torch.cat([vols["coarse"], vols["pooled-max"]], dim=1)  # the mean of the two means
            gt, valid = item["disparity"][0], item["valid"][0]
            for name, v in vols.items():
                m = v.mean(dim=1)
                d4 = m.argmax(dim=1, keepdim=True).float() * 4.0
                rows.setdefault(name, []).append(score(d4, padder, gt, valid))
                for k in AGG_WINDOWS:  # the same spatial support added to each: a k x k box of 1/4 cells
                    agg = F.avg_pool2d(m, k, stride=1, padding=k // 2, count_include_pad=False)
                    d4 = agg.argmax(dim=1, keepdim=True).float() * 4.0
                    rows.setdefault(f"{name} box{k}", []).append(score(d4, padder, gt, valid))
        print(f"{spec} ({len(ds)} pairs): raw 1/4 WTA, bad-2 / off > 6 px / bad-8 % at full resolution, mean over pairs")
        for name, vals in rows.items():
            m = [sum(v[j] for v in vals) / len(vals) for j in range(3)]
            print(f"  {name:18s} {m[0]:5.1f} / {m[1]:5.1f} / {m[2]:5.1f}   build {1000 * sum(secs.get(name, [0.0])) / len(vals):6.1f} ms")


if __name__ == "__main__":
    main(*sys.argv[1:])
