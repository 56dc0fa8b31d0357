"""Issue 14 (and sgm's robustness), thirty-third session: the census cost of sgm and of sgm-refine's SGM-family bases
on pre-filtered images (stereonet.cost.prefilter: "vertical" [1, 2, 1] / 4 along the columns, "binomial" 3x3), against
none. Rule: docs/experiments/prefilter.txt. eval.py's metrics after the shared fill, through val_sets.compare (one
table per run, then each pair's bad-2).
Run: python docs/experiments/prefilter_probe.py "sgm,sgm-refine" "none,vertical,binomial" "val2al;val4al;wb2k;wb4k" """
import sys

sys.path.insert(0, "docs/experiments")
from val_sets import compare, expand  # noqa: E402

from stereonet.matchers import get_matcher  # noqa: E402

methods = sys.argv[1].split(",")
settings = sys.argv[2].split(",")
variants = {}
for m in methods:
    for s in settings:
        variants[f"{m}@{s}"] = (get_matcher(m), {} if s == "none" else {"prefilter": s})
compare(variants, expand(sys.argv[3]))
