"""Decision script of docs/experiments/smd_head_noc.txt: the shipped smd.pt against the head trained on the new
dispnet.pt, both as ``smd`` runs (with its left-right check), eval.py's fill, AUSE by the uncertainty.
    python docs/experiments/smd_head_noc_eval.py "val2ay;val4ay;synthetic:32"
"""
import sys

sys.path.insert(0, "docs/experiments")
import val_sets  # noqa: E402

from stereonet.matchers.learned import smd_matcher  # noqa: E402

val_sets.compare({"smd-shipped": (smd_matcher, {"checkpoint": "stereonet/weights/smd.pt", "wmf_radius": 0}),
                  "smd-head-noc": (smd_matcher, {"checkpoint": "docs/experiments/weights/smd_head_noc.pt",
                                                   "wmf_radius": 0})},
                 val_sets.expand(sys.argv[1]))
