"""Fused block matching (cost rows + selection in one numba pass, no volume) == selection of the volume."""

from __future__ import annotations

import numba
import pytest
import torch

from stereonet import matchers
from stereonet.cost import build_cost_volume
from stereonet.select.wta import block_select_disparity, select_disparity

CASES = [
    ("ad", 1, {}), ("sad", 5, {}), ("ssd", 7, {}), ("zsad", 5, {}), ("lssad", 5, {}), ("ncc", 5, {}),
    ("census", 3, {"census_window": 5}), ("census", 1, {"census_window": 9}), ("census_ad", 3, {}),
    ("adaptive", 5, {"mode": "multiwindow"}), ("adaptive", 3, {"mode": "shiftable", "base": "ssd"}),
]


def _pair(quantized: bool, b: int = 2, c: int = 3, h: int = 70, w: int = 41, shift: int = 4):
    """Random textured pair (h > 2 row blocks), optionally on 8-bit levels (many exact cost ties)."""
    g = torch.Generator().manual_seed(11)
    big = torch.rand(b, c, h, w + shift, generator=g)
    if quantized:
        big = (big * 8).round() / 8  # 9 grey levels: exact ties everywhere
    noise = 0.0 if quantized else 0.02 * torch.rand(b, c, h, w, generator=g)
    return big[..., shift:].contiguous(), (big[..., :w] + noise).clamp(0, 1).contiguous()


@pytest.mark.parametrize("cost, window, opts", CASES)
@pytest.mark.parametrize("quantized", [False, True])
def test_fused_equals_volume_selection(cost, window, opts, quantized):
    left, right = _pair(quantized)
    vol = build_cost_volume(left, right, 12, cost=cost, window=window, backend="numba", **opts)
    ref = select_disparity(vol, "parabola", 0.1, lr_tol=1.0, backend="numba")
    fast = block_select_disparity(left, right, 12, cost, window, "parabola", 0.1, 1.0, **opts)
    assert not ref[2].all() and not ref[4].all()  # uniqueness and LR check both reject something
    for name, a, b in zip(("disp", "min_cost", "unique", "disp_right", "lr_ok"), ref, fast):
        assert a.shape == b.shape == (2, 1, 70, 41), name
        assert torch.equal(a, b), name


@pytest.mark.parametrize("subpixel, uniqueness, lr_tol", [(None, 0.0, None), ("equiangular", 0.3, 0.0)])
def test_fused_selection_options(subpixel, uniqueness, lr_tol):
    left, right = _pair(False, b=1, c=1)
    vol = build_cost_volume(left, right, 20, cost="sad", window=3, backend="numba")
    ref = select_disparity(vol, subpixel, uniqueness, lr_tol=lr_tol, backend="torch")
    fast = block_select_disparity(left, right, 20, "sad", 3, subpixel, uniqueness, lr_tol)
    for a, b in zip(ref, fast):
        torch.testing.assert_close(a, b, rtol=1e-6, atol=1e-6)


def test_volume_independent_of_thread_count():
    left, right = _pair(False, b=1)
    threads = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = build_cost_volume(left, right, 12, cost="sad", window=9, backend="numba")
    finally:
        numba.set_num_threads(threads)
    assert torch.equal(one, build_cost_volume(left, right, 12, cost="sad", window=9, backend="numba"))


@pytest.mark.parametrize("name", ["bm-sad", "bm-ncc", "bm-census", "bm-adaptive"])
def test_registered_fast_path_equals_volume_path(name):
    left, right = _pair(True, b=1)
    fast = matchers.match(name, left, right, 12)
    slow = matchers.match(name, left, right, 12, keep_volume=True)
    assert fast.cost_volume is None and slow.cost_volume.shape == (1, 13, 70, 41)
    assert torch.equal(fast.disparity, slow.disparity) and torch.equal(fast.valid, slow.valid)
    for key in ("disparity_right", "lr_valid", "unique"):
        assert torch.equal(fast.extras[key], slow.extras[key]), key
