"""Issue 14, twenty-ninth session (probe, data_gen only): the chooser's class prior on textured renders.

refine.pt learned from the data_gen pixels where exactly one of its two maps (siamese-census-sgm, sgm) is within 1 px;
on the standard renders (prior2 + prior4) map 0 is the right one on 80 % of them (twenty-eighth session). How much of
that comes from the weak / flat textured surfaces? The same count on renders without them (tex2 + tex4) beside the
standard sets (prior2 + prior4), whole sets compared (the items do not say which surface a pixel shows).
    python docs/experiments/chooser_prior_textured.py "prior2;prior4" "tex2;tex4"
"""
import sys

from val_sets import load

from stereonet.matchers.learned import load_network, refine_bases

net = load_network("refine", None)
for group in sys.argv[1:]:
    counts, total = [0, 0], 0
    for spec in group.split(";"):
        ds = load(spec)
        for i in range(len(ds)):
            item = ds[i]
            left, right = item["left"][None].float(), item["right"][None].float()
            cand, valid, _ = refine_bases(net.bases, left, right, int(item["max_disp"]))
            ok = (cand - item["disparity"][None]).abs() <= 1.0
            gv = item["valid"][None, 0].bool()
            decisive = gv & (ok[:, 0] ^ ok[:, 1])
            counts[0] += int((decisive & ok[:, 0]).sum())
            counts[1] += int((decisive & ok[:, 1]).sum())
            total += int(gv.sum())
    share = counts[0] / max(1, counts[0] + counts[1])
    print(f"{group}: decisive pixels {counts[0] + counts[1]} ({100 * (counts[0] + counts[1]) / total:.1f} % of "
          f"ground truth); map 0 ({net.bases[0]}) right on {100 * share:.1f} %, map 1 ({net.bases[1]}) on "
          f"{100 * (1 - share):.1f} %", flush=True)
