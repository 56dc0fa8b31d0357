"""Ray ∩ light-plane triangulation: known answers, degenerate planes, flying-pixel filter, gradcheck."""

from __future__ import annotations

import pytest
import torch

from data_gen import Camera
from stereonet.active.triangulate import (
    plane_to_camera,
    projector_column_planes,
    ray_plane_depth,
    reject_depth_edges,
)
from stereonet.checks import StereoInputError

K = torch.tensor([[100.0, 0.0, 32.0], [0.0, 100.0, 24.0], [0.0, 0.0, 1.0]], dtype=torch.float64)


def _grid(h=48, w=64):
    v, u = torch.meshgrid(torch.arange(h, dtype=torch.float64), torch.arange(w, dtype=torch.float64), indexing="ij")
    return torch.stack([u, v], dim=-1)


def test_fronto_parallel_plane_gives_constant_depth():
    uv = _grid()
    depth, valid = ray_plane_depth(K, uv, torch.tensor([0.0, 0.0, 2.0], dtype=torch.float64).expand(48, 64, 3),
                                   torch.full((48, 64), 5.0, dtype=torch.float64))
    assert valid.all()
    torch.testing.assert_close(depth, torch.full_like(depth, 2.5))


def test_slanted_plane_matches_analytic_depth():
    # plane x + z = 3  ->  z = 3 / (x/z + 1) with x/z = (u - cx) / f
    uv = _grid()
    depth, valid = ray_plane_depth(K, uv, torch.tensor([1.0, 0.0, 1.0], dtype=torch.float64).expand(48, 64, 3),
                                   torch.full((48, 64), 3.0, dtype=torch.float64))
    expected = 3.0 / ((uv[..., 0] - 32.0) / 100.0 + 1.0)
    assert valid.all()
    torch.testing.assert_close(depth, expected)


def test_plane_through_camera_centre_raises_or_is_invalid():
    uv = _grid(4, 4)
    n = torch.tensor([1.0, 0.0, -0.2], dtype=torch.float64).expand(4, 4, 3)
    zero = torch.zeros(4, 4, dtype=torch.float64)
    with pytest.raises(StereoInputError, match="camera centre"):
        ray_plane_depth(K, uv, n, zero)
    depth, valid = ray_plane_depth(K, uv, n, zero, degenerate="invalid")
    assert not valid.any() and (depth == 0).all()


def test_grazing_rays_are_invalid_and_behind_camera_is_invalid():
    # plane x = 0.1 seen edge-on near the principal column: rays there nearly lie in the plane
    uv = _grid()
    n = torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64).expand(48, 64, 3)
    depth, valid = ray_plane_depth(K, uv, n, torch.full((48, 64), 0.1, dtype=torch.float64), min_angle_deg=5.0)
    cols = uv[..., 0]
    assert not valid[cols <= 32].any()  # left half: the plane is behind or parallel
    x_over_z = (cols - 32.0) / 100.0
    ok = valid & (cols > 32)
    assert ok.any()
    torch.testing.assert_close(depth[ok], 0.1 / x_over_z[ok])
    steep = torch.rad2deg(torch.atan(x_over_z / torch.sqrt(1 + ((uv[..., 1] - 24) / 100) ** 2)))
    assert not valid[steep < 4.9].any()


def test_projector_column_plane_contains_projected_points():
    cam = Camera.pinhole(120.0, 64, 48)
    proj = Camera.pinhole(200.0, 128, 96, eye=(0.2, -0.05, 0.02), target=(0.0, 0.0, 2.0))
    g = torch.Generator().manual_seed(0)
    pts = torch.rand(50, 3, generator=g, dtype=torch.float64) * torch.tensor([1.0, 1.0, 1.5]) + torch.tensor([-0.5, -0.5, 1.5])
    uvp, _ = proj.project(pts)
    n, c = projector_column_planes(uvp[:, 0], cam, proj)
    pc = cam.to_camera(pts)
    torch.testing.assert_close((pc * n).sum(-1), c)
    # and triangulating the camera pixel of each point with its projector column gives its depth back
    uvc, z = cam.project(pts)
    depth, valid = ray_plane_depth(cam.K, uvc, n, c)
    assert valid.all()
    torch.testing.assert_close(depth, z)


def test_plane_to_camera_roundtrip():
    cam = Camera.pinhole(100.0, 32, 24, eye=(0.3, 0.1, -0.2), target=(0.0, 0.0, 2.0))
    n_w = torch.tensor([[0.2, 0.1, 1.0]], dtype=torch.float64)
    c_w = torch.tensor([2.5], dtype=torch.float64)
    p_w = torch.tensor([[0.0, 0.0, 2.5]], dtype=torch.float64)  # n_w . p_w = 2.5
    n_c, c_c = plane_to_camera(n_w, c_w, cam)
    torch.testing.assert_close((cam.to_camera(p_w) * n_c).sum(-1), c_c)


def test_reject_depth_edges_keeps_slanted_plane_drops_step():
    uv = _grid()
    slanted = 3.0 / ((uv[..., 0] - 32.0) / 100.0 * 0.8 + 1.0)  # steep slanted plane: inverse depth affine
    valid = torch.ones(1, 1, 48, 64, dtype=torch.bool)
    assert reject_depth_edges(slanted[None, None], valid).all()
    step = torch.where(uv[..., 0] < 30, 2.0, 3.0).to(torch.float64)[None, None]
    keep = reject_depth_edges(step, valid)
    assert not keep[..., 29].any() and not keep[..., 30].any()
    assert keep[..., :28].all() and keep[..., 32:].all()


def test_ray_plane_depth_gradcheck():
    g = torch.Generator().manual_seed(1)
    uv = (torch.rand(5, 2, generator=g, dtype=torch.float64) * 40).requires_grad_()
    n = (torch.tensor([0.1, -0.1, 1.0], dtype=torch.float64) + 0.05 * torch.rand(5, 3, generator=g,
                                                                                dtype=torch.float64)).requires_grad_()
    c = (2.0 + torch.rand(5, generator=g, dtype=torch.float64)).requires_grad_()
    assert torch.autograd.gradcheck(lambda a, b, d: ray_plane_depth(K, a, b, d)[0], (uv, n, c))
