"""The data_gen validation sets of the fused-cost experiments (seeds 5150/5151, not the benchmark's): ``val2``
(12 pairs, difficulty 2) and ``val4`` (8 pairs, difficulty 4); any other spec as eval.py reads it."""
import data_gen
from stereonet.data import _SyntheticItems, load_dataset


def load(spec):
    if spec == "val2":
        return _SyntheticItems(data_gen.SyntheticStereo(count=12, seed=5150, difficulty=2), spec)
    if spec == "val4":
        return _SyntheticItems(data_gen.SyntheticStereo(count=8, seed=5151, difficulty=4), spec)
    return load_dataset(spec)
