"""siamese-census-sgm with its mixed cost rounded to quarter bits (the 16-bit path, ``mix_step=0.25``, the default
from the twelfth session) against the unrounded float32 path (``mix_step=None``): data_gen validation sets of
choose_fused_weight.py, then the real pairs (evaluation only).

    python docs/experiments/mix_step_validation.py [SPECS]     (default "val2;val4"; e.g. "real")
"""
import sys

from val_sets import compare

from stereonet.matchers.learned import siamese_census_sgm_matcher

specs = sys.argv[1].split(";") if len(sys.argv) > 1 else ["val2", "val4"]
compare({"mix-quarter-bits": (siamese_census_sgm_matcher, {"mix_step": 0.25, "precision": "float32"}),
         "mix-float32": (siamese_census_sgm_matcher, {"mix_step": None, "precision": "float32"})}, specs)
