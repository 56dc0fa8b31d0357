"""Laser stripe scanning: sub-pixel peaks with known centres, sweep geometry, a scan against GT depth,
and the degenerate cases (no stripe, saturation, two stripes, sheet through the camera centre)."""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest
import torch

from data_gen import Camera, Material, Plane, Scene, Sphere
from stereonet.active.laser import laser_scan, stripe_peaks, sweep_planes, triangulate_stripes
from stereonet.active.triangulate import plane_to_camera, ray_plane_depth
from stereonet.checks import StereoInputError


def _gaussian_rows(centres: torch.Tensor, w: int = 40, sigma: float = 1.2, amp: float = 0.6) -> torch.Tensor:
    x = torch.arange(w, dtype=torch.float64)
    rows = amp * torch.exp(-0.5 * ((x[None] - centres[:, None]) / sigma) ** 2)
    return rows[None, None]  # 1x1xHxW


def test_subpixel_peak_recovers_gaussian_centres():
    centres = torch.linspace(5.0, 34.0, 57, dtype=torch.float64)  # all sub-pixel phases
    cols, valid = stripe_peaks(_gaussian_rows(centres))
    assert valid.all()
    assert (cols[0, 0] - centres).abs().max() < 1e-6  # the 3-point Gaussian fit is exact for Gaussians


def test_subpixel_peak_with_noise_is_accurate():
    g = torch.Generator().manual_seed(0)
    centres = 8 + 24 * torch.rand(200, generator=g, dtype=torch.float64)
    img = (_gaussian_rows(centres) + 0.005 * torch.randn(1, 1, 200, 40, generator=g, dtype=torch.float64)).clamp(0, 1)
    cols, valid = stripe_peaks(img)
    assert valid.float().mean() > 0.95
    assert (cols[0, 0] - centres)[valid[0, 0]].abs().median() < 0.05


def test_rows_without_stripe_saturated_or_ambiguous_are_invalid():
    base = _gaussian_rows(torch.tensor([10.3, 20.7, 15.2, 25.5], dtype=torch.float64))
    img = base.clone()
    img[..., 0, :] = 0.01  # no stripe (dark row)
    img[..., 1, :] = (base[..., 1, :] * 3).clamp(max=1.0)  # clipped peak
    img[..., 2, :] += _gaussian_rows(torch.tensor([32.0], dtype=torch.float64))[..., 0, :]  # second stripe
    cols, valid = stripe_peaks(img)
    assert valid[0, 0].tolist() == [False, False, False, True]
    assert abs(float(cols[0, 0, 3]) - 25.5) < 1e-6
    assert (cols[0, 0, :3] == 0).all()


def test_stripe_peaks_checks_input():
    with pytest.raises(StereoInputError, match="image"):
        stripe_peaks(torch.zeros(1, 3, 4, 8))
    with pytest.raises(TypeError, match="image"):
        stripe_peaks(torch.zeros(1, 1, 4, 8, dtype=torch.int64))


def test_sweep_planes_contain_origin_and_axis():
    origin = torch.tensor([0.4, -0.1, 0.05], dtype=torch.float64)
    n, c = sweep_planes(origin, [-30.0, 0.0, 20.0])
    torch.testing.assert_close(n @ origin, c)
    torch.testing.assert_close(n @ torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64), torch.zeros(3, dtype=torch.float64))
    # angle 0: the sheet contains the forward direction, so its normal is +-x
    torch.testing.assert_close(n[1].abs(), torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64))


def _scene():
    # a wall at z = 2.5 m and a sphere with a checker of 0.1 m cells (one checker period = 16 texels of 12.5 mm)
    checker = Material(kind="checker", colors=np.array([[0.4, 0.4, 0.5], [0.9, 0.8, 0.7], [0.0, 0.0, 0.0]]),
                       texel_mm=0.2 / 16, period=16.0)
    return Scene([Plane((0.0, 0.0, 2.5), (0.0, 0.0, -1.0), material=Material.flat((0.7, 0.7, 0.7))),
                  Sphere((0.1, 0.0, 1.8), 0.35, material=checker)])


def test_laser_scan_matches_gt_depth():
    cam = Camera.pinhole(80.0, 80, 60)
    scan = laser_scan(_scene(), cam, origin=(0.5, 0.0, 0.0), angles_deg=torch.linspace(-35, 5, 50), seed=1)
    e = scan.errors()
    assert e["points"] > 700
    assert e["median_abs_err"] < 2e-3  # metres, at 1.5-2.5 m depth
    assert e["p95_abs_err"] < 3e-2  # one stripe pixel is ~10 cm at this resolution
    # no wrong depth reported valid: every point is within the depth change of a 1-pixel stripe shift
    n_c, c_c = plane_to_camera(scan.normals[scan.sheet], scan.offsets[scan.sheet], cam)
    one_px = torch.stack([ray_plane_depth(cam.K, scan.uv + torch.tensor([s, 0.0], dtype=torch.float64), n_c, c_c)[0]
                          for s in (-1.0, 1.0)])
    step = (one_px - scan.points[:, 2]).abs().amax(0)
    assert ((scan.points[:, 2] - scan.gt_depth).abs() <= step).all()
    assert scan.valid.any() and (scan.range_image[~scan.valid] == 0).all()


def test_sheet_through_camera_centre_gives_no_depth(caplog):
    cam = Camera.pinhole(60.0, 40, 30)
    scene = _scene()
    # laser at the camera centre: every sheet contains the camera centre (parallel to the camera rays)
    with caplog.at_level(logging.WARNING):
        scan = laser_scan(scene, cam, origin=(0.0, 0.0, 0.0), angles_deg=[-10.0, 0.0, 10.0])
    assert scan.points.shape[0] == 0 and not scan.valid.any()
    assert "camera centre" in caplog.text


def test_triangulate_stripes_grazing_sheet_invalid():
    cam = Camera.pinhole(60.0, 40, 30)
    # sheet almost containing the camera rays of column ~20: depth there would be wildly ill-conditioned
    n = torch.tensor([[1.0, 0.0, 0.0]], dtype=torch.float64)
    c = torch.tensor([1e-4], dtype=torch.float64)
    cols = torch.full((1, 1, 30), 19.5, dtype=torch.float64)
    pts, _, ok = triangulate_stripes(cols, torch.ones(1, 1, 30, dtype=torch.bool), cam, n, c, min_angle_deg=1.0)
    assert not ok.any()
    assert math.isfinite(float(pts.abs().max()))
