"""Decision script of docs/experiments/smd_wmf.txt: the shipped smd.pt as it runs (its left-right check, rejected
pixels scored at the fill's value; ``smd-shipped``) and with the weighted median after the filled mode, the
uncertainty scored at the filtered value (``smd-wmf``); eval.py's fill, AUSE by the uncertainty.
    python docs/experiments/smd_wmf_eval.py "val2ba;val4ba;wb2n;wb4n"
"""
import sys

sys.path.insert(0, "docs/experiments")
import val_sets  # noqa: E402

from stereonet.matchers.learned import smd_matcher  # noqa: E402

val_sets.compare({"smd-shipped": (smd_matcher, {"lr_check": True, "wmf_radius": 0}),
                  "smd-wmf": (smd_matcher, {"lr_check": True, "wmf_radius": 9})},
                 val_sets.expand(sys.argv[1]))
