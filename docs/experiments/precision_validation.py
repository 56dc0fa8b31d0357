"""The Siamese matchers with the feature tower in bfloat16 (``precision="bfloat16"``, what ``"auto"`` picks on a
CPU with native bfloat16, from the thirteenth session) against float32: data_gen validation sets of
choose_fused_weight.py, then the real pairs (evaluation only).

    python docs/experiments/precision_validation.py [SPECS]     (default "val2;val4"; e.g. "real")

Rule, written after the first val4 result (+0.4 bad-2) and before the noise floor was measured: bfloat16 is the
default ("auto") only if its val2 and val4 mean bad-2 changes are no larger than the largest change of the noise
floor (precision_noise_floor.py, float32 cost + noise of bfloat16's size, two seeds) + 0.1, and no real pair moves
by more than 0.1 (the check of a speed change, as for mix_step); otherwise it stays opt-in (precision="bfloat16").
"""
import sys

from val_sets import compare

from stereonet.matchers.learned import siamese_census_sgm_matcher, siamese_sgm_matcher

specs = sys.argv[1].split(";") if len(sys.argv) > 1 else ["val2", "val4"]
compare({f"{label}-{p}": (fn, {"precision": p}) for label, fn in [("census-sgm", siamese_census_sgm_matcher),
                                                                 ("siamese-sgm", siamese_sgm_matcher)]
         for p in ("float32", "bfloat16")}, specs)
