import math

import numpy as np
import pytest
import torch

from stereonet.checks import StereoInputError
from stereonet.metrics import (
    bad_pixel_rate,
    d1_kitti,
    density,
    depth_discontinuities,
    epe,
    evaluate,
    soft_edge_error,
)

# A 2x3 example, errors by hand:
#   gt   = [[10, 20, 40], [ 5, 100, 50]]
#   pred = [[10.5, 23, 44], [ 5, 104.5, 0 (invalid pred)]]
#   err  = [[0.5, 3, 4], [0, 4.5, inf]]; gt_valid False at (1, 0) -> evaluated 5 pixels
GT = torch.tensor([[10.0, 20.0, 40.0], [5.0, 100.0, 50.0]])
PRED = torch.tensor([[10.5, 23.0, 44.0], [5.0, 104.5, 0.0]])
GT_VALID = torch.tensor([[True, True, True], [False, True, True]])
PRED_VALID = torch.tensor([[True, True, True], [True, True, False]])


def test_epe_hand_computed():
    # predicted & valid gt: errors 0.5, 3, 4, 4.5 -> mean 3.0
    assert epe(PRED, GT, GT_VALID, PRED_VALID) == pytest.approx(3.0)
    assert epe(PRED, GT, GT_VALID) == pytest.approx((0.5 + 3 + 4 + 4.5 + 50) / 5)


@pytest.mark.parametrize("tau,expected", [(0.0, 100.0), (0.5, 80.0), (1.0, 80.0), (3.0, 60.0), (4.0, 40.0),
                                          (4.5, 20.0), (1000.0, 20.0)])
def test_bad_tau_counts_missing_as_error(tau, expected):
    assert bad_pixel_rate(PRED, GT, GT_VALID, tau, PRED_VALID) == pytest.approx(expected)


def test_d1_kitti_needs_both_conditions():
    # err > 3: (0,2) 4 with 4/40 = 10% -> outlier; (1,1) 4.5 with 4.5% -> not; (1,2) missing -> outlier
    assert d1_kitti(PRED, GT, GT_VALID, PRED_VALID) == pytest.approx(40.0)
    # 3 px exactly is not an outlier (strict >)
    assert d1_kitti(torch.tensor([[13.0]]), torch.tensor([[10.0]])) == 0.0
    assert d1_kitti(torch.tensor([[13.01]]), torch.tensor([[10.0]])) == 100.0


def test_density():
    assert density(PRED_VALID, GT_VALID) == pytest.approx(80.0)
    assert density(PRED_VALID) == pytest.approx(100.0 * 5 / 6)


def test_masks_and_evaluate_keys():
    occ = torch.tensor([[False, False, True], [False, False, True]])
    out = evaluate(PRED, GT, GT_VALID, PRED_VALID, occlusion=occ)
    for s in ("", "_noc", "_occ"):
        for k in ("epe", "bad1", "bad2", "bad4", "d1", "density"):
            assert isinstance(out[k + s], float)
    # noc = (0,0), (0,1), (1,1): errors 0.5, 3, 4.5
    assert out["epe_noc"] == pytest.approx(8.0 / 3)
    assert out["bad2_noc"] == pytest.approx(200.0 / 3)
    assert out["density_noc"] == 100.0
    # occ = (0,2) err 4 and (1,2) missing
    assert out["epe_occ"] == pytest.approx(4.0)
    assert out["bad4_occ"] == pytest.approx(50.0)
    assert out["d1_occ"] == pytest.approx(100.0)
    assert out["density_occ"] == pytest.approx(50.0)
    assert out["bad1"] == pytest.approx(80.0) and out["density"] == pytest.approx(80.0)
    assert "epe_noc" not in evaluate(PRED, GT, GT_VALID, PRED_VALID)


def test_empty_mask_is_nan_not_zero():
    occ = torch.zeros(2, 3, dtype=torch.bool)
    out = evaluate(PRED, GT, GT_VALID, PRED_VALID, occlusion=occ)
    assert math.isnan(out["epe_occ"]) and math.isnan(out["bad1_occ"])


def test_pixel_vs_image_reduction():
    gt = torch.zeros(2, 1, 1, 4)
    pred = torch.zeros(2, 1, 1, 4)
    pred[0, 0, 0, 0] = 2.0            # image 0: 1 of 4 valid pixels bad
    valid = torch.ones(2, 1, 1, 4, dtype=torch.bool)
    valid[1, 0, 0, 2:] = False         # image 1: 2 valid pixels, both good
    pred[1, 0, 0, 2:] = 99.0           # ignored (no GT)
    assert bad_pixel_rate(pred, gt, valid, 1.0) == pytest.approx(100.0 / 6)
    assert bad_pixel_rate(pred, gt, valid, 1.0, reduction="image") == pytest.approx((25.0 + 0.0) / 2)
    assert epe(pred, gt, valid) == pytest.approx(2.0 / 6)
    assert epe(pred, gt, valid, reduction="image") == pytest.approx((0.5 + 0.0) / 2)
    with pytest.raises(StereoInputError, match="reduction"):
        epe(pred, gt, valid, reduction="mean")


def test_inputs_checked_and_numpy_accepted():
    assert epe(PRED.numpy(), GT.numpy(), GT_VALID.numpy(), PRED_VALID.numpy()) == pytest.approx(3.0)
    with pytest.raises(StereoInputError, match="pred: expected shape"):
        epe(torch.zeros(3, 3), GT, GT_VALID)
    with pytest.raises(StereoInputError, match="pred: expected finite"):
        epe(torch.full((2, 3), float("nan")), GT, GT_VALID)
    with pytest.raises(StereoInputError, match="gt: expected finite"):
        epe(PRED, torch.full((2, 3), float("inf")), torch.ones(2, 3, dtype=torch.bool))
    with pytest.raises(TypeError, match="gt_valid: expected a bool"):
        epe(PRED, GT, GT.clone())
    # NaN predictions are fine where marked invalid; inf GT fine where invalid (Middlebury PFM)
    p = PRED.clone()
    p[1, 2] = float("nan")
    g = GT.clone()
    g[1, 0] = float("inf")
    assert epe(p, g, GT_VALID, PRED_VALID) == pytest.approx(3.0)


def test_metrics_have_no_grad():
    pred = PRED.clone().requires_grad_(True)
    assert isinstance(epe(pred, GT, GT_VALID), float)


# ------------------------------------------------------------ soft edge error
def _step_scene():
    """A 5x6 disparity step: 10 on the left 3 columns, 30 on the right 3."""
    gt = torch.full((5, 6), 10.0)
    gt[:, 3:] = 30.0
    return gt


def test_depth_discontinuities_marks_both_sides():
    edges = depth_discontinuities(_step_scene())[0, 0]
    expected = torch.zeros(5, 6, dtype=torch.bool)
    expected[:, 2:4] = True
    assert torch.equal(edges, expected)
    assert depth_discontinuities(_step_scene(), dilation=3)[0, 0, :, 1:5].all()


def test_see_forgives_one_pixel_shift_but_not_blur():
    gt = _step_scene()
    shifted = torch.full((5, 6), 10.0)
    shifted[:, 4:] = 30.0   # edge one pixel late: column 3 predicted 10 but 10 is in its 3x3 window
    assert soft_edge_error(shifted, gt) == 0.0
    assert epe(shifted, gt) > 0
    blurred = gt.clone()
    blurred[:, 2:4] = 20.0  # halfway: 10 px from both sides
    assert soft_edge_error(blurred, gt) == pytest.approx(10.0)
    # k = 1 is plain EPE on the edge pixels
    assert soft_edge_error(shifted, gt, k=1) == pytest.approx(20.0 * 5 / 10)


def test_see_hand_computed_window_and_invalid_neighbours():
    gt = torch.tensor([[0.0, 0.0, 8.0, 8.0]])
    pred = torch.tensor([[0.0, 3.0, 6.0, 8.0]])
    # edges: columns 1, 2. col 1: window gt {0, 0, 8} -> min(|3-0|, |3-8|) = 3; col 2: {0, 8, 8} -> 2
    assert soft_edge_error(pred, gt) == pytest.approx(2.5)
    valid = torch.tensor([[True, True, True, False]])
    # col 2 is still an edge (jump to col 1); its window loses col 3 but keeps itself (8): still 2
    assert soft_edge_error(pred, gt, valid) == pytest.approx(2.5)
    with pytest.raises(StereoInputError, match="k: expected an odd"):
        soft_edge_error(pred, gt, k=2)


def test_see_in_evaluate_and_against_numpy_reference():
    rng = np.random.default_rng(0)
    gt = np.kron(rng.integers(0, 5, (4, 5)) * 4.0, np.ones((4, 4)))  # blocky, many edges
    pred = gt + rng.normal(0, 1.5, gt.shape)
    # brute-force reference: loops over edge pixels
    g = torch.from_numpy(gt)
    edges = depth_discontinuities(g)[0, 0].numpy()
    errs = []
    for y, x in zip(*np.nonzero(edges)):
        win = gt[max(0, y - 1):y + 2, max(0, x - 1):x + 2]
        errs.append(np.abs(win - pred[y, x]).min())
    ref = float(np.mean(errs))
    assert soft_edge_error(pred, gt) == pytest.approx(ref)
    assert evaluate(pred, gt)["see"] == pytest.approx(ref)


def test_numpy_views_and_non_numeric_arrays():
    """A reversed numpy view is a valid input (torch.from_numpy refused negative strides); strings are named."""
    import numpy as np

    from stereonet import metrics
    from stereonet.checks import StereoInputError

    g = (np.random.default_rng(0).random((16, 24)) * 8).astype(np.float32)
    res = metrics.evaluate(g[:, ::-1] + 1.0, g[:, ::-1])
    assert res["epe"] == pytest.approx(1.0, abs=1e-5)
    with pytest.raises(StereoInputError, match="numeric"):
        metrics.evaluate(np.full((16, 24), "a"), g)
