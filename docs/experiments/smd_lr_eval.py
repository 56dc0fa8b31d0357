"""Decision script of docs/experiments/smd_lr.txt: the shipped smd.pt without and with its left-right check
(``smd(lr_check=True)``: rejected pixels invalid, uncertainty 1), eval.py's fill, AUSE by the head's uncertainty.
    python docs/experiments/smd_lr_eval.py "val2aw;val4aw;synthetic:32"
"""
import sys

sys.path.insert(0, "docs/experiments")
import val_sets  # noqa: E402

from stereonet.matchers.learned import smd_matcher  # noqa: E402

val_sets.compare({"smd-plain": (smd_matcher, {"lr_check": False}), "smd-lr": (smd_matcher, {"lr_check": True})},
                 val_sets.expand(sys.argv[1]))
