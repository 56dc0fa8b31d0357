"""Issue 15 item 3: graphcut with and without label pruning on data_gen sets (rule in graphcut_pruning.txt).

    python docs/experiments/graphcut_pruning.py "val2n;val4n" [K:r,K:r,...]
    python docs/experiments/graphcut_pruning.py "val2q;val4q" 2:2:2,4:2:4   (K:r:census_candidates)
    python docs/experiments/graphcut_pruning.py "val2s;val4s" 2:2:2,2:1:2,1:2:1,1:1:1 --no-full

Prints, per configuration and set, the mean bad-2 after eval.py's fill and the summed wall time over the pairs
with its ratio to opencv-sgbm's on the same pairs (same process)."""
import functools
import statistics
import sys

from val_sets import load

from stereonet.evaluation import run_evaluation
from stereonet.matchers import get_matcher, register

specs = sys.argv[1].split(";")
configs = [tuple(int(v) for v in c.split(":")) for c in
           (sys.argv[2] if len(sys.argv) > 2 else "2:1,2:2,3:1,3:2,4:1,4:2").split(",")]
if "--no-full" not in sys.argv:
    configs = [None] + configs
graphcut = get_matcher("graphcut")
names = ["opencv-sgbm"]
for c in configs:
    name = "gc-full" if c is None else f"gc-k{c[0]}-r{c[1]}" + (f"-c{c[2]}" if len(c) > 2 else "")
    options = {"candidates": None} if c is None else {"candidates": c[0], "candidate_radius": c[1]}
    if c is not None and len(c) > 2:
        options["census_candidates"] = c[2]
    register(name, kind="classical", description="exp")(functools.partial(graphcut, **options))
    names.append(name)
ev = run_evaluation(names, specs, fill=True, progress=False, load=load)
rows = {}
for p in ev.pairs:
    rows.setdefault((p.method, p.dataset), []).append(p)
print("| method | " + " | ".join(f"{s} bad-2 | {s} s (x sgbm)" for s in specs) + " |")
for name in names:
    cells = []
    for s in specs:
        ps = rows[(name, s)]
        base = sum(q.seconds for q in rows[("opencv-sgbm", s)])
        t = sum(q.seconds for q in ps)
        cells.append(f"{statistics.fmean(q.metrics['bad2'] for q in ps):.2f} | {t:.1f} ({t / base:.0f}x)")
    print(f"| {name} | " + " | ".join(cells) + " |", flush=True)
