"""Per-pair real bad-2 (after the shared fill) for methods with optional checkpoints: label=method[@ckpt].

``dispnet-nolr`` is ``dispnet`` without its left-right check (``lr_check=False``), as every ``dispnet`` row before the
thirty-fifth session was measured (the check is ``dispnet``'s default since then). ``smd-lr`` / ``smd-nolr`` are ``smd``
with / without its left-right check (``lr_check``, thirty-sixth session; docs/experiments/smd_lr.txt), ``smd-lr-one``
the check with rejected pixels at uncertainty 1 (``lr_uncertainty="one"``). ``dispnet-nowmf`` is ``dispnet`` with its
check but without the weighted median after it (``wmf_radius=0``), as ``dispnet`` ran in the thirty-fifth and
thirty-sixth sessions (the filter is its default since the thirty-seventh; docs/experiments/dispnet_wmf.txt);
``dispnet-nolr`` is also without the filter. The three ``smd-*`` variants run without the weighted median that is
``smd``'s default since the thirty-seventh session (docs/experiments/smd_wmf.txt), as their recorded rows did."""
import functools
import json
import os
import statistics
import sys

from stereonet import matchers
from stereonet.evaluation import expand_data_specs, format_table, run_evaluation
from stereonet.matchers.learned import dispnet_matcher, smd_matcher

matchers.register("dispnet-nolr", kind="learned", needs_weights=True,
                  description="dispnet without its left-right check")(functools.partial(dispnet_matcher, lr_check=False,
                                                                                       wmf_radius=0))
matchers.register("dispnet-nowmf", kind="learned", needs_weights=True,
                  description="dispnet without its weighted median")(functools.partial(dispnet_matcher, wmf_radius=0))
for _name, _opts in (("smd-lr", {"lr_check": True, "wmf_radius": 0}),
                     ("smd-lr-one", {"lr_check": True, "lr_uncertainty": "one", "wmf_radius": 0}),
                     ("smd-nolr", {"lr_check": False, "wmf_radius": 0})):
    matchers.register(_name, kind="learned", needs_weights=True,
                      description=f"smd with {_opts}")(functools.partial(smd_matcher, **_opts))

methods = [matchers.register_checkpoint_variant(arg) for arg in sys.argv[1].split(",")]
specs = sys.argv[2].split(";") if len(sys.argv) > 2 else ["real"]

ev = run_evaluation(methods, expand_data_specs(",".join(specs)), fill=True, progress=False)
print(format_table(ev.rows))
table = {}
for p in ev.pairs:
    table.setdefault(p.method, {})[f"{p.dataset}/{p.pair}"] = None if p.metrics is None else p.metrics
pairs = list(next(iter(table.values())).keys())
print("| method | " + " | ".join(pairs) + " | median bad-2 | median SEE | median AUSE |")
for m, row in table.items():
    b = [row[k]["bad2"] for k in pairs]
    see = [row[k]["see"] for k in pairs if row[k].get("see") == row[k].get("see")]
    au = [row[k]["ause"] for k in pairs if "ause" in row[k]]
    print(f"| {m} | " + " | ".join(f"{x:.1f}" for x in b) + f" | {statistics.median(b):.1f} | "
          f"{statistics.median(see):.2f} | " + (f"{statistics.median(au):.2f}" if au else "-") + " |")
print("\nSEE per pair (px):")
print("| method | " + " | ".join(pairs) + " | median SEE | mean SEE |")
for m, row in table.items():
    see = [row[k].get("see", float("nan")) for k in pairs]
    finite = [x for x in see if x == x]
    print(f"| {m} | " + " | ".join(f"{x:.2f}" for x in see) + f" | {statistics.median(finite):.2f} | "
          f"{statistics.fmean(finite):.2f} |")
out = sys.argv[3] if len(sys.argv) > 3 else "/tmp/exp/pairs.json"
os.makedirs(os.path.dirname(out) or ".", exist_ok=True)
json.dump({m: row for m, row in table.items()}, open(out, "w"), indent=1)
