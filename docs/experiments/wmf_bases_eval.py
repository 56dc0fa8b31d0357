"""Issue 14, thirty-second session: sgm-refine with its base maps filtered by the weighted median before the choice
(base_wmf_radius=9; rule docs/experiments/wmf_bases.txt) against the shipped sgm-refine (final filter only).
Run: python docs/experiments/wmf_bases_eval.py "val2ae;val4ae;wb2d;wb4d"   (or "real")"""
import sys

sys.path.insert(0, "docs/experiments")
from val_sets import compare, expand

from stereonet.matchers.learned import WMF_RADIUS, sgm_refine_matcher

compare({"shipped": (sgm_refine_matcher, {}),
         "filtered-bases": (sgm_refine_matcher, {"base_wmf_radius": WMF_RADIUS})}, expand(sys.argv[1]))
