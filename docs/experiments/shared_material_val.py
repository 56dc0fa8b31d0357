"""Issue 14, twenty-fifth session: methods on data_gen sets (the rule of docs/experiments/shared_material.txt) or on
the real pairs (evaluation only), with eval.py's fill: per set the mean EPE, bad-2 and SEE over its pairs, and each
pair's numbers in OUT.json.
Run: python docs/experiments/shared_material_val.py "label=method@weights.pt,..." "synthetic:32;shm32" [OUT.json]"""
import json
import statistics
import sys

sys.path.insert(0, "docs/experiments")
from val_sets import expand, load  # noqa: E402

from stereonet import matchers  # noqa: E402
from stereonet.evaluation import format_table, run_evaluation  # noqa: E402

methods = [matchers.register_checkpoint_variant(arg) for arg in sys.argv[1].split(",")]
specs = expand(sys.argv[2])
ev = run_evaluation(methods, specs, fill=True, progress=False, load=load)
print(format_table(ev.rows))
table = {}
for p in ev.pairs:
    table.setdefault(p.method, {}).setdefault(p.dataset, {})[p.pair] = p.metrics
print("| method | set | pairs | mean EPE | mean bad-2 | mean SEE | median bad-2 |")
for m, sets in table.items():
    for s, pairs in sets.items():
        rows = list(pairs.values())
        see = [r["see"] for r in rows if r.get("see") == r.get("see")]
        print(f"| {m} | {s} | {len(rows)} | {statistics.fmean(r['epe'] for r in rows):.3f} | "
              f"{statistics.fmean(r['bad2'] for r in rows):.2f} | {statistics.fmean(see):.3f} | "
              f"{statistics.median(r['bad2'] for r in rows):.2f} |")
if len(sys.argv) > 3:
    json.dump(table, open(sys.argv[3], "w"), indent=1)
