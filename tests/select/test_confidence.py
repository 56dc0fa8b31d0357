"""Cost-margin confidence: clear minimum -> 1, flat or double minimum -> 0, chunking exact, sgm ranks errors."""

from __future__ import annotations

import pytest
import torch

from stereonet.checks import StereoInputError
from stereonet.select import confidence as conf_mod
from stereonet.select.confidence import cost_margin_confidence


@pytest.mark.parametrize("backend", ["torch", "numba"])
def test_margin_by_hand(backend):
    # one pixel each: clear minimum, flat curve, two far minima, minimum next to a near-tie (excluded)
    curves = torch.tensor([[0.0, 10, 10, 10, 10], [5.0, 5, 5, 5, 5], [1.0, 8, 8, 8, 1], [2.0, 2.1, 9, 9, 9]])
    cost = curves.T.reshape(1, 5, 1, 4)
    c = cost_margin_confidence(cost, backend=backend)[0, 0, 0]
    assert c.tolist() == pytest.approx([1.0, 0.0, 0.0, (9 - 2) / 9], abs=1e-5)


@pytest.mark.parametrize("backend", ["torch", "numba"])
def test_non_finite_costs_are_never_winners(backend):
    def conf(values):
        return float(cost_margin_confidence(torch.tensor(values).reshape(1, -1, 1, 1), backend=backend))

    assert conf([float("inf"), 1.0, 9.0, 4.0, float("nan")]) == pytest.approx(0.75)  # c1 = 1, c2 = 4
    assert conf([float("inf")] * 3) == 0.0
    assert conf([1.0, 2.0, float("inf")]) == 1.0


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_chunked_torch_equals_numba(monkeypatch, dtype):
    g = torch.Generator().manual_seed(0)
    cost = torch.rand(2, 9, 23, 17, generator=g, dtype=dtype)
    cost[0, :, 3, 4] = 0.5  # a flat curve
    cost[1, 2, 5, 6] = float("nan")
    whole = cost_margin_confidence(cost, backend="torch")
    monkeypatch.setattr(conf_mod, "CHUNK_ELEMENTS", 9 * 17 * 2 * 3)  # 3 rows per chunk, last chunk partial
    torch.testing.assert_close(cost_margin_confidence(cost, backend="torch"), whole, rtol=0, atol=0)
    fast = cost_margin_confidence(cost.float().permute(0, 2, 3, 1).contiguous().permute(0, 3, 1, 2), backend="numba")
    torch.testing.assert_close(fast, whole.float(), rtol=1e-6, atol=1e-6)
    assert whole.dtype == dtype and whole.shape == (2, 1, 23, 17) and whole.min() >= 0 and whole.max() <= 1


def test_bad_input():
    with pytest.raises(StereoInputError, match="at least 2"):
        cost_margin_confidence(torch.zeros(1, 1, 3, 3))
    with pytest.raises(StereoInputError, match="backend"):
        cost_margin_confidence(torch.zeros(1, 4, 3, 3), backend="gpu")
    with pytest.raises(StereoInputError, match="exclude"):
        cost_margin_confidence(torch.zeros(1, 4, 3, 3), exclude=-1)


def test_sgm_confidence_ranks_its_errors():
    from stereonet.data import load_dataset
    from stereonet.evaluation import apply_fill
    from stereonet.matchers import match
    from stereonet.metrics import sparsification_ause

    item = load_dataset("synthetic:1")[0]
    left, right = item["left"][None].float(), item["right"][None].float()
    out = match("sgm", left, right, int(item["max_disp"]))
    assert out.confidence is not None and out.confidence.shape == out.disparity.shape
    assert bool((out.confidence[~out.valid] == 0).all())
    gt, gv = item["disparity"][None], item["valid"][None].bool()
    filled = apply_fill(out)  # what eval.py --fill scores: every pixel predicted, the confidence kept
    own = sparsification_ause(filled.disparity, gt, gv, confidence=filled.confidence)
    flat = sparsification_ause(filled.disparity, gt, gv, confidence=torch.ones_like(filled.confidence))
    lr_only = sparsification_ause(filled.disparity, gt, gv, confidence=out.valid.float())
    assert own < lr_only < flat
