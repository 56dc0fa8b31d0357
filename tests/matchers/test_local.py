"""Registered local matchers (bm-*, sgm): known answers through the registry, numba == torch selection."""

from __future__ import annotations

import pytest
import torch

from stereonet import matchers
from stereonet.checks import StereoInputError
from stereonet.cost import build_cost_volume
from stereonet.select.wta import select_disparity

NAMES = ["bm-sad", "bm-ssd", "bm-zsad", "bm-lssad", "bm-ncc", "bm-census", "bm-adaptive", "sgm"]


def _plane(d: int = 6, h: int = 36, w: int = 96):
    g = torch.Generator().manual_seed(7)
    big = torch.rand(1, 3, h, w + 20, generator=g)
    return big[..., 10:10 + w].contiguous(), big[..., 10 + d:10 + w + d].contiguous()


@pytest.mark.parametrize("name", NAMES)
def test_registered_plane(name):
    left, right = _plane()
    out = matchers.match(name, left, right, 16)
    assert out.disparity.shape == (1, 1, 36, 96) and out.valid.dtype == torch.bool
    # bm-* (fused path) and sgm (16-bit fixed-point path) build no float volume unless asked to
    assert out.cost_volume is None
    assert matchers.match(name, left, right, 16, keep_volume=True).cost_volume.shape == (1, 17, 36, 96)
    inner = (slice(None), slice(None), slice(6, -6), slice(22, -6))
    good = (out.disparity[inner] - 6).abs() < 0.5
    assert (good & out.valid[inner]).float().mean() > 0.95
    assert not out.valid[..., :4].any()  # x < d: no match in the right image, LR check rejects


@pytest.mark.parametrize("name", ["bm-sad", "sgm"])
def test_registered_fill_option(name):
    left, right = _plane()
    out = matchers.match(name, left, right, 16, fill=True)
    assert torch.isfinite(out.disparity).all()
    assert (out.disparity[..., :4] - 6).abs().max() < 0.5  # border pixels take their valid neighbour


@pytest.mark.parametrize("subpixel", [None, "parabola", "equiangular"])
def test_select_numba_equals_torch(subpixel):
    g = torch.Generator().manual_seed(2)
    left, right = torch.rand(1, 1, 20, 40, generator=g), torch.rand(1, 1, 20, 40, generator=g)
    vol = build_cost_volume(left, right, 9, cost="sad", window=3)
    a = select_disparity(vol, subpixel, 0.1, lr_tol=1.0, backend="torch")
    b = select_disparity(vol, subpixel, 0.1, lr_tol=1.0, backend="numba")
    assert not a[4].all() and a[4].any()
    for x, y in zip(a, b):
        torch.testing.assert_close(x, y, rtol=1e-5, atol=1e-5)


def test_registered_bad_input():
    left, right = _plane()
    with pytest.raises(StereoInputError, match="max_disp"):
        matchers.match("sgm", left, right, 0)
    with pytest.raises(StereoInputError, match="max_disp"):
        matchers.match("bm-sad", left, right, 96)
    with pytest.raises(StereoInputError, match="right"):
        matchers.match("bm-ncc", left, right[:, :1], 8)
    with pytest.raises(StereoInputError, match="block_size"):
        matchers.match("bm-sad", left, right, 8, block_size=4)


def test_options_use_opencv_names_and_units():
    """uniqueness_ratio in percent, disp12_max_diff in px (< 0: no LR check), speckle_window / speckle_range,
    block_size, as cv2.StereoSGBM; the back end's own names are refused with the name to use."""
    left, right = _plane()
    default = matchers.match("sgm", left, right, 8)
    explicit = matchers.match("sgm", left, right, 8, block_size=1, uniqueness_ratio=5, disp12_max_diff=1,
                              speckle_window=100, speckle_range=1)
    assert torch.equal(default.disparity, explicit.disparity) and torch.equal(default.valid, explicit.valid)
    no_lr = matchers.match("bm-sad", left, right, 8, disp12_max_diff=-1, uniqueness_ratio=0)
    strict = matchers.match("bm-sad", left, right, 8, disp12_max_diff=0, uniqueness_ratio=30)
    assert no_lr.valid.all() and not strict.valid.all()
    for old, new in [("uniqueness", "uniqueness_ratio"), ("lr_tol", "disp12_max_diff"),
                     ("speckle_size", "speckle_window"), ("speckle_diff", "speckle_range"), ("window", "block_size")]:
        with pytest.raises(StereoInputError, match=f"{old}: this option is called {new}"):
            matchers.match("sgm", left, right, 8, **{old: 1})


@pytest.mark.parametrize("method, options, needle", [
    ("sgm", {"disp12_max_diff": float("nan")}, "disp12_max_diff"),  # NaN used to switch the check off silently
    ("bm-sad", {"disp12_max_diff": "1"}, "disp12_max_diff"),
    ("sgm", {"speckle_range": float("nan")}, "speckle_range"),  # NaN used to reject every pixel
    ("bm-sad", {"uniqueness_ratio": "abc"}, "uniqueness_ratio"),
    ("sgm", {"uniqueness_ratio": None}, "uniqueness_ratio"),
    ("siamese-sgm", {"disp12_max_diff": float("nan")}, "tol"),
])
def test_nan_or_non_numeric_back_end_options_are_one_line_errors(method, options, needle):
    from stereonet.checks import StereoInputError
    from stereonet.matchers import match

    left = torch.rand(1, 3, 24, 48, generator=torch.Generator().manual_seed(0))
    with pytest.raises(StereoInputError, match=needle):
        match(method, left, torch.roll(left, -2, -1), 8, **options)


@pytest.mark.parametrize("method", ["sgm", "bp", "sgm-refine"])
def test_half_precision_images_run_the_torch_reference(method):
    """float16 / bfloat16 pass the image checks; the compiled kernels take float32/float64, so these run in torch
    (they used to fail inside numba)."""
    from stereonet.matchers import match

    left = torch.rand(1, 3, 24, 48, generator=torch.Generator().manual_seed(0))
    right = torch.roll(left, -2, -1)
    ref = match(method, left, right, 8).disparity
    for dtype in (torch.float16, torch.bfloat16):
        out = match(method, left.to(dtype), right.to(dtype), 8).disparity
        assert out.dtype == dtype
        both = torch.isfinite(out.float()) & torch.isfinite(ref)
        assert float((out.float() - ref)[both].abs().median()) < 0.05


@pytest.mark.parametrize("method, options, size, needle", [
    ("opencv-bm", {"block_size": 4}, (24, 48), "block_size"),
    ("opencv-bm", {"texture_threshold": -1}, (24, 48), "texture_threshold"),
    ("opencv-bm", {}, (12, 48), "smaller than opencv-bm's 15 px window"),
    ("opencv-sgbm", {"block_size": 5.0}, (24, 48), "block_size"),
    ("opencv-sgbm", {"disp12_max_diff": 1.5}, (24, 48), "disp12_max_diff"),
    ("opencv-sgbm", {}, (24, 5), "OpenCV cannot match a 5x24 pair"),
])
def test_opencv_matchers_name_bad_options_and_sizes(method, options, size, needle):
    from stereonet.checks import StereoInputError
    from stereonet.matchers import match

    left = torch.rand(1, 3, *size, generator=torch.Generator().manual_seed(0))
    with pytest.raises(StereoInputError, match=needle):
        match(method, left, torch.roll(left, -1, -1), 2, **options)
