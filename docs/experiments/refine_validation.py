"""sgm (and siamese-census-sgm, the first map of a two-map file) against sgm-refine weights on the data_gen
validation sets of the fused-weight choice (val2, val4; seeds 5150/5151, never the training or benchmark pairs),
eval.py's fill, bad-2 per set and per pair.
    python docs/experiments/refine_validation.py W1.pt[,W2.pt...] ["val2;val4" | "real"]
"""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from val_sets import compare  # noqa: E402

from stereonet.matchers.learned import sgm_refine_matcher, siamese_census_sgm_matcher  # noqa: E402
from stereonet.matchers.local import sgm  # noqa: E402
from stereonet.models.weights import load_weights  # noqa: E402

weights = sys.argv[1].split(",")
specs = sys.argv[2].split(";") if len(sys.argv) > 2 else ["val2", "val4"]
variants = {"sgm-base": (sgm, {})}
if any("siamese-census-sgm" in load_weights(w, "refine")[1]["config"].get("bases", ()) for w in weights):
    variants["census-sgm-base"] = (siamese_census_sgm_matcher, {})
for w in weights:
    variants[f"refine-{Path(w).stem}"] = (sgm_refine_matcher, {"checkpoint": w})
compare(variants, specs)
