"""Issue 14, thirty-second session: sgm-refine with only sgm's base map filtered by the weighted median before the
choice (rule docs/experiments/wmf_sgm_base.txt) against the shipped sgm-refine (final filter only).
Run: python docs/experiments/wmf_sgm_base_eval.py "val2ag;val4ag;wb2f;wb4f"   (or "real")"""
import sys

sys.path.insert(0, "docs/experiments")
from val_sets import compare, expand

from stereonet.matchers.learned import WMF_RADIUS, sgm_refine_matcher

compare({"shipped": (sgm_refine_matcher, {}),
         "sgm-base-filtered": (sgm_refine_matcher, {"base_wmf_radius": WMF_RADIUS, "base_wmf_bases": ("sgm",)})},
        expand(sys.argv[1]))
