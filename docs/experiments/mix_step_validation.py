"""siamese-census-sgm with its mixed cost rounded to quarter bits (the 16-bit path, ``mix_step=0.25``, the default
from the twelfth session) against the unrounded float32 path (``mix_step=None``): data_gen validation sets of
choose_fused_weight.py, then the real pairs (evaluation only).

    python docs/experiments/mix_step_validation.py [SPECS]     (default "val2;val4"; e.g. "real")
"""
import functools
import sys

from val_sets import load

from stereonet.evaluation import format_table, run_evaluation
from stereonet.matchers import register
from stereonet.matchers.learned import siamese_census_sgm_matcher

specs = sys.argv[1].split(";") if len(sys.argv) > 1 else ["val2", "val4"]
for name, step in [("mix-quarter-bits", 0.25), ("mix-float32", None)]:
    register(name, kind="learned", description="exp")(functools.partial(siamese_census_sgm_matcher, mix_step=step))


ev = run_evaluation(["mix-quarter-bits", "mix-float32"], specs, fill=True, progress=False, load=load)
print(format_table(ev.rows))
for p in ev.pairs:
    print("PAIR", p.method, p.dataset, p.pair, None if p.metrics is None else round(p.metrics["bad2"], 3))
