"""ICP and scan merging: exact Kabsch, both ICP variants recover known poses on a sampled analytic surface,
no-overlap raises, multi-scan alignment of rendered range scans, merged PLY round trip."""

from __future__ import annotations

import math

import pytest
import torch

from stereonet.active.icp import (
    align_scans,
    best_rigid_transform,
    estimate_normals,
    icp,
    merge_scans,
    relative_pose,
    rotation_error_deg,
    rotation_matrix,
    voxel_downsample,
)
from stereonet.checks import StereoInputError


def _surface(n=3000, seed=0):
    """Points on z = 0.3 sin(2x) cos(3y) + 0.2 x^2 over [-1, 1]^2 (no symmetry ICP could slide along)."""
    g = torch.Generator().manual_seed(seed)
    xy = torch.rand(n, 2, generator=g, dtype=torch.float64) * 2 - 1
    z = 0.3 * torch.sin(2 * xy[:, 0]) * torch.cos(3 * xy[:, 1]) + 0.2 * xy[:, 0] ** 2
    return torch.cat([xy, z[:, None]], 1)


def test_rotation_matrix_is_rodrigues():
    R = rotation_matrix([0.0, 0.0, math.pi / 2])
    torch.testing.assert_close(R @ torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64),
                               torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64))
    assert rotation_error_deg(R, torch.eye(3, dtype=torch.float64)) == pytest.approx(90.0)


def test_best_rigid_transform_exact():
    P = _surface(200)
    R = rotation_matrix([0.3, -0.5, 0.8])
    t = torch.tensor([0.5, -1.0, 2.0], dtype=torch.float64)
    R_est, t_est = best_rigid_transform(P, P @ R.T + t)
    torch.testing.assert_close(R_est, R)
    torch.testing.assert_close(t_est, t)
    assert torch.linalg.det(R_est) == pytest.approx(1.0)


@pytest.mark.parametrize("method", ["point_to_point", "point_to_plane"])
def test_icp_recovers_known_pose(method):
    P = _surface(2500)
    g = torch.Generator().manual_seed(1)
    R = rotation_matrix([0.05, -0.08, 0.1])  # ~7.6 degrees
    t = torch.tensor([0.05, -0.03, 0.02], dtype=torch.float64)
    Q = _surface(2500, seed=5) @ R.T + t + 0.002 * torch.randn(2500, 3, generator=g, dtype=torch.float64)
    res = icp(P, Q, method=method, max_distance=0.3, max_iterations=100)
    assert rotation_error_deg(res.R, R) < 0.3
    assert float((res.t - t).norm()) < 5e-3
    assert res.rmse < 0.03 and res.overlap > 0.9  # independent samplings: NN spacing ~0.04


def test_point_to_plane_converges_in_fewer_iterations():
    P = _surface(2000)
    R = rotation_matrix([0.04, 0.02, -0.06])
    Q = P @ R.T + torch.tensor([0.03, 0.0, -0.02], dtype=torch.float64)
    a = icp(P, Q, method="point_to_point", max_distance=0.3, max_iterations=100)
    b = icp(P, Q, method="point_to_plane", max_distance=0.3, max_iterations=100)
    assert b.converged and b.iterations < a.iterations


def test_no_overlap_raises():
    P = _surface(500)
    far = P + torch.tensor([5.0, 0.0, 0.0], dtype=torch.float64)
    with pytest.raises(StereoInputError, match="do not overlap"):
        icp(P, far, max_distance=0.1)
    with pytest.raises(StereoInputError, match="method"):
        icp(P, P, method="plane_to_plane")
    with pytest.raises(StereoInputError, match="source"):
        icp(torch.zeros(10, 2, dtype=torch.float64), P)


def test_estimate_normals_of_plane_face_viewpoint():
    g = torch.Generator().manual_seed(0)
    pts = torch.cat([torch.rand(400, 2, generator=g, dtype=torch.float64), torch.full((400, 1), 2.0, dtype=torch.float64)], 1)
    n = estimate_normals(pts, k=8, viewpoint=(0.5, 0.5, 0.0))
    torch.testing.assert_close(n, torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64).expand_as(n))


def test_voxel_downsample_averages():
    pts = torch.tensor([[0.01, 0.01, 0.01], [0.03, 0.03, 0.03], [1.01, 0.0, 0.0]], dtype=torch.float64)
    col = torch.tensor([[0, 0, 0], [200, 100, 50], [9, 9, 9]], dtype=torch.uint8)
    p, c = voxel_downsample(pts, col, 0.1)
    order = torch.argsort(p[:, 0])
    torch.testing.assert_close(p[order[0]], torch.full((3,), 0.02, dtype=torch.float64))
    assert c[order[0]].tolist() == [100, 50, 25] and c.dtype == torch.uint8


def test_align_rendered_scans_and_write_ply(tmp_path):
    from stereonet.active.demo import orbit_cameras
    from stereonet.active.render import render_range_scan
    from stereonet.active.scenes import make_scene
    from stereonet.io import read_ply, write_ply

    scene = make_scene("textured", 2, objects=3)
    cams = orbit_cameras(3, spread_deg=30.0, width=80, height=60, focal=80.0)
    scans = [render_range_scan(scene, c, noise_std=0.002, seed=i, max_range=4.0) for i, c in enumerate(cams)]
    gt = [relative_pose(scans[0].R, scans[0].t, s.R, s.t) for s in scans]
    init_R = [rotation_matrix([0.03, -0.04, 0.02]) @ R for R, _ in gt]
    init_t = [t + torch.tensor([0.03, 0.02, -0.03], dtype=torch.float64) for _, t in gt]
    al = align_scans([s.points for s in scans], init_R, init_t, method="point_to_plane", voxel=0.03)
    for i in (1, 2):
        assert rotation_error_deg(al.R[i], gt[i][0]) < 0.5
        assert float((al.t[i] - gt[i][1]).norm()) < 0.01
        assert rotation_error_deg(init_R[i], gt[i][0]) > 2.0  # the guess really was off
    pts, col = merge_scans([s.points for s in scans], [s.colors for s in scans], al.R, al.t, voxel=0.01)
    write_ply(tmp_path / "merged.ply", pts, col)
    p2, c2 = read_ply(tmp_path / "merged.ply")
    assert p2.shape == pts.shape and c2 is not None and (c2 == col.numpy()).all()
    # a scan that shares nothing with the others (pushed 20 m away by its guess) is an error, not a pose
    far_t = list(init_t)
    far_t[2] = far_t[2] + torch.tensor([20.0, 0.0, 0.0], dtype=torch.float64)
    with pytest.raises(StereoInputError, match=r"points\[2\].*do not overlap"):
        align_scans([s.points for s in scans], init_R, far_t, voxel=0.03)


def test_ransac_rigid_ignores_outliers():
    from stereonet.active.icp import ransac_rigid

    g = torch.Generator().manual_seed(3)
    P = _surface(60)
    R = rotation_matrix([0.2, -0.4, 0.3])
    t = torch.tensor([0.3, 0.1, -0.2], dtype=torch.float64)
    Q = P @ R.T + t
    Q[:20] = torch.rand(20, 3, generator=g, dtype=torch.float64) * 3  # a third are wrong matches
    R_est, t_est, inl = ransac_rigid(P, Q, threshold=0.01)
    # the matrices themselves (the angle via arccos cannot resolve below ~1e-6 degrees in float64)
    assert float((R_est - R).abs().max()) < 1e-8 and float((t_est - t).norm()) < 1e-6
    assert inl[20:].all() and not inl[:20].any()
    with pytest.raises(StereoInputError, match="no rigid motion"):
        ransac_rigid(P, torch.rand(60, 3, generator=g, dtype=torch.float64) * 3, threshold=0.001)


def test_feature_guess_between_rendered_scans():
    from stereonet.active.demo import orbit_cameras
    from stereonet.active.icp import feature_guess
    from stereonet.active.render import render_range_scan
    from stereonet.active.scenes import make_scene

    scene = make_scene("textured", 0)
    cams = orbit_cameras(2, spread_deg=12.0, width=160, height=120, focal=160.0)
    a, b = (render_range_scan(scene, c, seed=i, max_range=4.0) for i, c in enumerate(cams))
    R, t, n = feature_guess(a, b)
    R_gt, t_gt = relative_pose(a.R, a.t, b.R, b.t)
    assert n >= 6
    assert rotation_error_deg(R, R_gt) < 1.5 and float((t - t_gt).norm()) < 0.05
