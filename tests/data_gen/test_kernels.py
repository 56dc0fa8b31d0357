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
