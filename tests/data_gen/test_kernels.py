"""The numba kernels of data_gen._kernels against the torch reference path of data_gen.render."""

from __future__ import annotations

import numpy as np
import pytest
import torch

import data_gen
from data_gen.render import render_view, visible_from


@pytest.mark.parametrize("seed,rectified,difficulty", [(0, True, 4), (1, False, 3), (2, True, 1)])
def test_compiled_render_and_visibility_match_the_torch_reference(seed, rectified, difficulty):
    rng = np.random.default_rng(seed)
    rig = data_gen.sample_rig(rng, 48, 80, rectified=rectified, distortion=not rectified)
    scene = data_gen.sample_scene(rng, difficulty, rig, data_gen.default_max_disp(difficulty, 80), num_objects=10)
    for cam in (rig.left, rig.right):
        other = rig.right if cam is rig.left else rig.left
        ref = render_view(scene, cam, 2, compiled=False, second_eye=other.center)
        fast = render_view(scene, cam, 2, compiled=True, second_eye=other.center)
        assert (ref["ids"] == fast["ids"]).float().mean() > 0.999
        assert torch.equal(ref["edges"], fast["edges"]) or (ref["edges"] != fast["edges"]).float().mean() < 1e-3
        same = ref["ids"] == fast["ids"]
        torch.testing.assert_close(fast["depth"][same], ref["depth"][same], rtol=1e-4, atol=0)
        diff = (ref["image"] - fast["image"]).abs()
        assert diff.median() < 1e-5 and torch.quantile(diff.flatten(), 0.99) < 1e-3
        assert float((ref["specular"] - fast["specular"]).abs().max()) < 1e-3
        assert float((ref["specular_second"] - fast["specular_second"]).abs().max()) < 1e-3
        points = ref["points"].double()
        v_ref = visible_from(scene, other, points, compiled=False)
        v_fast = visible_from(scene, other, points, compiled=True)
        assert (v_ref == v_fast).float().mean() > 0.999


def test_compiled_camera_response_matches_the_torch_reference():
    from data_gen.pair import _camera_response_torch, _photometric, apply_camera_response
    from data_gen.scene import DIFFICULTY

    img = torch.rand(3, 40, 64, generator=torch.Generator().manual_seed(0))
    rng = np.random.default_rng(1)
    for level in (0, 2, 4):
        params = _photometric(rng, DIFFICULTY[level])
        params["gamma"] = 0.8 if level == 4 else params["gamma"]  # a clearly non-linear response
        fast = apply_camera_response(img, params, noise=False)
        ref = _camera_response_torch(img, params, True, True, False)
        assert fast.shape == ref.shape == (3, 40, 64) and fast.dtype == torch.float32
        assert float((fast - ref).abs().max()) < 1e-3  # gamma from a 4096-entry table
        noisy = apply_camera_response(img, params) - fast
        noisy_ref = _camera_response_torch(img, params, True, True, True) - ref
        inner = (ref > 0.05) & (ref < 0.95)  # away from the clipping
        ratio = float(noisy[inner].std() / noisy_ref[inner].std())
        assert 0.9 < ratio < 1.1 and abs(float(noisy[inner].mean())) < 0.2 * float(noisy_ref[inner].std())


def test_vectorised_pixel_boxes_match_the_single_sphere_boxes():
    rng = np.random.default_rng(4)
    rig = data_gen.sample_rig(rng, 48, 80, rectified=False, distortion=True)
    centres = np.array([[0.0, 0.0, 2000.0], [300.0, -100.0, 800.0], [0.0, 0.0, 5.0], [0.0, 0.0, -500.0]])
    radii = np.array([100.0, 50.0, 20.0, 10.0])  # the last two reach behind / lie behind the cameras
    for cam in (rig.left, rig.right):
        boxes = cam.pixel_bboxes(centres, radii)
        for c, r, box in zip(centres, radii, boxes):
            single = cam.pixel_bbox(c, r)
            if single is None:
                assert np.isnan(box).all()
            else:
                np.testing.assert_allclose(box, single)
    assert np.isinf(rig.left.pixel_bboxes(centres, radii)[2]).all()


def test_render_pair_ground_truth_is_the_same_with_the_torch_reference(monkeypatch):
    fast = data_gen.render_pair(8, 0, difficulty=3, height=32, width=64, rectified=False)
    monkeypatch.setattr(data_gen.render, "USE_KERNELS", False)
    ref = data_gen.render_pair(8, 0, difficulty=3, height=32, width=64, rectified=False)
    for key in ("valid", "valid_right", "occlusion"):
        assert (fast[key] != ref[key]).float().mean() < 0.01, key
    both = fast["valid"] & ref["valid"]
    torch.testing.assert_close(fast["disparity"][both], ref["disparity"][both], rtol=0, atol=1e-3)
    torch.testing.assert_close(fast["depth"], ref["depth"], rtol=1e-5, atol=0)
    assert float((fast["left"] - ref["left"]).abs().mean()) < 0.02  # same scene, different noise samples
