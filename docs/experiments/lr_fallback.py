"""Left-right fallback (eighteenth session): ``sgm``'s own value wherever its left-right check keeps the pixel,
a learned matcher's value everywhere else, against ``sgm-refine`` (shipped), ``siamese-census-sgm`` and ``sgm``
on fresh data_gen sets (``val2e``/``val4e``, seeds 5158/5159), eval.py's fill, bad-2 per set and per pair.
The rule it is judged by is in ``lr_fallback.txt`` (written before the run).
    python docs/experiments/lr_fallback.py ["val2e;val4e" | "real"]
"""
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

from val_sets import compare  # noqa: E402

from stereonet.matchers.learned import sgm_refine_matcher, siamese_census_sgm_matcher  # noqa: E402
from stereonet.matchers.local import sgm  # noqa: E402
from stereonet.select.fill import fill_occlusions  # noqa: E402
from stereonet.types import StereoOutput  # noqa: E402


def fallback(left, right, max_disp, learned="sgm-refine"):
    """``sgm`` where its raw output is valid (left-right check passed), the learned map (filled) elsewhere."""
    base = sgm(left, right, max_disp)
    if learned == "sgm-refine":
        other = sgm_refine_matcher(left, right, max_disp, wmf_radius=0)  # as measured (eighteenth session)
    else:
        other = siamese_census_sgm_matcher(left, right, max_disp)
    other_disp = other.disparity if bool(other.valid.all()) else fill_occlusions(other.disparity, other.valid)
    disp = torch.where(base.valid, base.disparity, other_disp)
    return StereoOutput(disp, torch.ones_like(base.valid))


specs = sys.argv[1].split(";") if len(sys.argv) > 1 else ["val2e", "val4e"]
compare({"sgm-base": (sgm, {}), "census-sgm": (siamese_census_sgm_matcher, {}),
         "refine": (sgm_refine_matcher, {}),
         "lr-fallback-refine": (fallback, {"learned": "sgm-refine"}),
         "lr-fallback-census-sgm": (fallback, {"learned": "siamese-census-sgm"})}, specs)
