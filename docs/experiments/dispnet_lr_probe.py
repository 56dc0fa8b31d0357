"""Issue 14 item 2 (thirty-fifth session; rule docs/experiments/dispnet_lr.txt): ``dispnet`` with and without its
left-right check (``lr_check=True``: the network also run on the mirrored, swapped pair; inconsistent pixels
invalid -> eval.py's shared fill), and the same check at 2 and 3 px (reported, not decided on).
    python docs/experiments/dispnet_lr_probe.py "SETS" [weights]"""
import sys

sys.path.insert(0, "docs/experiments")
import val_sets  # noqa: E402

from stereonet.matchers.learned import dispnet_matcher  # noqa: E402
from stereonet.select.lr_check import left_right_check  # noqa: E402
from stereonet.types import StereoOutput  # noqa: E402


def lr_at(left, right, max_disp, tol, checkpoint=None):
    """The check at another tolerance (the matcher's is fixed at 1 px)."""
    a = dispnet_matcher(left, right, max_disp, checkpoint=checkpoint, lr_check=False, wmf_radius=0)
    b = dispnet_matcher(right.flip(-1), left.flip(-1), max_disp, checkpoint=checkpoint, lr_check=False,
                        wmf_radius=0)
    return StereoOutput(a.disparity, left_right_check(a.disparity, b.disparity.flip(-1), tol))


ck = sys.argv[2] if len(sys.argv) > 2 else None
variants = {"plain": (dispnet_matcher, {"checkpoint": ck, "lr_check": False}),
            "lr1": (dispnet_matcher, {"checkpoint": ck, "lr_check": True}),
            "lr2": (lr_at, {"tol": 2.0, "checkpoint": ck}),
            "lr3": (lr_at, {"tol": 3.0, "checkpoint": ck})}
val_sets.compare(variants, val_sets.expand(sys.argv[1]))
