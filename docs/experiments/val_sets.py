"""The data_gen validation sets of the fused-cost experiments (seeds 5150/5151, not the benchmark's): ``val2``
(12 pairs, difficulty 2) and ``val4`` (8 pairs, difficulty 4); ``val2b``/``val4b`` the same sizes on seeds 5152/5153
(first used by the seventeenth session's confirmation of sgm-refine-choose), ``val2c``/``val4c`` on seeds 5154/5155
(its resumed run), ``val2d``/``val4d`` on seeds 5156/5157 (the three-map run); any other spec as eval.py reads it. ``compare``
runs named variants of a matcher on them and prints the table and each pair's bad-2."""
import functools

import data_gen
from stereonet.data import _SyntheticItems, load_dataset


def load(spec):
    if spec == "val2":
        return _SyntheticItems(data_gen.SyntheticStereo(count=12, seed=5150, difficulty=2), spec)
    if spec == "val4":
        return _SyntheticItems(data_gen.SyntheticStereo(count=8, seed=5151, difficulty=4), spec)
    if spec == "val2b":
        return _SyntheticItems(data_gen.SyntheticStereo(count=12, seed=5152, difficulty=2), spec)
    if spec == "val4b":
        return _SyntheticItems(data_gen.SyntheticStereo(count=8, seed=5153, difficulty=4), spec)
    if spec == "val2c":
        return _SyntheticItems(data_gen.SyntheticStereo(count=12, seed=5154, difficulty=2), spec)
    if spec == "val4c":
        return _SyntheticItems(data_gen.SyntheticStereo(count=8, seed=5155, difficulty=4), spec)
    if spec == "val2d":
        return _SyntheticItems(data_gen.SyntheticStereo(count=12, seed=5156, difficulty=2), spec)
    if spec == "val4d":
        return _SyntheticItems(data_gen.SyntheticStereo(count=8, seed=5157, difficulty=4), spec)
    return load_dataset(spec)


def compare(variants, specs):
    """``variants``: {name: (matcher function, its options)}, each registered under ``name`` and evaluated with
    eval.py's fill on ``specs`` (e.g. ``["val2", "val4"]`` or ``["real"]``)."""
    from stereonet.evaluation import format_table, run_evaluation
    from stereonet.matchers import register

    for name, (fn, options) in variants.items():
        register(name, kind="learned", description="exp")(functools.partial(fn, **options))
    ev = run_evaluation(list(variants), specs, fill=True, progress=False, load=load)
    print(format_table(ev.rows))
    for p in ev.pairs:
        print("PAIR", p.method, p.dataset, p.pair, None if p.metrics is None else round(p.metrics["bad2"], 3))
