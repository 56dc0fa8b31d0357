"""Differentiable pieces: soft-argmin and smooth-min DP / SGM aggregation (float64 gradchecks, hard limits)."""

from __future__ import annotations

import pytest
import torch

from stereonet.aggregate.dp import energy_dp
from stereonet.aggregate.soft import (
    sgm_penalty_matrix,
    soft_argmax,
    soft_argmin,
    soft_dp_aggregate,
    soft_path_aggregate,
    soft_sgm_aggregate,
)
from stereonet.checks import StereoInputError


def hard_sgm_path_left_to_right(cost: torch.Tensor, P1: float, P2: float) -> torch.Tensor:
    """Hirschmüller's recursion for the left-to-right path, written out with hard minima."""
    pen = sgm_penalty_matrix(cost.shape[1], P1, P2, cost.dtype)
    out = cost.clone()
    for x in range(1, cost.shape[-1]):
        prev = out[..., x - 1]  # BxDxH
        step = (prev[:, None] + pen.view(1, *pen.shape, 1)).amin(dim=2) - prev.amin(dim=1, keepdim=True)
        out[..., x] = cost[..., x] + step
    return out


def rand(*shape, seed=0):
    return torch.rand(*shape, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)


def test_soft_argmin_limits():
    cost = rand(2, 9, 4, 5)
    hard = cost.argmin(dim=1, keepdim=True).double()
    torch.testing.assert_close(soft_argmin(cost, 1e-4), hard)
    assert torch.allclose(soft_argmin(cost, 1e6), torch.full_like(hard, 4.0), atol=1e-4)  # mean of 0..8
    torch.testing.assert_close(soft_argmax(-cost, 0.3), soft_argmin(cost, 0.3))
    out = soft_argmin(cost, 0.5)
    assert out.shape == (2, 1, 4, 5) and out.min() >= 0 and out.max() <= 8


def test_soft_argmin_gradcheck():
    cost = rand(1, 5, 3, 4).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda c: soft_argmin(c, 0.7), (cost,))


def test_soft_sgm_gradcheck():
    cost = rand(1, 4, 3, 4).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda c: soft_sgm_aggregate(c, 0.1, 0.4, temperature=0.3), (cost,))


def test_soft_dp_gradcheck():
    cost = rand(1, 4, 2, 5).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda c: soft_argmin(soft_dp_aggregate(c, 0.3, 2.0, 0.4), 0.4), (cost,))


@pytest.mark.parametrize("direction", ["left", "right", "up", "down"])
def test_soft_sgm_path_tends_to_hard_sgm(direction):
    cost = rand(1, 6, 5, 7, seed=1)
    pen = sgm_penalty_matrix(6, 0.2, 0.7)
    soft = soft_path_aggregate(cost, pen, 1e-7, direction)
    # express every direction as left-to-right on a rearranged volume
    view = {"left": lambda c: c, "right": lambda c: c.flip(3), "up": lambda c: c.transpose(2, 3),
            "down": lambda c: c.transpose(2, 3).flip(3)}[direction]
    undo = {"left": lambda c: c, "right": lambda c: c.flip(3), "up": lambda c: c.transpose(2, 3),
            "down": lambda c: c.flip(3).transpose(2, 3)}[direction]
    hard = undo(hard_sgm_path_left_to_right(view(cost), 0.2, 0.7))
    torch.testing.assert_close(soft, hard, atol=1e-5, rtol=0)
    total = soft_sgm_aggregate(cost, 0.2, 0.7, 1e-7)
    assert total.shape == cost.shape


def test_soft_dp_tends_to_energy_dp():
    """Min-marginals at τ -> 0: their minimum is the optimal scanline energy at every pixel, argmin = Viterbi."""
    cost = rand(1, 6, 4, 9, seed=2)
    marg = soft_dp_aggregate(cost, 0.3, 2.0, temperature=1e-7)
    exact = energy_dp(cost, 0.3, 2.0)
    torch.testing.assert_close(marg.amin(dim=1), exact.energy[:, :, None].expand(1, 4, 9), atol=1e-5, rtol=0)
    assert torch.equal(marg.argmin(dim=1, keepdim=True).double(), exact.disparity)


def test_soft_sgm_smooths_a_noisy_plane():
    g = torch.Generator().manual_seed(0)
    d = torch.arange(8, dtype=torch.float64).view(1, 8, 1, 1)
    cost = (d - 3).abs() + 3.0 * torch.rand(1, 8, 10, 12, generator=g, dtype=torch.float64)
    agg = soft_sgm_aggregate(cost, 1.5, 4.0, temperature=0.1)
    assert (agg.argmin(1) == 3).float().mean() > (cost.argmin(1) == 3).float().mean()
    assert (agg.argmin(1) == 3).float().mean() > 0.9


def test_bad_inputs():
    cost = rand(1, 4, 3, 5)
    with pytest.raises(StereoInputError, match="temperature"):
        soft_argmin(cost, 0.0)
    with pytest.raises(StereoInputError, match="temperature"):
        soft_sgm_aggregate(cost, 0.1, 0.2, temperature=-1.0)
    with pytest.raises(StereoInputError, match="P1"):
        soft_sgm_aggregate(cost, 0.5, 0.1)
    with pytest.raises(StereoInputError, match="penalty"):
        soft_path_aggregate(cost, torch.zeros(3, 3), 1.0)
    with pytest.raises(StereoInputError, match="direction"):
        soft_path_aggregate(cost, torch.zeros(4, 4), 1.0, direction="diagonal")
    with pytest.raises(StereoInputError, match="cost"):
        soft_argmin(cost[0], 1.0)
