"""One camera model: data_gen's :class:`~data_gen.Camera` (the renderer's and the active sensors' cameras) and
the differentiable functions of :mod:`stereonet.geometry.camera` give the same pixels, depths and rays,
OpenCV distortion included."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from data_gen import Camera
from stereonet.geometry.camera import back_project, camera_centre, project_points, world_to_camera


def _camera(dist) -> Camera:
    return Camera.pinhole(420.0, 320, 240, eye=(0.15, -0.1, -0.05), target=(0.1, 0.05, 3.0), cx=158.3, cy=121.7,
                          dist=dist)


def _points(n: int = 300) -> torch.Tensor:
    g = torch.Generator().manual_seed(0)
    return torch.rand(n, 3, generator=g, dtype=torch.float64) * torch.tensor([2.0, 1.5, 2.0]) + torch.tensor(
        [-0.9, -0.7, 2.0])


@pytest.mark.parametrize("dist", [None, (-0.12, 0.03, 0.0, 0.0, 0.0), (0.08, -0.02, 0.001, -0.002, 0.004)])
def test_data_gen_camera_projects_like_geometry_camera(dist):
    cam = _camera(dist)
    pts = _points()
    K, R, t = (torch.as_tensor(a) for a in (cam.K, cam.R, cam.t))
    d = None if cam.dist is None else torch.as_tensor(cam.dist)
    pix_ref, z_ref = project_points(pts, K, R, t, d, return_depth=True)
    pix, z = cam.project(pts)
    torch.testing.assert_close(pix, pix_ref, rtol=0, atol=1e-9)
    torch.testing.assert_close(z, z_ref, rtol=0, atol=1e-12)
    torch.testing.assert_close(cam.to_camera(pts), world_to_camera(pts, R, t))
    torch.testing.assert_close(torch.as_tensor(cam.center), camera_centre(R, t))


@pytest.mark.parametrize("dist", [None, (-0.12, 0.03, 0.0, 0.0, 0.0), (0.08, -0.02, 0.001, -0.002, 0.004)])
def test_data_gen_rays_are_geometry_back_projections(dist):
    cam = _camera(dist)
    g = torch.Generator().manual_seed(1)
    pix = torch.rand(200, 2, generator=g, dtype=torch.float64) * torch.tensor([319.0, 239.0])
    K, R, t = (torch.as_tensor(a) for a in (cam.K, cam.R, cam.t))
    d = None if cam.dist is None else torch.as_tensor(cam.dist)
    at_depth_1 = back_project(pix, K, None, R, t, d)  # world points at camera depth 1
    rays = cam.ray_dirs(pix[:, 0], pix[:, 1])  # world directions with camera z = 1 from the centre
    torch.testing.assert_close(torch.as_tensor(cam.center) + rays, at_depth_1, rtol=0, atol=1e-8)
    np.testing.assert_allclose(cam.project(at_depth_1)[0].numpy(), pix.numpy(), atol=1e-6)
