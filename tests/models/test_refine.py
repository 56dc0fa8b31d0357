"""RefineNet (the network of sgm-refine) and the sgm-refine matcher."""

from __future__ import annotations

import pytest
import torch

from stereonet.checks import StereoInputError
from stereonet.models.refine import INPUT_CHANNELS, RefineNet, candidate_offsets, census_distance, shift
from stereonet.models.weights import load_weights, save_weights


def _pair(h=24, w=40, d=3):
    g = torch.Generator().manual_seed(0)
    right = torch.rand(1, 3, h, w + d, generator=g)
    left = right[..., :w].clone()
    right = right[..., d:d + w].clone()  # x_right = x_left - d
    return left, right


def test_untrained_refinement_returns_the_map_and_is_stateless():
    torch.manual_seed(0)
    net = RefineNet(channels=4, dilations=(1, 2))
    left, right = _pair()
    disp = torch.rand(1, 1, *left.shape[-2:]) * 8
    valid = disp > 2
    conf = torch.rand_like(disp)
    out = net(left, right, disp, valid, conf, 16)
    assert torch.equal(out, disp)  # zero-initialised head: starts at the classical map
    assert net.inputs(left, right, disp, valid, conf, 16).shape[1] == INPUT_CHANNELS
    assert torch.equal(net(left, right, disp, valid, conf, torch.tensor([16.0])), out)
    net.eval()
    assert torch.equal(net(left, right, disp, valid, conf, 16), out)


def test_refinement_learns_a_correction_on_one_pair():
    """Fitting one pair whose map is off by 2 px inside a square (the photometric residual shows where): the
    training loss falls well below its start."""
    torch.manual_seed(0)
    net = RefineNet(channels=8, dilations=(1, 2))
    left, right = _pair()
    gt = torch.full((1, 1, *left.shape[-2:]), 3.0)
    disp = gt.clone()
    disp[..., 6:14, 10:22] += 2.0
    valid = torch.ones_like(gt, dtype=torch.bool)
    conf = torch.ones_like(gt)
    opt = torch.optim.Adam(net.parameters(), lr=3e-3)
    losses = []
    for _ in range(150):
        loss = torch.nn.functional.smooth_l1_loss(net(left, right, disp, valid, conf, 16), gt)  # as RefineModule
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert losses[-1] < 0.3 * losses[0], (losses[0], losses[-1])


def test_refine_net_rejects_bad_config():
    with pytest.raises(StereoInputError, match="channels"):
        RefineNet(channels=0)
    with pytest.raises(StereoInputError, match="dilations"):
        RefineNet(dilations=())
    with pytest.raises(StereoInputError, match="mode"):
        RefineNet(mode="blend")
    with pytest.raises(StereoInputError, match="radii"):
        RefineNet(mode="select", radii=[0])
    with pytest.raises(StereoInputError, match="radii"):
        RefineNet(mode="select", radii=[])  # one map and no neighbours: nothing to choose from
    with pytest.raises(StereoInputError, match="select"):
        RefineNet().scores(*_pair(), torch.ones(1, 1, 24, 40), torch.ones(1, 1, 24, 40, dtype=torch.bool),
                           torch.ones(1, 1, 24, 40), 16)


@pytest.mark.parametrize("dy,dx", [(0, 3), (0, -3), (2, 0), (-2, 0), (5, -7), (-30, 50)])
def test_shift_reads_the_neighbour_and_replicates_the_border(dy, dx):
    x = torch.arange(6 * 9, dtype=torch.float32).view(1, 1, 6, 9)
    out = shift(x, dy, dx)
    for y in range(6):
        for c in range(9):
            assert out[0, 0, y, c] == x[0, 0, min(max(y + dy, 0), 5), min(max(c + dx, 0), 8)]
    assert shift(x > 20, dy, dx).dtype == torch.bool


def test_untrained_selection_keeps_the_map_and_offers_the_neighbours():
    torch.manual_seed(0)
    net = RefineNet(channels=4, dilations=(1, 2), mode="select", radii=(1, 4))
    left, right = _pair()
    disp = torch.rand(1, 1, *left.shape[-2:]) * 8
    valid, conf = disp > 2, torch.rand_like(disp)
    scores, cands = net.scores(left, right, disp, valid, conf, 16)
    offsets = candidate_offsets((1, 4))
    assert scores.shape[1] == cands.shape[1] == len(offsets) == 17
    assert torch.equal(cands[:, :1], disp)
    k = offsets.index((0, 4))
    assert torch.equal(cands[0, k, :, :-4], disp[0, 0, :, 4:])
    assert torch.equal(net(left, right, disp, valid, conf, 16), disp)  # all scores tie: candidate 0 wins


def test_selection_learns_to_replace_a_wrong_patch_by_its_neighbours():
    """A 2-px-wide stripe of the map is off by 5 px and flagged invalid (as sgm flags what it fills); the true
    value is one pixel away on either side. Trained with RefineModule's loss, the hard choice repairs the stripe
    and keeps the rest."""
    torch.manual_seed(0)
    net = RefineNet(channels=8, dilations=(1, 2), mode="select", radii=(1, 3))
    left, right = _pair()
    gt = torch.full((1, 1, *left.shape[-2:]), 3.0)
    disp = gt.clone()
    disp[..., 10:12] += 5.0
    valid = torch.ones_like(gt, dtype=torch.bool)
    valid[..., 10:12] = False
    conf = valid.float()
    opt = torch.optim.Adam(net.parameters(), lr=1e-2)
    for _ in range(80):
        scores, cands = net.scores(left, right, disp, valid, conf, 16)
        right_ones = (cands - gt).abs() <= 1.0
        loss = -(torch.logsumexp(scores.masked_fill(~right_ones, -1e4), 1) - torch.logsumexp(scores, 1)).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    with torch.no_grad():
        out = net(left, right, disp, valid, conf, 16)
    assert ((out - gt).abs() > 2).sum() < 0.2 * ((disp - gt).abs() > 2).sum()


def test_sgm_refine_matcher_runs_from_a_weights_file(tmp_path):
    from stereonet.matchers import match
    from stereonet.matchers.learned import sgm_base

    net = RefineNet(channels=4, dilations=(1, 2))
    path = tmp_path / "refine.pt"
    save_weights(path, "refine", {"channels": 4, "dilations": [1, 2]}, net)
    loaded, info = load_weights(path, expected="refine")
    assert info["model"] == "refine" and isinstance(loaded, RefineNet)
    left, right = _pair(32, 64, 4)
    out = match("sgm-refine", left, right, 16, checkpoint=str(path), wmf_radius=0)
    base, valid, _ = sgm_base(left, right, 16)
    assert bool(out.valid.all())
    assert torch.equal(out.disparity, base)  # untrained: sgm's filled map, every pixel
    assert out.confidence is not None and out.confidence.shape == out.disparity.shape
    with pytest.raises(StereoInputError, match="backend"):
        match("sgm-refine", left, right, 16, checkpoint=str(path), backend="onnx")
    with pytest.raises(StereoInputError, match="'refine'"):
        load_weights(path, expected="siamese")  # a refine file where another network is expected: named


def test_sgm_refine_matcher_runs_a_selection_file(tmp_path):
    from stereonet.matchers import match
    from stereonet.matchers.learned import sgm_base

    net = RefineNet(channels=4, dilations=(1, 2), mode="select", radii=[1, 3])
    path = tmp_path / "refine.pt"
    save_weights(path, "refine", {"channels": 4, "dilations": [1, 2], "mode": "select", "radii": [1, 3]}, net)
    left, right = _pair(32, 64, 4)
    out = match("sgm-refine", left, right, 16, checkpoint=str(path), wmf_radius=0)
    base, _, _ = sgm_base(left, right, 16)
    assert torch.equal(out.disparity, base) and bool(out.valid.all())
    torch.nn.init.normal_(net.score_out.weight)  # any scores: the output is one of the candidates at each pixel
    save_weights(path, "refine", {"channels": 4, "dilations": [1, 2], "mode": "select", "radii": [1, 3]}, net)
    out = match("sgm-refine", left, right, 16, checkpoint=str(path), wmf_radius=0)
    cands = torch.cat([shift(base, dy, dx) for dy, dx in candidate_offsets((1, 3))], 1)
    assert bool(((cands - out.disparity).abs() < 1e-6).any(1).all())


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64], ids=["float32", "float64"])
def test_sgm_refine_follows_the_input_dtype(tmp_path, dtype):
    """What tests/test_dtype_device.py checks for shipped weights, here with a weights file of each mode."""
    from stereonet.matchers import match

    left, right = (t.to(dtype) for t in _pair(32, 64, 4))
    for config in ({"channels": 4, "dilations": [1]}, {"channels": 4, "dilations": [1], "mode": "select", "radii": [2]}):
        path = tmp_path / "refine.pt"
        save_weights(path, "refine", config, RefineNet(**config))
        out = match("sgm-refine", left, right, 16, checkpoint=str(path), wmf_radius=0)
        assert out.disparity.dtype == out.confidence.dtype == dtype and out.valid.dtype == torch.bool


def test_two_map_selection_starts_at_the_first_map_and_offers_both():
    """bases of two matchers: the untrained choice is the first map; the candidates are each map's own value and
    its neighbours, in that order; each map adds its own input planes."""
    torch.manual_seed(0)
    net = RefineNet(channels=4, dilations=(1, 2), mode="select", radii=(1, 4), bases=("siamese-census-sgm", "sgm"))
    left, right = _pair()
    disp = torch.rand(1, 2, *left.shape[-2:]) * 8
    valid, conf = disp > 2, torch.rand_like(disp)
    assert net.inputs(left, right, disp, valid, conf, 16).shape[1] == INPUT_CHANNELS + 4
    scores, cands = net.scores(left, right, disp, valid, conf, 16)
    k = len(candidate_offsets((1, 4)))
    assert scores.shape[1] == cands.shape[1] == 2 * k
    assert torch.equal(cands[:, :1], disp[:, :1]) and torch.equal(cands[:, k:k + 1], disp[:, 1:])
    assert torch.equal(net(left, right, disp, valid, conf, 16), disp[:, :1])
    torch.nn.init.normal_(net.score_out.weight)  # a trained head may take the second map's value
    torch.nn.init.normal_(net.score_out.bias)
    out = net(left, right, disp, valid, conf, 16)
    assert bool(((cands - out).abs() < 1e-6).any(1).all())
    with pytest.raises(StereoInputError, match=r"disparity: expected \(B, 2, H, W\)"):
        net(left, right, disp[:, :1], valid, conf, 16)


def test_refine_net_rejects_bad_bases():
    with pytest.raises(StereoInputError, match="bases"):
        RefineNet(mode="select", bases=("sgm", "opencv-sgbm"))
    with pytest.raises(StereoInputError, match="bases"):
        RefineNet(mode="select", bases=("sgm", "sgm"))
    with pytest.raises(StereoInputError, match="bases: more than one map needs mode 'select'"):
        RefineNet(bases=("siamese-census-sgm", "sgm"))


def test_sgm_refine_matcher_runs_a_two_map_selection_file(tmp_path):
    """A file whose network reads siamese-census-sgm and sgm: the matcher runs both (the shipped Siamese weights),
    an untrained file returns the first map filled, and any scores pick one candidate of either map."""
    from stereonet.matchers import match
    from stereonet.matchers.learned import refine_bases

    config = {"channels": 4, "dilations": [1], "mode": "select", "radii": [2], "bases": ["siamese-census-sgm", "sgm"]}
    net = RefineNet(**config)
    path = tmp_path / "refine.pt"
    save_weights(path, "refine", config, net)
    left, right = _pair(32, 64, 4)
    out = match("sgm-refine", left, right, 16, checkpoint=str(path), wmf_radius=0)
    maps, valid, conf = refine_bases(("siamese-census-sgm", "sgm"), left, right, 16)
    assert maps.shape[1] == valid.shape[1] == conf.shape[1] == 2
    assert torch.equal(out.disparity, maps[:, :1]) and bool(out.valid.all())
    assert torch.equal(maps[:, 1:], refine_bases(("sgm",), left, right, 16)[0])
    torch.nn.init.normal_(net.score_out.weight)
    torch.nn.init.normal_(net.score_out.bias)
    save_weights(path, "refine", config, net)
    out = match("sgm-refine", left, right, 16, checkpoint=str(path), wmf_radius=0)
    cands = torch.cat([shift(maps[:, m:m + 1], dy, dx) for m in range(2) for dy, dx in candidate_offsets((2,))], 1)
    assert bool(((cands - out.disparity).abs() < 1e-6).any(1).all())


def test_choice_between_two_maps_without_neighbours():
    """radii=() with two bases: the candidates are the two maps' own values; untrained, the first wins; a trained
    head picks one of the two at every pixel."""
    torch.manual_seed(0)
    net = RefineNet(channels=4, dilations=(1,), mode="select", radii=(), bases=("siamese-census-sgm", "sgm"))
    left, right = _pair()
    disp = torch.rand(1, 2, *left.shape[-2:]) * 8
    valid, conf = disp > 2, torch.rand_like(disp)
    scores, cands = net.scores(left, right, disp, valid, conf, 16)
    assert scores.shape[1] == 2 and torch.equal(cands, disp)
    assert torch.equal(net(left, right, disp, valid, conf, 16), disp[:, :1])
    torch.nn.init.normal_(net.score_out.weight)
    out = net(left, right, disp, valid, conf, 16)
    assert bool(((out == disp[:, :1]) | (out == disp[:, 1:])).all())


def test_refine_bases_stacks_each_named_matcher_filled():
    """refine_bases: one channel per named matcher, in order, each that matcher's map with the shared fill."""
    from stereonet.matchers import match
    from stereonet.matchers.learned import refine_bases
    from stereonet.select.fill import fill_occlusions

    left, right = _pair(32, 64, 4)
    names = ("siamese-census-sgm", "sgm", "siamese-sgm")
    maps, valid, conf = refine_bases(names, left, right, 16)
    assert maps.shape[1] == valid.shape[1] == conf.shape[1] == 3
    for i, name in enumerate(names):
        out = match(name, left, right, 16)
        assert torch.equal(maps[:, i:i + 1], fill_occlusions(out.disparity, out.valid))
        assert torch.equal(valid[:, i:i + 1], out.valid)
    with pytest.raises(StereoInputError, match="bases"):
        refine_bases(("dispnet",), left, right, 16)


def test_census_distance_ignores_brightness_and_sees_a_wrong_disparity():
    """0 for the same image and for a monotonic brightness change (gain, offset, gamma), in [0, 1], and larger
    for the right image warped by a wrong disparity than by the true one."""
    from stereonet.models.layers import standardize_image, warp_right

    left, right = _pair(32, 48, 3)
    grey_l, grey_r = standardize_image(left, grey=True), standardize_image(right, grey=True)
    assert float(census_distance(grey_l, grey_l).abs().max()) == 0.0
    assert float(census_distance(grey_l, (0.5 * grey_l + 3.0) ** 3).abs().max()) == 0.0
    true = warp_right(grey_r, torch.full_like(grey_l, 3.0))
    wrong = warp_right(grey_r, torch.full_like(grey_l, 7.0))
    inner = (slice(None), slice(None), slice(4, -4), slice(12, -4))  # away from the borders the warp replicates
    d_true, d_wrong = census_distance(grey_l, true)[inner], census_distance(grey_l, wrong)[inner]
    assert float(d_true.max()) == 0.0 and float(d_wrong.mean()) > 0.2
    noise = census_distance(grey_l, torch.rand_like(grey_l))
    assert 0.0 <= float(noise.min()) and float(noise.max()) <= 1.0


def test_census_evidence_adds_one_candidate_plane_and_keeps_the_untrained_choice(tmp_path):
    """evidence="census": one more input to the candidate scorer, the untrained network still returns the first
    map, a trained head reads the plane (changing it changes the scores), and a weights file keeps the option."""
    from stereonet.matchers.learned import load_network

    torch.manual_seed(0)
    kw = dict(channels=4, dilations=(1,), mode="select", radii=(), bases=("siamese-census-sgm", "sgm"))
    plain, census = RefineNet(**kw), RefineNet(**kw, evidence="census")
    assert census.score_candidate.in_channels == plain.score_candidate.in_channels + 1
    left, right = _pair()
    disp = torch.rand(1, 2, *left.shape[-2:]) * 8
    valid, conf = disp > 2, torch.rand_like(disp)
    assert torch.equal(census(left, right, disp, valid, conf, 16), disp[:, :1])
    torch.nn.init.normal_(census.score_out.weight)
    with torch.no_grad():
        census.score_candidate.weight[:, -1] = 0.0
        before, _ = census.scores(left, right, disp, valid, conf, 16)
        census.score_candidate.weight[:, -1] = 5.0
        after, _ = census.scores(left, right, disp, valid, conf, 16)
    assert not torch.allclose(before, after)
    config = {"channels": 4, "dilations": [1], "mode": "select", "radii": [], "bases": ["siamese-census-sgm", "sgm"],
              "evidence": "census"}
    save_weights(tmp_path / "refine.pt", "refine", config, census)
    loaded = load_network("refine", str(tmp_path / "refine.pt"))
    assert loaded.evidence == "census"
    with pytest.raises(StereoInputError, match="evidence"):
        RefineNet(channels=4, dilations=(1,), evidence="census")  # residual mode has no candidates
    with pytest.raises(StereoInputError, match="evidence"):
        RefineNet(**kw, evidence="ncc")


@pytest.mark.parametrize("k", [1, 2, 5])
def test_first_argmax_equals_torch_argmax_with_ties_and_nan(k):
    """The selection's argmax over candidates (computed along a contiguous axis) gives torch's indices: the
    first of tied maxima, a NaN as the maximum (the first NaN), for any number of candidates."""
    from stereonet.models.refine import first_argmax

    g = torch.Generator().manual_seed(k)
    scores = torch.randint(0, 3, (2, k, 7, 9), generator=g).float()  # many ties
    scores[0, :, 0, 0] = float("nan")
    scores[1, k - 1, 1, 1] = float("nan")
    scores[1, :, 2, 2] = -float("inf")
    got = first_argmax(scores)
    assert got.shape == (2, 1, 7, 9) and torch.equal(got, scores.argmax(dim=1, keepdim=True))


def test_cross_costs_rate_each_answer_by_each_aggregate():
    """cross_costs: plane e * M + k is base e's aggregated cost at base k's disparity above e's best, in units of
    scale * CROSS_NORM, mapped by t / (1 + t); a sub-pixel value takes the better of its two integer neighbours;
    the volume's dtype and strides (an int16 permuted view, as sgm's aggregate_fixed) do not matter."""
    from stereonet.models.refine import CROSS_NORM, cross_costs

    g = torch.Generator().manual_seed(3)
    b, d, h, w = 2, 9, 5, 7
    hwd = [torch.randint(0, 3000, (b, h, w, d), generator=g, dtype=torch.int16) for _ in range(2)]
    vols = [v.permute(0, 3, 1, 2) for v in hwd]  # (B, D, H, W) views of (B, H, W, D) memory
    scales = [4.0, 16.0]
    disp = torch.rand(b, 2, h, w, generator=g) * (d - 1)
    disp[0, 0, 0, 0] = 0.0
    disp[0, 1, 0, 0] = float(d - 1)  # both ends of the range
    out = cross_costs(list(zip(vols, scales)), disp)
    assert out.shape == (b, 4, h, w) and out.dtype == disp.dtype
    for e in range(2):
        v = vols[e].float()
        best = v.min(1).values
        for k in range(2):
            low = disp[:, k].floor().long().clamp(0, d - 1)
            high = (low + 1).clamp(max=d - 1)
            at = torch.minimum(v.gather(1, low[:, None])[:, 0], v.gather(1, high[:, None])[:, 0])
            t = (at - best) / (scales[e] * CROSS_NORM)
            assert torch.allclose(out[:, e * 2 + k], t / (1 + t))
    assert float(out.min()) >= 0.0 and float(out.max()) < 1.0
    own = vols[0].float().argmin(1, keepdim=True).float()  # a base's own best disparity rates 0 under its own cost
    assert float(cross_costs([(vols[0], 1.0), (vols[1], 1.0)], torch.cat([own, own], 1))[:, 0].abs().max()) == 0.0
    with pytest.raises(StereoInputError, match="aggregates"):
        cross_costs([(vols[0], 1.0)], disp)


def test_cross_evidence_reads_every_base_and_keeps_the_untrained_choice(tmp_path):
    """evidence="cross": one candidate plane per base, the untrained network returns the first map, the scores
    depend on the cross costs, the matcher computes them from the bases' own aggregates (the maps unchanged), and
    networks that cannot have them are refused with one line."""
    from stereonet.matchers import match
    from stereonet.matchers.learned import load_network, refine_bases

    torch.manual_seed(0)
    kw = dict(channels=4, dilations=(1,), mode="select", radii=(), bases=("siamese-census-sgm", "sgm"))
    plain, cross = RefineNet(**kw), RefineNet(**kw, evidence="cross")
    assert cross.score_candidate.in_channels == plain.score_candidate.in_channels + 2
    left, right = _pair(32, 64, 4)
    maps, valid, conf = refine_bases(kw["bases"], left, right, 16)
    maps2, valid2, conf2, costs = refine_bases(kw["bases"], left, right, 16, cross=True)
    assert torch.equal(maps, maps2) and torch.equal(valid, valid2) and torch.equal(conf, conf2)
    assert costs.shape == (1, 4, 32, 64) and float(costs.max()) > 0.0
    assert torch.equal(cross(left, right, maps, valid, conf, 16, costs), maps[:, :1])
    with pytest.raises(StereoInputError, match="cross"):
        cross(left, right, maps, valid, conf, 16)
    torch.nn.init.normal_(cross.score_out.weight)
    before, _ = cross.scores(left, right, maps, valid, conf, 16, costs)
    after, _ = cross.scores(left, right, maps, valid, conf, 16, costs.flip(1))
    assert not torch.allclose(before, after)
    config = {**{k: list(v) if isinstance(v, tuple) else v for k, v in kw.items()}, "evidence": "cross"}
    path = tmp_path / "refine.pt"
    save_weights(path, "refine", config, cross)
    assert load_network("refine", str(path)).evidence == "cross"
    out = match("sgm-refine", left, right, 16, checkpoint=str(path), wmf_radius=0)
    expected = cross(left, right, maps, valid, conf, 16, costs)
    assert torch.equal(out.disparity, expected)
    with pytest.raises(StereoInputError, match="evidence"):
        RefineNet(**{**kw, "radii": (1,)}, evidence="cross")  # neighbours' values have no cross costs
    with pytest.raises(StereoInputError, match="evidence"):
        RefineNet(**{**kw, "bases": ("siamese-sgm", "sgm")}, evidence="cross")
    with pytest.raises(StereoInputError, match="bases"):
        refine_bases(("siamese-sgm", "sgm"), left, right, 16, cross=True)


def test_siamese_census_sgm_keeps_its_fixed_aggregate():
    """keep_volume="fixed" on the mixed 16-bit path (siamese-census-sgm): the int16 aggregate over its scale equals
    the float32 aggregate that keep_volume=True returns, and the map is the same as without the option."""
    from stereonet.matchers import match

    left, right = _pair(32, 64, 4)
    out = match("siamese-census-sgm", left, right, 16)
    fixed = match("siamese-census-sgm", left, right, 16, keep_volume="fixed")
    kept = match("siamese-census-sgm", left, right, 16, keep_volume=True)
    acc, scale = fixed.extras["aggregate_fixed"], fixed.extras["aggregate_scale"]
    assert acc.dtype == torch.int16 and fixed.cost_volume is None
    assert torch.equal(acc.float() / scale.float(), kept.cost_volume)
    assert torch.equal(fixed.disparity, out.disparity) and torch.equal(fixed.valid, out.valid)


def test_sgm_refine_ends_with_the_weighted_median_of_its_choice(tmp_path):
    """By default the matcher's map is the image-guided weighted median (WMF_RADIUS, WMF_SIGMA_COLOR, WMF_STRIDE)
    of the choice, which extras["unfiltered"] keeps and wmf_radius=0 returns; other settings reach the filter (the
    stride capped at the radius); bad settings are one-line errors naming the option."""
    from stereonet.matchers import match
    from stereonet.matchers.learned import WMF_RADIUS, WMF_SIGMA_COLOR, WMF_STRIDE
    from stereonet.select.filters import weighted_median_filter

    config = {"channels": 4, "dilations": [1], "mode": "select", "radii": [2], "bases": ["siamese-census-sgm", "sgm"]}
    net = RefineNet(**config)
    torch.nn.init.normal_(net.score_out.weight, generator=torch.Generator().manual_seed(0))
    path = tmp_path / "refine.pt"
    save_weights(path, "refine", config, net)
    left, right = _pair(40, 72, 2)
    far_left, far_right = _pair(40, 72, 9)
    left[..., 28:], right[..., 28:] = 0.5 * far_left[..., 28:] + 0.25, 0.5 * far_right[..., 28:] + 0.25  # a nearer, duller band
    plain = match("sgm-refine", left, right, 16, checkpoint=str(path), wmf_radius=0)
    out = match("sgm-refine", left, right, 16, checkpoint=str(path))
    assert torch.equal(out.extras["unfiltered"], plain.disparity)
    expected = weighted_median_filter(plain.disparity, left, radius=WMF_RADIUS, sigma_color=WMF_SIGMA_COLOR,
                                      stride=WMF_STRIDE)
    assert WMF_STRIDE > 1 and not torch.equal(expected, weighted_median_filter(
        plain.disparity, left, radius=WMF_RADIUS, sigma_color=WMF_SIGMA_COLOR))  # the stride matters here
    assert torch.equal(out.disparity, expected) and not torch.equal(out.disparity, plain.disparity)
    other = match("sgm-refine", left, right, 16, checkpoint=str(path), wmf_radius=3, wmf_sigma_color=0.05,
                  wmf_stride=1)
    assert torch.equal(other.disparity, weighted_median_filter(plain.disparity, left, radius=3, sigma_color=0.05))
    capped = match("sgm-refine", left, right, 16, checkpoint=str(path), wmf_radius=1, wmf_stride=4)
    assert torch.equal(capped.disparity, weighted_median_filter(plain.disparity, left, radius=1,
                                                                sigma_color=WMF_SIGMA_COLOR))
    for bad, name in (({"wmf_radius": -1}, "wmf_radius"), ({"wmf_radius": 1.5}, "wmf_radius"),
                      ({"wmf_sigma_color": 0.0}, "wmf_sigma_color"), ({"wmf_stride": 0}, "wmf_stride")):
        with pytest.raises(StereoInputError, match=name):
            match("sgm-refine", left, right, 16, checkpoint=str(path), **bad)


def test_refine_bases_filter_each_map_before_the_choice(tmp_path):
    """refine_bases(wmf=(r, s)): each filled map is the weighted median of the unfiltered one, validity and
    confidence unchanged; sgm-refine's base_wmf_radius passes it on (extras["base"] is the filtered first map)."""
    from stereonet.matchers import match
    from stereonet.matchers.learned import refine_bases
    from stereonet.select.filters import weighted_median_filter

    left, right = _pair(40, 72, 2)
    far_left, far_right = _pair(40, 72, 9)
    left[..., 28:], right[..., 28:] = 0.5 * far_left[..., 28:] + 0.25, 0.5 * far_right[..., 28:] + 0.25
    bases = ("siamese-census-sgm", "sgm")
    plain = refine_bases(bases, left, right, 16)
    filtered = refine_bases(bases, left, right, 16, wmf=(3, 0.2))
    expected = torch.cat([weighted_median_filter(plain[0][:, m:m + 1], left, radius=3, sigma_color=0.2)
                          for m in range(2)], 1)
    assert torch.equal(filtered[0], expected) and not torch.equal(filtered[0], plain[0])
    assert torch.equal(filtered[1], plain[1]) and torch.equal(filtered[2], plain[2])
    config = {"channels": 4, "dilations": [1], "mode": "select", "radii": [], "bases": list(bases)}
    path = tmp_path / "refine.pt"
    save_weights(path, "refine", config, RefineNet(**config))
    out = match("sgm-refine", left, right, 16, checkpoint=str(path), base_wmf_radius=3, wmf_sigma_color=0.2,
                wmf_radius=0)
    assert torch.equal(out.extras["base"], expected[:, :1])
    with pytest.raises(StereoInputError, match="base_wmf_radius"):
        match("sgm-refine", left, right, 16, checkpoint=str(path), base_wmf_radius=-2)


def test_refine_bases_filter_only_the_named_maps():
    """wmf_bases=("sgm",): sgm's map filtered, siamese-census-sgm's left as it is."""
    from stereonet.matchers.learned import refine_bases

    left, right = _pair(40, 72, 2)
    far_left, far_right = _pair(40, 72, 9)
    left[..., 28:], right[..., 28:] = 0.5 * far_left[..., 28:] + 0.25, 0.5 * far_right[..., 28:] + 0.25
    bases = ("siamese-census-sgm", "sgm")
    plain = refine_bases(bases, left, right, 16)[0]
    every = refine_bases(bases, left, right, 16, wmf=(3, 0.2))[0]
    only = refine_bases(bases, left, right, 16, wmf=(3, 0.2), wmf_bases=("sgm",))[0]
    assert torch.equal(only[:, :1], plain[:, :1]) and torch.equal(only[:, 1:], every[:, 1:])
    assert not torch.equal(only[:, 1:], plain[:, 1:])


def test_refine_bases_prefilter_reaches_both_sgm_family_bases(tmp_path):
    """prefilter: each SGM-family base's map is that matcher's own with the option, filled; sgm-refine passes it on."""
    from stereonet.matchers import match
    from stereonet.matchers.learned import refine_bases
    from stereonet.select.fill import fill_occlusions

    left, right = _pair(40, 72, 2)
    g = torch.Generator().manual_seed(4)
    left = (left + 0.05 * torch.randn(left.shape, generator=g)).clamp(0, 1)
    right = (right + 0.05 * torch.randn(right.shape, generator=g)).clamp(0, 1)
    bases = ("siamese-census-sgm", "sgm")
    plain = refine_bases(bases, left, right, 16)[0]
    smooth = refine_bases(bases, left, right, 16, prefilter="binomial")[0]
    for i, name in enumerate(bases):
        own = match(name, left, right, 16, prefilter="binomial")
        assert torch.equal(smooth[:, i:i + 1], fill_occlusions(own.disparity, own.valid))
        assert not torch.equal(smooth[:, i:i + 1], plain[:, i:i + 1])
    config = {"channels": 4, "dilations": [1], "mode": "select", "radii": [2], "bases": list(bases)}
    path = tmp_path / "refine.pt"
    save_weights(path, "refine", config, RefineNet(**config))
    out = match("sgm-refine", left, right, 16, checkpoint=str(path), prefilter="binomial", wmf_radius=0)
    assert torch.equal(out.extras["base"], smooth[:, :1])


def test_a_network_trained_on_filtered_maps_reads_them_so(tmp_path):
    """A weights file with filtered_bases: the matcher filters those maps (sgm-refine's radius and colour scale)
    before the choice without being told; an unknown name is refused naming the option."""
    from stereonet.matchers import match
    from stereonet.matchers.learned import WMF_RADIUS, WMF_SIGMA_COLOR, refine_bases

    left, right = _pair(40, 72, 2)
    far_left, far_right = _pair(40, 72, 9)
    left[..., 28:], right[..., 28:] = 0.5 * far_left[..., 28:] + 0.25, 0.5 * far_right[..., 28:] + 0.25
    bases = ["siamese-census-sgm", "sgm"]
    config = {"channels": 4, "dilations": [1], "mode": "select", "radii": [], "bases": bases,
              "filtered_bases": ["siamese-census-sgm"]}
    path = tmp_path / "refine.pt"
    save_weights(path, "refine", config, RefineNet(**config))
    out = match("sgm-refine", left, right, 16, checkpoint=str(path), wmf_radius=0)
    expected = refine_bases(tuple(bases), left, right, 16, wmf=(WMF_RADIUS, WMF_SIGMA_COLOR),
                            wmf_bases=("siamese-census-sgm",))[0]
    assert torch.equal(out.extras["base"], expected[:, :1])  # untrained: the first map, filtered
    with pytest.raises(StereoInputError, match="filtered_bases"):
        RefineNet(**{**config, "filtered_bases": ["bp"]})
