"""α-expansion graph cuts: energy never increases, exact on binary Potts, known answers, bad input."""

from __future__ import annotations

import itertools

import pytest
import torch

from stereonet.aggregate.graphcut import alpha_expansion
from stereonet.aggregate.mrf import grid_energy
from stereonet.checks import StereoInputError
from stereonet.matchers import match


def test_energy_never_increases_and_recovers_the_truth():
    g = torch.Generator().manual_seed(0)
    truth = torch.full((1, 1, 24, 40), 3)
    truth[..., 6:18, 12:28] = 10
    d = torch.arange(16).view(1, 16, 1, 1)
    cost = (d - truth).abs().clamp(max=4).float() + 3.0 * torch.rand(1, 16, 24, 40, generator=g)
    res = alpha_expansion(cost, 1.0, 2.0, cycles=2)
    hist = res.history[0]
    assert len(hist) > 16 and all(b <= a for a, b in zip(hist, hist[1:]))
    assert hist[-1] < 0.8 * hist[0]
    torch.testing.assert_close(res.energy, grid_energy(cost, res.disparity.long(), 1.0, 2.0))
    assert abs(hist[-1] - float(res.energy)) < 1e-6 * hist[-1]
    assert (res.disparity.long() == truth).float().mean() > 0.98


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_exact_on_binary_potts(seed):
    """With two labels an expansion move is the whole problem: the result is the global optimum."""
    g = torch.Generator().manual_seed(seed)
    cost = torch.rand(1, 2, 3, 4, generator=g, dtype=torch.float64)
    wr = torch.rand(1, 1, 3, 4, generator=g, dtype=torch.float64)
    wd = torch.rand(1, 1, 3, 4, generator=g, dtype=torch.float64)
    res = alpha_expansion(cost, 0.7, 1.0, weights_right=wr, weights_down=wd)
    best = min(float(grid_energy(cost, torch.tensor(lab).view(1, 1, 3, 4), 0.7, 1.0, wr, wd))
               for lab in itertools.product((0, 1), repeat=12))
    assert abs(float(res.energy) - best) < 1e-9


def test_within_factor_two_of_optimum_on_tiny_grid():
    """α-expansion's guarantee for Potts: E <= 2 E* (Boykov et al. 2001, Theorem 6.1)."""
    g = torch.Generator().manual_seed(5)
    cost = torch.rand(1, 3, 2, 4, generator=g, dtype=torch.float64)
    res = alpha_expansion(cost, 0.5, 1.0, cycles=3)
    best = min(float(grid_energy(cost, torch.tensor(lab).view(1, 1, 2, 4), 0.5, 1.0))
               for lab in itertools.product(range(3), repeat=8))
    assert best - 1e-12 <= float(res.energy) <= 2 * best


def test_plane_and_matcher(textured_pair):
    left, right, d = textured_pair
    out = match("graphcut", left, right, 10, cost="sad", window=3)
    assert out.valid[..., 10:].all() and out.cost_volume.shape == (1, 11, 48, 96)
    assert (out.disparity[..., 10:] - d).abs().max() < 0.5
    assert out.extras["energy"].shape == (1,)


def test_init_is_used():
    cost = torch.zeros(1, 3, 4, 4)
    init = torch.full((1, 1, 4, 4), 2.0)
    res = alpha_expansion(cost, 1.0, 2.0, init=init)  # every labelling of zero cost: constant init is optimal
    assert torch.all(res.disparity == 2) and res.history[0] == [0.0] * len(res.history[0])


def test_bad_inputs():
    cost = torch.rand(1, 4, 5, 6)
    with pytest.raises(StereoInputError, match="cycles"):
        alpha_expansion(cost, 1.0, cycles=0)
    with pytest.raises(StereoInputError, match="init"):
        alpha_expansion(cost, 1.0, init=torch.full((1, 1, 5, 6), 7.0))
    with pytest.raises(StereoInputError, match="init"):
        alpha_expansion(cost, 1.0, init=torch.zeros(1, 1, 5, 5))
    with pytest.raises(StereoInputError, match="smoothness"):
        alpha_expansion(cost, -0.5)
    with pytest.raises(TypeError, match="cost"):
        alpha_expansion(cost.int(), 1.0)


def test_each_expansion_move_is_optimal():
    """The min cut finds the best of all 2^N ways to switch pixels to α (brute force on a 2x3 grid)."""
    import numpy as np

    from stereonet.aggregate.graphcut import _energy, _expansion_move

    rng = np.random.default_rng(0)
    for _ in range(30):
        cost = rng.random((5, 2, 3)) * 3
        labels = rng.integers(0, 5, (2, 3))
        s_right, s_down = rng.random((2, 3)), rng.random((2, 3))
        alpha = int(rng.integers(0, 5))
        move = _expansion_move(cost, labels, alpha, s_right, s_down, 2.0)
        assert np.all((move == labels) | (move == alpha))
        best = min(_energy(cost, np.where(np.array(x).reshape(2, 3) == 1, alpha, labels), s_right, s_down, 2.0)
                   for x in itertools.product((0, 1), repeat=6))
        assert _energy(cost, move, s_right, s_down, 2.0) <= best + 1e-9


def _expansion_terms_numpy(cost, labels, alpha, s_right, s_down, truncation):
    """The vectorised numpy construction the kernel replaced (Kolmogorov-Zabih terms of one expansion move)."""
    import numpy as np

    h, w = labels.shape
    keep_cost = np.take_along_axis(cost, labels[None], axis=0)[0]
    alpha_cost = cost[alpha].astype(np.float64, copy=True)
    to_alpha = np.minimum(np.abs(labels - alpha), truncation)
    caps = []
    for slope, lead, trail in ((s_right, np.s_[:, :-1], np.s_[:, 1:]), (s_down, np.s_[:-1, :], np.s_[1:, :])):
        s = slope[lead]
        e00 = s * np.minimum(np.abs(labels[lead] - labels[trail]), truncation)
        e01 = s * to_alpha[lead]
        e10 = s * to_alpha[trail]
        alpha_cost[lead] += e10 - e00
        alpha_cost[trail] -= e10
        capacity = np.zeros((h, w))
        capacity[lead] = np.maximum(e01 + e10 - e00, 0.0)
        caps.append(capacity)
    low = np.minimum(keep_cost, alpha_cost)
    return caps[0], caps[1], alpha_cost - low, keep_cost - low


@pytest.mark.parametrize("h, w", [(1, 1), (1, 7), (6, 1), (13, 17)])
def test_expansion_kernel_builds_the_same_graph_as_the_numpy_construction(h, w):
    """Every capacity of the compiled construction equals the vectorised numpy one to the bit (same float64
    operations in the same order), for every alpha, on random costs, labels and contrast slopes."""
    import numpy as np

    from stereonet.kernels.graphcut import expansion_terms

    rng = np.random.default_rng(h * 100 + w)
    cost = rng.random((9, h, w)) * 3
    labels = rng.integers(0, 9, (h, w)).astype(np.int64)
    s_right, s_down = rng.random((h, w)) * 0.9, rng.random((h, w)) * 0.9
    for alpha in range(9):
        out = [np.full((h, w), np.nan) for _ in range(4)]
        expansion_terms(cost, labels, alpha, s_right, s_down, 2.0, *out)
        for got, want in zip(out, _expansion_terms_numpy(cost, labels, alpha, s_right, s_down, 2.0)):
            assert np.array_equal(got, want)


def _random_problem(seed, n=6, h=7, w=9):
    g = torch.Generator().manual_seed(seed)
    cost = torch.rand(1, n, h, w, generator=g, dtype=torch.float64) * 3
    wr = torch.rand(1, 1, h, w, generator=g, dtype=torch.float64)
    wd = torch.rand(1, 1, h, w, generator=g, dtype=torch.float64)
    return cost, wr, wd


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_pruned_moves_with_every_label_a_candidate_match_the_unpruned_method(seed):
    """Every label a candidate of every pixel: each restricted move frees every pixel not already labelled α, the same
    optimal move as the grid graph's, so the same labels (random float costs: no ties) and the same energy trace."""
    cost, wr, wd = _random_problem(seed)
    n, h, w = cost.shape[1:]
    every = torch.arange(n).view(1, n, 1, 1).expand(1, n, h, w)
    full = alpha_expansion(cost, 0.8, 2.0, cycles=2, weights_right=wr, weights_down=wd)
    pruned = alpha_expansion(cost, 0.8, 2.0, cycles=2, weights_right=wr, weights_down=wd, candidates=every,
                             candidate_radius=0)
    assert torch.equal(full.disparity, pruned.disparity)
    assert len(full.history[0]) == len(pruned.history[0])
    assert all(abs(a - b) < 1e-9 * a for a, b in zip(full.history[0], pruned.history[0]))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_pruned_energy_never_increases_and_its_trace_ends_at_the_energy(seed):
    cost, wr, wd = _random_problem(seed, n=8, h=12, w=15)
    g = torch.Generator().manual_seed(seed + 10)
    cand = torch.randint(0, 8, (1, 2, 12, 15), generator=g)
    res = alpha_expansion(cost, 0.8, 2.0, cycles=3, weights_right=wr, weights_down=wd, candidates=cand,
                          candidate_radius=1)
    hist = res.history[0]
    assert all(b <= a for a, b in zip(hist, hist[1:])) and hist[-1] < hist[0]
    assert abs(hist[-1] - float(res.energy)) < 1e-9 * hist[-1]
    torch.testing.assert_close(res.energy, grid_energy(cost, res.disparity.long(), 0.8, 2.0, wr, wd))


def test_each_pruned_move_is_optimal_over_the_pixels_it_frees():
    """Brute force over every way to switch the freed pixels (those within the radius of a seed, not already α)
    to α, the others fixed: the restricted min cut (edges to fixed pixels folded into the terminals) is the best."""
    import numpy as np

    from stereonet.aggregate.graphcut import _energy, _RestrictedMoves

    rng = np.random.default_rng(1)
    for trial in range(30):
        h, w, n = 3, 4, 5
        cost = rng.random((n, h, w)) * 3
        labels = rng.integers(0, n, (h, w)).astype(np.int64)
        s_right, s_down = rng.random((h, w)), rng.random((h, w))
        cand = rng.integers(0, n, (1, h, w))
        alpha, radius = int(rng.integers(0, n)), int(trial % 2)
        moves = _RestrictedMoves(cand, n, radius)
        before = _energy(cost, labels, s_right, s_down, 2.0)
        after_labels = labels.copy()
        change = moves.move(cost, after_labels, alpha, s_right, s_down, 2.0, 1e-12)
        seeds = np.argwhere(cand[0] == alpha)
        free = np.zeros((h, w), bool)
        for y, x in seeds:
            free[max(y - radius, 0):y + radius + 1, max(x - radius, 0):x + radius + 1] = True
        free &= labels != alpha
        assert np.all((after_labels == labels) | (free & (after_labels == alpha)))
        cells = np.argwhere(free)
        best = before
        for bits in itertools.product((0, 1), repeat=len(cells)):
            trial_labels = labels.copy()
            for (y, x), bit in zip(cells, bits):
                if bit:
                    trial_labels[y, x] = alpha
            best = min(best, _energy(cost, trial_labels, s_right, s_down, 2.0))
        after = _energy(cost, after_labels, s_right, s_down, 2.0)
        assert after <= best + 1e-9 and abs((before + change) - after) < 1e-9


def test_pruned_matcher_and_bad_candidates(textured_pair):
    left, right, d = textured_pair
    out = match("graphcut", left, right, 10, cost="sad", window=3, candidates=3, candidate_radius=1)
    assert (out.disparity[..., 10:] - d).abs().max() < 0.5
    with pytest.raises(StereoInputError, match="candidates"):
        match("graphcut", left, right, 10, candidates=0)
    cost = torch.rand(1, 4, 5, 6)
    with pytest.raises(StereoInputError, match="candidates"):
        alpha_expansion(cost, 1.0, candidates=torch.full((1, 2, 5, 6), 4))
    with pytest.raises(StereoInputError, match="candidates"):
        alpha_expansion(cost, 1.0, candidates=torch.zeros(1, 2, 5, 5, dtype=torch.long))
    with pytest.raises(StereoInputError, match="candidates"):
        alpha_expansion(cost, 1.0, candidates=torch.zeros(1, 2, 5, 6))
    with pytest.raises(StereoInputError, match="candidate_radius"):
        alpha_expansion(cost, 1.0, candidates=torch.zeros(1, 2, 5, 6, dtype=torch.long), candidate_radius=-1)


def test_graphcut_matcher_on_a_one_pixel_tall_pair_and_a_nan_smoothness():
    """A one-row pair has no vertical edges (their mean contrast weight was NaN and surfaced as a 'P1/P2' error
    the matcher has no option for); a NaN smoothness is named as such."""
    from stereonet.checks import StereoInputError
    from stereonet.matchers import match

    g = torch.Generator().manual_seed(0)
    left = torch.rand(1, 3, 1, 48, generator=g)
    out = match("graphcut", left, torch.roll(left, -2, -1), 8)
    assert out.disparity.shape == (1, 1, 1, 48) and bool(torch.isfinite(out.disparity).all())
    with pytest.raises(StereoInputError, match="smoothness"):
        match("graphcut", torch.rand(1, 3, 24, 48, generator=g), torch.rand(1, 3, 24, 48, generator=g), 8,
              smoothness=float("nan"))
