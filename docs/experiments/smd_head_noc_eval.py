"""Decision script of docs/experiments/smd_head_noc.txt: the shipped smd.pt against the head trained on the new
dispnet.pt, both as ``smd`` runs (with its left-right check), eval.py's fill, AUSE by the uncertainty.
    python docs/experiments/smd_head_noc_eval.py [--now] "val2ay;val4ay;synthetic:32"
Without ``--now`` as the thirty-sixth session ran them (check and fill, no weighted median); with it as smd runs by
default since the thirty-seventh (docs/experiments/smd_head_noc_retest.txt).
"""
import sys

sys.path.insert(0, "docs/experiments")
import val_sets  # noqa: E402

from stereonet.matchers.learned import smd_matcher  # noqa: E402

now = "--now" in sys.argv[1:]
args = [a for a in sys.argv[1:] if a != "--now"]
options = {} if now else {"wmf_radius": 0}  # --now: as smd runs by default (check, fill, weighted median)
val_sets.compare({"smd-shipped": (smd_matcher, {"checkpoint": "stereonet/weights/smd.pt", **options}),
                  "smd-head-noc": (smd_matcher, {"checkpoint": "docs/experiments/weights/smd_head_noc.pt",
                                                   **options})},
                 val_sets.expand(args[0]))
