"""siamese-census-sgm's SGM penalties (P1, P2, in census bits; the fused cost is in bits too) chosen on data_gen
validation only (val_sets.py: val2, val4), with the shipped weights and learned weight.

Rule fixed before the run (twelfth session): score = bad-2(val2) / bad-2_current(val2) + bad-2(val4) / bad-2_current(val4),
current = sgm's own penalties (P1 2, P2 48); a grid point replaces them only if it is lower on *both* sets, and then
the one with the lowest score.

    python docs/experiments/fused_penalties.py "1,2,4" "32,48,72"
"""
import functools
import sys

from val_sets import load

from stereonet.evaluation import format_table, run_evaluation
from stereonet.matchers import register
from stereonet.matchers.learned import siamese_census_sgm_matcher

p1s = [float(x) for x in sys.argv[1].split(",")]
p2s = [float(x) for x in sys.argv[2].split(",")]
methods = []
for p1 in p1s:
    for p2 in p2s:
        name = f"P1={p1:g},P2={p2:g}"
        register(name, kind="learned", description="exp")(functools.partial(siamese_census_sgm_matcher, P1=p1, P2=p2))
        methods.append(name)
ev = run_evaluation(methods, ["val2", "val4"], fill=True, progress=False, load=load)
print(format_table(ev.rows))
