"""Structured light: pattern codes round-trip, decoders on synthetic captures with known answers, undecodable
pixels flagged, camera + projector depth against GT, and active vs passive stereo on a textureless scene."""

from __future__ import annotations

import math

import pytest
import torch

from data_gen import Camera, Material, Plane, Scene, Sphere, visible_from_point
from stereonet.active.scenes import make_rig, make_scene
from stereonet.active.structured_light import (
    capture_patterns,
    coded_light_scan,
    compare_active_passive,
    decode_gray_code,
    decode_phase_shift,
    gray_code,
    gray_code_bits,
    gray_code_patterns,
    gray_to_binary,
    phase_shift_patterns,
    projector_depth,
    random_dot_pattern,
    to_grey,
    unwrap_phase,
)
from stereonet.checks import StereoInputError


def test_gray_code_roundtrip_and_single_bit_changes():
    n = torch.arange(1024)
    g = gray_code(n)
    assert torch.equal(gray_to_binary(g, 10), n)
    flips = g[1:] ^ g[:-1]
    assert torch.equal(flips & (flips - 1), torch.zeros_like(flips))  # neighbours differ in exactly one bit


@pytest.mark.parametrize("width,unit", [(100, 1), (320, 2), (640, 8)])
def test_gray_patterns_decode_to_their_columns(width, unit):
    pats = gray_code_patterns(3, width, unit)
    assert pats.shape == (2 * gray_code_bits(width, unit), 3, width)
    captures = 0.1 + 0.8 * pats[None]  # a perfect camera looking straight at the projector
    index, valid = decode_gray_code(captures)
    assert valid.all()
    assert torch.equal(index[0, 0, 0], torch.arange(width) // unit)


def test_phase_shift_and_unwrap_give_exact_columns():
    width, period = 256, 16
    pats = phase_shift_patterns(2, width, period, steps=4).double()
    phase, modulation, pvalid = decode_phase_shift(0.1 + 0.7 * pats[None])
    assert pvalid.all()
    torch.testing.assert_close(modulation, torch.full_like(modulation, 0.35))
    units = (torch.arange(width) // (period // 2)).view(1, 1, 1, -1).expand(1, 1, 2, width)
    cols, valid = unwrap_phase(phase, pvalid, units, torch.ones_like(pvalid), period)
    assert valid.all()
    torch.testing.assert_close(cols[0, 0, 0], torch.arange(width, dtype=torch.float64), atol=1e-6, rtol=0)


def test_unwrap_rejects_disagreeing_codes():
    period = 16
    phase = torch.full((1, 1, 1, 3), 1.5 * math.pi, dtype=torch.float64)  # x = 11.5 (+ k * 16)
    units = torch.tensor([1, 2, 0]).view(1, 1, 1, 3)  # unit 1 holds columns 8..15; units 0 and 2 cannot
    ok = torch.ones(1, 1, 1, 3, dtype=torch.bool)
    cols, valid = unwrap_phase(phase, ok, units, ok, period)
    assert valid[0, 0, 0].tolist() == [True, False, False]
    assert float(cols[0, 0, 0, 0]) == pytest.approx(11.5) and (cols[0, 0, 0, 1:] == 0).all()


def test_undecodable_pixels_are_invalid():
    pats = gray_code_patterns(1, 64, 1)
    cap = (0.1 + 0.8 * pats[None]).repeat(1, 1, 3, 1)
    cap[:, :, 1] = 0.02  # dark row: no contrast
    cap[:, :, 2, :32] = 1.0  # saturated pixels
    _, valid = decode_gray_code(cap)
    assert valid[0, 0, 0].all() and not valid[0, 0, 1].any() and not valid[0, 0, 2, :32].any()
    ph = (0.4 + 0.7 * phase_shift_patterns(1, 64, 16)[None]).clamp(max=1.0)  # clipped sinusoid
    _, _, pvalid = decode_phase_shift(ph)
    clipped = (ph >= 0.99).any(1, keepdim=True)
    assert clipped.float().mean() > 0.5 and not pvalid[clipped].any() and pvalid[~clipped].all()
    with pytest.raises(StereoInputError, match="captures"):
        decode_gray_code(cap[:, :3])


def test_random_dots_deterministic_and_sparse():
    a = random_dot_pattern(60, 80, density=0.05, seed=3)
    assert torch.equal(a, random_dot_pattern(60, 80, density=0.05, seed=3))
    assert not torch.equal(a, random_dot_pattern(60, 80, density=0.05, seed=4))
    assert 0.0 <= float(a.min()) and float(a.max()) <= 1.0 and 0.02 < float((a > 0.5).float().mean()) < 0.2


def _scene():
    return Scene([Plane((0.0, 0.0, 2.37), (0.0, 0.0, -1.0), material=Material.flat((0.6, 0.6, 0.6))),
                  Sphere((0.05, 0.0, 1.7), 0.3, material=Material.flat((0.5, 0.45, 0.4)))])


def test_camera_projector_depth_matches_gt():
    cam = Camera.pinhole(80.0, 80, 60)
    proj = Camera.pinhole(160.0, 160, 120, eye=(0.25, 0.0, 0.0))
    scan = coded_light_scan(_scene(), cam, proj, method="gray+phase", period=16)
    e = scan.errors()
    assert e["density"] > 70
    assert e["median_abs_err"] < 3e-3
    assert e["wrong_code"] == 0.0
    assert (scan.depth[~scan.valid] == 0).all()
    gray = coded_light_scan(_scene(), cam, proj, method="gray", unit=4).errors()
    assert gray["density"] > 30 and gray["wrong_code"] == 0.0
    assert gray["median_abs_err"] > e["median_abs_err"]  # quantised to stripes vs sub-pixel phase


def test_saturated_and_shadowed_pixels_get_no_depth():
    cam = Camera.pinhole(80.0, 80, 60)
    proj = Camera.pinhole(160.0, 160, 120, eye=(0.25, 0.0, 0.0))
    bright = Scene([Plane((0.0, 0.0, 2.5), (0.0, 0.0, -1.0), material=Material.flat((0.6, 0.6, 0.6))),
                    Sphere((0.05, 0.0, 1.7), 0.3, material=Material.flat((1.0, 1.0, 1.0)))])
    scan = coded_light_scan(bright, cam, proj, power=2.5)  # the white sphere saturates
    saturated = (to_grey(scan.captures) >= 0.99).any(1)[0]
    assert saturated.sum() > 100
    assert not scan.valid[0, 0][saturated].any()
    assert scan.errors()["wrong_code"] == 0.0
    # projector shadow of the sphere on the wall: no pattern, no depth
    plain = coded_light_scan(_scene(), cam, proj)
    wall = plain.view.hit & (plain.view.depth > 2.3)
    lit = visible_from_point(_scene(), proj.center, plain.view.points.reshape(-1, 3)).view(wall.shape)
    shadow = wall & ~lit
    assert shadow.sum() > 20 and not plain.valid[0, 0][shadow].any()


def test_projector_depth_checks_shapes():
    cam = Camera.pinhole(80.0, 80, 60)
    proj = Camera.pinhole(160.0, 160, 120, eye=(0.25, 0.0, 0.0))
    with pytest.raises(StereoInputError, match="columns"):
        projector_depth(torch.zeros(1, 1, 10, 10), torch.ones(1, 1, 10, 10, dtype=torch.bool), cam, proj)
    with pytest.raises(StereoInputError, match="patterns"):
        capture_patterns(_scene(), cam, proj, torch.zeros(2, 10, 10))


def test_capture_is_lambertian_times_pattern():
    cam = Camera.pinhole(50.0, 40, 30)
    proj = Camera.pinhole(50.0, 40, 30, eye=(0.0, 0.0, 0.0))  # co-located: no shadows, no parallax
    scene = Scene([Plane((0.0, 0.0, 2.0), (0.0, 0.0, -1.0), material=Material.flat((0.5, 0.5, 0.5)))])
    pats = torch.stack([torch.zeros(30, 40), torch.ones(30, 40)])
    cap = capture_patterns(scene, cam, proj, pats, power=0.6, ambient=0.2, light=0.0, noise_std=0.0)
    grey = to_grey(cap.images)[0]
    lam = 1.0 / cap.view.points.norm(dim=-1) * 2.0  # cos between normal (0,0,-1) and the ray to the origin
    torch.testing.assert_close(grey[1] - grey[0], (0.5 * 0.6 * lam).float(), atol=1e-5, rtol=0)


def test_dot_projector_makes_textureless_scene_matchable():
    rig = make_rig(128, 96, focal=120.0, baseline=0.2)
    dots = random_dot_pattern(rig.projector.height, rig.projector.width, density=0.08, dot_sigma=1.0)
    r = compare_active_passive(make_scene("textureless", 1, objects=2), rig, "opencv-sgbm", dots)
    assert r["passive"]["bad2_noc"] > 50
    assert r["active"]["bad2_noc"] < r["passive"]["bad2_noc"] - 30
