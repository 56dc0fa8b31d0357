"""The projector on data_gen's rigs and scenes: repainted textureless scenes become matchable with dots."""

from __future__ import annotations

import pytest
import torch

from stereonet.active.structured_light import random_dot_pattern
from stereonet.checks import StereoInputError

data_gen = pytest.importorskip("data_gen")


def test_dots_on_datagen_textureless_scene_lower_bad2():
    from stereonet.active.datagen_bridge import datagen_active_pair
    from stereonet.matchers import match
    from stereonet.metrics import evaluate

    dots = random_dot_pattern(96, 128, density=0.1, dot_sigma=0.9, seed=0)
    bad2 = {}
    for name, pat in (("passive", None), ("active", dots)):
        pair, max_disp = datagen_active_pair(0, 1, pat, surface="textureless", height=96, width=128)
        assert pair.left.shape == (1, 3, 96, 128) and pair.valid.any()
        if name == "passive":
            # flat albedo: the only image structure is shading, far from enough to match
            assert float(pair.left[0].std(dim=(1, 2)).max()) < 0.2
        res = match("opencv-sgbm", pair.left, pair.right, max_disp)
        bad2[name] = evaluate(res.disparity, pair.disparity, pair.valid, res.valid, occlusion=pair.occlusion,
                              see=False)["bad2_noc"]
    assert bad2["passive"] > 50
    assert bad2["active"] < bad2["passive"] - 30


def test_pattern_shape_and_surface_are_checked():
    from stereonet.active.datagen_bridge import datagen_active_pair

    with pytest.raises(StereoInputError, match="pattern"):
        datagen_active_pair(0, 0, torch.zeros(10, 10), height=48, width=64)
    with pytest.raises(StereoInputError, match="surface"):
        datagen_active_pair(0, 0, None, surface="shiny", height=48, width=64)
