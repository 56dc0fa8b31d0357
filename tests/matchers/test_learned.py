"""Learned matchers through the registry: weights loading, output contract, bad checkpoints."""

from __future__ import annotations

import subprocess
import sys

import pytest
import torch

from stereonet import matchers
from stereonet.checks import StereoInputError
from stereonet.matchers import available, match
from stereonet.models.dispnet import DispNet
from stereonet.models.siamese import SiameseNet
from stereonet.models.smd import SMDNet
from stereonet.models.weights import WEIGHTS_DIR_ENV, save_weights


@pytest.fixture(scope="module")
def weights(tmp_path_factory):
    """Tiny random networks saved as slim weight files: {name: path}."""
    folder = tmp_path_factory.mktemp("weights")
    torch.manual_seed(0)
    nets = {"dispnet": (DispNet, {"max_disp": 16, "channels": 8}),
            "smd": (SMDNet, {"max_disp": 16, "channels": 8, "hidden": [8]}),
            "siamese": (SiameseNet, {"channels": 8, "layers": 3})}
    paths = {}
    for name, (cls, cfg) in nets.items():
        paths[name] = folder / f"{name}.pt"
        save_weights(paths[name], name, cfg, cls(**cfg))
    return paths


def test_learned_names_registered():
    assert {"siamese", "siamese-sgm", "dispnet", "smd"} <= set(available("learned"))


@pytest.mark.parametrize("name", ["dispnet", "smd", "siamese", "siamese-sgm"])
def test_output_contract_odd_size(weights, name):
    left, right = torch.rand(1, 3, 37, 53), torch.rand(1, 3, 37, 53)
    ckpt = weights["siamese" if name.startswith("siamese") else name]
    out = match(name, left, right, 12, checkpoint=str(ckpt))
    assert out.disparity.shape == (1, 1, 37, 53) and out.valid.dtype == torch.bool
    assert torch.isfinite(out.disparity).all()
    assert out.disparity.min() >= 0 and out.disparity.max() <= 12
    if name == "smd":
        assert out.uncertainty is not None and ((out.uncertainty >= 0) & (out.uncertainty <= 1)).all()
        assert torch.equal(out.confidence, 1 - out.uncertainty)
        assert set(out.extras) == {"mu1", "mu2", "b1", "b2", "pi", "lr_consistent", "unfiltered"}
        assert out.valid.all()  # the default fills the check's rejections and filters
    if name == "siamese-sgm":
        assert out.valid.all() and out.extras["lr_consistent"].dtype == torch.bool


def test_beyond_trained_range_runs_downscaled(weights):
    left, right = torch.rand(1, 3, 40, 96), torch.rand(1, 3, 40, 96)
    out = match("dispnet", left, right, 40, checkpoint=str(weights["dispnet"]))  # trained up to 16
    assert out.disparity.shape == (1, 1, 40, 96) and out.disparity.max() <= 40
    out = match("smd", left, right, 40, checkpoint=str(weights["smd"]), upsample=2.0)
    assert out.disparity.shape == (1, 1, 80, 192)


def test_dispnet_lr_check_marks_the_pixels_its_mirrored_run_disagrees_with(weights):
    """``dispnet``'s check (``lr_check=True``, the default; here without the filter, ``wmf_radius=0``): the same
    disparity as without, and ``valid`` is the project's left-right rule against the network's answer on the
    mirrored, swapped pair, mirrored back (here on an odd size beyond the trained range, so padding and the
    downscaled path are crossed); a bad value is a one-line error naming the option."""
    from stereonet.select.lr_check import left_right_check

    torch.manual_seed(1)
    left, right = torch.rand(1, 3, 37, 70), torch.rand(1, 3, 37, 70)
    ckpt = str(weights["dispnet"])
    plain = match("dispnet", left, right, 24, checkpoint=ckpt, lr_check=False, wmf_radius=0)
    checked = match("dispnet", left, right, 24, checkpoint=ckpt, wmf_radius=0)
    assert torch.equal(checked.disparity, plain.disparity)
    mirrored = match("dispnet", right.flip(-1), left.flip(-1), 24, checkpoint=ckpt, lr_check=False,
                     wmf_radius=0).disparity.flip(-1)
    expected = left_right_check(checked.disparity, mirrored)
    assert plain.valid.all() and checked.valid.dtype == torch.bool
    assert torch.equal(checked.valid, expected)
    assert 0 < checked.valid.float().mean() < 1
    with pytest.raises(StereoInputError, match="lr_check: expected True or False"):
        match("dispnet", left, right, 24, checkpoint=ckpt, lr_check="yes")


def test_dispnet_default_fills_the_check_then_filters_with_the_weighted_median(weights):
    """By default ``dispnet`` fills the pixels its check rejects by the shared rule and filters the map with the
    image-guided weighted median (radius 9, colour scale 0.2, stride 2): every pixel valid, the check's validity and
    the network's own map kept in the extras; other filter options pass through, and ``lr_check=False`` filters the
    network's map as it is; bad filter options are one-line errors naming the option."""
    from stereonet.select.fill import fill_occlusions
    from stereonet.select.filters import weighted_median_filter

    torch.manual_seed(3)
    base = torch.rand(1, 3, 40, 72)
    left, right = base, torch.roll(base, -5, dims=-1)  # a pair with a match, so the map has structure
    ckpt = str(weights["dispnet"])
    bare = match("dispnet", left, right, 24, checkpoint=ckpt, wmf_radius=0)
    out = match("dispnet", left, right, 24, checkpoint=ckpt)
    assert out.valid.all() and torch.equal(out.extras["lr_consistent"], bare.valid)
    assert torch.equal(out.extras["unfiltered"], bare.disparity)
    expected = weighted_median_filter(fill_occlusions(bare.disparity, bare.valid), left, radius=9, sigma_color=0.2,
                                      stride=2)
    assert torch.equal(out.disparity, expected)
    small = match("dispnet", left, right, 24, checkpoint=ckpt, wmf_radius=3, wmf_sigma_color=0.1, wmf_stride=5)
    assert torch.equal(small.disparity, weighted_median_filter(fill_occlusions(bare.disparity, bare.valid), left,
                                                               radius=3, sigma_color=0.1, stride=3))
    unchecked = match("dispnet", left, right, 24, checkpoint=ckpt, lr_check=False)
    assert torch.equal(unchecked.disparity, weighted_median_filter(bare.disparity, left, radius=9, sigma_color=0.2,
                                                                   stride=2))
    for options, message in ((dict(wmf_radius=-1), "wmf_radius: expected an integer >= 0"),
                             (dict(wmf_sigma_color=0.0), "wmf_sigma_color: expected a value > 0"),
                             (dict(wmf_stride=0), "wmf_stride: expected an integer >= 1")):
        with pytest.raises(StereoInputError, match=message):
            match("dispnet", left, right, 24, checkpoint=ckpt, **options)


@pytest.mark.parametrize("upsample", [1.0, 2.0])
def test_smd_lr_check_rejects_and_distrusts_the_pixels_its_mirrored_run_disagrees_with(weights, upsample):
    """``smd`` checks by default (``lr_check=True``; here without its weighted median): the same disparity and extras
    as without; ``valid`` is the one left-right rule against
    the mirrored, swapped pair's answer at a tolerance of 1 input pixel (``upsample`` pixels of the output grid);
    accepted pixels keep the head's uncertainty, rejected ones get the mixture's probability that the shared fill's
    answer is off by more than 2 px (``lr_uncertainty="one"``: 1); bad values are one-line errors naming the option
    (odd size beyond the trained range: padding and the downscaled path crossed)."""
    from stereonet.matchers.learned import SMD_ERROR_TAU
    from stereonet.models.smd import MixtureParams, error_probability
    from stereonet.select.fill import fill_occlusions
    from stereonet.select.lr_check import LR_TOL, left_right_check

    torch.manual_seed(2)
    left, right = torch.rand(1, 3, 37, 70), torch.rand(1, 3, 37, 70)
    ckpt = str(weights["smd"])
    plain = match("smd", left, right, 24, checkpoint=ckpt, upsample=upsample, lr_check=False, wmf_radius=0)
    checked = match("smd", left, right, 24, checkpoint=ckpt, upsample=upsample, wmf_radius=0)  # the default checks
    assert torch.equal(checked.disparity, plain.disparity) and plain.valid.all()
    assert all(torch.equal(checked.extras[k], v) for k, v in plain.extras.items())
    mirrored = match("smd", right.flip(-1), left.flip(-1), 24, checkpoint=ckpt, upsample=upsample,
                     lr_check=False, wmf_radius=0).disparity.flip(-1)
    assert torch.equal(checked.valid, left_right_check(checked.disparity, mirrored, LR_TOL * upsample))
    assert 0 < checked.valid.float().mean() < 1
    assert torch.equal(checked.uncertainty[checked.valid], plain.uncertainty[checked.valid])
    assert torch.equal(checked.confidence, 1 - checked.uncertainty)
    # a rejected pixel's uncertainty: the mixture's probability that the shared fill's answer is off by > 2 px
    mix = MixtureParams(**plain.extras)
    expected = error_probability(mix, fill_occlusions(checked.disparity, checked.valid), SMD_ERROR_TAU)
    assert torch.allclose(checked.uncertainty[~checked.valid], expected[~checked.valid])
    assert not torch.allclose(expected[~checked.valid], plain.uncertainty[~checked.valid])  # the fill's, not the head's
    one = match("smd", left, right, 24, checkpoint=ckpt, upsample=upsample, lr_check=True, lr_uncertainty="one",
                wmf_radius=0)
    assert torch.equal(one.valid, checked.valid)
    assert torch.equal(one.uncertainty[one.valid], checked.uncertainty[one.valid])
    assert (one.uncertainty[~one.valid] == 1).all() and (one.confidence[~one.valid] == 0).all()
    with pytest.raises(StereoInputError, match="lr_check: expected True or False"):
        match("smd", left, right, 24, checkpoint=ckpt, lr_check=1)
    with pytest.raises(StereoInputError, match="lr_uncertainty: expected 'fill' or 'one'"):
        match("smd", left, right, 24, checkpoint=ckpt, lr_check=True, lr_uncertainty="max")


@pytest.mark.skipif(not matchers.weights_available("smd"), reason="shipped smd weights not installed")
@pytest.mark.parametrize("upsample", [1.0, 2.0])
def test_smd_weighted_median_filters_the_filled_mode_and_scores_the_filtered_answer(upsample):
    """``smd(wmf_radius=R)``: the mode with the check's rejections filled by the shared rule, through the weighted
    median with radius, stride and step threshold in input pixels (``upsample`` times them on the output grid,
    guided by the left image resized to it); every pixel valid; the uncertainty is the mixture's probability that
    the filtered answer is off by more than 2 px (``lr_uncertainty="one"``: 1 where the check rejected); the check's
    validity and the mode kept in the extras; a bad option is a one-line error naming it. Shipped smd.pt on a data_gen
    render, so the map has depth edges for the filter to move."""
    import torch.nn.functional as F

    import data_gen
    from stereonet.matchers.learned import SMD_ERROR_TAU
    from stereonet.models.smd import MixtureParams, error_probability
    from stereonet.select.fill import fill_occlusions
    from stereonet.select.filters import weighted_median_filter

    def guide_of(image, disp):
        h, w = disp.shape[-2:]
        return image if upsample == 1 else F.interpolate(image, size=(h, w), mode="bilinear", align_corners=False)

    item = data_gen.SyntheticStereo(1, seed=12, difficulty=2, height=64, width=128)[0]
    left, right, md = item["left"][None], item["right"][None], item["max_disp"]
    bare = match("smd", left, right, md, upsample=upsample, wmf_radius=0)
    out = match("smd", left, right, md, upsample=upsample, wmf_radius=3, wmf_stride=2)
    default = match("smd", left, right, md, upsample=upsample)  # radius 9, stride 2 since the thirty-seventh session
    assert torch.equal(default.disparity, weighted_median_filter(
        fill_occlusions(bare.disparity, bare.valid), guide_of(left, bare.disparity), radius=round(9 * upsample),
        sigma_color=0.2, stride=round(2 * upsample), jump=upsample))
    radius = round(3 * upsample)
    expected = weighted_median_filter(fill_occlusions(bare.disparity, bare.valid), guide_of(left, bare.disparity),
                                      radius=radius,
                                      sigma_color=0.2, stride=min(round(2 * upsample), radius), jump=upsample)
    assert torch.equal(out.disparity, expected) and out.valid.all()
    assert not torch.equal(expected, fill_occlusions(bare.disparity, bare.valid))  # the filter moved pixels
    assert torch.equal(out.extras["lr_consistent"], bare.valid) and torch.equal(out.extras["unfiltered"],
                                                                                bare.disparity)
    mix = MixtureParams(**{k: bare.extras[k] for k in ("mu1", "mu2", "b1", "b2", "pi")})
    assert torch.allclose(out.uncertainty, error_probability(mix, expected, SMD_ERROR_TAU))
    assert torch.equal(out.confidence, 1 - out.uncertainty)
    one = match("smd", left, right, md, upsample=upsample, wmf_radius=3, wmf_stride=2, lr_uncertainty="one")
    assert torch.equal(one.disparity, out.disparity)
    assert (~bare.valid).any() and (one.uncertainty[~bare.valid] == 1).all()
    assert torch.equal(one.uncertainty[bare.valid], out.uncertainty[bare.valid])
    with pytest.raises(StereoInputError, match="wmf_radius: expected an integer >= 0"):
        match("smd", left, right, md, wmf_radius=1.5)


@pytest.mark.skipif(not matchers.weights_available("dispnet"), reason="shipped dispnet weights not installed")
def test_dispnet_lr_check_finds_the_occlusions_of_a_render():
    """With the shipped dispnet.pt on data_gen renders, the left-right check rejects most of the ground truth's
    occlusions (a share there at least twice the share elsewhere), and elsewhere the pixels it rejects are
    mismatches: their bad-2 rate at least twice the accepted pixels'; the default's weighted median then moves some
    pixels (not most). The shares are pooled over eight renders: on one render the accepted pixels' bad-2 can be
    a few per cent or a few tens, so a one-render ratio says more about that render than about the check
    (docs/experiments/lr_reject_ratio.py: per render it ranges from under 2 to over 90 for either file; pooled
    here about 5 for both)."""
    import data_gen
    from stereonet.select.fill import fill_occlusions

    renders = data_gen.SyntheticStereo(8, seed=12, difficulty=2, height=96, width=192)
    counts = torch.zeros(6)
    for item in renders:
        out = match("dispnet", item["left"][None], item["right"][None], item["max_disp"], wmf_radius=0)
        occluded = item["occlusion"][None] & item["valid"][None]
        visible = ~item["occlusion"][None] & item["valid"][None]
        bad = (out.disparity - item["disparity"][None]).abs() > 2
        counts += torch.stack([(occluded & ~out.valid).sum(), occluded.sum(), (visible & ~out.valid).sum(),
                               visible.sum(), (bad & visible & ~out.valid).sum(), (bad & visible & out.valid).sum()])
    rejected_occ, n_occ, rejected_vis, n_vis, bad_rejected, bad_accepted = counts.tolist()
    assert n_occ > 0 and rejected_vis > 0 and n_vis > rejected_vis
    rejected_occluded, rejected_visible = rejected_occ / n_occ, rejected_vis / n_vis
    assert rejected_occluded > 0.5 and rejected_occluded > 2 * rejected_visible, (rejected_occluded, rejected_visible)
    bad_rejected, bad_accepted = bad_rejected / rejected_vis, bad_accepted / (n_vis - rejected_vis)
    assert bad_rejected > 2 * bad_accepted, (bad_rejected, bad_accepted)
    # the default then fills and filters: on a render with depth edges the weighted median moves some pixels
    filtered = match("dispnet", item["left"][None], item["right"][None], item["max_disp"])
    moved = (filtered.disparity - fill_occlusions(out.disparity, out.valid)).abs() > 0.5
    assert filtered.valid.all() and 0 < moved.float().mean() < 0.5


def test_wrong_checkpoint_and_missing_weights(weights, tmp_path, monkeypatch):
    left = right = torch.rand(1, 3, 32, 48)
    with pytest.raises(StereoInputError, match="expected a 'dispnet' model, got a 'siamese'"):
        match("dispnet", left, right, 8, checkpoint=str(weights["siamese"]))
    monkeypatch.setenv(WEIGHTS_DIR_ENV, str(tmp_path))
    with pytest.raises(FileNotFoundError, match="not found"):
        match("smd", left, right, 8)


def test_registry_does_not_import_lightning():
    code = "import sys, stereonet.matchers.learned; print('lightning' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_siamese_census_sgm_mixes_the_learned_cost_into_sgm():
    import torch

    from stereonet.matchers import match
    from stereonet.matchers.learned import weights_available

    if not weights_available("siamese-census-sgm"):
        pytest.skip("stereonet/weights/siamese.pt is not present")
    g = torch.Generator().manual_seed(0)
    big = torch.rand(1, 3, 40, 110, generator=g)
    left, right = big[..., 10:100].contiguous(), big[..., 16:106].contiguous()  # disparity 6 everywhere
    plain = match("sgm", left, right, 16)
    zero = match("siamese-census-sgm", left, right, 16, learned_weight=0.0)
    torch.testing.assert_close(zero.disparity, plain.disparity)  # a = 0 is sgm itself
    mixed = match("siamese-census-sgm", left, right, 16)
    inner = mixed.disparity[..., 4:-4, 20:-4][mixed.valid[..., 4:-4, 20:-4]]
    assert inner.numel() > 100 and float((inner - 6).abs().median()) < 0.5
    assert mixed.confidence is not None
    with pytest.raises(ValueError, match="learned_weight"):
        match("siamese-census-sgm", left, right, 16, learned_weight=1.5)


@pytest.mark.skipif(not matchers.weights_available("siamese"), reason="shipped siamese weights not installed")
def test_register_checkpoint_variant_runs_the_method_with_those_weights(monkeypatch):
    from stereonet.models.weights import default_weights_path

    monkeypatch.setattr(matchers, "_REGISTRY", dict(matchers._REGISTRY))  # leave the real registry alone
    ckpt = default_weights_path("siamese")
    assert matchers.register_checkpoint_variant("siamese") == "siamese"
    name = matchers.register_checkpoint_variant(f"mine=siamese@{ckpt}")
    assert name == "mine" and matchers.spec("mine").kind == "learned"
    g = torch.Generator().manual_seed(0)
    left = torch.rand(1, 3, 24, 40, generator=g)
    right = torch.roll(left, -2, dims=-1)
    assert torch.equal(matchers.match("mine", left, right, 8).disparity,
                       matchers.match("siamese", left, right, 8, checkpoint=str(ckpt)).disparity)


def test_siamese_precision_option(weights):
    """precision: the bfloat16 tower gives float32 unit features close to the float32 tower's, and the
    matchers' disparities agree on almost every pixel; bad values and bfloat16 on ONNX are one-line errors."""
    from stereonet.matchers.learned import load_network
    from stereonet.models.graphs import NetworkGraph
    from stereonet.models.siamese import tower_dtype

    assert tower_dtype("float32") == torch.float32 and tower_dtype("bfloat16") == torch.bfloat16
    assert tower_dtype("auto", "meta") == torch.float32  # not a CPU: float32
    with pytest.raises(StereoInputError, match="precision: expected one of 'auto', 'float32', 'bfloat16'"):
        tower_dtype("half")
    graph = NetworkGraph("siamese", load_network("siamese", weights["siamese"]))
    images = torch.rand(2, 3, 41, 67, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        (f32,) = graph(images)
        (b16,) = graph.features(images, torch.bfloat16)
    assert b16.dtype == torch.float32 and b16.shape == f32.shape == (2, 8, 41, 67)
    assert torch.allclose(b16.norm(dim=1), torch.ones(2, 41, 67), atol=1e-5)
    error = float((b16 - f32).abs().max())
    assert 0 < error < 0.05  # really bfloat16 arithmetic, and close
    with pytest.raises(StereoInputError, match="dtype: only the 'siamese' network"):
        NetworkGraph("dispnet", load_network("dispnet", weights["dispnet"])).features(images, torch.bfloat16)
    big = torch.rand(1, 3, 48, 120, generator=torch.Generator().manual_seed(2))
    left, right = big[..., 12:108].contiguous(), big[..., 18:114].contiguous()  # disparity 6 everywhere
    a = match("siamese-sgm", left, right, 16, checkpoint=str(weights["siamese"]), precision="float32")
    b = match("siamese-sgm", left, right, 16, checkpoint=str(weights["siamese"]), precision="bfloat16")
    assert float(((a.disparity - b.disparity).abs() > 0.5).float().mean()) < 0.02
    with pytest.raises(StereoInputError, match="precision: expected"):
        match("siamese", left, right, 16, checkpoint=str(weights["siamese"]), precision="fp8")
    pytest.importorskip("onnxruntime", reason="onnxruntime (optional extra) is not installed")
    with pytest.raises(StereoInputError, match="precision: 'bfloat16' runs on backend='torch' only"):
        match("siamese", left, right, 16, checkpoint=str(weights["siamese"]), backend="onnx", precision="bfloat16")


@pytest.mark.parametrize("inputs", ["census", "grey+census"])
def test_census_input_towers_run_through_every_siamese_path(tmp_path, inputs):
    """A weights file of a census-input tower runs in the three Siamese matchers (float32 and bfloat16), finds a
    constant shift untrained (census comparisons of random texture), and exports to ONNX with the same features."""
    torch.manual_seed(0)
    path = tmp_path / "siamese.pt"
    cfg = {"channels": 8, "layers": 2, "inputs": inputs, "census_window": 5}
    save_weights(path, "siamese", cfg, SiameseNet(**cfg))
    big = torch.rand(1, 3, 40, 110, generator=torch.Generator().manual_seed(3))
    left, right = big[..., 10:100].contiguous(), big[..., 16:106].contiguous()  # disparity 6 everywhere
    for name in ("siamese", "siamese-sgm", "siamese-census-sgm"):
        for precision in ("float32", "bfloat16"):
            out = match(name, left, right, 12, checkpoint=str(path), precision=precision)
            assert ((out.disparity[..., 12:] - 6).abs() < 1).float().mean() > 0.9, (name, precision)
    pytest.importorskip("onnxruntime", reason="onnxruntime (optional extra) is not installed")
    from stereonet.export import export_onnx

    report = export_onnx("siamese", tmp_path / "siamese.onnx", path, 40, 90, 12)
    assert report.graph_difference < 1e-4 and report.valid_agree


def test_sgm_refine_warns_once_when_the_installed_siamese_weights_are_not_its_own(tmp_path, monkeypatch):
    """refine.pt records the digest of the siamese.pt whose maps it was trained on (trained_on); with another
    siamese.pt installed, sgm-refine warns (naming both files) and still runs; with the same one it is silent."""
    import shutil
    import warnings

    from stereonet.matchers.learned import check_trained_on
    from stereonet.models.weights import default_weights_path, load_weights, weights_digest

    shipped_refine, shipped_siamese = default_weights_path("refine"), default_weights_path("siamese")
    if not (shipped_refine.is_file() and shipped_siamese.is_file()):
        pytest.skip("the shipped refine.pt / siamese.pt are not present")
    assert load_weights(shipped_refine)[1]["trained_on"] == {"siamese": weights_digest(shipped_siamese)}
    left = torch.rand(1, 3, 32, 64, generator=torch.Generator().manual_seed(0))
    for name, change in (("same", False), ("other", True)):
        folder = tmp_path / name
        folder.mkdir()
        shutil.copy(shipped_refine, folder / "refine.pt")
        net, info = load_weights(shipped_siamese)
        if change:
            with torch.no_grad():
                next(net.parameters()).add_(0.01)
        save_weights(folder / "siamese.pt", "siamese", dict(info["config"]), net)
        monkeypatch.setenv(WEIGHTS_DIR_ENV, str(folder))
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            match("sgm-refine", left, left, 8)
        messages = [str(w.message) for w in caught if "trained on the outputs" in str(w.message)]
        if change:
            assert len(messages) == 1 and "refine.pt" in messages[0] and "siamese" in messages[0]
        else:
            assert not messages
    assert check_trained_on.cache_info().currsize >= 2  # once per file: the second call is cached
