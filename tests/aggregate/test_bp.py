"""Loopy belief propagation: distance transform, numba == torch, known answers, energy, bad input."""

from __future__ import annotations

import math

import pytest
import torch

from stereonet.aggregate.bp import belief_propagation
from stereonet.aggregate.mrf import (
    contrast_edge_weights,
    grid_energy,
    truncated_linear_min_convolution,
)
from stereonet.checks import StereoInputError
from stereonet.matchers import match


def noisy_step_cost(seed: int = 0, noise: float = 3.0):
    """(1, 16, 24, 40) costs of a piecewise-constant truth (3 with a block of 10) plus uniform noise."""
    g = torch.Generator().manual_seed(seed)
    truth = torch.full((1, 1, 24, 40), 3)
    truth[..., 6:18, 12:28] = 10
    d = torch.arange(16).view(1, 16, 1, 1)
    cost = (d - truth).abs().clamp(max=4).float() + noise * torch.rand(1, 16, 24, 40, generator=g)
    return cost, truth


def pixel_cost(left, right, max_disp):
    b, _, h, w = left.shape
    vol = torch.ones(b, max_disp + 1, h, w, dtype=left.dtype)
    for d in range(max_disp + 1):
        vol[:, d, :, d:] = (left[..., d:] - right[..., : w - d]).abs().mean(1)
    return vol


def test_distance_transform_matches_brute_force():
    g = torch.Generator().manual_seed(0)
    h = torch.rand(2, 9, 3, 4, generator=g, dtype=torch.float64) * 5
    slope = torch.rand(2, 1, 3, 4, generator=g, dtype=torch.float64)
    d = torch.arange(9, dtype=torch.float64)
    for T in (1.0, 2.5, 100.0):
        pen = (d[:, None] - d[None, :]).abs().clamp(max=T)  # [d, d']
        brute = (h[:, None] + slope[:, None] * pen.view(1, 9, 9, 1, 1)).amin(dim=2)
        torch.testing.assert_close(truncated_linear_min_convolution(h, slope, T), brute)


@pytest.mark.parametrize("levels", [1, 3])
def test_numba_equals_torch_reference(levels):
    g = torch.Generator().manual_seed(0)
    cost = torch.rand(2, 7, 13, 17, generator=g, dtype=torch.float64)
    wr, wd = (torch.rand(2, 1, 13, 17, generator=g, dtype=torch.float64) for _ in range(2))
    kw = dict(iterations=3, levels=levels, weights_right=wr, weights_down=wd)
    a = belief_propagation(cost, 0.4, 2.0, backend="numba", **kw)
    b = belief_propagation(cost, 0.4, 2.0, backend="torch", **kw)
    torch.testing.assert_close(a.beliefs, b.beliefs)
    assert torch.equal(a.disparity, b.disparity)


def test_plane_gives_constant_disparity(textured_pair):
    left, right, d = textured_pair
    res = belief_propagation(pixel_cost(left, right, 12), 0.1, 2.0, iterations=4, levels=3)
    assert torch.all(res.disparity[..., 12:] == d)
    assert res.beliefs.shape == (1, 13, 48, 96)


def test_energy_decreases_and_recovers_the_truth():
    cost, truth = noisy_step_cost()
    wta = cost.argmin(dim=1, keepdim=True)
    res = belief_propagation(cost, 1.0, 2.0, iterations=5, levels=3)
    e_wta = grid_energy(cost, wta, 1.0, 2.0)
    assert float(res.energy) < 0.8 * float(e_wta)
    torch.testing.assert_close(res.energy, grid_energy(cost, res.disparity.long(), 1.0, 2.0))
    assert (res.disparity.long() == truth).float().mean() > 0.98
    assert (wta == truth).float().mean() < 0.8
    # more iterations at one level do not end far above the coarse-to-fine energy
    single = belief_propagation(cost, 1.0, 2.0, iterations=10, levels=1)
    assert float(single.energy) < float(e_wta)


def test_contrast_weights():
    img = torch.zeros(1, 3, 4, 5)
    img[..., 3:] = 1.0
    wr, wd = contrast_edge_weights(img, threshold=0.1, factor=4.0)
    assert wr.shape == (1, 1, 4, 5) and wd.shape == (1, 1, 4, 5)
    assert torch.all(wr[..., 2] == 1.0) and torch.all(wr[..., :2] == 4.0) and torch.all(wr[..., -1] == 0)
    assert torch.all(wd[..., :-1, :] == 4.0) and torch.all(wd[..., -1, :] == 0)


def test_bp_matcher(textured_pair):
    left, right, d = textured_pair
    out = match("bp", left.expand(1, 3, -1, -1), right.expand(1, 3, -1, -1), 10, cost="sad", window=3)
    assert out.valid[..., 10:].all() and out.cost_volume.shape == (1, 11, 48, 96)
    assert torch.equal(out.valid, ~out.extras["occlusion"])
    assert (out.disparity[..., 10:] - d).abs().max() < 0.5


@pytest.mark.parametrize("precision,levels", [("int16", 3), ("float", 3), ("int16", 1)])
def test_bp_matcher_without_the_belief_volume_gives_the_same_disparities(precision, levels):
    """keep_beliefs=False (the matcher's default) returns no belief volume and the same disparity bits as refining
    on the kept volume (subpixel_refine of the beliefs: the way the matcher refined before); belief_propagation's
    ``near`` holds the beliefs at d - 1, d, d + 1 of the kept volume, whether the volume was kept or not."""
    from stereonet.aggregate.bp import belief_propagation
    from stereonet.select.subpixel import subpixel_refine

    g = torch.Generator().manual_seed(3)
    big = torch.rand(1, 3, 37, 70, generator=g)
    left, right = big[..., :65].contiguous(), big[..., 5:].contiguous()  # disparity 5
    kept = match("bp", left, right, 12, precision=precision, levels=levels, keep_beliefs=True)
    lean = match("bp", left, right, 12, precision=precision, levels=levels)
    assert "beliefs" not in lean.extras and lean.extras["energy"].shape == (1,)
    beliefs = kept.extras["beliefs"]
    labels = beliefs.argmin(1, keepdim=True)
    assert torch.equal(lean.disparity, kept.disparity) and torch.equal(lean.valid, kept.valid)
    refined = subpixel_refine(beliefs, labels.to(beliefs.dtype))
    inner = ~kept.extras["occlusion"]
    assert torch.equal(lean.disparity[inner], refined[inner])
    assert (lean.disparity != lean.disparity.round()).float().mean() > 0.5  # sub-pixel values, not integers
    assert ((lean.disparity[..., 12:] - 5).abs() < 1).float().mean() > 0.9
    volume = kept.cost_volume
    for keep in (True, False):
        res = belief_propagation(volume, 0.3, 4.0, 5, levels, precision=precision, keep_beliefs=keep)
        assert (res.beliefs is None) != keep
        full = belief_propagation(volume, 0.3, 4.0, 5, levels, precision=precision).beliefs
        d = res.disparity.long()
        ref = torch.cat([full.gather(1, (d + k).clamp(0, volume.shape[1] - 1)) for k in (-1, 0, 1)], 1)
        assert torch.equal(res.near, ref)


def test_bad_inputs():
    cost = torch.rand(1, 4, 6, 8)
    with pytest.raises(StereoInputError, match="truncation"):
        belief_propagation(cost, 1.0, 0.0)
    with pytest.raises(StereoInputError, match="smoothness"):
        belief_propagation(cost, math.nan)
    with pytest.raises(StereoInputError, match="iterations"):
        belief_propagation(cost, 1.0, iterations=0)
    with pytest.raises(StereoInputError, match="weights_right"):
        belief_propagation(cost, 1.0, weights_right=torch.ones(1, 1, 6, 9))
    with pytest.raises(StereoInputError, match="cost"):
        belief_propagation(torch.full((1, 4, 6, 8), math.inf), 1.0)
    with pytest.raises(StereoInputError, match="backend"):
        belief_propagation(cost, 1.0, backend="gpu")
    with pytest.raises(StereoInputError, match="right"):
        match("bp", torch.rand(1, 1, 8, 16), torch.rand(1, 1, 8, 15), 4)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_numba_equals_torch_on_odd_shapes(dtype):
    """Odd H and W (every pyramid level pads and crops), D = 13, 3 levels, 2 batch items: the row-major
    wavefront kernel gives the reference's beliefs and labels."""
    g = torch.Generator().manual_seed(1)
    cost = (torch.rand(2, 13, 37, 53, generator=g, dtype=torch.float64) * 4).to(dtype)
    wr, wd = ((torch.rand(2, 1, 37, 53, generator=g, dtype=torch.float64) * 2).to(dtype) for _ in range(2))
    for iterations in (1, 4):
        kw = dict(iterations=iterations, levels=3, weights_right=wr, weights_down=wd)
        a = belief_propagation(cost, 0.7, 3.0, backend="numba", **kw)
        b = belief_propagation(cost, 0.7, 3.0, backend="torch", **kw)
        # float32: the reference's cummin form itself is ~2.5e-4 off its float64 self on beliefs up to ~18
        rtol, atol = (1e-4, 1e-3) if dtype == torch.float32 else (1e-12, 1e-12)
        torch.testing.assert_close(a.beliefs, b.beliefs, rtol=rtol, atol=atol)
        ties = (a.disparity != b.disparity)
        assert ties.float().mean() < 1e-3  # float32 ties aside
        torch.testing.assert_close(a.energy, b.energy, rtol=1e-6, atol=1e-3)


@pytest.mark.parametrize("rows_per_step", [1, 2])
def test_two_strips_meet_exactly_at_every_height(rows_per_step, monkeypatch):
    """The wavefront's two strips of rows (swept towards each other, synchronised only where they meet) give the
    reference's beliefs for every small height: one block (the bottom strip empty), strips of equal or unequal block
    counts, a last block cut short, and a pyramid level above (bp_finest) as well as a single level (bp_level)."""
    from stereonet.kernels import bp as kernels

    monkeypatch.setattr(kernels, "ROWS_PER_STEP", rows_per_step)
    g = torch.Generator().manual_seed(5)
    for height in (1, 2, 3, 4, 5, 6, 7, 9, 12):
        cost = torch.rand(1, 6, height, 11, generator=g, dtype=torch.float64) * 4
        wd = torch.rand(1, 1, height, 11, generator=g, dtype=torch.float64) * 2
        for iterations in (1, 2, 3):
            for levels in (1, 2):
                kw = dict(iterations=iterations, levels=levels, weights_down=wd)
                a = belief_propagation(cost, 0.6, 2.5, backend="numba", **kw)
                b = belief_propagation(cost, 0.6, 2.5, backend="torch", **kw)
                torch.testing.assert_close(a.beliefs, b.beliefs, rtol=1e-12, atol=1e-12,
                                           msg=f"H={height} J={iterations} levels={levels}")


@pytest.mark.parametrize("rows_per_step", [2, 3, 5, 64])
def test_wavefront_blocks_of_rows_give_the_same_bits(rows_per_step):
    """bp_level's wavefront over blocks of K rows (H = 37: not a multiple of 2, 3 or 5; K = 64 > H: one block)
    gives exactly the messages of the one-row wavefront, which equals the torch reference (tests above)."""
    import numpy as np

    from stereonet.kernels.bp import bp_level, ring_shape

    rng = np.random.default_rng(3)
    cost = (rng.random((2, 37, 9, 29)) * 4).astype(np.float32)
    slopes = np.concatenate([s := (rng.random((2, 4, 37, 29)) * 0.8).astype(np.float32), s * np.float32(3.0)], 1)
    results = []
    for k in (1, rows_per_step):
        start = np.zeros((2, 37, 4, 9, 29), np.float32)
        rings = np.full(ring_shape(4, k, 9, 29), np.nan, np.float32)  # any content: every slot read is written first
        bp_level(cost, start, start, rings, np.ascontiguousarray(slopes), 4, k)
        results.append(start)
    assert np.isfinite(results[1]).all()
    assert np.array_equal(results[0], results[1])



@pytest.mark.parametrize("dtype,iterations,rows_per_step", [("float32", 4, 1), ("int16", 3, 2), ("float32", 1, 3),
                                                              ("int16", 5, 64)])
def test_finest_level_in_one_wavefront_equals_upsample_level_and_beliefs(dtype, iterations, rows_per_step):
    """bp_finest (coarse messages -> iterations -> beliefs and labels, no full message set) gives the bits of
    upsample2 + bp_level + beliefs_argmin, on odd sizes (H = 37, W = 29: the last coarse pixel has one child), for
    float32 and int16 fixed point, one iteration (the first is the last) and blocks of several rows."""
    import numpy as np

    from stereonet.kernels.bp import beliefs_argmin, beliefs_view, bp_finest, bp_level, ring_shape, upsample2

    rng = np.random.default_rng(7)
    B, H, D, W, h, w = 2, 37, 9, 29, 19, 15
    scale_dtype = np.float32
    if dtype == "int16":
        cost = rng.integers(0, 400, (B, H, D, W)).astype(np.int16)
        s = rng.integers(0, 50, (B, 4, H, W)).astype(np.int16)
        slopes = np.ascontiguousarray(np.concatenate([s, s * np.int16(3)], 1))
        coarse = rng.integers(0, 300, (B, h, 4, D, w)).astype(np.int16)
        scale = np.array([1 / 256], scale_dtype)
    else:
        cost = (rng.random((B, H, D, W)) * 4).astype(np.float32)
        s = (rng.random((B, 4, H, W)) * 0.8).astype(np.float32)
        slopes = np.ascontiguousarray(np.concatenate([s, s * np.float32(3.0)], 1))
        coarse = (rng.random((B, h, 4, D, w)) * 2).astype(np.float32)
        scale = np.array([1.0], scale_dtype)
    start = np.empty((B, H, 4, D, W), cost.dtype)
    upsample2(coarse.reshape(B, h, -1, w), start.reshape(B, H, -1, W))
    final = start if iterations >= 2 else np.empty_like(start)
    bp_level(cost, start, final, np.empty(ring_shape(iterations, 1, D, W), cost.dtype), slopes, iterations, 1)
    labels_ref = np.empty((B, H, W), np.int64)
    beliefs_argmin(cost, final, labels_ref, scale)
    beliefs_ref = beliefs_view(final, scale_dtype)
    fill = np.iinfo(np.int16).max if dtype == "int16" else np.nan  # any ring content: every slot read is written first
    rings = np.full(ring_shape(iterations + 1, rows_per_step, D, W), fill, cost.dtype)
    beliefs = np.full((B, H, D, W), np.nan, scale_dtype)
    labels = np.full((B, H, W), -1, np.int64)
    near = np.full((B, 3, H, W), np.nan, scale_dtype)
    bp_finest(cost, coarse, rings, slopes, iterations, beliefs, near, labels, scale, rows_per_step)
    assert np.isfinite(beliefs).all() and (labels >= 0).all()
    assert np.array_equal(beliefs, beliefs_ref) and np.array_equal(labels, labels_ref)
    # near: the beliefs at label - 1, label, label + 1 (the label's own value beyond the range)
    near_ref = np.stack([np.take_along_axis(beliefs_ref, np.clip(labels + k, 0, D - 1)[:, :, None], axis=2)[:, :, 0]
                         for k in (-1, 0, 1)], axis=1)
    assert (labels == 0).any() and np.array_equal(near, near_ref)
    # without a belief volume (no rows): the same labels and near values, every row through a scratch row
    labels2 = np.full((B, H, W), -1, np.int64)
    near2 = np.full((B, 3, H, W), np.nan, scale_dtype)
    bp_finest(cost, coarse, np.full_like(rings, fill), slopes, iterations, np.empty((B, 0, D, W), scale_dtype), near2,
              labels2, scale, rows_per_step)
    assert np.array_equal(labels2, labels_ref) and np.array_equal(near2, near_ref)


def test_one_iteration_writes_every_slot_of_a_fresh_final_set():
    """With one iteration the result goes to another buffer: whatever it held (NaN here), every slot comes back
    written, the border slots no neighbour sends to as zeros."""
    import numpy as np

    from stereonet.kernels.bp import bp_level, ring_shape

    rng = np.random.default_rng(5)
    cost = (rng.random((1, 11, 6, 13)) * 4).astype(np.float32)
    slopes = np.ascontiguousarray(np.concatenate([s := (rng.random((1, 4, 11, 13)) * 0.8).astype(np.float32),
                                                  s * np.float32(2.0)], 1))
    start = (rng.random((1, 11, 4, 6, 13)) * 0.5).astype(np.float32)
    start[:, :, 0, :, 0] = start[:, :, 1, :, -1] = start[:, 0, 2] = start[:, -1, 3] = 0
    finals = []
    for fill in (np.nan, 0.0):
        final = np.full_like(start, fill)
        bp_level(cost, start, final, np.full(ring_shape(1, 1, 6, 13), np.nan, np.float32), slopes, 1, 1)
        finals.append(final)
    assert np.isfinite(finals[0]).all() and np.array_equal(finals[0], finals[1])
    assert not finals[0][:, :, 0, :, 0].any() and not finals[0][:, :, 1, :, -1].any()
    assert not finals[0][:, 0, 2].any() and not finals[0][:, -1, 3].any()

def _on_grid(x: torch.Tensor, scale: int = 1024) -> torch.Tensor:
    return (x * scale).round() / scale


@pytest.mark.parametrize("levels, with_weights", [(1, True), (3, False)])
def test_int16_fixed_point_is_the_float_kernel_on_the_rounded_inputs(levels, with_weights):
    """precision="int16": costs and slopes on the 1/1024 grid make min-sum exact integer arithmetic, so the
    fixed-point levels (and the float coarse levels of a 3-level pyramid, whose messages are rounded onto the grid
    when they initialise the finer level) give the float kernel's beliefs and labels bit for bit."""
    g = torch.Generator().manual_seed(4)
    cost = _on_grid(torch.rand(2, 11, 37, 45, generator=g) * 3)
    wr = wd = None
    if with_weights:
        wr, wd = (_on_grid(torch.rand(2, 1, 37, 45, generator=g)) for _ in range(2))  # bound 3 + 5 * 3 < 32000 / 1024
    kw = dict(iterations=3, levels=levels, weights_right=wr, weights_down=wd)
    smoothness = 1.0 if with_weights else 0.5  # λ·w on the grid too
    a = belief_propagation(cost, smoothness, 3.0, precision="float", **kw)
    b = belief_propagation(cost, smoothness, 3.0, precision="int16", **kw)
    assert torch.equal(a.disparity, b.disparity)
    assert torch.equal(a.beliefs, b.beliefs)


def test_int16_plan_keeps_float_where_int16_would_not_hold_the_values():
    """The finest level's bound (max cost + 5 max s·T) sets the scale; coarse levels whose summed costs exceed
    int16 at that scale stay float; a smoothness far above the costs turns fixed point off, and a float64 cost
    or the torch backend are never quantised."""
    import numpy as np

    from stereonet.aggregate.bp import FIXED_POINT_LIMIT, fixed_point_plan

    maxima = [2.0 * 4 ** level for level in range(4)]
    slopes = [np.full((1, 8, 4, 4), 3.6, np.float32) for _ in range(4)]
    scale, fixed = fixed_point_plan(maxima, slopes)
    assert scale == 1024 and fixed == [True, True, False, False]
    assert all(scale * (m + 5 * 3.6) <= FIXED_POINT_LIMIT for m, f in zip(maxima, fixed) if f)
    assert fixed_point_plan(maxima, [s * 100 for s in slopes]) == (0, [False] * 4)
    g = torch.Generator().manual_seed(5)
    cost = torch.rand(1, 7, 20, 24, generator=g, dtype=torch.float64)
    a = belief_propagation(cost, 0.4, 2.0, levels=2, precision="float")
    b = belief_propagation(cost, 0.4, 2.0, levels=2, precision="int16")
    assert torch.equal(a.beliefs, b.beliefs)
    with pytest.raises(StereoInputError, match="precision"):
        belief_propagation(cost, 0.4, precision="half")


def test_bp_matcher_int16_default_stays_close_to_float():
    """The registered bp runs in fixed point by default: on a textured pair its labels agree with the float run
    almost everywhere (rounding the costs to 1/1024 flips only near-ties)."""
    g = torch.Generator().manual_seed(6)
    big = torch.rand(1, 3, 48, 80, generator=g)
    left, right = big[..., 4:].contiguous(), big[..., :76].contiguous()
    a = match("bp", left, right, 12, precision="float")
    b = match("bp", left, right, 12)
    assert float(((a.disparity - b.disparity).abs() > 0.5).float().mean()) < 0.01
