"""Issue 14, thirty-second session: the balanced chooser (docs/experiments/sgm_refine_balanced.txt) against the shipped
refine.pt, both without the weighted median (as the rule was written, before sgm-refine had it) and with it
(information). Run: python docs/experiments/refine_balanced_eval.py "wb2c;wb4c;val2ad;val4ad" (or "real")."""
import sys

sys.path.insert(0, "docs/experiments")
from val_sets import compare

from stereonet.matchers.learned import sgm_refine_matcher

bal = "docs/experiments/weights/sgm_refine_balanced.pt"
compare({"shipped-nowmf": (sgm_refine_matcher, {"wmf_radius": 0}),
         "bal-nowmf": (sgm_refine_matcher, {"checkpoint": bal, "wmf_radius": 0}),
         "shipped-wmf": (sgm_refine_matcher, {}),
         "bal-wmf": (sgm_refine_matcher, {"checkpoint": bal})}, sys.argv[1].split(";"))
