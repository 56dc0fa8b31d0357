"""The powered decision of docs/experiments/dispnet_powered.txt: DispNet weights files against the shipped one on
the 256 fresh data_gen pairs of ``pow2;pow4;powb2;powb4``, each file as ``dispnet`` runs by default (its left-right
check, the fill, the weighted median), eval.py's fill; then, per candidate, the paired per-pair differences of bad-2
and SEE against the first file: their mean, standard error and t over all pairs and per set, and the verdict of the
rule (the thresholds are the rule's, fixed before any of these pairs was rendered).

    cd docs/experiments && python dispnet_powered_eval.py shipped=weights/dispnet_noc_long.pt aa=weights/dispnet_aa_long.pt rs2=weights/dispnet_rs2_long.pt

Later rules of the same protocol name their own fresh sets and pooled threshold (the first ``--sets=`` and ``--t=``
arguments), e.g. ``--sets="pow2c;pow4c;powb2c;powb4c" --t=-1.96`` for one candidate (docs/experiments/dispnet_long4x.txt).
``--matcher=smd`` runs the files as ``smd`` runs by default instead and adds the rule of docs/experiments/smd_head_4x.txt
on its uncertainty: the paired AUSE, whose pooled mean difference may not be positive and which may not be worse with
t >= +2.0 on any set. ``--target=see`` (docs/experiments/smd_head_edge.txt) tests the edges instead: the pooled paired
t of SEE must be at or below ``--t``, the mean paired bad-2 difference at most +0.1 points, and no set worse in bad-2
(or, with ``--matcher=smd``, in AUSE) with t >= +2.0.
"""
import math
import statistics
import sys

import val_sets

from stereonet.matchers.learned import dispnet_matcher, smd_matcher

SETS = ("pow2", "pow4", "powb2", "powb4")
T_POOLED = -2.24  # Bonferroni over two candidates, two-sided 5 %: |z| >= 2.24
T_SET_WORSE = 2.0  # a set on which a candidate is this significantly worse vetoes it
SEE_MARGIN = 0.1  # px: the mean paired SEE difference may not exceed this
BAD2_MARGIN = 0.1  # points: with --target=see, the mean paired bad-2 difference may not exceed this


def paired(rows, a, b, key):
    """Differences ``b - a`` of ``key`` over the pairs both have finite."""
    out = []
    for res in rows.values():
        if a in res and b in res:
            x, y = res[a].get(key), res[b].get(key)
            if x is not None and y is not None and math.isfinite(x) and math.isfinite(y):
                out.append(y - x)
    return out


def summary(d):
    n = len(d)
    mean = statistics.fmean(d)
    se = statistics.stdev(d) / math.sqrt(n) if n > 1 else float("nan")
    return n, mean, se, mean / se if se > 0 else float("nan")


if __name__ == "__main__":
    from stereonet.evaluation import format_table, run_evaluation
    from stereonet.matchers import register

    args = sys.argv[1:]
    sets, t_pooled, matcher, target = SETS, T_POOLED, "dispnet", "bad2"
    while args and args[0].startswith("--"):  # a later rule's own sets and threshold (or a smoke test on used sets)
        key, value = args.pop(0).split("=", 1)
        if key == "--sets":
            sets = tuple(value.split(";"))
        elif key == "--t":
            t_pooled = float(value)
        elif key == "--matcher" and value in ("dispnet", "smd"):
            matcher = value
        elif key == "--target" and value in ("bad2", "see"):
            target = value
        else:
            raise SystemExit(f"{key}={value}: expected --sets=, --t=, --matcher=dispnet|smd or --target=bad2|see")
    run = {"dispnet": dispnet_matcher, "smd": smd_matcher}[matcher]
    keys = ("bad2", "see", "ause") if matcher == "smd" else ("bad2", "see")
    names = []
    for arg in args:
        name, path = arg.split("=", 1)
        names.append(f"{matcher}-{name}")
        register(names[-1], kind="learned", description="exp")(
            lambda left, right, max_disp, _p=path, **kw: run(left, right, max_disp, checkpoint=_p, **kw))
    ev = run_evaluation(names, list(sets), fill=True, progress=True, load=val_sets.load)
    print(format_table(ev.rows))
    per_set = {s: {} for s in sets}
    for p in ev.pairs:
        if p.metrics is not None:
            per_set[p.dataset].setdefault(p.pair, {})[p.method] = {k: p.metrics.get(k) for k in keys}
            print("PAIR", p.method, p.dataset, p.pair, *(None if p.metrics.get(k) is None else round(p.metrics[k], 3)
                                                          for k in keys))
    control = names[0]
    pooled_rows = {(s, k): v for s in sets for k, v in per_set[s].items()}
    verdicts = {}
    for cand in names[1:]:
        print(f"\n{cand} - {control} (negative = the candidate is better)")
        vetoed = False
        for s in sets:
            n, mean, se, t = summary(paired(per_set[s], control, cand, "bad2"))
            _, smean, _, _ = summary(paired(per_set[s], control, cand, "see"))
            better = sum(x < 0 for x in paired(per_set[s], control, cand, "bad2"))
            print(f"  {s:6s} n={n:3d} bad-2 diff {mean:+.2f} (se {se:.2f}, t {t:+.2f}; better on {better})  SEE diff {smean:+.3f}")
            vetoed |= t >= T_SET_WORSE
            if "ause" in keys:
                _, amean, ase, at = summary(paired(per_set[s], control, cand, "ause"))
                print(f"  {s:6s} AUSE diff {amean:+.3f} (se {ase:.3f}, t {at:+.2f})")
                vetoed |= at >= T_SET_WORSE
        n, mean, se, t = summary(paired(pooled_rows, control, cand, "bad2"))
        _, smean, sse, st = summary(paired(pooled_rows, control, cand, "see"))
        better = sum(x < 0 for x in paired(pooled_rows, control, cand, "bad2"))
        if target == "see":
            print(f"  pooled SEE t {st:+.2f} (the target; better on "
                  f"{sum(x < 0 for x in paired(pooled_rows, control, cand, 'see'))})")
            positive = st <= t_pooled and mean <= BAD2_MARGIN and not vetoed
        else:
            positive = t <= t_pooled and smean <= SEE_MARGIN and not vetoed
        if "ause" in keys:
            _, amean, ase, at = summary(paired(pooled_rows, control, cand, "ause"))
            print(f"  pooled AUSE diff {amean:+.3f} (se {ase:.3f}, t {at:+.2f})")
            positive &= amean <= 0
        verdicts[cand] = (positive, mean)
        print(f"  pooled n={n} bad-2 diff {mean:+.2f} (se {se:.2f}, t {t:+.2f}; better on {better} of {n})  "
              f"SEE diff {smean:+.3f} (se {sse:.3f})  set veto: {vetoed}  -> {'POSITIVE' if positive else 'NEGATIVE'}")
    winners = sorted((mean, c) for c, (ok, mean) in verdicts.items() if ok)
    print("\nDECISION:", f"{winners[0][1]} replaces {control}" if winners else f"{control} stays")
