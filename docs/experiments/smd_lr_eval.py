"""Decision script of docs/experiments/smd_lr.txt: the shipped smd.pt without its left-right check (``smd-plain``),
with it and rejected pixels at uncertainty 1 (``smd-lr``, ``lr_uncertainty="one"``; the first rule) and with it and
rejected pixels scored by the mixture's probability that the shared fill's answer is off (``smd-lr-fill``, the
second rule); eval.py's fill, AUSE by the uncertainty.
    python docs/experiments/smd_lr_eval.py "val2aw;val4aw;synthetic:32"
"""
import sys

sys.path.insert(0, "docs/experiments")
import val_sets  # noqa: E402

from stereonet.matchers.learned import smd_matcher  # noqa: E402

val_sets.compare({"smd-plain": (smd_matcher, {"lr_check": False, "wmf_radius": 0}),
                  "smd-lr": (smd_matcher, {"lr_check": True, "lr_uncertainty": "one", "wmf_radius": 0}),
                  "smd-lr-fill": (smd_matcher, {"lr_check": True, "lr_uncertainty": "fill", "wmf_radius": 0})},
                 val_sets.expand(sys.argv[1]))
