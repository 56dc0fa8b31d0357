"""Local selection: WTA, sub-pixel, uniqueness, LR check on a step edge, textbook fill, filters."""

from __future__ import annotations

import pytest
import torch

from stereonet.checks import StereoInputError
from stereonet.cost import build_cost_volume
from stereonet.select.fill import fill_occlusions
from stereonet.select.filters import median_filter, speckle_filter
from stereonet.select.lr_check import left_right_check, left_right_difference, right_cost_volume, wta_right
from stereonet.select.subpixel import subpixel_refine
from stereonet.select.wta import uniqueness_mask, wta

FG = (40, 70)  # foreground columns in the left image
D_FG, D_BG = 8, 2


def step_pair(h: int = 32, w: int = 112, seed: int = 0):
    """Foreground strip (disparity 8) over a background plane (disparity 2); textures in left coordinates.

    Left-only (occluded) pixels: background x in [34, 40) whose right match x - 2 is hidden by the strip.
    """
    g = torch.Generator().manual_seed(seed)
    bg = torch.rand(1, 1, h, w, generator=g, dtype=torch.float64)
    fg = torch.rand(1, 1, h, w, generator=g, dtype=torch.float64)
    x = torch.arange(w)
    in_fg = (x >= FG[0]) & (x < FG[1])
    left = torch.where(in_fg, fg, bg)
    xr = torch.arange(w)
    fg_src = xr + D_FG
    hit = (fg_src >= FG[0]) & (fg_src < FG[1])
    bg_src = (xr + D_BG).clamp(max=w - 1)
    right = torch.where(hit, fg[..., fg_src.clamp(max=w - 1)], bg[..., bg_src])
    gt = torch.where(in_fg, float(D_FG), float(D_BG)).expand(1, 1, h, w)
    return left, right, gt


def test_wta_and_right_wta_on_step():
    left, right, gt = step_pair()
    vol = build_cost_volume(left, right, 12, cost="sad", window=5)
    disp, min_cost = wta(vol)
    assert disp.shape == (1, 1, 32, 112) and min_cost.shape == disp.shape
    far = torch.zeros(112, dtype=torch.bool)
    far[14:30] = True
    far[46:64] = True
    far[78:100] = True
    assert (disp[..., far] == gt[..., far]).float().mean() > 0.98
    disp_right = wta_right(vol)
    torch.testing.assert_close(disp_right, wta(right_cost_volume(vol))[0])


def test_lr_check_flags_occluded_band():
    left, right, gt = step_pair()
    vol = build_cost_volume(left, right, 12, cost="sad", window=3)
    disp, _ = wta(vol)
    ok = left_right_check(disp, wta_right(vol), tol=0)
    band = ok[0, 0, 4:-4, 35:39]  # inside the occluded band [34, 40)
    assert band.float().mean() < 0.2
    assert ok[0, 0, 4:-4, 48:62].float().mean() > 0.95
    assert ok[0, 0, 4:-4, 80:100].float().mean() > 0.95


def test_fill_takes_background_side():
    disp = torch.tensor([[[[2.0, 2.0, 0.0, 0.0, 8.0, 8.0, 0.0, 5.0, 0.0]]]])
    valid = torch.tensor([[[[1, 1, 0, 0, 1, 1, 0, 1, 0]]]], dtype=torch.bool)
    out = fill_occlusions(disp, valid)
    assert out.flatten().tolist() == [2.0, 2.0, 2.0, 2.0, 8.0, 8.0, 5.0, 5.0, 5.0]
    none = fill_occlusions(disp, torch.zeros_like(valid))
    assert none.eq(0).all()


def test_fill_on_step_recovers_background():
    left, right, gt = step_pair()
    vol = build_cost_volume(left, right, 12, cost="sad", window=3)
    disp, _ = wta(vol)
    ok = left_right_check(disp, wta_right(vol), tol=0)
    filled = fill_occlusions(disp, ok)
    assert (filled[0, 0, 4:-4, 34:40] == D_BG).float().mean() > 0.9


@pytest.mark.parametrize("method", ["parabola", "equiangular"])
def test_subpixel_recovers_vertex(method):
    d = torch.arange(9, dtype=torch.float64).view(1, 9, 1, 1)
    true = 4.3
    cost = (d - true).square() if method == "parabola" else (d - true).abs()
    ref = subpixel_refine(cost, wta(cost)[0], method=method)
    assert ref.item() == pytest.approx(true, abs=1e-9)


@pytest.mark.parametrize("method", ["parabola", "equiangular"])
def test_refine_from_neighbours_is_subpixel_refine(method):
    """The three-value form gives subpixel_refine's bits, the range's ends included (offset 0 there)."""
    from stereonet.select.subpixel import refine_from_neighbours

    g = torch.Generator().manual_seed(0)
    cost = torch.rand(2, 7, 5, 6, generator=g)
    d = wta(cost)[0].long()
    d[0, 0, 0, :3] = torch.tensor([0, 6, 3])
    near = [cost.gather(1, (d + k).clamp(0, 6)) for k in (-1, 0, 1)]
    out = refine_from_neighbours(d, *near, 7, method)
    assert torch.equal(out, subpixel_refine(cost, d.float(), method=method))
    assert out[0, 0, 0, 0] == 0 and out[0, 0, 0, 1] == 6


def test_subpixel_boundary_and_flat():
    cost = torch.zeros(1, 5, 1, 2, dtype=torch.float64)
    cost[0, :, 0, 1] = torch.tensor([0.0, 1, 2, 3, 4])
    out = subpixel_refine(cost, wta(cost)[0])
    assert out.flatten().tolist() == [0.0, 0.0]
    with pytest.raises(StereoInputError, match="method"):
        subpixel_refine(cost, wta(cost)[0], method="cubic")


def test_uniqueness():
    cost = torch.tensor([1.0, 0.0, 0.05, 1.0, 1.0]).view(1, 5, 1, 1)  # neighbour d=2 is ignored
    assert uniqueness_mask(cost, wta(cost)[0], 0.5).item()
    cost2 = torch.tensor([1.0, 0.5, 1.0, 0.55, 1.0]).view(1, 5, 1, 1)
    assert not uniqueness_mask(cost2, wta(cost2)[0], 0.2).item()
    assert uniqueness_mask(cost2, wta(cost2)[0], 0.05).item()


def test_median_and_speckle():
    disp = torch.full((1, 1, 20, 20), 3.0)
    disp[0, 0, 5, 5] = 30.0  # a 1-pixel outlier
    disp[0, 0, 10:13, 10:13] = 15.0  # a 9-pixel blob
    valid = torch.ones_like(disp, dtype=torch.bool)
    med = median_filter(disp, 3)
    assert med[0, 0, 5, 5] == 3.0 and med[0, 0, 11, 11] == 15.0
    med_v = median_filter(disp, 3, valid=disp < 20)
    assert med_v[0, 0, 5, 5] == 3.0
    kept = speckle_filter(disp, valid, max_size=10, max_diff=1.0)
    assert not kept[0, 0, 5, 5] and not kept[0, 0, 11, 11] and kept[0, 0, 0, 0]
    assert speckle_filter(disp, valid, max_size=5)[0, 0, 11, 11]


def test_lr_check_shapes_raise():
    with pytest.raises(StereoInputError, match="disp_right"):
        left_right_check(torch.zeros(1, 1, 4, 5), torch.zeros(1, 1, 4, 6))


@pytest.mark.parametrize("with_valid", [False, True])
def test_median_numba_equals_torch(with_valid):
    g = torch.Generator().manual_seed(4)
    disp = torch.rand(2, 1, 13, 17, generator=g) * 10
    valid = torch.rand(2, 1, 13, 17, generator=g) > 0.4 if with_valid else None
    for size in (3, 5):
        torch.testing.assert_close(median_filter(disp, size, valid, backend="numba"),
                                   median_filter(disp, size, valid, backend="torch"))


def test_dsi_scanline_and_plot(tmp_path):
    from stereonet.aggregate.dsi import dsi_scanline, plot_dsi

    left, right, gt = step_pair()
    vol = build_cost_volume(left, right, 12, cost="sad", window=5)
    dsi, path = dsi_scanline(vol, 16)
    assert dsi.shape == (13, 112) and path.shape == (112,)
    assert (path[46:64] == D_FG).all() and (path[80:100] == D_BG).all()
    _, given = dsi_scanline(vol, 16, path=gt)
    assert torch.equal(given, gt[0, 0, 16])
    out = tmp_path / "dsi.png"
    plot_dsi(dsi, {"WTA": path, "ground truth": given}, out=out)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(StereoInputError, match="row"):
        dsi_scanline(vol, 32)


def test_wta_right_numba_equals_loop():
    g = torch.Generator().manual_seed(8)
    vol = torch.randint(0, 5, (2, 6, 7, 11), generator=g).float()  # many ties
    fast = wta_right(vol)
    ref = wta(right_cost_volume(vol.double()))[0].float()
    torch.testing.assert_close(fast, ref)


def test_left_right_difference_is_what_the_check_thresholds():
    # one row of 6: left disparities and right disparities hand-made, matches xr = round(x - dL)
    dl = torch.tensor([[[[0.0, 1.0, 1.4, 5.0, 2.0, float("nan")]]]])
    dr = torch.tensor([[[[0.5, 3.0, 1.0, 2.0, 7.0, 0.0]]]])
    diff = left_right_difference(dl, dr)
    # x=0: xr=0 |0-0.5|; x=1: xr=0 |1-0.5|; x=2: xr=1 |1.4-3|; x=3: xr=-2 outside; x=4: xr=2 |2-1|; x=5: NaN, no match
    inf = float("inf")
    assert torch.allclose(diff[0, 0, 0], torch.tensor([0.5, 0.5, 1.6, inf, 1.0, inf]))
    for tol in (0.0, 0.5, 1.0, 2.0, float("inf")):
        assert torch.equal(left_right_check(dl, dr, tol=tol), (diff <= tol) & torch.isfinite(diff))
    with pytest.raises(StereoInputError, match="disp_right"):
        left_right_difference(dl, torch.zeros(1, 1, 1, 5))
