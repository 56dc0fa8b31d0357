"""Probe (used sets; no rule; thirty-fifth session): smd with the same left-right check as dispnet's (the mirrored,
swapped pair; 1 px), its uncertainty left as the head gives it.
    python docs/experiments/smd_lr_probe.py "val2ai;val4ai"
"""
import sys

sys.path.insert(0, "docs/experiments")
import val_sets  # noqa: E402

from stereonet.matchers.learned import smd_matcher  # noqa: E402
from stereonet.select.lr_check import left_right_check  # noqa: E402


def smd_lr(left, right, max_disp):
    a = smd_matcher(left, right, max_disp, lr_check=False, wmf_radius=0)
    b = smd_matcher(right.flip(-1), left.flip(-1), max_disp, lr_check=False, wmf_radius=0)
    a.valid = left_right_check(a.disparity, b.disparity.flip(-1))  # the one rule's 1 px
    return a


val_sets.compare({"smd-plain": (smd_matcher, {"lr_check": False, "wmf_radius": 0}), "smd-lr": (smd_lr, {})}, val_sets.expand(sys.argv[1]))
