"""Disparity <-> depth <-> coloured points (PLY), Q reprojection against OpenCV, gradients, bad input."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from stereonet.checks import StereoInputError
from stereonet.geometry import (
    depth_to_disparity,
    disparity_to_depth,
    disparity_to_points,
    reproject_disparity,
)
from stereonet.types import Calibration

CALIB = Calibration.rectified(focal=500.0, cx=31.5, cy=23.5, baseline=0.12, image_size=(64, 48), doffs=2.5)


def _disparity(seed: int = 0, dtype=torch.float64) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return (1 + 40 * torch.rand(1, 1, 48, 64, generator=g)).to(dtype)


def test_depth_formula_and_round_trip():
    d = _disparity()
    z = disparity_to_depth(d, CALIB)
    assert z.shape == d.shape and z.dtype == d.dtype
    assert torch.allclose(z, 500.0 * 0.12 / (d + 2.5))
    assert torch.allclose(depth_to_disparity(z, CALIB), d)
    # explicit numbers give the same as the calibration
    assert torch.allclose(disparity_to_depth(d, focal=500.0, baseline=0.12, doffs=2.5), z)
    assert torch.allclose(depth_to_disparity(z, focal=500.0, baseline=0.12, doffs=2.5), d)


def test_no_depth_is_zero_never_nan():
    d = _disparity()
    d[0, 0, 0, :5] = torch.tensor([0.0, -2.5, -10.0, 1.0, float("nan")])
    valid = torch.ones_like(d, dtype=torch.bool)
    valid[0, 0, 0, 3:5] = False
    z = disparity_to_depth(d, CALIB, valid=valid)
    assert bool(torch.isfinite(z).all())
    assert z[0, 0, 0, 0] > 0  # d = 0 still has depth because doffs > 0
    assert torch.equal(z[0, 0, 0, 1:5], torch.zeros(4, dtype=z.dtype))
    zero_depth = torch.zeros(1, 1, 2, 2, dtype=torch.float64)
    assert torch.equal(depth_to_disparity(zero_depth, CALIB), zero_depth)


def test_points_are_back_projections_with_colours(tmp_path):
    from stereonet.io import read_ply, write_ply

    d = _disparity(dtype=torch.float32)
    valid = d > 10
    image = torch.rand(1, 3, 48, 64, generator=torch.Generator().manual_seed(1))
    points, colors = disparity_to_points(d, valid, CALIB, image)
    n = int(valid.sum())
    assert points.shape == (n, 3) and points.dtype == torch.float32
    assert colors.shape == (n, 3) and colors.dtype == torch.uint8
    # projecting the points with K1 gives back the valid pixels (row-major order) and their depth
    v, u = torch.nonzero(valid[0, 0], as_tuple=True)
    K = CALIB.K1.float()
    uv = points[:, :2] / points[:, 2:] * torch.stack([K[0, 0], K[1, 1]]) + K[:2, 2]
    assert torch.allclose(uv, torch.stack([u, v], -1).float(), atol=1e-3)
    assert torch.allclose(points[:, 2], disparity_to_depth(d, CALIB)[valid])
    assert torch.equal(colors, (image[0, :, v, u].T * 255).round().to(torch.uint8))
    grey_points, grey_colors = disparity_to_points(d, valid, CALIB, image[:, :1])
    assert torch.equal(grey_colors[:, 0], grey_colors[:, 2])
    assert disparity_to_points(d, None, CALIB)[1] is None
    path = tmp_path / "cloud.ply"
    write_ply(path, points, colors)
    back_points, back_colors = read_ply(path)
    assert np.allclose(np.asarray(back_points), points.numpy()) and np.array_equal(
        np.asarray(back_colors), colors.numpy()
    )


def test_q_reprojection_matches_opencv():
    f, cx, cy, B, doffs = 500.0, 31.5, 23.5, 0.12, 2.5
    Q = torch.tensor(
        [[1.0, 0, 0, -cx], [0, 1, 0, -cy], [0, 0, 0, f], [0, 0, 1 / B, doffs / B]], dtype=torch.float64
    )
    d = _disparity()
    ours = reproject_disparity(d, Q)
    # reference: cv2.reprojectImageTo3D(disparity, Q)
    ref = cv2.reprojectImageTo3D(d[0, 0].float().numpy(), Q.numpy())
    assert np.allclose(ours[0].permute(1, 2, 0).numpy(), ref, rtol=1e-5)
    points, _ = disparity_to_points(d, None, CALIB)
    assert torch.allclose(ours[0].reshape(3, -1).T, points)


def test_gradcheck_depth():
    d = _disparity()[..., :4, :5].clone().requires_grad_()
    focal = torch.tensor(500.0, dtype=torch.float64, requires_grad=True)
    baseline = torch.tensor(0.12, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(
        lambda x, f, b: disparity_to_depth(x, focal=f, baseline=b, doffs=2.5), (d, focal, baseline)
    )
    z = disparity_to_depth(d.detach(), CALIB).requires_grad_()
    assert torch.autograd.gradcheck(lambda x: depth_to_disparity(x, CALIB), (z,))
    assert torch.autograd.gradcheck(lambda x: disparity_to_points(x, None, CALIB)[0], (d,))


def test_bad_input():
    d = _disparity()
    unrectified = Calibration(CALIB.K1, CALIB.K2, torch.eye(3), torch.tensor([-0.1, 0.02, 0.0]))
    with pytest.raises(StereoInputError, match="rectified"):
        disparity_to_depth(d, unrectified)
    swapped = Calibration.rectified(500.0, 31.5, 23.5, baseline=-0.12)
    with pytest.raises(StereoInputError, match="right of the left"):
        disparity_to_depth(d, swapped)
    with pytest.raises(StereoInputError, match="disparity"):
        disparity_to_depth(d[0], CALIB)
    with pytest.raises(StereoInputError, match="focal"):
        disparity_to_depth(d, focal=0.0, baseline=1.0)
    with pytest.raises(StereoInputError, match="either calib"):
        disparity_to_depth(d, CALIB, focal=1.0)
    bad = d.clone()
    bad[0, 0, 3, 3] = float("nan")
    with pytest.raises(StereoInputError, match="disparity: expected finite"):
        disparity_to_depth(bad, CALIB)
    with pytest.raises(StereoInputError, match="valid"):
        disparity_to_depth(d, CALIB, valid=torch.ones(1, 1, 2, 2, dtype=torch.bool))
    with pytest.raises(StereoInputError, match="single map"):
        disparity_to_points(d.expand(2, -1, -1, -1), None, CALIB)
