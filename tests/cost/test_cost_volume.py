"""Cost volumes: known answers on a textured fronto-parallel plane, naive references, bad input."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from stereonet.checks import StereoInputError
from stereonet.cost import (
    COSTS,
    box_mean,
    box_sum,
    build_cost_volume,
    census_signs,
    census_transform,
    correlation_similarity,
    hamming,
    min_filter,
    popcount,
)


def _plane(d: int = 5, c: int = 3, seed: int = 0, h: int = 40, w: int = 80):
    g = torch.Generator().manual_seed(seed)
    big = torch.rand(1, c, h, w + 24, generator=g, dtype=torch.float64)
    return big[..., 10:10 + w].contiguous(), big[..., 10 + d:10 + w + d].contiguous()


@pytest.mark.parametrize("cost", COSTS + ("adaptive",))
def test_plane_constant_disparity(cost):
    left, right = _plane(5)
    vol = build_cost_volume(left, right, 12, cost=cost, window=5)
    assert vol.shape == (1, 13, 40, 80) and vol.dtype == torch.float64
    assert torch.isfinite(vol).all()
    disp = vol.argmin(1)[0, :, 12:]  # away from the left border (x < d has no match)
    assert (disp == 5).float().mean() > 0.99


@pytest.mark.parametrize("window", [1, 3, 7])
def test_sad_ssd_match_naive(window):
    left, right = _plane(3, c=1, h=12, w=20)
    r = window // 2
    sad = build_cost_volume(left, right, 6, cost="sad", window=window)
    ssd = build_cost_volume(left, right, 6, cost="ssd", window=window)
    # naive: right shifted with replicated border, then mean over the in-image window
    for d in (0, 2, 5):
        rs = torch.cat([right[..., :1].expand(-1, -1, -1, d), right[..., :20 - d]], -1)
        for y in (0, 5, 11):
            for x in (d + r, 15):
                ys, xs = slice(max(y - r, 0), y + r + 1), slice(max(x - r, 0), x + r + 1)
                diff = left[0, 0, ys, xs] - rs[0, 0, ys, xs]
                assert sad[0, d, y, x].item() == pytest.approx(diff.abs().mean().item(), abs=1e-9)
                assert ssd[0, d, y, x].item() == pytest.approx(diff.square().mean().item(), abs=1e-9)


def test_invalid_positions_get_large_finite_cost():
    left, right = _plane(2)
    vol = build_cost_volume(left, right, 10, cost="sad", window=3)
    valid_max = max(vol[0, d, :, d:].max().item() for d in range(11))  # in-image costs
    fill = vol[0, 10, 0, 0].item()
    assert vol[0, 10, :, :10].eq(fill).all() and vol[0, 1, :, 0].eq(fill).all()
    assert fill >= valid_max + 1 and fill < 10


def test_chunking_gives_same_volume():
    left, right = _plane(4, h=12, w=24)
    for cost in ("sad", "ncc", "census"):
        full = build_cost_volume(left, right, 7, cost=cost, window=5)
        chunked = build_cost_volume(left, right, 7, cost=cost, window=5, memory_budget=1)
        torch.testing.assert_close(full, chunked)


def test_ncc_constant_images_no_nan():
    left = torch.full((1, 1, 16, 32), 0.5)
    right = torch.full((1, 1, 16, 32), 0.5)
    vol = build_cost_volume(left, right, 8, cost="ncc", window=5)
    assert torch.isfinite(vol).all()
    assert torch.allclose(vol[0, :, :, 8:], torch.ones(9, 16, 24))  # NCC := 0 -> cost 1


def test_ncc_gain_and_bias_invariant():
    left, right = _plane(4, c=1)
    vol_a = build_cost_volume(left, right, 8, cost="ncc", window=5)
    vol_b = build_cost_volume(left, 0.5 * right + 0.2, 8, cost="ncc", window=5)
    torch.testing.assert_close(vol_a[..., 8:], vol_b[..., 8:], atol=1e-9, rtol=0)


def test_box_filters_match_pooling():
    x = torch.rand(2, 3, 9, 13, dtype=torch.float64)
    ref = F.avg_pool2d(x, 5, stride=1, padding=2, count_include_pad=False)
    torch.testing.assert_close(box_mean(x, 5), ref)
    torch.testing.assert_close(box_sum(x, 3), F.avg_pool2d(x, 3, 1, 1, count_include_pad=True) * 9)
    torch.testing.assert_close(min_filter(x, 3), -F.max_pool2d(-x, 3, 1, 1))


def test_census_and_popcount():
    v = torch.tensor([0, 1, 3, 2**61 + 7, 2**62 - 1], dtype=torch.int64)
    assert popcount(v).tolist() == [0, 1, 2, 4, 62]
    img = torch.rand(1, 1, 10, 12)
    codes = census_transform(img, 9)  # 80 bits -> 2 words
    assert codes.shape == (1, 2, 10, 12)
    assert hamming(codes, codes).eq(0).all()
    assert hamming(codes, census_transform(1.0 - img, 9)).max() <= 80


def test_census_signs_are_the_census_bits_as_unit_vectors():
    g = torch.Generator().manual_seed(2)
    img = torch.rand(2, 3, 9, 11, generator=g)
    signs = census_signs(img, 5)
    assert signs.shape == (2, 24, 9, 11) and signs.dtype == img.dtype
    assert torch.allclose((signs * signs).sum(1), torch.ones(2, 9, 11))
    codes = census_transform(img, 5)[:, 0]  # 24 bits in one word
    bits = torch.stack([(codes >> k) & 1 for k in range(24)], dim=1)
    assert torch.equal(signs > 0, bits == 1)  # same neighbour order as the packed code
    other = torch.rand(2, 3, 9, 11, generator=g)
    dots = (signs * census_signs(other, 5)).sum(1, keepdim=True)
    assert torch.allclose(dots, 1 - 2 * hamming(census_transform(img, 5), census_transform(other, 5)) / 24, atol=1e-6)
    from stereonet.cost.census import grey_numpy, to_grey

    assert torch.equal(to_grey(img)[0, 0], torch.from_numpy(grey_numpy(img[0])))  # the same bits in numpy
    grey = torch.rand(2, 1, 9, 11, generator=g)
    assert torch.equal(census_signs(grey ** 3 * 0.7 + 0.1, 5), census_signs(grey, 5))  # any increasing change
    with pytest.raises(StereoInputError, match="census_window"):
        census_signs(img, 4)
    inner = census_signs(img, 5, pad=False)  # only where the whole window is inside: the same values there
    assert inner.shape == (2, 24, 5, 7) and torch.equal(inner, signs[..., 2:-2, 2:-2])



def test_grey_numpy_equals_to_grey_on_any_layout():
    """The numba luma kernel gives torch's bits on contiguous images, on views of (H, W, C) pixels (as photos load)
    and on crops, with 8-bit values (many equal greys, where census comparisons would flip on a rounding change)."""
    from stereonet.cost.census import grey_numpy, to_grey

    g = torch.Generator().manual_seed(3)
    img = torch.randint(0, 256, (1, 3, 67, 131), generator=g).float() / 255
    hwc = img.permute(0, 2, 3, 1).contiguous().permute(0, 3, 1, 2)
    for x in (img, hwc, hwc[..., 3:-5, 7:], torch.rand(1, 3, 5, 4, generator=g)):
        assert torch.equal(to_grey(x)[0, 0], torch.from_numpy(grey_numpy(x[0])))
    assert grey_numpy(img[0, :1]).shape == (67, 131)  # one channel: the plane itself

def test_correlation_similarity_gradcheck_and_values():
    fl = torch.rand(1, 4, 5, 9, dtype=torch.float64, requires_grad=True)
    fr = torch.rand(1, 4, 5, 9, dtype=torch.float64, requires_grad=True)
    sim = correlation_similarity(fl, fr, 3)
    assert sim.shape == (1, 4, 5, 9)
    assert sim[0, 2, 1, 5].item() == pytest.approx((fl[0, :, 1, 5] * fr[0, :, 1, 3]).mean().item())
    assert sim[0, 3, :, :3].eq(0).all()
    assert torch.autograd.gradcheck(lambda a, b: correlation_similarity(a, b, 3), (fl, fr), fast_mode=True)


@pytest.mark.parametrize("cost", ["sad", "ssd", "ncc", "zsad"])
def test_window_costs_gradcheck(cost):
    g = torch.Generator().manual_seed(1)
    left = torch.rand(1, 1, 6, 10, generator=g, dtype=torch.float64, requires_grad=True)
    right = torch.rand(1, 1, 6, 10, generator=g, dtype=torch.float64)
    # positions x >= max_disp only: the out-of-image fill value is a (detached) data-dependent constant

    def fn(a):
        return build_cost_volume(a, right, 3, cost=cost, window=3)[..., 3:]

    assert torch.autograd.gradcheck(fn, (left,), fast_mode=True)


@pytest.mark.parametrize("kwargs, match", [
    (dict(max_disp=0), "max_disp"), (dict(max_disp=80), "max_disp"), (dict(window=4), "window"),
    (dict(cost="nope"), "cost"),
])
def test_bad_input(kwargs, match):
    left, right = _plane(2)
    args = dict(max_disp=8, cost="sad", window=5) | kwargs
    with pytest.raises(StereoInputError, match=match):
        build_cost_volume(left, right, **args)


def test_mismatched_pair_raises():
    left, right = _plane(2)
    with pytest.raises(StereoInputError, match="right"):
        build_cost_volume(left, right[..., :-1], 8)
    with pytest.raises(StereoInputError, match="right"):
        build_cost_volume(left, right[:, :1], 8)
    with pytest.raises(StereoInputError, match="census_window"):
        build_cost_volume(left, right, 8, cost="census", census_window=6)


@pytest.mark.parametrize("cost, kwargs", [
    ("ad", {}), ("sad", {}), ("ssd", {}), ("zsad", {}), ("lssad", {}), ("ncc", {}), ("census", {}),
    ("census", {"census_window": 9}), ("census_ad", {}), ("adaptive", {"mode": "multiwindow"}),
    ("adaptive", {"mode": "shiftable", "base": "ssd"}),
])
def test_numba_backend_equals_torch(cost, kwargs):
    g = torch.Generator().manual_seed(3)
    left, right = torch.rand(2, 3, 17, 29, generator=g), torch.rand(2, 3, 17, 29, generator=g)
    ref = build_cost_volume(left, right, 7, cost=cost, window=5, backend="torch", **kwargs)
    fast = build_cost_volume(left, right, 7, cost=cost, window=5, backend="numba", **kwargs)
    assert fast.shape == ref.shape == (2, 8, 17, 29) and fast.dtype == torch.float32
    torch.testing.assert_close(fast, ref, rtol=1e-5, atol=1e-5 * max(1.0, float(ref.abs().max())))
    auto = build_cost_volume(left, right, 7, cost=cost, window=5, **kwargs)
    assert not auto.is_contiguous()  # auto picks the numba (B, H, W, D) layout for float32 CPU input
    rows = build_cost_volume(left, right, 7, cost=cost, window=5, backend="numba", layout="hdw", **kwargs)
    assert rows.permute(0, 2, 1, 3).is_contiguous()  # image rows of D runs of W costs
    assert torch.equal(rows, fast)  # the same values in another memory order


def test_unknown_layout_raises():
    left, right = _plane(2)
    for backend in ("torch", "numba"):
        with pytest.raises(StereoInputError, match="layout"):
            build_cost_volume(left, right, 8, cost="census_ad", layout="dhw", backend=backend)
