"""The decision table of docs/experiments/dispnet_reach.txt: DispNet weights files side by side on data_gen sets
(eval.py's fill; its table has the per-set means of bad-2, EPE and SEE, then each pair's bad-2).

    cd docs/experiments && python dispnet_reach_eval.py [--lr-check | --now] "val2an;val4an" control=weights/dispnet_census_3d.pt reach=PATH

Without ``--lr-check`` every pixel is the network's (as the files were trained and the earlier rules written); with
it each file runs as ``dispnet`` ran in the thirty-fifth and thirty-sixth sessions (its left-right check, then the
shared fill); never with the weighted median that is ``dispnet``'s default since the thirty-seventh (``wmf_radius=0``),
so the recorded tables reproduce. With ``--now`` each file runs as ``dispnet`` runs by default since the thirty-seventh
session (its check, the fill, the weighted median).
"""
import sys

import val_sets

from stereonet.matchers.learned import dispnet_matcher

if __name__ == "__main__":
    lr_check = "--lr-check" in sys.argv[1:]
    now = "--now" in sys.argv[1:]
    args = [a for a in sys.argv[1:] if a not in ("--lr-check", "--now")]
    specs = val_sets.expand(args[0])
    variants = {}
    for arg in args[1:]:
        name, path = arg.split("=", 1)
        # as the networks were trained and the earlier rules written: every pixel the network's (no left-right
        # check), or with --lr-check its check and the fill; --now: as dispnet runs by default (check, fill, filter)
        options = {"checkpoint": path} if now else {"checkpoint": path, "lr_check": lr_check, "wmf_radius": 0}
        variants[f"dispnet-{name}"] = (dispnet_matcher, options)
    val_sets.compare(variants, specs)
