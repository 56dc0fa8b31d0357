"""The decision table of docs/experiments/dispnet_reach.txt: DispNet weights files side by side on data_gen sets
(eval.py's fill; its table has the per-set means of bad-2, EPE and SEE, then each pair's bad-2).

    cd docs/experiments && python dispnet_reach_eval.py "val2an;val4an" control=weights/dispnet_census_3d.pt reach=PATH
"""
import sys

import val_sets

from stereonet.matchers.learned import dispnet_matcher

if __name__ == "__main__":
    specs = val_sets.expand(sys.argv[1])
    variants = {}
    for arg in sys.argv[2:]:
        name, path = arg.split("=", 1)
        # as the networks were trained and the rules written: every pixel the network's (no left-right check)
        variants[f"dispnet-{name}"] = (dispnet_matcher, {"checkpoint": path, "lr_check": False})
    val_sets.compare(variants, specs)
