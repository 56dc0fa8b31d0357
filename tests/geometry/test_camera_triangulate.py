"""Camera model (projection, back-projection, distortion) and triangulation; against OpenCV."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from stereonet.checks import StereoInputError
from stereonet.geometry import (
    back_project,
    distort_pixels,
    project_points,
    projection_matrix,
    reprojection_error,
    triangulate,
    triangulate_dlt,
    triangulate_midpoint,
    undistort_pixels,
)
from stereonet.geometry.random_scene import random_correspondences, random_rig, random_rotation
from stereonet.types import Calibration


@pytest.mark.parametrize("batch", [(), (2,), (2, 3)])
def test_projection_round_trip_shapes(batch):
    calib = random_rig(0, distortion=True)
    X = torch.rand(*batch, 30, 3, dtype=torch.float64) * torch.tensor([2.0, 2.0, 4.0]) + torch.tensor(
        [-1, -1, 2.0]
    )
    K, R, t = calib.K2.expand(*batch, 3, 3), calib.R.expand(*batch, 3, 3), calib.t.expand(*batch, 3)
    dist = calib.dist2.expand(*batch, 5)
    uv, z = project_points(X, K, R, t, dist=dist, return_depth=True)
    assert uv.shape == (*batch, 30, 2) and z.shape == (*batch, 30)
    back = back_project(uv, K, z, R, t, dist=dist)
    assert torch.allclose(back, X, atol=1e-8)


def test_projection_matches_opencv():
    calib = random_rig(1, distortion=True)
    X = torch.rand(50, 3, dtype=torch.float64) * torch.tensor([2.0, 2.0, 4.0]) + torch.tensor([-1, -1, 2.0])
    ours = project_points(X, calib.K2, calib.R, calib.t, dist=calib.dist2)
    # reference: cv2.projectPoints(X, cv2.Rodrigues(R)[0], t, K2, dist2)
    rvec, _ = cv2.Rodrigues(calib.R.numpy())
    ref, _ = cv2.projectPoints(X.numpy(), rvec, calib.t.numpy(), calib.K2.numpy(), calib.dist2.numpy())
    assert np.abs(ours.numpy() - ref[:, 0]).max() < 1e-9
    # undistortion (points inside the image) recovers the ideal pinhole pixels, like
    # cv2.undistortPoints(ref, K2, dist2, P=K2) (OpenCV iterates 5 times, we iterate 20)
    _, _, seen = random_correspondences(calib, 50, 1)
    ideal = undistort_pixels(seen, calib.K2, calib.dist2)
    ref_ideal = cv2.undistortPoints(
        seen.numpy()[:, None], calib.K2.numpy(), calib.dist2.numpy(), P=calib.K2.numpy()
    )
    assert np.abs(ideal.numpy() - ref_ideal[:, 0]).max() < 1e-3
    assert torch.allclose(distort_pixels(ideal, calib.K2, calib.dist2), seen, atol=1e-8)


def test_camera_bad_input():
    X = torch.rand(5, 3, dtype=torch.float64) + 1
    singular = torch.tensor([[500.0, 0, 0], [0, 500.0, 0], [0, 0, 0]], dtype=torch.float64)
    with pytest.raises(StereoInputError, match="K: expected an invertible"):
        project_points(X, singular)
    bad = X.clone()
    bad[0, 0] = float("nan")
    with pytest.raises(StereoInputError, match="points: expected finite"):
        project_points(bad, torch.eye(3, dtype=torch.float64))
    with pytest.raises(StereoInputError, match="R, t"):
        project_points(X, torch.eye(3, dtype=torch.float64), R=torch.eye(3, dtype=torch.float64))
    # a point on the camera plane stays finite
    on_plane = torch.tensor([[1.0, 1.0, 0.0]], dtype=torch.float64)
    uv, z = project_points(on_plane, torch.eye(3, dtype=torch.float64), return_depth=True)
    assert bool(torch.isfinite(uv).all()) and float(z[0]) == 0.0


@pytest.mark.parametrize("method", ["dlt", "midpoint"])
@pytest.mark.parametrize("distortion", [False, True])
def test_triangulation_recovers_points(method, distortion):
    calib = random_rig(3, distortion=distortion)
    X, p1, p2 = random_correspondences(calib, 200, 3)
    tri = triangulate(p1, p2, calib, method=method)
    rel = (tri.points - X).norm(dim=-1) / X[:, 2]
    assert float(rel.max()) < 1e-3 * 1e-3  # far below the required 0.1 %
    assert float(tri.reprojection_error.max()) < 1e-6
    assert bool(tri.valid.all())


def test_triangulation_with_noise_reports_reprojection_error():
    calib = random_rig(4)
    X, p1, p2 = random_correspondences(calib, 300, 4)
    g = torch.Generator().manual_seed(0)
    noisy = p2 + 0.5 * torch.randn(p2.shape, generator=g, dtype=torch.float64)
    dlt = triangulate(p1, noisy, calib)
    mid = triangulate(p1, noisy, calib, method="midpoint")
    for tri in (dlt, mid):
        assert 0.05 < float(tri.reprojection_error.median()) < 0.5  # roughly sigma / 2 per view (RMS)


def test_triangulation_against_opencv():
    calib = random_rig(5)
    X, p1, p2 = random_correspondences(calib, 40, 5)
    g = torch.Generator().manual_seed(0)
    p2 = p2 + 0.3 * torch.randn(p2.shape, generator=g, dtype=torch.float64)
    P1, P2 = projection_matrix(calib.K1), projection_matrix(calib.K2, calib.R, calib.t)
    ours = triangulate_dlt(P1, P2, p1, p2)
    # reference: cv2.triangulatePoints(P1, P2, p1.T, p2.T)
    Xh = cv2.triangulatePoints(P1.numpy(), P2.numpy(), p1.numpy().T, p2.numpy().T)
    ref = torch.from_numpy((Xh[:3] / Xh[3]).T)
    # ours is kornia's DLT (SVD solver), the same unequilibrated system as OpenCV's: they agree to roundoff
    assert float(((ours - ref).norm(dim=-1) / ref[:, 2]).max()) < 1e-3
    assert (
        float(reprojection_error(ours, P2, p2).mean()) <= float(reprojection_error(ref, P2, p2).mean()) * 1.05
    )


def test_parallel_rays_are_flagged_not_nan():
    K = torch.tensor([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]], dtype=torch.float64)
    calib = Calibration(K, K, torch.eye(3, dtype=torch.float64), torch.tensor([-0.1, 0.0, 0.0]))
    p = torch.tensor([[320.0, 240.0], [400.0, 200.0]], dtype=torch.float64)  # zero disparity: rays parallel
    for method in ("dlt", "midpoint"):
        tri = triangulate(p, p.clone(), calib, method=method)
        assert bool(torch.isfinite(tri.points).all()) and bool(torch.isfinite(tri.reprojection_error).all())
        assert not bool(tri.valid.any())
    with pytest.raises(StereoInputError, match="pure rotation"):
        triangulate(
            p, p, Calibration(K, K, random_rotation(3, torch.Generator().manual_seed(0)), torch.zeros(3))
        )


def test_gradcheck_triangulation():
    calib = random_rig(6)
    _, p1, p2 = random_correspondences(calib, 5, 6)
    P1, P2 = projection_matrix(calib.K1), projection_matrix(calib.K2, calib.R, calib.t)
    p1, p2 = p1.clone().requires_grad_(), (p2 + 0.2).requires_grad_()
    assert torch.autograd.gradcheck(lambda a, b: triangulate_dlt(P1, P2, a, b), (p1, p2), eps=1e-6, atol=1e-6)
    K1, K2 = calib.K1.clone().requires_grad_(), calib.K2
    assert torch.autograd.gradcheck(
        lambda a, b, k: triangulate_midpoint(a, b, k, K2, calib.R, calib.t), (p1, p2, K1), eps=1e-6, atol=1e-6
    )


def test_triangulate_midpoint_and_uncalibrated_rectification_check_their_inputs():
    from stereonet.checks import StereoInputError
    from stereonet.geometry.rectify import stereo_rectify_uncalibrated
    from stereonet.geometry.triangulate import triangulate_midpoint

    K = torch.tensor([[50.0, 0, 32], [0, 50, 24], [0, 0, 1]], dtype=torch.float64)
    p = torch.rand(10, 2, dtype=torch.float64) * 40
    eye = torch.eye(3, dtype=torch.float64)
    with pytest.raises(StereoInputError, match="t: expected finite"):  # used to return NaN points
        triangulate_midpoint(p, p, K, K, eye, torch.full((3,), float("nan"), dtype=torch.float64))
    with pytest.raises(StereoInputError, match="pts2"):
        triangulate_midpoint(p, p[:5], K, K, eye, torch.tensor([1.0, 0, 0], dtype=torch.float64))
    for size in ((0, 0), 64, (64.5, 48)):
        with pytest.raises(StereoInputError, match="image_size"):
            stereo_rectify_uncalibrated(p, p, size)


def test_epipolar_helpers_and_dlt_check_their_inputs():
    from stereonet.checks import StereoInputError
    from stereonet.geometry.epipolar import epipoles, essential_from_fundamental, sampson_distance
    from stereonet.geometry.triangulate import triangulate_dlt

    p = torch.rand(10, 2, dtype=torch.float64) * 40
    F = torch.tensor([[0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]], dtype=torch.float64)
    assert sampson_distance(p, p, F).shape == (10,)
    with pytest.raises(StereoInputError, match="pts2"):
        sampson_distance(p, p[:4], F)
    with pytest.raises(StereoInputError, match="F"):
        sampson_distance(p, p, F[:2])
    nan_F = torch.full((3, 3), float("nan"), dtype=torch.float64)
    for call in (lambda: epipoles(nan_F), lambda: essential_from_fundamental(nan_F, torch.eye(3, dtype=torch.float64),
                                                                             torch.eye(3, dtype=torch.float64))):
        with pytest.raises(StereoInputError, match="F: expected finite"):
            call()
    P = torch.cat([torch.eye(3), torch.zeros(3, 1)], 1).double()
    with pytest.raises(StereoInputError, match="P1"):
        triangulate_dlt(P[:, :3], P, p, p)
    with pytest.raises(StereoInputError, match="pts2"):
        triangulate_dlt(P, P, p, p[:3])
