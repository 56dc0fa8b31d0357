# python docs/experiments/choice_share.py   (twentieth session; output in the model card and sgm_refine_ranges.txt)
"""Share of pixels where the shipped sgm-refine returns sgm's filled value rather than siamese-census-sgm's
(where the two maps differ by > 1 px), on data_gen val sets and the real pairs (evaluation only)."""
import sys, torch
sys.path.insert(0, "docs/experiments")
from val_sets import load
from stereonet import matchers
from stereonet.select.fill import fill_occlusions
torch.set_num_threads(2)
for spec in ["val2i", "val4i", "real"]:
    ds = load(spec)
    shares = []
    for i in range(len(ds)):
        it = ds[i]
        l, r = it["left"][None].float(), it["right"][None].float()
        md = int(it["max_disp"])
        out = matchers.match("sgm-refine", l, r, md)
        s = matchers.match("sgm", l, r, md)
        c = matchers.match("siamese-census-sgm", l, r, md)
        sd, cd = fill_occlusions(s.disparity, s.valid), fill_occlusions(c.disparity, c.valid)
        differ = (sd - cd).abs() > 1
        took_sgm = ((out.disparity - sd).abs() < 1e-4) & differ
        shares.append((100 * took_sgm.sum() / differ.sum().clamp(min=1)).item())
        print(spec, it["name"], "differ %.1f%%" % (100 * differ.float().mean()), "sgm chosen where they differ %.1f%%" % shares[-1])
    print(spec, "mean", round(sum(shares) / len(shares), 1))
