"""Compiled kernels against their torch references on shapes that cross every block, chunk and vector width.

The numba kernels vectorise along disparities (8 float32 lanes) or image rows, run rows in fixed blocks
(``stereonet.kernels.block.ROW_BLOCK`` = 32) or up to 64 row chunks (selection), and take fast paths
for interior pixels (3x3 median network); the shapes below are not multiples of any of these, some are
smaller than one vector (D < 8, W < D) and some span several blocks, all in float32.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from stereonet import matchers
from stereonet.aggregate.sgm import (
    DIRECTIONS_16,
    _path_torch,
    p2_maps_numpy,
    quantize_penalty,
    sgm_aggregate,
    sgm_aggregate_torch,
)
from stereonet.checks import StereoInputError
from stereonet.cost import build_cost_volume
from stereonet.kernels.block import ROW_BLOCK
from stereonet.kernels.sgm import fixed_point_scale, fixed_to_float, sgm_fixed_hwd, sgm_numba_hwd
from stereonet.matchers.local import select_and_filter
from stereonet.select.confidence import cost_margin_confidence
from stereonet.select.filters import median_filter
from stereonet.select.wta import select_disparity, select_disparity_confidence

# (H, W, D): one row, W < D, D < one vector, D = 37 (4 vectors + 5), D = 64 (exact vectors), H > ROW_BLOCK
SGM_SHAPES = [(1, 11, 9), (5, 7, 1), (13, 9, 37), (9, 40, 13), (3, 2, 64), (ROW_BLOCK + 3, 6, 5)]


def _cost_hwd(h: int, w: int, d: int, seed: int, integer: bool = False) -> np.ndarray:
    rng = np.random.default_rng(seed)
    c = rng.random((h, w, d), dtype=np.float32) * np.float32(48.0)
    return np.floor(c) if integer else c


@pytest.mark.parametrize("h, w, d", SGM_SHAPES)
def test_sgm_kernel_each_path_equals_torch_bitwise(h, w, d):
    """One direction at a time, the kernel's path cost L_r is the torch recurrence bit for bit."""
    cost = _cost_hwd(h, w, d, seed=h * w + d)
    grey = np.random.default_rng(d).random((h, w), dtype=np.float32)
    p2 = p2_maps_numpy(2.0, 20.0, DIRECTIONS_16, grey, 15.0)
    cost_t = torch.from_numpy(cost).permute(2, 0, 1)[None].contiguous()  # 1xDxHxW
    for i, (dx, dy) in enumerate(DIRECTIONS_16):
        fast = sgm_numba_hwd(cost, np.float32(2.0), p2[i:i + 1], np.array([[dx, dy]], np.int64))
        ref = _path_torch(cost_t, dx, dy, 2.0, torch.from_numpy(p2[i])[None])[0].permute(1, 2, 0)
        assert torch.equal(torch.from_numpy(fast), ref), (dx, dy)


@pytest.mark.parametrize("h, w, d", SGM_SHAPES)
def test_sgm_kernel_uint8_costs_equal_float32(h, w, d):
    cost = _cost_hwd(h, w, d, seed=d, integer=True)
    p2 = p2_maps_numpy(2.0, 48.0, DIRECTIONS_16[:8], np.random.default_rng(h).random((h, w), dtype=np.float32), 20.0)
    dirs = np.asarray(DIRECTIONS_16[:8], np.int64)
    a = sgm_numba_hwd(cost, np.float32(2.0), p2, dirs)
    b = sgm_numba_hwd(cost.astype(np.uint8), np.float32(2.0), p2, dirs)
    assert b.dtype == np.float32 and np.array_equal(a, b)


@pytest.mark.parametrize("h, w, d", SGM_SHAPES)
@pytest.mark.parametrize("step", [1 / 16, 1 / 4])
def test_sgm_fixed_point_kernel_equals_torch_per_path_and_float_kernel(h, w, d, step):
    """The 16-bit kernel on uint8 costs with penalties on the ``step`` grid: each path is the torch
    recurrence (on the rounded penalties) bit for bit, and the 8- and 16-path sums equal the float32
    kernel's exactly (every partial sum is a multiple of the step)."""
    cost = _cost_hwd(h, w, d, seed=3 * d + h, integer=True)
    grey = np.random.default_rng(w).random((h, w), dtype=np.float32)
    P1 = quantize_penalty(1.3, step)
    p2 = p2_maps_numpy(P1, quantize_penalty(30.0, step), DIRECTIONS_16, grey, 15.0, step)
    assert np.array_equal(p2, np.round(p2 / np.float32(step)) * np.float32(step))  # on the grid
    cost_t = torch.from_numpy(cost).permute(2, 0, 1)[None].contiguous()
    u8 = cost.astype(np.uint8)
    for i, (dx, dy) in enumerate(DIRECTIONS_16):
        s = fixed_point_scale(u8, P1, p2[i:i + 1], 1, step)
        assert s == round(1 / step)
        fast = fixed_to_float(sgm_fixed_hwd(u8, P1, p2[i:i + 1], np.array([[dx, dy]], np.int64), s), s)
        ref = _path_torch(cost_t, dx, dy, P1, torch.from_numpy(p2[i])[None])[0].permute(1, 2, 0)
        assert torch.equal(torch.from_numpy(fast), ref), (dx, dy)
    for n in (4, 8, 16):
        dirs = np.asarray(DIRECTIONS_16[:n], np.int64)
        a = sgm_numba_hwd(cost, np.float32(P1), p2[:n], dirs)  # float32 kernel
        b = sgm_numba_hwd(u8, np.float32(P1), p2[:n], dirs, penalty_step=step)  # 16-bit kernel
        assert fixed_point_scale(u8, P1, p2[:n], n, step) is not None
        assert np.array_equal(a, b), n


def test_sgm_fixed_point_falls_back_when_not_exact():
    """Fixed point only where it is exact: penalties off the grid, a step that is not 1/2^k, or a sum that
    would overflow int16 (255-bit costs) run the float32 kernel, with the float32 result."""
    rng = np.random.default_rng(0)
    u8 = rng.integers(0, 49, (9, 21, 13)).astype(np.uint8)
    dirs = np.asarray(DIRECTIONS_16[:8], np.int64)
    p2 = np.full((8, 9, 21), 48.0, np.float32)
    assert fixed_point_scale(u8, 2.0, p2, 8, 1 / 16) == 16
    assert fixed_point_scale(u8, 2.0, p2 + np.float32(0.01), 8, 1 / 16) is None  # off the grid
    assert fixed_point_scale(u8, 2.0, p2, 8, 0.1) is None  # not a power of two
    assert fixed_point_scale(u8, 2.0, p2, 8, None) is None
    assert fixed_point_scale(u8.astype(np.float32), 2.0, p2, 8, 1 / 16) is None  # float costs
    big = np.full_like(u8, 255)
    assert fixed_point_scale(big, 2.0, p2, 8, 1 / 16) is None  # 8 x 16 x (255 + 48) > 32767
    assert np.array_equal(sgm_numba_hwd(big, np.float32(2.0), p2, dirs, penalty_step=1 / 16),
                          sgm_numba_hwd(big.astype(np.float32), np.float32(2.0), p2, dirs))


@pytest.mark.parametrize("h", [1, 2, 3, 5, 17, 40])
@pytest.mark.parametrize("chunk", [1, 3, 16])
@pytest.mark.parametrize("paths", [8, 16])
def test_fixed_point_concurrent_sweeps_share_one_buffer_exactly(h, chunk, paths, monkeypatch):
    """The two sweeps on two threads into one int16 buffer (rows handed over in the middle, in chunks)
    give the one-thread result bit for bit, for odd/even heights, chunks of 1 row up to more than half, and
    both equal the float32 kernel: 8 paths (four per sweep, added to the sum in one pass) and 16 (knight
    moves cross two rows; eight per sweep, added one by one)."""
    import numba

    from stereonet.aggregate.sgm import sgm_directions
    from stereonet.kernels import sgm as kernel

    monkeypatch.setattr(kernel, "SWEEP_CHUNK", chunk)
    rng = np.random.default_rng(h * 31 + chunk + paths)
    u8 = rng.integers(0, 49, (h, 23, 11)).astype(np.uint8)
    dirs = np.asarray(sgm_directions(paths), np.int64)
    assert paths != 16 or dirs.tolist() == np.asarray(DIRECTIONS_16).tolist()
    p2 = (rng.integers(2 * 16, 30 * 16, (paths, h, 23)) / 16).astype(np.float32)
    # the branch is chosen by numba's thread count; force each (the concurrent one uses Python threads, so it
    # runs on any machine)
    monkeypatch.setattr(numba, "get_num_threads", lambda: 1)
    sequential = sgm_fixed_hwd(u8, 2.0, p2, dirs, 16)
    monkeypatch.setattr(numba, "get_num_threads", lambda: 2)
    assert np.array_equal(sgm_fixed_hwd(u8, 2.0, p2, dirs, 16), sequential)
    float_ref = sgm_numba_hwd(u8.astype(np.float32), np.float32(2.0), p2, dirs)
    assert np.array_equal(fixed_to_float(sequential, 16), float_ref)


@pytest.mark.parametrize("h, w, d", [(ROW_BLOCK + 3, 41, 19), (131, 450, 64), (9, 5, 12), (4, 30, 4), (6, 11, 3)])
@pytest.mark.parametrize("method, ratio, lr_tol", [(1, 0.05, 1.0), (2, 0.0, -1.0), (0, 0.3, 0.0)])
def test_fixed_point_selection_equals_float_selection(h, w, d, method, ratio, lr_tol):
    """The selection pass reading an int16 ``s * S`` volume (the int16 min/blend kernel for D >= 4, the
    row-by-row conversion below) gives the float32 volume's results exactly: more rows than the 64 row
    chunks, W < D (right-reference diagonal shorter than D), ties at the best and at the second best."""
    from stereonet.kernels.select import select_confidence_hwd

    rng = np.random.default_rng(h * w + d)
    acc = rng.integers(0, 3000, (h, w, d)).astype(np.int16)
    acc[2, 1] = 7  # ties everywhere in one pixel
    acc[..., d - 1] = acc[..., 0]  # ties between far disparities
    ref = select_confidence_hwd(acc.astype(np.float32) / np.float32(16), method, ratio, lr_tol, np.float32(1e-6))
    got = select_confidence_hwd(acc, method, ratio, lr_tol, np.float32(1e-6), 1.0 / 16)
    for a, b in zip(ref, got):
        assert a.dtype == b.dtype and np.array_equal(a, b)


@pytest.mark.parametrize("paths", [4, 8, 16])
def test_sgm_aggregate_numba_equals_torch_across_vector_widths(paths):
    g = torch.Generator().manual_seed(paths)
    cost = torch.rand(2, 37, 19, 45, generator=g) * 30
    image = torch.rand(2, 3, 19, 45, generator=g)
    ref = sgm_aggregate_torch(cost, 1.5, 12.0, paths, image, p2_alpha=8.0)
    fast = sgm_aggregate(cost, 1.5, 12.0, paths, image, p2_alpha=8.0, backend="numba")
    torch.testing.assert_close(fast, ref, rtol=1e-6, atol=1e-4)  # the direction sums differ in order only


@pytest.mark.parametrize("d, h, w", [(2, 3, 5), (13, 70, 45), (37, 66, 9)])
@pytest.mark.parametrize("uniqueness", [0.0, 0.1])
def test_select_confidence_equals_torch(d, h, w, uniqueness):
    g = torch.Generator().manual_seed(d * h)
    cost = (torch.rand(2, d, h, w, generator=g) * 16).round()  # many exact ties
    (disp, min_cost, unique, disp_right, lr_ok), conf = select_disparity_confidence(
        cost, "parabola", uniqueness, 1.0, backend="numba")
    ref = select_disparity(cost, "parabola", uniqueness, 1.0, backend="torch")
    torch.testing.assert_close(disp, ref[0], rtol=1e-6, atol=1e-6)
    for name, a, b in (("min_cost", min_cost, ref[1]), ("unique", unique, ref[2]),
                       ("disp_right", disp_right, ref[3]), ("lr_ok", lr_ok, ref[4])):
        assert torch.equal(a, b), name
    torch.testing.assert_close(conf, cost_margin_confidence(cost, backend="torch"), rtol=1e-6, atol=1e-6)
    assert torch.equal(conf, cost_margin_confidence(cost, backend="numba"))


def test_select_confidence_non_finite_costs():
    g = torch.Generator().manual_seed(7)
    cost = torch.rand(1, 11, 5, 13, generator=g)
    cost[0, :, 0, 0] = float("inf")  # no finite cost
    cost[0, 0, 1, 1] = float("nan")  # NaN first
    cost[0, 3:, 2, 2] = float("inf")  # no finite competitor beyond the neighbours
    cost[0, 4, 3, 3] = float("nan")
    _, conf = select_disparity_confidence(cost, None, 0.0, None, backend="numba")
    assert torch.equal(conf, cost_margin_confidence(cost, backend="numba"))
    torch.testing.assert_close(conf, cost_margin_confidence(cost, backend="torch"), rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("h, w", [(3, 3), (37, 41), (ROW_BLOCK + 5, 70)])
@pytest.mark.parametrize("density", [1.0, 0.9, 0.3])
def test_median_network_equals_torch(h, w, density):
    g = torch.Generator().manual_seed(h + w)
    disp = (torch.rand(2, 1, h, w, generator=g) * 20).round() / 4  # ties as in integer disparities
    valid = torch.rand(2, 1, h, w, generator=g) < density
    assert torch.equal(median_filter(disp, 3, valid, backend="numba"), median_filter(disp, 3, valid, backend="torch"))


@pytest.mark.parametrize("cost, window, kwargs", [("sad", 5, {}), ("ncc", 7, {}), ("census", 1, {"census_window": 7}),
                                                  ("census_ad", 3, {}), ("sad", 9, {}), ("ssd", 11, {}),
                                                  ("sad", 13, {}), ("zsad", 15, {}), ("lssad", 9, {}),
                                                  ("ncc", 13, {}), ("adaptive", 7, {"mode": "multiwindow"})])
def test_block_engine_volume_equals_torch_across_row_blocks(cost, window, kwargs):
    """The row-block engine restarts its vertical sums every ROW_BLOCK rows: H = 2 blocks + 6 rows, W not
    a multiple of anything, D = 13. Windows 3..11 take the written-out horizontal sums, 13 and 15 the
    doubling (both paths of ``kernels.block._box_row``); zsad/lssad/ncc also the planar box means."""
    g = torch.Generator().manual_seed(5)
    h, w = 2 * ROW_BLOCK + 6, 43
    left, right = torch.rand(2, 3, h, w, generator=g), torch.rand(2, 3, h, w, generator=g)
    ref = build_cost_volume(left, right, 12, cost=cost, window=window, backend="torch", **kwargs)
    fast = build_cost_volume(left, right, 12, cost=cost, window=window, backend="numba", **kwargs)
    assert fast.shape == ref.shape == (2, 13, h, w)
    torch.testing.assert_close(fast, ref, rtol=1e-5, atol=1e-5 * max(1.0, float(ref.abs().max())))


@pytest.mark.parametrize("h, w, window", [(2 * ROW_BLOCK + 6, 43, 9), (ROW_BLOCK + 1, 5, 15), (3, 70, 3)])
def test_box_planes_steps_equal_the_numpy_composition(h, w, window):
    """The ZSAD / LS-SAD inputs and NCC's window statistics, each computed in one numba pass with the box mean,
    are the bits of the numpy composition they replace (``img - mean``, ``img / (mean + eps)``, ``mu`` and
    ``1 / sqrt(maximum(box(g * g) - mu * mu, 0))`` above the variance floor, else 0), across row blocks, with a
    window wider than the image and flat patches (variance at the floor)."""
    from stereonet.cost.volume import LSSAD_EPS, NCC_MIN_VARIANCE
    from stereonet.kernels.block import BOX_MEAN, BOX_SCALED, BOX_ZERO_MEAN, box_planes, ncc_window_stats

    img = np.random.default_rng(h + w).random((3, h, w), dtype=np.float32)
    img[:, : h // 2] = 0.25  # flat rows and columns: windows of zero variance
    img[:, :, : w // 2] = 0.25
    eps = np.float32(LSSAD_EPS)
    mean = box_planes(img, window, BOX_MEAN, np.float32(0.0))
    assert np.array_equal(box_planes(img, window, BOX_ZERO_MEAN, eps), img - mean)
    assert np.array_equal(box_planes(img, window, BOX_SCALED, eps), img / (mean + eps))
    grey = np.ascontiguousarray(img[0])
    floor = np.float32(NCC_MIN_VARIANCE)
    mu, isd = ncc_window_stats(grey, window, floor)
    var = np.maximum(box_planes((grey * grey)[None], window, BOX_MEAN, np.float32(0.0))[0] - mu * mu, np.float32(0))
    ok = var > floor
    assert np.array_equal(mu, mean[0]) and not ok.all() and ok.any()
    assert np.array_equal(isd, np.where(ok, np.float32(1) / np.sqrt(np.where(ok, var, np.float32(1))), np.float32(0)))


def test_registered_sgm_fast_path_equals_public_composition():
    """``sgm`` on CPU feeds a uint8 census volume to the 16-bit kernel and selects with the confidence in
    one pass from the int16 aggregate; the result equals the documented composition of the public functions
    (penalties on the census grid) exactly, with and without ``keep_volume``, and the torch backend's too."""
    from stereonet.aggregate.sgm import CENSUS_PENALTY_STEP

    g = torch.Generator().manual_seed(2)
    h, w = ROW_BLOCK + 7, 53
    big = torch.rand(2, 3, h, w + 6, generator=g)
    left, right = big[..., 6:].contiguous(), big[..., :w].contiguous()
    out = matchers.match("sgm", left, right, 20)
    kept = matchers.match("sgm", left, right, 20, keep_volume=True)
    vol = build_cost_volume(left, right, 20, cost="census", window=1, census_window=7)
    agg = sgm_aggregate(vol, 2.0, 48.0, paths=8, image=left, p2_alpha=20.0, penalty_step=CENSUS_PENALTY_STEP)
    ref = select_and_filter(agg, subpixel="parabola", uniqueness=0.05, lr_tol=1.0, median=3, speckle_size=100,
                            speckle_diff=1.0, fill=False)
    assert out.cost_volume is None and torch.equal(kept.cost_volume, agg)
    for o in (out, kept):
        assert torch.equal(o.disparity, ref.disparity) and torch.equal(o.valid, ref.valid)
        assert torch.equal(o.confidence, cost_margin_confidence(agg) * ref.valid.float())
    slow = matchers.match("sgm", left, right, 20, backend="torch")  # the float volume path, torch cost
    assert torch.equal(slow.valid, out.valid) and torch.equal(slow.disparity, out.disparity)
    assert torch.equal(slow.cost_volume, agg)
    fixed = matchers.match("sgm", left, right, 20, keep_volume="fixed")  # the int16 aggregate itself
    acc, scale = fixed.extras["aggregate_fixed"], fixed.extras["aggregate_scale"]
    assert fixed.cost_volume is None and acc.dtype == torch.int16 and acc.shape == agg.shape
    assert torch.equal(acc.float() / scale.float(), agg)
    assert torch.equal(fixed.disparity, out.disparity) and torch.equal(fixed.valid, out.valid)
    one = matchers.match("sgm", left[:1], right[:1], 20, keep_volume="fixed")  # one item: a view, no copy
    assert torch.equal(one.extras["aggregate_fixed"].float() / one.extras["aggregate_scale"].float(), agg[:1])
    elsewhere = matchers.match("sgm", left, right, 20, keep_volume="fixed", backend="torch")
    assert "aggregate_fixed" not in elsewhere.extras and torch.equal(elsewhere.cost_volume, agg)
    with pytest.raises(ValueError, match="keep_volume: expected a bool or 'fixed'"):
        matchers.match("sgm", left, right, 20, keep_volume="int16")


# (B, F, H, W, max_disp): W < D, one feature, F not a multiple of a vector, several images
FEATURE_SHAPES = [(1, 32, 5, 70, 64), (2, 16, 9, 12, 20), (1, 1, 3, 8, 3), (2, 33, ROW_BLOCK + 3, 17, 9)]


@pytest.mark.parametrize("b, f, h, w, max_disp", FEATURE_SHAPES)
def test_feature_cost_kernel_equals_torch(b, f, h, w, max_disp):
    """The learned (Siamese) cost ``1 - <f_l, f_r>``: numba kernel = torch loop to float32 rounding, the
    out-of-image triangle exactly INVALID_COST, on plain and channels-last features."""
    from stereonet.models.siamese import INVALID_COST, siamese_cost_volume

    g = torch.Generator().manual_seed(f)
    fl = torch.nn.functional.normalize(torch.randn(b, f, h, w, generator=g), dim=1)
    fr = torch.nn.functional.normalize(torch.randn(b, f, h, w, generator=g), dim=1)
    ref = siamese_cost_volume(fl, fr, max_disp, backend="torch")
    for a, c in [(fl, fr), (fl.contiguous(memory_format=torch.channels_last),
                            fr.contiguous(memory_format=torch.channels_last))]:
        fast = siamese_cost_volume(a, c, max_disp, backend="numba")
        assert fast.shape == ref.shape == (b, max_disp + 1, h, w)
        torch.testing.assert_close(fast, ref, rtol=0, atol=1e-6)
        xs = torch.arange(w)
        outside = (xs[None, :] < torch.arange(max_disp + 1)[:, None])[None, :, None, :].expand_as(fast)
        assert torch.all(fast[outside] == INVALID_COST) and torch.all(fast[~outside] <= 2.0 + 1e-6)
    fl_nan = fl.clone()
    fl_nan[0, 0, 1, 2] = float("nan")  # no 'nnan' in the kernel's fastmath flags: NaN stays NaN
    assert torch.isnan(siamese_cost_volume(fl_nan, fr, max_disp, backend="numba")[0, :3, 1, 2]).all()


def _mixed_pair(scale: float = 2.0):
    g = torch.Generator().manual_seed(5)
    h, w, max_disp = ROW_BLOCK + 5, 47, 16
    big = torch.rand(1, 3, h, w + 5, generator=g)
    left, right = big[..., 5:].contiguous(), big[..., :w].contiguous()
    return left, right, max_disp, torch.rand(1, max_disp + 1, h, w, generator=g) * scale


@pytest.mark.parametrize("mix_step", [0.25, None])
def test_sgm_with_a_mixed_in_volume_fast_path_equals_float_path(mix_step):
    """``sgm(extra_cost=(a, b, V))`` (siamese-census-sgm's cost): the uint8 census + numba mix path gives the
    same aggregated cost and maps as the float32 volume path (census volume built by torch, mixed by torch),
    with the mixed cost rounded to quarter bits (the default) and unrounded."""
    left, right, max_disp, other = _mixed_pair()
    opts = dict(extra_cost=(0.25, 18.0, other), mix_step=mix_step, keep_volume=True)
    fast = matchers.match("sgm", left, right, max_disp, **opts)
    slow = matchers.match("sgm", left, right, max_disp, **opts, backend="torch")
    torch.testing.assert_close(fast.cost_volume, slow.cost_volume, rtol=1e-6, atol=1e-3)
    assert torch.equal(fast.valid, slow.valid) and torch.equal(fast.disparity, slow.disparity)
    plain = matchers.match("sgm", left, right, max_disp, keep_volume=True)
    assert not torch.equal(plain.cost_volume, fast.cost_volume)  # the mixed-in volume was used
    if mix_step is not None:  # the rounded cost: every aggregated value on the 1/16-bit grid (exact float sums)
        assert torch.equal(fast.cost_volume * 16, torch.round(fast.cost_volume * 16))


@pytest.mark.parametrize("scale", [2.0, 40.0])
def test_sgm_mixed_16_bit_path_equals_float32_kernel(scale):
    """The default CPU path of a mixed-in cost (quarter-bit uint8, int16 aggregation, selection from it) gives
    the very maps and confidence of the float32 kernel on the same rounded cost (exact sums on the grid), and
    a cost too large for uint8 (scale 40: up to 4 * 18 * 40 quarter bits) falls back to that kernel."""
    left, right, max_disp, other = _mixed_pair(scale)
    fast = matchers.match("sgm", left, right, max_disp, extra_cost=(0.25, 18.0, other))
    ref = matchers.match("sgm", left, right, max_disp, extra_cost=(0.25, 18.0, other), keep_volume=True)
    slow = matchers.match("sgm", left, right, max_disp, extra_cost=(0.25, 18.0, other), backend="torch")
    assert (fast.cost_volume is None) == (scale == 2.0)  # the 16-bit path keeps no float volume
    for out in (ref, slow):
        assert torch.equal(fast.disparity, out.disparity) and torch.equal(fast.valid, out.valid)
    torch.testing.assert_close(fast.confidence, ref.confidence, rtol=0, atol=1e-6)
    unrounded = matchers.match("sgm", left, right, max_disp, extra_cost=(0.25, 18.0, other), mix_step=None)
    assert not torch.equal(unrounded.disparity, fast.disparity)  # the rounding is real (sub-pixel values move)


def test_sgm_mix_step_rounds_only_census_costs():
    """The quarter-bit grid is in Hamming bits: a mix into another cost (SAD, in [0, 1]) stays unrounded."""
    left, right, max_disp, other = _mixed_pair()
    opts = dict(cost="sad", P1=0.05, P2=0.6, keep_volume=True, extra_cost=(0.5, 0.1, other))
    rounded = matchers.match("sgm", left, right, max_disp, **opts)
    plain = matchers.match("sgm", left, right, max_disp, **opts, mix_step=None)
    assert torch.equal(rounded.cost_volume, plain.cost_volume)
    assert not torch.equal(rounded.cost_volume * 16, torch.round(rounded.cost_volume * 16))


@pytest.mark.parametrize("bad", [0.3, 2.0, "quarter", 0.0])
def test_sgm_mix_step_must_be_a_power_of_two_grid(bad):
    left, right, max_disp, other = _mixed_pair()
    with pytest.raises(StereoInputError, match="mix_step"):
        matchers.match("sgm", left, right, max_disp, extra_cost=(0.25, 18.0, other), mix_step=bad)


@pytest.mark.parametrize("alpha", [0.0, 20.0])
def test_fixed_point_p2_maps_equal_numpy_maps_on_the_grid(alpha):
    """The int16 P2 maps (one numba pass) are ``s`` times the numpy maps with the same penalty step."""
    from stereonet.kernels.sgm import p2_maps_fixed

    grey = np.random.default_rng(4).random((ROW_BLOCK + 3, 29), dtype=np.float32)
    grey[3, :] = grey[4, :]  # zero gradients: P2 itself
    ref = p2_maps_numpy(2.0, 48.0, DIRECTIONS_16, grey, alpha, 1 / 16)
    got = p2_maps_fixed(grey, np.float32(2.0), np.float32(48.0), np.float32(alpha),
                        np.asarray(DIRECTIONS_16, np.int64), 16)
    assert got.dtype == np.int16 and np.array_equal(got.astype(np.float32) / np.float32(16), ref)
