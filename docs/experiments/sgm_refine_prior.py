"""The shipped chooser with its data_gen class prior removed by logit adjustment (rule: sgm_refine_prior.txt).

    python docs/experiments/sgm_refine_prior.py [real]

Measures pi0/pi1 on prior2 + prior4, then evaluates sgm-refine with and without the adjustment on val2o/val4o
(or, with "real", on the real pairs: evaluation only)."""
import math
import sys

import torch
from val_sets import load

from stereonet.evaluation import format_table, run_evaluation
from stereonet.matchers import register
from stereonet.matchers.learned import load_network, refine_bases
from stereonet.types import StereoOutput

net = load_network("refine", None)
assert net.mode == "select" and len(net.bases) == 2 and not net.radii


def scores_of(left, right, max_disp):
    base, valid, confidence = refine_bases(net.bases, left, right, max_disp)
    with torch.no_grad():
        scores, candidates = net.scores(left, right, base, valid, confidence, max_disp)
    return scores, candidates, base, confidence


counts = [0, 0]
for spec in ("prior2", "prior4"):
    ds = load(spec)
    for i in range(len(ds)):
        item = ds[i]
        left, right = item["left"][None].float(), item["right"][None].float()
        _, cand, _, _ = scores_of(left, right, int(item["max_disp"]))
        ok = (cand - item["disparity"][None]).abs() <= 1.0
        decisive = item["valid"][None, 0].bool() & (ok[:, 0] ^ ok[:, 1])
        counts[0] += int((decisive & ok[:, 0]).sum())
        counts[1] += int((decisive & ok[:, 1]).sum())
bias = math.log(counts[0] / counts[1])
print(f"decisive pixels: map 0 ({net.bases[0]}) right {counts[0]}, map 1 ({net.bases[1]}) right {counts[1]}; "
      f"b = log(pi0/pi1) = {bias:.4f}", flush=True)


@register("sgm-refine-prior", kind="learned", description="exp: refine.pt, class prior removed")
def adjusted(left, right, max_disp):
    scores, cand, base, confidence = scores_of(left, right, max_disp)
    scores[:, 1] += bias
    disp = cand.gather(1, scores.argmax(1, keepdim=True))
    return StereoOutput(disp, torch.ones_like(disp, dtype=torch.bool), confidence=confidence[:, :1])


real = len(sys.argv) > 1 and sys.argv[1] == "real"
specs = ["real"] if real else ["val2o", "val4o"]
methods = ["sgm", "siamese-census-sgm", "sgm-refine", "sgm-refine-prior"]
if real:
    from stereonet.evaluation import expand_data_specs
    ev = run_evaluation(methods, expand_data_specs("real"), fill=True, progress=False)
else:
    ev = run_evaluation(methods, specs, fill=True, progress=False, load=load)
print(format_table(ev.rows))
for p in ev.pairs:
    print("PAIR", p.method, p.dataset, p.pair, None if p.metrics is None else round(p.metrics["bad2"], 2))
