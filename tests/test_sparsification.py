"""Sparsification curves and AUSE: oracle ranking gives 0, a useless ranking the full gap, misses go first."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from stereonet.checks import StereoInputError
from stereonet.metrics import bad_pixel_rate, sparsification, sparsification_ause


def _errors(n: int = 400, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    gt = torch.rand(1, 1, 20, n // 20, generator=g, dtype=torch.float64) * 50
    err = torch.rand(gt.shape, generator=g, dtype=torch.float64) * 6  # a third of the pixels above 4 px
    return gt + err, gt, err


def test_oracle_ranking_has_zero_ause():
    pred, gt, err = _errors()
    assert sparsification_ause(pred, gt, uncertainty=err) == pytest.approx(0.0, abs=1e-12)
    assert sparsification_ause(pred, gt, confidence=-err) == pytest.approx(0.0, abs=1e-12)


def test_curve_starts_at_bad_rate_and_oracle_falls_to_zero():
    pred, gt, err = _errors()
    fractions, curve, oracle = sparsification(pred, gt, uncertainty=torch.zeros_like(err), steps=10)
    assert fractions.tolist() == pytest.approx([i / 10 for i in range(10)])
    assert curve[0] == pytest.approx(bad_pixel_rate(pred, gt, tau=2.0))
    assert oracle[0] == pytest.approx(curve[0])
    # two thirds of the pixels are bad: once more than that is removed, the oracle keeps only good ones
    assert oracle[-1] == 0.0 and np.all(np.diff(oracle) <= 1e-12)
    # a ranking that says nothing removes good and bad pixels alike: the bad rate stays, the AUSE is the full gap
    assert curve == pytest.approx(np.full(10, curve[0]), abs=1e-9)


def test_ties_are_scored_by_expectation_not_pixel_order():
    """Errors all in the first rows and a binary confidence that cannot tell them apart from half the good
    pixels: the curve is what a random order inside each tie group gives in expectation, the same whichever
    way the rows are stored (pixel order used to decide ties: the flipped image scored differently)."""
    pred, gt, err = _errors()
    bad_rows = torch.zeros_like(err)
    bad_rows[..., :5, :] = 5.0  # the first quarter of the rows are the errors (> 2 px)
    pred = gt + bad_rows
    conf = torch.ones_like(err)
    conf[..., :10, :] = 0.0  # the method distrusts the first half: all errors and as many good pixels
    _, curve, _ = sparsification(pred, gt, confidence=conf, steps=4)
    _, flipped, _ = sparsification(pred.flip(-2), gt.flip(-2), confidence=conf.flip(-2), steps=4)
    # removing 25 % of 400 takes half of the distrusted 200 pixels: 50 errors of 100 bad in expectation
    assert curve == pytest.approx([25.0, 50 / 300 * 100, 0.0, 0.0])
    assert flipped == pytest.approx(curve)


def test_worse_ranking_gives_larger_ause():
    pred, gt, err = _errors()
    noise = torch.randn(err.shape, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    good = sparsification_ause(pred, gt, uncertainty=err + 0.5 * noise)
    useless = sparsification_ause(pred, gt, uncertainty=noise)
    inverted = sparsification_ause(pred, gt, uncertainty=-err)
    assert 0 < good < useless < inverted


def test_missing_predictions_are_removed_first():
    pred, gt, err = _errors()
    pv = torch.ones_like(gt, dtype=torch.bool)
    pv[..., :2] = False  # 10 % of the pixels have no answer; their confidence claims they are perfect
    conf = torch.where(pv, -err, torch.full_like(err, 1e9))
    _, curve, oracle = sparsification(pred, gt, confidence=conf, pred_valid=pv, steps=10)
    full_rank = sparsification(pred[..., 2:], gt[..., 2:], confidence=-err[..., 2:], steps=9)[1]
    assert curve[0] > full_rank[0]  # misses count as errors before removal
    assert curve[1] == pytest.approx(full_rank[0])  # after removing 10 %: exactly the predicted pixels
    assert oracle[1] == pytest.approx(curve[1])


def test_bad_input():
    pred, gt, err = _errors()
    with pytest.raises(StereoInputError, match="exactly one"):
        sparsification_ause(pred, gt)
    with pytest.raises(StereoInputError, match="exactly one"):
        sparsification_ause(pred, gt, uncertainty=err, confidence=err)
    with pytest.raises(StereoInputError, match="uncertainty: expected shape"):
        sparsification_ause(pred, gt, uncertainty=err[..., :3])
    with pytest.raises(StereoInputError, match="steps"):
        sparsification(pred, gt, uncertainty=err, steps=0)
