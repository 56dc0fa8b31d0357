"""Choose the fused-cost weight on synthetic validation only (data_gen seeds 5150/5151, not the benchmark)."""
import functools
import sys

from val_sets import load

from stereonet.evaluation import format_table, run_evaluation
from stereonet.matchers import register
from stereonet.matchers.learned import siamese_census_sgm_matcher

ckpt = sys.argv[1]
alphas = [float(x) for x in sys.argv[2].split(",")]
specs = sys.argv[3].split(";") if len(sys.argv) > 3 else ["val2", "val4"]


def fused(left, right, max_disp, a=0.5, **options):
    """The registered siamese-census-sgm with learned_weight a (an earlier copy of the script rebuilt it by hand)."""
    return siamese_census_sgm_matcher(left, right, max_disp, checkpoint=ckpt, learned_weight=a, **options)


methods = ["sgm", "siamese-sgm"]
for a in alphas:
    n = f"fused{a}"
    register(n, kind="learned", description="exp")(functools.partial(fused, a=a))
    methods.append(n)

ev = run_evaluation(methods, specs, fill=True, progress=False, load=load,
                    options={"siamese-sgm": {"checkpoint": ckpt}})
print(format_table(ev.rows))
for p in ev.pairs:
    print("PAIR", p.method, p.dataset, p.pair, None if p.metrics is None else round(p.metrics["bad2"], 2))
