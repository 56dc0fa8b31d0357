"""sgm's opt-in weighted median (wmf_radius): off by default, else eval.py's fill then the image-guided filter."""

import pytest
import torch

from stereonet.checks import StereoInputError
from stereonet.matchers import match
from stereonet.select.fill import fill_occlusions
from stereonet.select.filters import weighted_median_filter


def _pair():
    g = torch.Generator().manual_seed(0)
    right = torch.rand(1, 3, 40, 84, generator=g)
    left = right[..., :72].clone()
    right = right[..., 2:74].clone()
    near = torch.rand(1, 3, 40, 84, generator=g)  # a nearer band (9 px) with its own texture
    left[..., 30:50], right[..., 30:50] = near[..., 30:50], near[..., 39:59]
    return left, right


def test_sgm_weighted_median_is_off_by_default_and_else_fill_then_filter():
    left, right = _pair()
    plain = match("sgm", left, right, 16)
    assert torch.equal(match("sgm", left, right, 16, wmf_radius=0).disparity, plain.disparity)
    out = match("sgm", left, right, 16, wmf_radius=5, wmf_sigma_color=0.1)
    filled = fill_occlusions(plain.disparity, plain.valid)
    expected = weighted_median_filter(filled, left, radius=5, sigma_color=0.1, stride=2)  # WMF_STRIDE by default
    assert torch.equal(out.disparity, expected) and bool(out.valid.all())
    every = match("sgm", left, right, 16, wmf_radius=5, wmf_sigma_color=0.1, wmf_stride=1)
    assert torch.equal(every.disparity, weighted_median_filter(filled, left, radius=5, sigma_color=0.1))
    assert torch.equal(out.extras["lr_consistent"], plain.valid) and not bool(plain.valid.all())
    for bad, name in (({"wmf_radius": -1}, "wmf_radius"), ({"wmf_sigma_color": 0}, "wmf_sigma_color"),
                      ({"wmf_radius": 3, "wmf_stride": True}, "wmf_stride")):
        with pytest.raises(StereoInputError, match=name):
            match("sgm", left, right, 16, **bad)
