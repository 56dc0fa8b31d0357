"""Scanline DP: three-case occlusion DP and per-scanline energy DP (numba kernels vs torch references)."""

from __future__ import annotations

import math

import pytest
import torch

from stereonet.aggregate.dp import energy_dp, scanline_dp, scanline_dp_path
from stereonet.aggregate.mrf import left_occlusions_from_disparity
from stereonet.checks import StereoInputError
from stereonet.matchers import match
from stereonet.select.fill import fill_occlusions, scanline_fill


def abs_diff_cost(left: torch.Tensor, right: torch.Tensor, max_disp: int) -> torch.Tensor:
    """Private pixelwise |L(x) - R(x - d)| volume (B, D, H, W); out-of-image positions cost 1."""
    b, _, h, w = left.shape
    vol = torch.ones(b, max_disp + 1, h, w, dtype=left.dtype)
    for d in range(max_disp + 1):
        vol[:, d, :, d:] = (left[..., d:] - right[..., : w - d]).abs().mean(1)
    return vol


def step_edge_pair(d_back: int = 2, d_front: int = 8, front: tuple[int, int] = (24, 44), h: int = 16, w: int = 64):
    """Textured background at ``d_back`` with a textured vertical strip at ``d_front`` (left columns ``front``).

    Returns left, right (1, 1, h, w), the true disparity (h, w) and the left-occluded mask (h, w).
    """
    g = torch.Generator().manual_seed(1)
    back = torch.rand(h, w + d_front + 1, generator=g)
    fore = torch.rand(h, w + d_front + 1, generator=g)
    a, b = front
    xs = torch.arange(w)
    in_front_left = (xs >= a) & (xs < b)
    left = torch.where(in_front_left, fore[:, :w], back[:, :w])
    xr = torch.arange(w)
    in_front_right = (xr >= a - d_front) & (xr < b - d_front)
    right = torch.where(in_front_right, fore[:, d_front:d_front + w], back[:, d_back:d_back + w])
    truth = torch.where(in_front_left, d_front, d_back).expand(h, w)
    band = (xs >= a - (d_front - d_back)) & (xs < a)
    occluded = (band | (xs < d_back)).expand(h, w)
    return left[None, None], right[None, None], truth, occluded


def test_plane_gives_constant_disparity(textured_pair):
    left, right, d = textured_pair
    res = scanline_dp(abs_diff_cost(left, right, 12), occlusion_cost=0.3)
    assert res.disparity.shape == left.shape and res.occlusion.dtype == torch.bool
    assert torch.all(res.disparity[..., 12:] == d)
    # the left border x < d has no match in the right image: labelled occluded
    assert res.occlusion[..., :d].float().mean() > 0.9
    assert not res.occlusion[..., 12:].any()


def test_step_edge_labels_the_occluded_band():
    left, right, truth, occluded = step_edge_pair()
    res = scanline_dp(abs_diff_cost(left, right, 12), occlusion_cost=0.25)
    label = res.occlusion[0, 0]
    recall = (label & occluded).sum() / occluded.sum()
    precision = (label & occluded).sum() / label.sum().clamp(min=1)
    assert recall > 0.9 and precision > 0.9
    visible = ~occluded
    assert (res.disparity[0, 0][visible] == truth[visible]).float().mean() > 0.97
    # occluded pixels take the (background) disparity of their left neighbour
    band = occluded.clone()
    band[:, :2] = False
    assert (res.disparity[0, 0][band & label] == 2).float().mean() > 0.9


@pytest.mark.parametrize("seed", [0, 1])
def test_three_case_numba_equals_torch_reference(seed):
    g = torch.Generator().manual_seed(seed)
    cost = torch.randint(0, 12, (2, 7, 5, 23), generator=g).float()  # integers: exact float sums
    a = scanline_dp(cost, 5.0, backend="numba")
    b = scanline_dp(cost, 5.0, backend="torch")
    assert torch.equal(a.disparity, b.disparity)
    assert torch.equal(a.occlusion, b.occlusion)
    assert torch.equal(a.energy, b.energy)


def test_three_case_energy_is_the_path_cost():
    """Re-add the path cost from the labels: matched pixels pay their cost; every occlusion pays once."""
    g = torch.Generator().manual_seed(3)
    cost = torch.randint(0, 9, (1, 6, 4, 20), generator=g).double()
    occ_cost = 4.0
    res = scanline_dp(cost, occ_cost)
    disp, occ = res.disparity[0, 0].long(), res.occlusion[0, 0]
    for y in range(cost.shape[2]):
        matched = ~occ[y]
        data = cost[0, :, y].gather(0, disp[y][None])[0][matched].sum()
        # left-occluded pixels, plus right pixels never matched before the last matched right pixel
        xs = torch.nonzero(matched)[:, 0]
        right_used = xs - disp[y][matched]
        right_skipped = int(right_used.max()) + 1 - len(right_used) if len(xs) else 0
        expected = float(data) + occ_cost * (int(occ[y].sum()) + right_skipped)
        assert math.isclose(expected, float(res.energy[0, y]), rel_tol=1e-9)
        assert torch.all(right_used[1:] > right_used[:-1])  # ordering constraint, one-to-one


@pytest.mark.parametrize("truncation", [1.0, 2.5, math.inf])
def test_energy_dp_numba_equals_torch_reference(truncation):
    g = torch.Generator().manual_seed(0)
    cost = torch.rand(2, 8, 5, 19, generator=g, dtype=torch.float64)
    weights = torch.rand(2, 1, 5, 19, generator=g, dtype=torch.float64)
    a = energy_dp(cost, 0.35, truncation, weights=weights, backend="numba")
    b = energy_dp(cost, 0.35, truncation, weights=weights, backend="torch")
    assert torch.equal(a.disparity, b.disparity)
    torch.testing.assert_close(a.energy, b.energy)


def test_energy_dp_is_optimal_and_smooths():
    g = torch.Generator().manual_seed(0)
    truth = torch.full((1, 1, 6, 40), 3)
    truth[..., 15:30] = 7
    d = torch.arange(10).view(1, 10, 1, 1)
    cost = (d - truth).abs().clamp(max=3).double() + 2.5 * torch.rand(1, 10, 6, 40, generator=g, dtype=torch.float64)
    res = energy_dp(cost, 1.0, 2.0)
    assert (res.disparity.long() == truth).float().mean() > 0.95
    # the optimum is no worse than the true labelling and its energy is its own
    def row_energy(lab):
        data = cost.gather(1, lab).sum(dim=(1, 3))[0]
        return data + (lab[..., 1:] - lab[..., :-1]).abs().clamp(max=2).sum(dim=(1, 3))[0].double()
    assert torch.all(res.energy[0] <= row_energy(truth) + 1e-9)
    torch.testing.assert_close(res.energy[0], row_energy(res.disparity.long()))
    assert (res.disparity.long() != cost.argmin(1, keepdim=True)).any()  # WTA would be noisier


def test_fill_left_occluded():
    disp = torch.tensor([[9, 4, 9, 9, 6, 9, 1]])
    occ = torch.tensor([[True, False, True, True, False, True, False]])
    assert scanline_fill(disp, ~occ, "left").tolist() == [[4, 4, 4, 4, 6, 6, 1]]
    # the same rule through the one public fill (B, 1, H, W); the textbook rule picks the smaller neighbour
    four = lambda t: t.view(1, 1, 1, -1).float()
    assert fill_occlusions(four(disp), four(~occ).bool(), rule="left").flatten().tolist() == [4, 4, 4, 4, 6, 6, 1]
    assert fill_occlusions(four(disp), four(~occ).bool()).flatten().tolist() == [4, 4, 4, 4, 6, 1, 1]


def test_dp_matcher(textured_pair):
    left, right, d = textured_pair
    out = match("dp", left, right, 10, cost="sad", window=3, occlusion_cost=0.1)
    assert out.cost_volume.shape == (1, 11, 48, 96)
    assert torch.equal(out.valid, ~out.extras["occlusion"])
    assert (out.disparity[..., 10:] - d).abs().max() < 0.5
    assert out.valid[..., 10:].all() and not out.valid[..., :d].any()
    out = match("dp", left, right, 10, mode="energy", cost="sad", window=3)
    assert out.valid[..., 10:].all() and (out.disparity[..., 10:] - d).abs().max() < 0.5


def test_occlusions_from_disparity_on_the_step_edge():
    _, _, truth, occluded = step_edge_pair()
    found = left_occlusions_from_disparity(truth[None, None].double())
    assert torch.equal(found[0, 0], occluded)


def test_bad_inputs():
    cost = torch.rand(1, 4, 3, 8)
    with pytest.raises(StereoInputError, match="occlusion_cost"):
        scanline_dp(cost, 0.0)
    with pytest.raises(StereoInputError, match="cost"):
        scanline_dp(cost[0], 1.0)
    with pytest.raises(StereoInputError, match="cost"):
        scanline_dp(cost.clone().fill_(math.nan), 1.0)
    with pytest.raises(StereoInputError, match="backend"):
        scanline_dp(cost, 1.0, backend="cuda-magic")
    with pytest.raises(StereoInputError, match="smoothness"):
        energy_dp(cost, -1.0)
    with pytest.raises(StereoInputError, match="weights"):
        energy_dp(cost, 1.0, weights=torch.ones(1, 1, 3, 7))
    with pytest.raises(TypeError, match="cost"):
        energy_dp(cost.long(), 1.0)
    with pytest.raises(StereoInputError, match="max_disp"):
        match("dp", torch.rand(1, 1, 8, 8), torch.rand(1, 1, 8, 8), 8)


def test_scanline_path_for_teaching():
    left, right, truth, occluded = step_edge_pair()
    cost = abs_diff_cost(left, right, 12)
    res = scanline_dp(cost, 0.25)
    p = scanline_dp_path(cost, 0.25, row=3)
    assert p.dsi.shape == (13, 64) and p.path.shape[1] == 3
    assert abs(p.energy - float(res.energy[0, 3])) < 1e-9
    matched = p.path[p.path[:, 2] == 0]
    assert torch.equal(matched[:, 1], res.disparity[0, 0, 3].long()[matched[:, 0]])
    left_occ = p.path[p.path[:, 2] == 1, 0]
    assert torch.equal(torch.sort(left_occ).values, torch.nonzero(res.occlusion[0, 0, 3])[:, 0])
    assert torch.all(p.path[1:, 0] >= p.path[:-1, 0])  # monotone: the ordering constraint
    with pytest.raises(StereoInputError, match="row"):
        scanline_dp_path(cost, 0.25, row=16)
