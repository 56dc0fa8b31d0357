"""Share of pixels where the shipped sgm-refine returns sgm's filled value rather than siamese-census-sgm's (where the
two maps differ by > 1 px), on data_gen val sets and the real pairs (evaluation only; twentieth session, output in the
model card and sgm_refine_ranges.txt).

    python docs/experiments/choice_share.py
"""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from val_sets import load  # noqa: E402

from stereonet import matchers  # noqa: E402
from stereonet.select.fill import fill_occlusions  # noqa: E402

for spec in ["val2i", "val4i", "real"]:
    ds = load(spec)
    shares = []
    for i in range(len(ds)):
        item = ds[i]
        left, right, max_disp = item["left"][None].float(), item["right"][None].float(), int(item["max_disp"])
        out = matchers.match("sgm-refine", left, right, max_disp, wmf_radius=0)  # the choice, before its filter
        s = matchers.match("sgm", left, right, max_disp)
        c = matchers.match("siamese-census-sgm", left, right, max_disp)
        sd, cd = fill_occlusions(s.disparity, s.valid), fill_occlusions(c.disparity, c.valid)
        differ = (sd - cd).abs() > 1
        took_sgm = ((out.disparity - sd).abs() < 1e-4) & differ
        shares.append((100 * took_sgm.sum() / differ.sum().clamp(min=1)).item())
        print(spec, item["name"], f"differ {100 * differ.float().mean():.1f}%",
              f"sgm chosen where they differ {shares[-1]:.1f}%")
    print(spec, "mean", round(sum(shares) / len(shares), 1))
