"""Issue 14 item 3(b), thirty-first session: sparsification AUSE of smd's errors ranked by three functions of its own
mixture (rule and reasoning in docs/experiments/smd_uncertainty.txt): b (the chosen mode's scale, what smd returned before),
u1 = E|X - d*| and u2 = P(|X - d*| > 2) under the predicted mixture, d* the returned disparity. With "real" in the
specs, sgm's cost-margin AUSE on the same pairs is printed beside (evaluation only).
    python docs/experiments/smd_uncertainty.py "unc2;unc4"
    python docs/experiments/smd_uncertainty.py real
"""
import statistics
import sys

import torch

sys.path.insert(0, "docs/experiments")
from val_sets import expand, items  # noqa: E402

from stereonet import matchers  # noqa: E402
from stereonet.evaluation import _batch, apply_fill  # noqa: E402
from stereonet.metrics import sparsification_ause  # noqa: E402
from stereonet.models.smd import MixtureParams, error_probability  # noqa: E402

TAU = 2.0


def candidates(out):
    """The three uncertainties of one smd output (all in pixels of its grid, or a probability). ``b`` is read from the
    mixture (the mode the head outputs, as stereonet.models.smd.MixtureParams.mode_disparity picks it): the matcher's
    own ``uncertainty`` is u2 since this probe."""
    mix = MixtureParams(**out.extras)
    d = out.disparity
    w = (mix.pi, 1 - mix.pi)
    modes = ((mix.mu1, mix.b1), (mix.mu2, mix.b2))
    u1 = sum(wk * ((d - mu).abs() + b * torch.exp(-(d - mu).abs() / b)) for wk, (mu, b) in zip(w, modes))
    return {"b": mix.mode_disparity()[1], "u1": u1, "u2": error_probability(mix, d, TAU)}


specs = expand(sys.argv[1])
torch.set_num_threads(2)
table = {}
for spec, item in items(specs):
    left, right, max_disp = _batch(item["left"]).float(), _batch(item["right"]).float(), int(item["max_disp"])
    gt, gv = _batch(item["disparity"]).float(), _batch(item["valid"]).bool()
    out = matchers.match("smd", left, right, max_disp, lr_check=False, wmf_radius=0)  # as recorded
    row = {k: sparsification_ause(out.disparity, gt, gv, uncertainty=u, pred_valid=out.valid)
           for k, u in candidates(out).items()}
    if sys.argv[1] == "real":
        s = apply_fill(matchers.match("sgm", left, right, max_disp))  # as eval.py --fill scores it
        row["sgm margin"] = sparsification_ause(s.disparity, gt, gv, confidence=s.confidence, pred_valid=s.valid)
    table.setdefault(spec, []).append(row)
    print(spec, item["name"], " ".join(f"{k} {v:.3f}" for k, v in row.items()), flush=True)
for spec, rows in table.items():
    print(f"{spec}: mean AUSE " + ", ".join(f"{k} {statistics.fmean(r[k] for r in rows):.3f}" for k in rows[0])
          + " | median " + ", ".join(f"{k} {statistics.median(r[k] for r in rows):.3f}" for k in rows[0]))
