"""Learned networks: shapes, padding to the stride, statelessness, correlation, mixture, weights files."""

from __future__ import annotations

import pytest
import torch

from stereonet.checks import StereoInputError
from stereonet.cost.correlation import correlation_1d, group_correlation_1d
from stereonet.models.dispnet import DispNet, DispNetOutput, predict_disparity
from stereonet.models.layers import (
    InputPadder,
    local_correlation,
    standardize_image,
    unit_channels,
)
from stereonet.models.siamese import (
    INVALID_COST,
    SiameseNet,
    matching_loss,
    siamese_cost_volume,
    siamese_pair_loss,
)
from stereonet.models.smd import (
    MixtureParams,
    SMDNet,
    context_offsets,
    neighbourhood,
    predict_smd,
    query_grid,
)
from stereonet.models.weights import load_weights, save_weights


@pytest.fixture
def small_dispnet():
    torch.manual_seed(0)
    return DispNet(max_disp=16, channels=8).eval()


@pytest.mark.parametrize("hw", [(32, 64), (37, 50), (17, 33)])
def test_predict_pads_and_unpads_never_crops(small_dispnet, hw):
    left, right = torch.rand(1, 3, *hw), torch.rand(1, 3, *hw)
    disp = predict_disparity(small_dispnet, left, right)
    assert disp.shape == (1, 1, *hw)
    assert torch.isfinite(disp).all()


def test_input_padder_roundtrip():
    x = torch.rand(2, 3, 37, 50)
    padder = InputPadder(37, 50, 16)
    (p,) = padder.pad(x)
    assert p.shape[-2:] == (48, 64)
    assert torch.equal(padder.unpad(p), x)
    assert torch.equal(p[..., 36:, :50][:, :, -1], p[..., 47, :50])  # replicate padding


def test_forward_rejects_unpadded_input(small_dispnet):
    with pytest.raises(ValueError, match="multiples of 16"):
        small_dispnet(torch.rand(1, 3, 30, 64), torch.rand(1, 3, 30, 64))


@pytest.mark.parametrize("options, message", [
    ({"aggregation": "3d", "agg_dilations": (1, 2)}, "agg_dilations: expected three integers >= 1"),
    ({"aggregation": "3d", "agg_dilations": (1, 0, 2)}, "agg_dilations: expected three integers >= 1"),
    ({"aggregation": "2d", "agg_dilations": (1, 2, 4)}, "agg_dilations: only aggregation='3d'"),
    ({"refine_radius": -1}, "refine_radius: expected >= 0"),
    ({"refine_readout": "free"}, "refine_readout: expected 'residual' or 'matched'"),
    ({"refine_readout": "matched", "refine_radius": 0}, "refine_radius: refine_readout='matched' needs >= 1"),
    ({"volume": "fine"}, "volume: expected 'coarse', 'pooled' or 'both'"),
    ({"volume": "pooled"}, "volume: 'pooled' needs matching='census'"),
])
def test_dispnet_rejects_bad_options_naming_them(options, message):
    with pytest.raises(StereoInputError, match=message):
        DispNet(max_disp=16, channels=4, **options)


@pytest.mark.parametrize("matching", ["learned", "census"])
def test_dispnet_matched_readout_corrects_within_reach_and_starts_as_the_local_soft_argmax(matching):
    """``refine_readout="matched"``: the 1/2 and 1/1 corrections are soft-argmaxes over the local correlation's
    shifts, so whatever the logit heads hold, each stage moves its (bilinearly upsampled) input by at most
    ``refine_radius`` of its own pixels (2 r input px at 1/2, r at 1/1); the free residual with the same large
    head weights moves it further. At the start (heads zero) the 1/1 correction is exactly the soft-argmax of the
    scaled local correlation; gradients reach the logit heads."""
    from stereonet.aggregate.soft import soft_argmax
    from stereonet.models.dispnet import _up2

    torch.manual_seed(0)
    left, right = torch.rand(1, 3, 32, 64), torch.rand(1, 3, 32, 64)
    r = 2
    matched = DispNet(max_disp=16, channels=4, matching=matching, refine_readout="matched", refine_radius=r)
    out = matched(left, right)
    d1, d0 = out.pyramid[3], out.pyramid[4]
    n0 = (matched._census_features(left, right)[0] if matching == "census"
          else unit_channels(matched.enc0(torch.cat([standardize_image(left), standardize_image(right)]))))
    start = (soft_argmax(local_correlation(n0[:1], n0[1:], _up2(d1), r) * matched.local_scale) - r)
    torch.testing.assert_close(d0 - _up2(d1), start, rtol=1e-5, atol=1e-5)
    out.disparity.abs().mean().backward()
    assert matched.pred0.weight.grad.abs().sum() > 0 and matched.pred1.weight.grad.abs().sum() > 0
    residual = DispNet(max_disp=16, channels=4, matching=matching, refine_radius=r)
    with torch.no_grad():
        for net in (matched, residual):
            for head in (net.pred1, net.pred0):
                head.weight.normal_(0.0, 50.0)
            out = net(left, right)
            d2, d1, d0 = out.pyramid[2:]
            step1, step0 = (d1 - _up2(d2)).abs().max(), (d0 - _up2(d1)).abs().max()
            if net is matched:
                assert step1 <= 2 * r + 1e-4 and step0 <= r + 1e-4, (step1, step0)
            else:
                assert step1 > 2 * r or step0 > r, (step1, step0)


def test_dispnet_stateless_same_structure_train_and_eval(small_dispnet):
    left, right = torch.rand(2, 3, 32, 64), torch.rand(2, 3, 32, 64)
    outs = []
    for mode in (True, False):
        small_dispnet.train(mode)
        out = small_dispnet(left, right)
        assert isinstance(out, DispNetOutput)
        outs.append(out)
    assert [p.shape for p in outs[0].pyramid] == [p.shape for p in outs[1].pyramid]
    assert [tuple(p.shape[-2:]) for p in outs[0].pyramid] == [(2, 4), (4, 8), (8, 16), (16, 32), (32, 64)]
    assert torch.allclose(outs[0].disparity, outs[1].disparity)  # no dropout/BN: identical
    assert not any(isinstance(v, torch.Tensor) for v in vars(small_dispnet).values())


def test_correlation_matches_naive_loop():
    g = torch.Generator().manual_seed(1)
    fl, fr = torch.rand(2, 4, 3, 10, generator=g), torch.rand(2, 4, 3, 10, generator=g)
    corr = correlation_1d(fl, fr, 3)
    for d in range(4):
        for x in range(10):
            want = (fl[..., x] * fr[..., x - d]).mean(1) if x - d >= 0 else torch.zeros(2, 3)
            assert torch.allclose(corr[:, d, :, x], want)


def test_correlation_gradcheck():
    g = torch.Generator().manual_seed(2)
    fl = torch.rand(1, 2, 2, 5, generator=g, dtype=torch.float64, requires_grad=True)
    fr = torch.rand(1, 2, 2, 5, generator=g, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda a, b: correlation_1d(a, b, 2), (fl, fr))


def test_local_correlation_integer_disparity_matches_global():
    # at an integer disparity field d, shift s must give the global correlation at level d + s
    g = torch.Generator().manual_seed(3)
    fl, fr = torch.rand(2, 4, 3, 12, generator=g), torch.rand(2, 4, 3, 12, generator=g)
    disp = torch.randint(2, 5, (2, 1, 3, 12), generator=g).float()
    local = local_correlation(fl, fr, disp, radius=2)
    full = correlation_1d(fl, fr, 8)
    for k, s in enumerate(range(-2, 3)):
        level = (disp + s).long()
        want = full.gather(1, level)[:, 0]
        x = torch.arange(12).view(1, 1, 12)
        inside = (x - level[:, 0]) >= 0
        assert torch.allclose(local[:, k][inside], want[inside], atol=1e-6)
        assert torch.all(local[:, k][~inside].abs() < 1e-6)  # zeros outside the right image


def test_local_correlation_subpixel_is_linear_and_differentiable():
    g = torch.Generator().manual_seed(4)
    fl = torch.rand(1, 3, 2, 9, generator=g, dtype=torch.float64)
    fr = torch.rand(1, 3, 2, 9, generator=g, dtype=torch.float64)
    half = local_correlation(fl, fr, torch.full((1, 1, 2, 9), 2.5, dtype=torch.float64), radius=0)
    lo = local_correlation(fl, fr, torch.full((1, 1, 2, 9), 2.0, dtype=torch.float64), radius=0)
    hi = local_correlation(fl, fr, torch.full((1, 1, 2, 9), 3.0, dtype=torch.float64), radius=0)
    assert torch.allclose(half[..., 3:], 0.5 * (lo + hi)[..., 3:])  # bilinear between integer shifts
    disp = torch.full((1, 1, 2, 9), 1.3, dtype=torch.float64, requires_grad=True)
    fl.requires_grad_(True)
    assert torch.autograd.gradcheck(lambda a, d: local_correlation(a, fr, d, radius=1), (fl, disp))


def test_group_correlation_means_to_correlation_and_aggregation_variants():
    g = torch.Generator().manual_seed(5)
    fl, fr = torch.rand(2, 8, 3, 10, generator=g), torch.rand(2, 8, 3, 10, generator=g)
    gwc = group_correlation_1d(fl, fr, 4, groups=4)
    assert gwc.shape == (2, 4, 5, 3, 10)
    assert torch.allclose(gwc.mean(dim=1), correlation_1d(fl, fr, 4), atol=1e-6)
    assert torch.allclose(gwc[:, 1, 2, :, 5], (fl[:, 2:4, :, 5] * fr[:, 2:4, :, 3]).mean(dim=1), atol=1e-6)
    left, right = torch.rand(1, 3, 32, 48, generator=g), torch.rand(1, 3, 32, 48, generator=g)
    for aggregation in ("2d", "3d"):
        out = DispNet(max_disp=16, channels=8, aggregation=aggregation)(left, right)
        assert out.disparity.shape == (1, 1, 32, 48) and torch.isfinite(out.disparity).all()
    with pytest.raises(ValueError, match="aggregation"):
        DispNet(aggregation="4d")
    with pytest.raises(ValueError, match="groups"):
        DispNet(channels=8, groups=3)


def test_census_matching_finds_the_shift_untrained_and_keeps_its_config(tmp_path):
    """matching="census": the 1/4 correlation compares census signs of the two views (right view second), so an
    untrained network's soft-argmin start finds a textured pair's shift; the right view reaches the network only
    through those signs (an increasing change of the right image's intensities changes nothing)."""
    from stereonet.training.module import DispNetModule, SMDModule

    g = torch.Generator().manual_seed(7)
    shift = 8
    texture = torch.nn.functional.interpolate(torch.rand(1, 1, 16, 28, generator=g), size=(64, 112), mode="bilinear")
    left, right = texture[..., :96].repeat(1, 3, 1, 1), texture[..., shift:shift + 96].repeat(1, 3, 1, 1)
    net = DispNet(max_disp=32, channels=8, upsample="select", matching="census").eval()
    torch.nn.init.zeros_(net.corr_agg[-1].weight)
    torch.nn.init.zeros_(net.corr_agg[-1].bias)  # logits = correlation x temperature alone
    with torch.no_grad():
        net.corr_scale.fill_(24 * 10.0)  # the correlation is a mean over 24 channels: cosine 1 -> logit 10
    with torch.no_grad():
        out = net(left, right)
        again = net(left, right * 0.5)  # exact in floats: every comparison keeps its sign
    core = out.matched[..., 2:-2, 4:-2]  # away from the borders the shifted crop lacks
    assert (core - shift).abs().median() < 1.0
    assert torch.equal(out.disparity, again.disparity)
    learned = DispNet(max_disp=32, channels=8, upsample="select").eval()
    assert sum(p.numel() for p in learned.parameters()) == sum(p.numel() for p in net.parameters())
    module = DispNetModule(max_disp=32, channels=8, upsample="select", matching="census")
    assert module.model_config()["matching"] == "census"
    assert "matching" not in DispNetModule(max_disp=32, channels=8).model_config()  # older files stay valid
    path = tmp_path / "census.pt"
    save_weights(path, "dispnet", module.model_config(), module.model)
    loaded, _ = load_weights(path, expected="dispnet")
    assert loaded.matching == "census"
    smd = SMDModule(max_disp=32, channels=8, upsample="select", matching="census")
    save_weights(tmp_path / "smd.pt", "smd", smd.model_config(), smd.model)
    assert load_weights(tmp_path / "smd.pt", expected="smd")[0].backbone.matching == "census"
    with pytest.raises(ValueError, match="matching"):
        DispNet(matching="sift")
    with pytest.raises(ValueError, match="groups: expected a divisor of the 24 matching channels"):
        DispNet(matching="census", aggregation="3d", groups=5)
    grouped = DispNet(max_disp=32, channels=8, matching="census", aggregation="3d", groups=4)
    assert grouped(left, right).disparity.shape == left[:, :1].shape


def test_select_upsampling_keeps_depth_edges_sharp():
    """At a depth edge the matched choice among coarse neighbours gives the foreground's or the background's
    disparity where bilinear upsampling blends them (untrained head: the logits are the correlation alone)."""
    g = torch.Generator().manual_seed(3)
    h, w, near, far, edge = 8, 64, 12, 4, 32  # fine scale; true disparity far left of the edge, near right of it
    feat_right = torch.randn(1, 16, h, w + near, generator=g)
    xs = torch.arange(w)
    true = torch.where(xs < edge, far, near).float()
    feat_left = feat_right[..., (xs + near - true).long()]  # left(x) = right(x - d(x)) in a padded frame
    feat_right = feat_right[..., near:]  # crop so the padded frame's x + near is the image's x
    true_map = true.view(1, 1, 1, w).expand(1, 1, h, w)
    coarse = torch.nn.functional.avg_pool2d(torch.nn.functional.pad(true_map, (1, 0, 0, 0), mode="replicate")[..., :w],
                                            2)  # edge falls inside a coarse cell: that cell is a blend
    net = DispNet(max_disp=16, channels=8, upsample="select")
    context = torch.zeros(1, 8, h, w)
    with torch.no_grad():
        selected = net._select_up(coarse, unit_channels(feat_left), unit_channels(feat_right), context, 1,
                                  net.select0)
        bilinear = torch.nn.functional.interpolate(coarse, scale_factor=2.0, mode="bilinear", align_corners=False)
    band = (xs - edge).abs() <= 3  # the pixels beside the edge, away from the image border
    interior = band & (xs > near + 2)
    err_sel = (selected[0, 0, 1:-1] - true_map[0, 0, 1:-1]).abs()[:, interior]
    err_bil = (bilinear[0, 0, 1:-1] - true_map[0, 0, 1:-1]).abs()[:, interior]
    assert err_bil.mean() > 1.0  # the blend is far from both sides
    assert err_sel.mean() < 0.1 * err_bil.mean() and err_sel.max() < 0.5
    with pytest.raises(ValueError, match="upsample"):
        DispNet(upsample="nearest")


def test_unit_channels_equals_normalize():
    x = torch.randn(2, 5, 4, 6)
    assert torch.allclose(unit_channels(x), torch.nn.functional.normalize(x, dim=1), atol=1e-6)


def test_smd_queries_at_higher_resolution_and_uncertainty():
    torch.manual_seed(0)
    net = SMDNet(max_disp=16, channels=8).eval()
    left, right = torch.rand(1, 3, 30, 40), torch.rand(1, 3, 30, 40)
    disp, unc = predict_smd(net, left, right)
    assert disp.shape == unc.shape == (1, 1, 30, 40)
    disp2, unc2 = predict_smd(net, left, right, upsample=2.0)
    assert disp2.shape == (1, 1, 60, 80)
    assert (unc > 0).all() and (unc2 > 0).all()
    # values are in pixels of the output grid: the 2x map is about twice the 1x one
    assert torch.allclose(disp2[..., ::2, ::2].mean(), 2 * disp.mean(), rtol=0.2)


def test_context_offsets():
    assert context_offsets(0) == []
    assert sorted(context_offsets(1)) == sorted((dx, dy) for dx in (-1, 0, 1) for dy in (-1, 0, 1) if dx or dy)
    four = context_offsets(4)
    assert len(four) == 48 and len(set(four)) == 48 and (0, 0) not in four
    assert {dx for dx, _ in four} == {-4, -2, -1, 0, 1, 2, 4} == {dy for _, dy in four}
    assert {dx for dx, _ in context_offsets(5)} == {dx for dx, _ in four}  # powers of two up to the reach


def test_neighbourhood_samples_shifted_pixels_relative_to_the_centre():
    torch.manual_seed(0)
    maps = torch.rand(2, 3, 9, 11, dtype=torch.float64)
    grid = query_grid(2, 9, 11, dtype=torch.float64)  # pixel centres: bilinear samples are the pixels themselves
    offsets = [(1, 0), (0, -2), (-2, 1)]
    got = neighbourhood(maps, grid, offsets)
    assert got.shape == (2, 9, 9, 11)
    for k, (dx, dy) in enumerate(offsets):
        part = got[:, 3 * k:3 * k + 3]
        want = torch.roll(maps, shifts=(-dy, -dx), dims=(2, 3)) - maps  # maps[y + dy, x + dx] - maps[y, x]
        inner = (slice(None), slice(None), slice(2, -2), slice(2, -2))
        torch.testing.assert_close(part[inner], want[inner], rtol=0, atol=1e-12)
    # at the border the samples clamp (padding "border"): the left column looking left sees itself
    assert float(neighbourhood(maps, grid, [(-1, 0)])[..., 0].abs().max()) < 1e-12


def test_smd_context_head_sees_the_image_around_each_point():
    torch.manual_seed(0)
    left, right = torch.rand(1, 3, 32, 48), torch.rand(1, 3, 32, 48)
    with pytest.raises(ValueError, match="context"):
        SMDNet(max_disp=16, channels=8, context=-1)
    plain, ctx = SMDNet(max_disp=16, channels=8).eval(), SMDNet(max_disp=16, channels=8, context=2).eval()
    assert ctx.mlp[0].in_channels == plain.mlp[0].in_channels + 2 * 24
    grid = query_grid(1, 32, 48)
    with torch.no_grad():
        backbone = ctx.backbone(left, right)
        other = left.clone()
        other[..., 10:20, 10:20] = left[..., 10:20, 10:20].transpose(-1, -2)  # same pixels: same mean and std
        a, b = ctx.query(backbone, grid, left=left), ctx.query(backbone, grid, left=other)
        changed = (a.pi - b.pi).abs()[0, 0] > 1e-6
        assert changed[9:21, 9:21].any() and not changed[:6].any()  # only points whose neighbourhood changed
        with pytest.raises(StereoInputError, match="left: expected the backbone's left input"):
            ctx.query(backbone, grid)
        assert torch.equal(plain.query(backbone, grid).pi, plain.query(backbone, grid, left=other).pi)
    disp, unc = predict_smd(ctx, left[..., :30, :45], right[..., :30, :45], upsample=2.0)  # padded, any scale
    assert disp.shape == unc.shape == (1, 1, 60, 90) and bool(torch.isfinite(disp).all())
    # context_grey=False: the disparity neighbourhood alone; the image is not read (nor needed) by the head
    bare = SMDNet(max_disp=16, channels=8, context=2, context_grey=False).eval()
    assert bare.mlp[0].in_channels == plain.mlp[0].in_channels + 24
    with torch.no_grad():
        backbone = bare.backbone(left, right)
        assert torch.equal(bare.query(backbone, grid).pi, bare.query(backbone, grid, left=other).pi)
        moved = DispNetOutput(backbone.disparity.clone(), backbone.pyramid, backbone.features, backbone.matched)
        moved.disparity[..., 10:20, 10:20] += 3.0
        changed = (bare.query(backbone, grid).pi - bare.query(moved, grid).pi).abs()[0, 0] > 1e-6
        assert changed[8:22, 8:22].any() and not changed[:6].any()  # points whose neighbourhood's disparity moved
    disp, _ = predict_smd(bare, left[..., :30, :45], right[..., :30, :45], upsample=2.0)
    assert disp.shape == (1, 1, 60, 90) and bool(torch.isfinite(disp).all())


def test_smd_stateless_same_structure():
    torch.manual_seed(0)
    net = SMDNet(max_disp=16, channels=8)
    left, right = torch.rand(1, 3, 32, 32), torch.rand(1, 3, 32, 32)
    a = net.train()(left, right)
    b = net.eval()(left, right)
    assert type(a) is type(b) and a.disparity.shape == b.disparity.shape
    assert torch.allclose(a.disparity, b.disparity)


def test_mixture_mode_picks_higher_density():
    ones = torch.ones(1, 1, 1, 2)
    mix = MixtureParams(mu1=ones * 3, mu2=ones * 10, b1=torch.tensor([[[[1.0, 1.0]]]]),
                        b2=torch.tensor([[[[1.0, 0.1]]]]), pi=torch.tensor([[[[0.7, 0.3]]]]))
    disp, scale = mix.mode_disparity()
    assert disp.flatten().tolist() == [3.0, 10.0]  # 0.7/1 > 0.3/1 ; 0.7/1 < 0.3/0.1
    assert scale.flatten().tolist() == pytest.approx([1.0, 0.1])


def test_query_grid_hits_pixel_centres():
    grid = query_grid(1, 2, 4)
    assert grid.shape == (1, 2, 4, 2)
    assert torch.allclose(grid[0, 0, :, 0], torch.tensor([-0.75, -0.25, 0.25, 0.75]))


def test_siamese_features_unit_length_and_cost_volume():
    torch.manual_seed(0)
    net = SiameseNet(channels=8, layers=3)
    img = torch.rand(2, 3, 20, 30)
    f = net(img)
    assert f.shape == (2, 8, 20, 30)
    assert torch.allclose(f.norm(dim=1), torch.ones(2, 20, 30), atol=1e-5)
    cost = siamese_cost_volume(f, f.roll(1, dims=0), 5)
    assert cost.shape == (2, 6, 20, 30)
    assert (cost[:, 3, :, :3] == INVALID_COST).all()
    y, x, d = 4, 10, 3
    assert torch.allclose(cost[0, d, y, x], 1 - (f[0, :, y, x] * f[1, :, y, x - d]).sum())


def test_siamese_cost_finds_shift_on_textured_pair(textured_pair):
    """Even untrained, random 3x3 filters on random texture give the lowest cost at the true shift."""
    left, right, d = textured_pair
    torch.manual_seed(0)
    net = SiameseNet(channels=16, layers=3)
    with torch.no_grad():
        cost = siamese_cost_volume(net(left), net(right), 10)
    wta = cost.argmin(1)[..., 10:]
    assert (wta == d).float().mean() > 0.9


@pytest.mark.parametrize("inputs", ["grey", "census", "grey+census"])
def test_patch_features_equal_dense_features(inputs):
    torch.manual_seed(0)
    net = SiameseNet(channels=8, layers=3, inputs=inputs, census_window=5)
    img = torch.rand(2, 3, 20, 30)
    dense = net(img)
    x = torch.tensor([[0.0, 5, 29], [3, 7, 12]])
    y = torch.tensor([[0.0, 19, 4], [10, 2, 7]])
    patches = net.patch_features(img, x, y)
    ref = torch.stack([dense[b, :, y[b].long(), x[b].long()] for b in range(2)])
    assert torch.allclose(patches, ref, atol=1e-5)
    if inputs != "grey":  # census signs are discontinuous in the image: grid_sample's ~1e-7 flips tied signs
        return
    # fractional positions (sub-pixel positives): the bilinear patches torch's grid_sample samples
    import torch.nn.functional as F

    from stereonet.models.layers import standardize_image

    xf, yf = x.clamp(max=28.6) + 0.4, y.clamp(max=18.75) + 0.25
    grey = F.pad(standardize_image(img, grey=True), (net.radius,) * 4, mode="replicate")
    hp, wp = grey.shape[-2:]
    offs = torch.arange(-net.radius, net.radius + 1, dtype=torch.float32)
    k = offs.numel()
    px = (xf[:, :, None, None] + net.radius + offs).expand(2, 3, k, k)
    py = (yf[:, :, None, None] + net.radius + offs[:, None]).expand(2, 3, k, k)
    grid = torch.stack([(2 * px + 1) / wp - 1, (2 * py + 1) / hp - 1], dim=-1).reshape(2, 3 * k, k, 2)
    sampled = F.grid_sample(grey, grid, mode="bilinear", padding_mode="border", align_corners=False)
    with torch.no_grad():
        feats = net.tower(net._first_input(sampled.reshape(6, 1, k, k))).reshape(2, 3, -1)
    assert torch.allclose(net.patch_features(img, xf, yf), F.normalize(feats, dim=2).transpose(1, 2), atol=1e-4)


def test_census_input_tower_sees_only_the_local_order(textured_pair):
    """inputs="census": features unchanged by a monotonic change of intensity (the grey tower's change), the
    receptive field is the census ring plus the convolutions (a change 6 px away is not seen with 5x5 + 3
    layers, one 5 px away is), it still finds the shift untrained, and bad arguments name themselves."""
    left, right, d = textured_pair
    torch.manual_seed(0)
    net = SiameseNet(channels=16, layers=3, inputs="census", census_window=5)
    grey = SiameseNet(channels=16, layers=3)
    assert net.radius == 5 and net.tower[0].in_channels == 24 and grey.radius == 3
    bent = left.clamp(0, 1) ** 2.2 * 0.5 + 0.1
    with torch.no_grad():
        assert torch.allclose(net(bent), net(left), atol=1e-6)
        assert not torch.allclose(grey(bent), grey(left), atol=1e-3)
        cost = siamese_cost_volume(net(left), net(right), 10)
        assert (cost.argmin(1)[..., 10:] == d).float().mean() > 0.9
        base = net(left)
        for dist, seen in ((6, False), (5, True)):
            moved = left.clone()
            moved[..., 20, 20 + dist] = 1.0 - moved[..., 20, 20 + dist]
            assert (not torch.allclose(net(moved)[..., 20, 20], base[..., 20, 20], atol=1e-6)) == seen
    both = SiameseNet(channels=16, layers=3, inputs="grey+census", census_window=5)
    assert both.radius == 5 and both.tower[0].in_channels == 25
    with torch.no_grad():  # the grey channel is the standardised grey level of the same pixels
        assert torch.equal(both._first_input(torch.arange(81.0).view(1, 1, 9, 9))[:, 0], torch.arange(81.0).view(9, 9)[2:7, 2:7][None])
        assert not torch.allclose(both(bent), both(left), atol=1e-3)
    with pytest.raises(StereoInputError, match="inputs"):
        SiameseNet(inputs="rgb")
    with pytest.raises(StereoInputError, match="census_window"):
        SiameseNet(inputs="census", census_window=4)


def test_siamese_loss_prefers_true_disparity(textured_pair):
    left, right, d = textured_pair
    torch.manual_seed(0)
    net = SiameseNet(channels=8, layers=2)
    disp = torch.full((1, 1, *left.shape[-2:]), float(d))
    valid = torch.ones_like(disp, dtype=torch.bool)
    good = siamese_pair_loss(net, left, right, disp, valid, 256, generator=torch.Generator().manual_seed(0))
    bad = siamese_pair_loss(net, left, right, disp + 4, valid, 256, generator=torch.Generator().manual_seed(0))
    assert good < bad
    assert siamese_pair_loss(net, left, right, disp, torch.zeros_like(valid), 16) == 0
    with pytest.raises(ValueError, match="loss"):
        matching_loss(torch.zeros(3), torch.zeros(3), loss="nope")
    assert matching_loss(torch.ones(3), torch.zeros(3), margin=0.2) == 0


def test_siamese_distillation_term(textured_pair):
    """The distillation term is zero against an identical teacher, positive against another one, and its
    gradient pulls the student's similarities towards the teacher's (different widths)."""
    left, right, d = textured_pair
    torch.manual_seed(0)
    net = SiameseNet(channels=8, layers=2)
    disp = torch.full((1, 1, *left.shape[-2:]), float(d))
    valid = torch.ones_like(disp, dtype=torch.bool)

    def loss(teacher, distill=1.0):
        return siamese_pair_loss(net, left, right, disp, valid, 128, generator=torch.Generator().manual_seed(0),
                                 teacher=teacher, distill=distill)

    plain = loss(None)
    twin = SiameseNet(channels=8, layers=2)
    twin.load_state_dict(net.state_dict())
    assert torch.allclose(loss(twin), plain)
    other = SiameseNet(channels=16, layers=2).requires_grad_(False)
    assert loss(other, 0.0) == plain
    def term():  # the distillation term alone
        return loss(other, 1.0) - loss(None)

    first = term().item()
    assert first > 0
    opt = torch.optim.Adam(net.parameters(), lr=1e-2)
    for _ in range(30):
        opt.zero_grad()
        term().backward()
        opt.step()
    assert term().item() < 0.5 * first, first
    assert all(p.grad is None for p in other.parameters())


def test_census_siamese_module_writes_a_file_that_loads_the_same_tower(tmp_path, textured_pair):
    """SiameseModule(inputs="census") puts the input kind in the file's config (grey files keep the older
    config), the loaded tower gives the same features, and init_weights of another kind is refused naming both."""
    from stereonet.training.module import SiameseModule

    left = textured_pair[0]
    module = SiameseModule(channels=8, layers=2, inputs="census", census_window=3)
    assert module.model_config() == {"channels": 8, "layers": 2, "inputs": "census", "census_window": 3}
    assert SiameseModule(channels=8, layers=2).model_config() == {"channels": 8, "layers": 2}
    path = tmp_path / "siamese.pt"
    save_weights(path, "siamese", module.model_config(), module.model)
    net, _ = load_weights(path, expected="siamese")
    assert net.inputs == "census" and net.census_window == 3
    with torch.no_grad():
        assert torch.equal(net(left), module.model(left))
    with pytest.raises(ValueError, match="holds a tower of 8 channels x 2 layers on census 3x3, expected 8 channels x 2 layers$"):
        SiameseModule(channels=8, layers=2, init_weights=str(path))


def test_weights_roundtrip_and_errors(tmp_path, small_dispnet):
    path = tmp_path / "dispnet.pt"
    save_weights(path, "dispnet", {"max_disp": 16, "channels": 8}, small_dispnet)
    net, info = load_weights(path, expected="dispnet")
    assert info["model"] == "dispnet"
    for a, b in zip(net.state_dict().values(), small_dispnet.state_dict().values()):
        assert torch.equal(a, b)
    with pytest.raises(StereoInputError, match="expected a 'smd' model, got a 'dispnet'"):
        load_weights(path, expected="smd")
    with pytest.raises(FileNotFoundError, match="not found"):
        load_weights(tmp_path / "missing.pt", expected="dispnet")
    wrong = tmp_path / "wrong.pt"
    save_weights(wrong, "dispnet", {"max_disp": 16, "channels": 16}, small_dispnet)  # config says 16 channels
    with pytest.raises(StereoInputError, match="does not fit"):
        load_weights(wrong)
    junk = tmp_path / "junk.pt"
    torch.save({"a": torch.zeros(1)}, junk)
    with pytest.raises(StereoInputError, match="not a stereonet"):
        load_weights(junk)
    (tmp_path / "garbage.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(StereoInputError, match="not a readable"):
        load_weights(tmp_path / "garbage.pt")


def test_smd_detach_anchor_same_values_no_gradient_into_the_backbone_disparity():
    torch.manual_seed(0)
    net = SMDNet(max_disp=16, channels=8).eval()
    left, right = torch.rand(1, 3, 32, 32), torch.rand(1, 3, 32, 32)
    backbone = net.backbone(left, right)
    grid = query_grid(1, 32, 32)
    for detach in (False, True):
        mix = net.query(backbone, grid, detach_anchor=detach)
        (g,) = torch.autograd.grad(mix.mu1.sum() + mix.mu2.sum(), backbone.disparity, allow_unused=True)
        # the modes are offsets from the anchor: d(mu1 + mu2)/d(anchor) is 2 per query point (bilinear weights)
        assert (g is None or float(g.abs().sum()) == 0.0) == detach
        if not detach:
            plain = mix
    detached = net.query(backbone, grid, detach_anchor=True)
    for name in ("mu1", "mu2", "b1", "b2", "pi"):
        assert torch.equal(getattr(plain, name), getattr(detached, name))
    out = net(left, right, detach_anchor=True)
    assert torch.equal(out.disparity, net(left, right).disparity)


@pytest.mark.parametrize("dilation", [1, 2, 3])
def test_plane_conv3d_is_conv3d(dilation):
    """PlaneConv3d (three 2-D convolutions over depth planes) computes F.conv3d's 3x3x3 "same" convolution and its
    gradients, with nn.Conv3d's parameters (a state dict of either loads into the other); with a spatial dilation
    (taps ``dilation`` px apart in y and x, depth planes one apart) on a volume narrower than the dilated kernel."""
    from stereonet.models.layers import PlaneConv3d

    g = torch.Generator().manual_seed(4)
    conv = PlaneConv3d(3, 5, dilation)
    x = torch.randn(2, 3, 7, 6, 9, generator=g, requires_grad=True)
    out = conv(x)
    ref = torch.nn.functional.conv3d(x, conv.weight, conv.bias, padding=(1, dilation, dilation),
                                     dilation=(1, dilation, dilation))
    torch.testing.assert_close(out, ref, rtol=1e-5, atol=1e-5)
    upstream = torch.randn(out.shape, generator=g)
    for a, b in zip(torch.autograd.grad(out, (x, conv.weight, conv.bias), upstream),
                    torch.autograd.grad(ref, (x, conv.weight, conv.bias), upstream)):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-4)
    plain = torch.nn.Conv3d(3, 5, 3, padding=(1, dilation, dilation), dilation=(1, dilation, dilation))
    plain.load_state_dict(conv.state_dict())
    torch.testing.assert_close(plain(x), out, rtol=1e-5, atol=1e-5)
    with pytest.raises(StereoInputError, match="dilation"):
        PlaneConv3d(3, 5, 0)


def test_edge_samples_sit_near_depth_edges_with_the_other_side_as_negative():
    """A 40-px-wide front plane (disparity 12) on a back plane (disparity 3): with edge_share 0.5 half of the samples
    lie within the radius of the plane's outline (both pixels of a jump are marked) and take the other plane's match as their negative; with
    edge_share 0 the draw is the same as before the option existed."""
    from stereonet.models.siamese import edge_maps, sample_training_pixels

    disp = torch.full((2, 1, 30, 80), 3.0)
    disp[..., 30:70] = 12.0
    valid = torch.ones_like(disp, dtype=torch.bool)
    near, other = edge_maps(disp, valid, 4)
    assert near[0, 0, 5].nonzero().flatten().tolist() == list(range(25, 35)) + list(range(65, 75))
    assert other[0, 0, 5, 27] == 12.0 and other[0, 0, 5, 31] == 3.0 and other[0, 0, 5, 10] == 3.0

    def draw(**kw):
        return sample_training_pixels(disp, valid, 200, 1.5, 8.0, torch.Generator().manual_seed(3), **kw)

    plain = draw()
    off = draw(edge_share=0.0)
    assert all(torch.equal(a, b) for a, b in zip(plain, off))
    keep, xs, ys, x_pos, x_neg = draw(edge_share=0.5)
    d = disp[0, 0, 0, xs[0].long()]
    edge = ((xs[0] >= 25) & (xs[0] <= 34)) | ((xs[0] >= 65) & (xs[0] <= 74))
    assert bool(edge[:100].all()) and float(edge[100:].float().mean()) < 0.5
    side = other[0, 0, 0, xs[0, :100].long()]  # the window's farthest disparity: the other plane where it reaches
    usable = ((side - d[:100]).abs() >= 1.5) & (xs[0, :100] - side >= 0)
    assert float(usable.float().mean()) > 0.6 and set(side[usable].tolist()) == {3.0, 12.0}
    assert torch.equal(x_neg[0, :100][usable], (xs[0, :100] - side)[usable])
    assert bool(((x_neg[0, :100] - x_pos[0, :100]).abs()[~usable] >= 1.5).all())  # the random negatives elsewhere
    assert torch.equal(x_pos[0], xs[0] - d)
    only = draw(edge_share=1.0)[1]  # every sample near an edge
    assert bool((((only >= 25) & (only <= 34)) | ((only >= 65) & (only <= 74))).all())


def test_error_probability_is_the_mixture_tail_around_the_answer():
    """error_probability: exp(-tau / b) for one Laplace mode centred on the answer, the Monte Carlo frequency of
    |X - d| > tau for any mixture, and higher when the other mode is heavy and far, whatever its width."""
    from stereonet.models.smd import MixtureParams, error_probability

    one = lambda v: torch.full((1, 1, 1, 1), float(v), dtype=torch.float64)  # noqa: E731
    single = MixtureParams(one(5), one(40), one(0.5), one(3), one(1.0))
    assert torch.allclose(error_probability(single, one(5), 2.0), torch.exp(torch.tensor(-4.0, dtype=torch.float64)))
    g = torch.Generator().manual_seed(0)
    n = 400_000
    for mu1, mu2, b1, b2, pi, d in [(5, 9, 0.7, 2.0, 0.6, 5.5), (3, 3.5, 1.5, 0.3, 0.2, 4.8), (10, 2, 0.4, 4, 0.9, 0)]:
        mix = MixtureParams(one(mu1), one(mu2), one(b1), one(b2), one(pi))
        first = torch.rand(n, generator=g, dtype=torch.float64) < pi
        u = torch.rand(n, generator=g, dtype=torch.float64) - 0.5  # Laplace by inversion
        lap = -torch.sign(u) * torch.log1p(-2 * u.abs())
        x = torch.where(first, mu1 + b1 * lap, mu2 + b2 * lap)
        freq = float(((x - d).abs() > 2.0).double().mean())
        assert abs(float(error_probability(mix, one(d), 2.0)) - freq) < 4e-3, (mu1, mu2, b1, b2, pi, d)
    narrow_alone = MixtureParams(one(5), one(5), one(0.3), one(0.3), one(0.7))
    narrow_beside_far = MixtureParams(one(5), one(30), one(0.3), one(0.3), one(0.7))
    assert float(error_probability(narrow_beside_far, one(5))) > 0.29 > float(error_probability(narrow_alone, one(5)))


def test_pooled_group_correlation_equals_pooling_the_full_resolution_volume():
    """Level k of the pooled volume is, per group, the maximum over the disparities 4k-2 .. 4k+1 (within range) of
    the full-resolution group correlation averaged over each 4x4 cell: the same as pooling
    ``group_correlation_1d``'s whole volume (which it never builds), on a shape whose range ends mid-level and
    where the left-border cells have no match for the largest disparities."""
    import torch.nn.functional as F

    from stereonet.models.dispnet import pooled_group_correlation

    torch.manual_seed(0)
    fl, fr = torch.randn(2, 8, 12, 20), torch.randn(2, 8, 12, 20)
    max_disp, groups = 13, 2
    got = pooled_group_correlation(fl, fr, max_disp, groups, 4)
    full = F.avg_pool3d(group_correlation_1d(fl, fr, max_disp, groups), (1, 4, 4))  # BxGx(D+1)xH/4xW/4
    assert got.shape == (2, groups, max_disp // 4 + 1, 3, 5)
    for k in range(max_disp // 4 + 1):
        ds = [d for d in range(4 * k - 2, 4 * k + 2) if 0 <= d <= max_disp]
        torch.testing.assert_close(got[:, :, k], full[:, :, ds].amax(dim=2), rtol=1e-5, atol=1e-6)
    with pytest.raises(StereoInputError, match="feat_left: expected C divisible by groups=3"):
        pooled_group_correlation(fl, fr, max_disp, 3, 4)


@pytest.mark.parametrize("volume", ["pooled", "both"])
def test_dispnet_full_resolution_volume_trains_and_keeps_its_config(volume):
    """``volume="pooled"`` / ``"both"``: the network runs on any padded size, its loss reaches the 3-D aggregation
    (gradients on its first layer, whose input width doubles for "both"), and the weights config carries the option
    (a network built without it cannot take the tensors of "both", and computes other values for "pooled")."""
    from stereonet.models.weights import build_model
    from stereonet.training.module import DispNetModule

    torch.manual_seed(0)
    module = DispNetModule(max_disp=16, channels=4, matching="census", aggregation="3d", volume=volume)
    left, right = torch.rand(1, 3, 32, 48), torch.rand(1, 3, 32, 48)
    out = module.model(left, right)
    assert out.disparity.shape == (1, 1, 32, 48) and torch.isfinite(out.disparity).all()
    out.matched.mean().backward()
    first = module.model.corr_agg[0][0].weight
    assert first.shape[1] == (8 if volume == "both" else 4) and first.grad.abs().sum() > 0
    config = module.model_config()
    assert config["volume"] == volume
    assert "volume" not in DispNetModule(max_disp=16, channels=4, matching="census", aggregation="3d").model_config()
    net = build_model("dispnet", config).eval()
    net.load_state_dict(module.model.state_dict())
    coarse = build_model("dispnet", {k: v for k, v in config.items() if k != "volume"}).eval()
    module.eval()
    with torch.no_grad():
        assert torch.equal(net(left, right).disparity, module.model(left, right).disparity)
        if volume == "both":
            with pytest.raises(RuntimeError):
                coarse.load_state_dict(module.model.state_dict())
        else:
            coarse.load_state_dict(module.model.state_dict())
            assert not torch.allclose(coarse(left, right).disparity, net(left, right).disparity)
