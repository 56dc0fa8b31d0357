"""Eight-point F, robust F, epipolar lines/epipoles, E and its decomposition; against kornia and OpenCV."""

from __future__ import annotations

import math

import cv2
import pytest
import torch
from kornia.geometry.epipolar import find_fundamental

from stereonet.checks import StereoInputError
from stereonet.geometry import (
    DegenerateGeometryError,
    decompose_essential,
    epipolar_lines,
    epipoles,
    essential_from_fundamental,
    essential_from_pose,
    fundamental_8point,
    fundamental_from_essential,
    fundamental_from_pose,
    fundamental_robust,
    normalize_points_hartley,
    pose_from_essential,
    project_points,
    project_to_essential,
    sampson_distance,
)
from stereonet.geometry.random_scene import random_correspondences, random_rig, random_rotation


def _same_up_to_scale(A: torch.Tensor, B: torch.Tensor) -> float:
    """Largest entry difference of A and B after both are scaled to unit norm with a common sign."""
    a, b = A / A.norm(), B / B.norm()
    return float(min((a - b).abs().max(), (a + b).abs().max()))


def _angle_deg(R_a: torch.Tensor, R_b: torch.Tensor) -> float:
    c = (float(torch.trace(R_a.T @ R_b)) - 1) / 2
    return math.degrees(math.acos(max(-1.0, min(1.0, c))))


@pytest.mark.parametrize("seed", range(10))
def test_eight_exact_correspondences_have_zero_sampson(seed):
    calib = random_rig(seed)
    _, p1, p2 = random_correspondences(calib, 8, seed)
    F = fundamental_8point(p1, p2)
    assert F.shape == (3, 3) and F.dtype == torch.float64
    assert float(sampson_distance(p1, p2, F).max()) < 1e-6  # px²
    # 7 degrees of freedom: unit Frobenius norm, rank 2
    assert abs(float(torch.linalg.matrix_norm(F)) - 1) < 1e-12
    assert float(torch.linalg.svdvals(F)[2]) < 1e-12


def test_hartley_normalisation():
    pts = torch.rand(2, 50, 2, dtype=torch.float64) * 600 + 30
    x, T = normalize_points_hartley(pts)
    assert x.mean(-2).abs().max() < 1e-12
    assert torch.allclose(x.norm(dim=-1).mean(-1), torch.full((2,), math.sqrt(2), dtype=torch.float64))
    homog = torch.cat([pts, torch.ones_like(pts[..., :1])], -1) @ T.transpose(-1, -2)
    assert torch.allclose(homog[..., :2], x)


@pytest.mark.parametrize("batch", [(), (3,), (2, 2)])
def test_shapes_and_dtype(batch):
    calib = random_rig(0)
    _, p1, p2 = random_correspondences(calib, 20, 0)
    p1, p2 = p1.float().expand(*batch, 20, 2), p2.float().expand(*batch, 20, 2)
    F = fundamental_8point(p1, p2)
    assert F.shape == (*batch, 3, 3) and F.dtype == torch.float32
    assert sampson_distance(p1, p2, F).shape == (*batch, 20)
    assert epipolar_lines(p1, F).shape == (*batch, 20, 3)


def test_against_kornia_and_opencv():
    calib = random_rig(5)
    _, p1, p2 = random_correspondences(calib, 60, 5)
    g = torch.Generator().manual_seed(0)
    n1 = p1 + 0.3 * torch.randn(p1.shape, generator=g, dtype=torch.float64)
    n2 = p2 + 0.3 * torch.randn(p2.shape, generator=g, dtype=torch.float64)
    F = fundamental_8point(n1, n2)
    F_kornia = find_fundamental(n1[None], n2[None], method="8POINT")[0]
    # reference: cv2.findFundamentalMat(n1, n2, cv2.FM_8POINT)
    F_cv, _ = cv2.findFundamentalMat(n1.numpy(), n2.numpy(), cv2.FM_8POINT)
    assert _same_up_to_scale(F, F_kornia) < 1e-6
    assert _same_up_to_scale(F, torch.from_numpy(F_cv)) < 1e-6
    # the noisy estimate stays close to the true geometry
    assert float(sampson_distance(p1, p2, F).sqrt().median()) < 0.5


def test_sampson_matches_kornia():
    from kornia.geometry.epipolar import sampson_epipolar_distance

    p1, p2 = torch.rand(2, 30, 2, dtype=torch.float64).unbind(0)
    F = torch.randn(3, 3, dtype=torch.float64)
    assert torch.allclose(
        sampson_distance(p1 * 500, p2 * 500, F), sampson_epipolar_distance(p1 * 500, p2 * 500, F)
    )


def test_degrees_of_freedom_by_jacobian_rank():
    """F lives on a 7-dimensional manifold, E on a 5-dimensional one: the Jacobian of the estimate with
    respect to (many, noisy) input points has exactly that rank."""
    calib = random_rig(2)
    _, p1, p2 = random_correspondences(calib, 30, 2)
    g = torch.Generator().manual_seed(1)
    p1 = p1 + 0.5 * torch.randn(p1.shape, generator=g, dtype=torch.float64)
    J_F = torch.autograd.functional.jacobian(lambda a, b: fundamental_8point(a, b).flatten(), (p1, p2))
    J_F = torch.cat([j.reshape(9, -1) for j in J_F], 1)
    sv = torch.linalg.svdvals(J_F)
    assert int((sv > 1e-8 * sv[0]).sum()) == 7

    def essential(a, b):
        return essential_from_fundamental(fundamental_8point(a, b), calib.K1, calib.K2).flatten()

    J_E = torch.cat([j.reshape(9, -1) for j in torch.autograd.functional.jacobian(essential, (p1, p2))], 1)
    sv = torch.linalg.svdvals(J_E)
    assert int((sv > 1e-8 * sv[0]).sum()) == 5


@pytest.mark.parametrize("method", ["ransac", "lmeds"])
def test_robust_fundamental_recovers_inliers_with_30_percent_outliers(method):
    calib = random_rig(11)
    _, p1, p2 = random_correspondences(calib, 200, 11)
    g = torch.Generator().manual_seed(3)
    p1 = p1 + 0.3 * torch.randn(p1.shape, generator=g, dtype=torch.float64)
    p2 = p2 + 0.3 * torch.randn(p2.shape, generator=g, dtype=torch.float64)
    outlier = torch.zeros(200, dtype=torch.bool)
    outlier[torch.randperm(200, generator=g)[:60]] = True
    p2[outlier] = torch.rand(60, 2, generator=g, dtype=torch.float64) * torch.tensor([639.0, 479.0])
    # an outlier far from its true epipolar line is detectable; random ones near it are genuinely consistent
    F_true = fundamental_from_pose(calib.K1, calib.K2, calib.R, calib.t)
    detectable = outlier & (sampson_distance(p1, p2, F_true).sqrt() > 3.0)
    est = fundamental_robust(p1, p2, method=method, threshold=1.5, seed=0)
    assert est.inliers.dtype == torch.bool and est.inliers.shape == (200,)
    assert float(est.inliers[~outlier].double().mean()) > 0.95  # recall of the true inliers
    assert not bool((est.inliers & detectable).any())  # every detectable outlier rejected
    # the estimate is as good as the noise allows on the true inliers
    assert float(sampson_distance(p1[~outlier], p2[~outlier], est.F).sqrt().median()) < 0.5
    # reference: cv2.findFundamentalMat(p1, p2, cv2.FM_RANSAC, 1.5, 0.999) agrees on most matches
    _, mask = cv2.findFundamentalMat(p1.numpy(), p2.numpy(), cv2.FM_RANSAC, 1.5, 0.999)
    cv_inliers = torch.from_numpy(mask[:, 0].astype(bool))
    assert float((cv_inliers == est.inliers).double().mean()) > 0.85


def test_epipolar_lines_and_epipoles():
    calib = random_rig(4)
    _, p1, p2 = random_correspondences(calib, 40, 4)
    F = fundamental_from_pose(calib.K1, calib.K2, calib.R, calib.t)
    lines2 = epipolar_lines(p1, F, in_image=2)
    lines1 = epipolar_lines(p2, F, in_image=1)
    assert float((lines2[:, :2].norm(dim=-1) - 1).abs().max()) < 1e-12
    assert float((lines2[:, 0] * p2[:, 0] + lines2[:, 1] * p2[:, 1] + lines2[:, 2]).abs().max()) < 1e-8
    assert float((lines1[:, 0] * p1[:, 0] + lines1[:, 1] * p1[:, 1] + lines1[:, 2]).abs().max()) < 1e-8
    e1, e2 = epipoles(F)
    assert float((F @ e1).abs().max()) < 1e-12 and float((F.T @ e2).abs().max()) < 1e-12
    # e1 is the image of the right camera centre in the left camera, e2 the image of the left centre
    c2 = -(calib.R.T @ calib.t)
    expected_e1 = project_points(c2[None], calib.K1)[0]
    expected_e2 = project_points(torch.zeros(1, 3, dtype=torch.float64), calib.K2, calib.R, calib.t)[0]
    assert torch.allclose(e1[:2] / e1[2], expected_e1, rtol=1e-6)
    assert torch.allclose(e2[:2] / e2[2], expected_e2, rtol=1e-6)
    # every epipolar line in image 1 passes through e1
    assert float((lines1 @ (e1 / e1[2])).abs().max()) < 1e-6


@pytest.mark.parametrize("seed", range(5))
def test_essential_round_trip_and_decomposition(seed):
    calib = random_rig(seed, max_rotation_deg=20)
    _, p1, p2 = random_correspondences(calib, 50, seed)
    F = fundamental_8point(p1, p2)
    E = essential_from_fundamental(F, calib.K1, calib.K2)
    s = torch.linalg.svdvals(E)
    assert abs(float(s[0] - s[1])) < 1e-12 and float(s[2]) < 1e-12  # equal singular values, rank 2
    assert _same_up_to_scale(E, essential_from_pose(calib.R, calib.t)) < 1e-8
    assert _same_up_to_scale(fundamental_from_essential(E, calib.K1, calib.K2), F) < 1e-8
    R4, t4 = decompose_essential(E)
    assert R4.shape == (4, 3, 3) and t4.shape == (4, 3)
    assert torch.allclose(torch.linalg.det(R4), torch.ones(4, dtype=torch.float64))
    pose = pose_from_essential(E, p1, p2, calib.K1, calib.K2)
    assert int(pose.in_front.max()) == 50 and int((pose.in_front == 50).sum()) == 1
    t_dir = calib.t / calib.t.norm()
    assert _angle_deg(pose.R, calib.R) < 0.1
    assert math.degrees(math.acos(min(1.0, float(pose.t @ t_dir)))) < 0.1


def test_gradcheck_eight_point():
    calib = random_rig(8)
    _, p1, p2 = random_correspondences(calib, 12, 8)
    g = torch.Generator().manual_seed(2)
    p1 = (p1 + 0.5 * torch.randn(p1.shape, generator=g, dtype=torch.float64)).requires_grad_()
    p2 = p2.clone().requires_grad_()
    assert torch.autograd.gradcheck(fundamental_8point, (p1, p2), eps=1e-6, atol=1e-6)


# ---- bad input ---------------------------------------------------------------------------------------------


def test_fewer_than_eight_points():
    p = torch.rand(7, 2, dtype=torch.float64)
    with pytest.raises(DegenerateGeometryError, match="at least 8"):
        fundamental_8point(p, p)
    with pytest.raises(DegenerateGeometryError, match="at least 8"):
        fundamental_robust(p, p)


def test_nan_and_shape_errors():
    p = torch.rand(10, 2, dtype=torch.float64)
    q = p.clone()
    q[3, 1] = float("nan")
    with pytest.raises(StereoInputError, match="pts2.*finite"):
        fundamental_8point(p, q)
    with pytest.raises(StereoInputError, match="pts1"):
        fundamental_8point(torch.rand(10, 3), p)
    with pytest.raises(TypeError, match="pts1"):
        fundamental_8point(torch.ones(10, 2, dtype=torch.long), p)


def test_collinear_points_are_refused():
    x = torch.linspace(0, 500, 12, dtype=torch.float64)
    p1 = torch.stack([x, 0.5 * x + 20], -1)
    p2 = torch.stack([x + 3, 0.5 * x + 25], -1)
    with pytest.raises(DegenerateGeometryError, match="rank < 8"):
        fundamental_8point(p1, p2)


def test_planar_scene_and_pure_rotation_are_refused():
    calib = random_rig(6)
    g = torch.Generator().manual_seed(0)
    # exactly planar scene: z = 4 + 0.1 x, seen by both cameras
    xy = torch.rand(40, 2, generator=g, dtype=torch.float64) * 2 - 1
    X = torch.cat([xy, 4 + 0.1 * xy[:, :1]], -1)
    p1 = project_points(X, calib.K1)
    p2 = project_points(X, calib.K2, calib.R, calib.t)
    with pytest.raises(DegenerateGeometryError):
        fundamental_8point(p1, p2)
    noisy = p1 + 0.1 * torch.randn(p1.shape, generator=g, dtype=torch.float64)
    with pytest.raises(DegenerateGeometryError, match="homography"):
        fundamental_robust(noisy, p2, on_planar="raise")
    assert fundamental_robust(noisy, p2).planar  # the default flags it
    _, q1, q2 = random_correspondences(calib, 40, 6)
    assert not fundamental_robust(q1, q2).planar
    # pure rotation: the rotated views of any scene are related by K2 R K1^-1
    X = torch.cat([xy, 3 + 2 * torch.rand(40, 1, generator=g, dtype=torch.float64)], -1)
    R = random_rotation(5, g)
    q1 = project_points(X, calib.K1)
    q2 = project_points(X, calib.K1, R, torch.zeros(3, dtype=torch.float64))
    with pytest.raises(DegenerateGeometryError, match="homography"):
        fundamental_robust(q1, q2, on_planar="raise")
    with pytest.raises(DegenerateGeometryError, match="pure rotation"):
        project_to_essential(essential_from_pose(R, torch.zeros(3, dtype=torch.float64)))


def test_singular_intrinsics_are_refused():
    F = torch.randn(3, 3, dtype=torch.float64)
    K = torch.tensor([[500.0, 0, 320], [0, 0, 240], [0, 0, 1]], dtype=torch.float64)
    with pytest.raises(StereoInputError, match="K1.*invertible"):
        essential_from_fundamental(F, K, torch.eye(3, dtype=torch.float64))


def test_pose_from_zero_essential_is_refused():
    calib = random_rig(1)
    _, p1, p2 = random_correspondences(calib, 40, 1)
    with pytest.raises(DegenerateGeometryError, match="pure rotation"):
        pose_from_essential(torch.zeros(3, 3, dtype=torch.float64), p1, p2, calib.K1, calib.K2)
