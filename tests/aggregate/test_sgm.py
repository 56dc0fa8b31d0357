"""SGM: numba kernel == torch reference, fronto-parallel plane, step edge, bad input, gradcheck."""

from __future__ import annotations

import pytest
import torch

from stereonet.aggregate.sgm import p2_maps, sgm_aggregate, sgm_aggregate_torch, sgm_directions
from stereonet.checks import StereoInputError
from stereonet.cost import build_cost_volume


@pytest.mark.parametrize("paths", [4, 8, 16])
@pytest.mark.parametrize("guided", [False, True])
def test_numba_equals_torch(paths, guided):
    g = torch.Generator().manual_seed(paths)
    cost = torch.rand(2, 7, 11, 15, generator=g)
    image = torch.rand(2, 3, 11, 15, generator=g) if guided else None
    ref = sgm_aggregate_torch(cost, 0.1, 0.6, paths, image, p2_alpha=4.0)
    fast = sgm_aggregate(cost, 0.1, 0.6, paths, image, p2_alpha=4.0, backend="numba")
    torch.testing.assert_close(fast, ref, rtol=1e-6, atol=1e-5)


def test_path_recurrence_by_hand():
    # one row, left-to-right path only: L(x) = C(x) + min(L(x-1,d), L(x-1,d±1)+P1, m+P2) - m
    cost = torch.tensor([[[[0.0, 5.0]], [[5.0, 0.0]], [[5.0, 5.0]]]]).permute(0, 1, 2, 3)  # 1x3x1x2
    from stereonet.aggregate.sgm import _path_torch

    path = _path_torch(cost, 1, 0, 1.0, torch.full((1, 1, 2), 3.0))
    # x = 1: prev = (0, 5, 5), m = 0 -> d0: 5 + 0, d1: 0 + min(5, 0 + 1, 5 + 1, 3) = 1, d2: 5 + min(5, 6, 3) = 8
    assert path[0, :, 0, 1].tolist() == [5.0, 1.0, 8.0]


def test_plane_gives_constant_disparity():
    g = torch.Generator().manual_seed(0)
    big = torch.rand(1, 1, 40, 100, generator=g)
    left, right = big[..., 10:90].contiguous(), big[..., 16:96].contiguous()
    cost = build_cost_volume(left, right, 12, cost="census", window=1)
    agg = sgm_aggregate(cost, 1.0, 8.0, paths=8, image=left, p2_alpha=10.0)
    disp = agg.argmin(1)[0, :, 12:]
    assert (disp == 6).float().mean() > 0.99


def test_p2_adapts_to_gradient():
    image = torch.zeros(1, 1, 4, 6)
    image[..., 3:] = 1.0
    maps = p2_maps(1.0, 8.0, sgm_directions(4), image, (1, 4, 6), 10.0, torch.float32, torch.device("cpu"))
    assert maps[0, 0, 0, 3].item() == pytest.approx(max(1.0, 8.0 / 11.0))  # across the edge (left-to-right)
    assert maps[0, 0, 0, 2].item() == 8.0 and maps[0, 2, 2, 3].item() == 8.0


def test_gradcheck_torch_reference():
    g = torch.Generator().manual_seed(1)
    cost = torch.rand(1, 3, 2, 3, generator=g, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda c: sgm_aggregate(c, 0.05, 0.3, 8), (cost,), fast_mode=True)


def test_bad_input():
    cost = torch.rand(1, 4, 5, 6)
    with pytest.raises(StereoInputError, match="paths"):
        sgm_aggregate(cost, 1, 2, paths=6)
    with pytest.raises(StereoInputError, match="P1/P2"):
        sgm_aggregate(cost, 3, 2)
    with pytest.raises(StereoInputError, match="image"):
        sgm_aggregate(cost, 1, 2, image=torch.rand(1, 1, 5, 7))
    with pytest.raises(StereoInputError, match="backend"):
        sgm_aggregate(cost, 1, 2, backend="cuda")
    with pytest.raises(StereoInputError, match="penalty_step"):
        sgm_aggregate(cost, 1, 2, penalty_step=0.0)


def test_penalty_step_rounds_every_penalty_in_every_backend():
    """``penalty_step`` puts P1 and every edge-adapted P2 on the grid; torch and numba agree, and the result
    differs from the exact penalties (the rounding is real) only slightly."""
    from stereonet.aggregate.sgm import quantize_penalty

    assert quantize_penalty(2.03, 1 / 16) == 2.0 and quantize_penalty(2.0, None) == 2.0
    g = torch.Generator().manual_seed(3)
    cost = torch.randint(0, 40, (1, 9, 12, 17), generator=g).float()
    image = torch.rand(1, 3, 12, 17, generator=g)
    maps = p2_maps(2.0, 48.0, sgm_directions(8), image, (1, 12, 17), 20.0, torch.float32, torch.device("cpu"),
                   penalty_step=1 / 16)
    assert torch.equal(maps * 16, torch.round(maps * 16)) and bool((maps >= 2.0).all())
    ref = sgm_aggregate_torch(cost, 2.03, 48.0, 8, image, 20.0, penalty_step=1 / 16)
    fast = sgm_aggregate(cost, 2.03, 48.0, 8, image, 20.0, backend="numba", penalty_step=1 / 16)
    assert torch.equal(ref, fast)  # integer costs, penalties on a 1/16 grid: every sum is exact
    exact = sgm_aggregate_torch(cost, 2.03, 48.0, 8, image, 20.0)
    assert not torch.equal(ref, exact) and float((ref - exact).abs().max()) < 8 * 1.0


def test_numba_sequential_sweeps_equal(monkeypatch):
    from stereonet.kernels import sgm as _sgm_numba

    g = torch.Generator().manual_seed(5)
    cost = torch.rand(1, 6, 9, 12, generator=g)
    ref = sgm_aggregate_torch(cost, 0.1, 0.6, 8)
    monkeypatch.setattr(_sgm_numba, "CONCURRENT_MAX_BYTES", 0)  # the large-volume (single buffer) branch
    torch.testing.assert_close(sgm_aggregate(cost, 0.1, 0.6, 8, backend="numba"), ref, rtol=1e-6, atol=1e-5)
