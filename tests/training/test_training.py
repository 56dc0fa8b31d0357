"""Training: losses, schedules, every YAML through LightningCLI (fast_dev_run), overfitting one batch,
atomic checkpoints and resuming after a kill."""

from __future__ import annotations

import math
import sys
from pathlib import Path
from unittest import mock

import pytest
import torch

from stereonet.checks import StereoInputError
from stereonet.models.siamese import SiameseNet, siamese_pair_loss
from stereonet.training.callbacks import AtomicCheckpointIO
from stereonet.training.curriculum import difficulty_at
from stereonet.training.data import RandomShiftStereo, collate_pairs, gt_nonoccluded, swap_flip
from stereonet.training.losses import (
    aggregated_cost_hinge,
    bimodal_laplacian_nll,
    coarse_to_fine_weights,
    disparity_errors,
    edge_weights,
    multiscale_l1_loss,
)
from stereonet.training.module import DispNetModule, RefineModule, SiameseModule, SMDModule

CONFIGS = sorted((Path(__file__).resolve().parents[2] / "configs").glob("*.yaml"))
TINY = ["--data.source", "random-shift", "--data.height", "32", "--data.width", "64", "--data.batch_size", "2",
        "--data.val_pairs", "2", "--data.pool_size", "2", "--data.reuse", "1"]


def _cli(args):
    from stereonet.cli.train import main

    with mock.patch.object(sys, "argv", ["train.py"]):  # pytest's own argv is not the CLI's
        return main(args=args, run=False)


def test_configs_exist():
    assert {p.stem for p in CONFIGS} >= {"dispnet", "smd", "siamese"}


@pytest.mark.parametrize("config", CONFIGS, ids=[p.stem for p in CONFIGS])
def test_every_config_survives_fast_dev_run(config, tmp_path, monkeypatch):
    import yaml

    init = yaml.safe_load(config.read_text())["model"].get("init_args", {}).get("init_backbone")
    start = ["--model.init_backbone", str(config.parents[1] / init)] if init else []  # relative to the repository
    monkeypatch.chdir(tmp_path)
    cli = _cli(["--config", str(config), *TINY, *start, "--trainer.fast_dev_run", "true"])
    cli.trainer.fit(cli.model, datamodule=cli.datamodule)
    assert cli.trainer.state.finished
    assert cli.trainer.global_step == 1
    assert torch.isfinite(cli.trainer.callback_metrics["val/epe"])


def test_unknown_config_key_is_rejected(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit):
        _cli(["--config", str(CONFIGS[0]), "--model.init_args.no_such_key", "1"])
    with pytest.raises(SystemExit):
        _cli(["--config", str(CONFIGS[0]), "--data.batch_size", "four"])


def test_coarse_to_fine_weights_move():
    first, last = coarse_to_fine_weights(0.0, 5), coarse_to_fine_weights(1.0, 5)
    assert max(range(5), key=first.__getitem__) == 0
    assert max(range(5), key=last.__getitem__) == 4
    assert sum(first) == pytest.approx(1.0) and sum(last) == pytest.approx(1.0)


def test_curriculum_easy_first():
    levels = [difficulty_at(p / 100, 4, 0.5) for p in range(101)]
    assert levels[0] == 0 and levels[-1] == 4 and levels[50] == 4
    assert all(a <= b for a, b in zip(levels, levels[1:]))
    assert difficulty_at(0.0, 4, 0.0) == 4  # no curriculum


def test_multiscale_loss_zero_at_truth():
    gt = torch.rand(1, 1, 16, 32) * 5
    valid = torch.ones_like(gt, dtype=torch.bool)
    pyramid = [torch.nn.functional.interpolate(gt, scale_factor=1 / s, mode="area") for s in (4, 2)] + [gt]
    total, per_scale = multiscale_l1_loss(pyramid, gt, valid, [0.0, 0.0, 1.0])
    assert total == 0 and per_scale[0] > 0
    with pytest.raises(ValueError, match="weights"):
        multiscale_l1_loss(pyramid, gt, valid, [1.0])


def test_bimodal_nll_reduces_to_laplacian_and_gradcheck():
    mu1, mu2 = torch.tensor([[[[2.0]]]]), torch.tensor([[[[9.0]]]])
    b1, b2 = torch.tensor([[[[0.5]]]]), torch.tensor([[[[1.0]]]])
    target, valid = torch.tensor([[[[2.5]]]]), torch.ones(1, 1, 1, 1, dtype=torch.bool)
    nll = bimodal_laplacian_nll(mu1, mu2, b1, b2, torch.ones_like(mu1) - 1e-7, target, valid)
    assert nll == pytest.approx(float(torch.log(2 * b1) + 0.5 / b1), rel=1e-4)
    g = torch.Generator().manual_seed(0)
    args = [torch.rand(1, 1, 2, 3, generator=g, dtype=torch.float64) * s + o
            for s, o in ((5, 0), (5, 0), (1, 0.2), (1, 0.2), (0.8, 0.1))]
    args = [a.requires_grad_() for a in args]
    tgt = torch.rand(1, 1, 2, 3, generator=g, dtype=torch.float64) * 5
    assert torch.autograd.gradcheck(lambda *a: bimodal_laplacian_nll(*a, tgt, torch.ones_like(tgt, dtype=torch.bool)),
                                    tuple(args))


def test_edge_weighted_nll_weights_the_pixels_beside_depth_edges():
    gt = torch.full((1, 1, 6, 10), 5.0)
    gt[..., 5:] = 20.0  # a vertical depth edge between columns 4 and 5
    valid = torch.ones_like(gt, dtype=torch.bool)
    w = edge_weights(gt, valid, 4.0)
    assert torch.equal(w[0, 0, 0], torch.tensor([1.0, 1, 1, 4, 4, 4, 4, 1, 1, 1]))  # 1 px either side of the jump
    assert torch.equal(edge_weights(gt, valid, 1.0), torch.ones_like(gt))
    # the weighted mean: an error only at the edge counts 4x more than with uniform weights (up to the norm)
    mu = gt.clone()
    mu[..., 4] += 3.0  # wrong only beside the edge
    b, pi = torch.ones_like(gt), torch.full_like(gt, 0.5)
    base = bimodal_laplacian_nll(mu, mu, b, b, pi, gt, valid)
    weighted = bimodal_laplacian_nll(mu, mu, b, b, pi, gt, valid, w)
    floor = float(torch.log(torch.tensor(2.0)))  # NLL of an exact prediction with b = 1
    assert (base - floor) == pytest.approx(3.0 * 6 / 60, rel=1e-5)
    assert (weighted - floor) == pytest.approx(3.0 * 6 * 4 / (60 + 3 * 24), rel=1e-5)


def test_swap_flip_gives_a_consistent_pair():
    left, right = torch.rand(3, 4, 8), torch.rand(3, 4, 8)
    d, dr = torch.rand(1, 4, 8), torch.rand(1, 4, 8)
    v = torch.ones(1, 4, 8, dtype=torch.bool)
    out = swap_flip({"left": left, "right": right, "disparity": d, "disparity_right": dr, "valid": v,
                     "valid_right": v})
    assert torch.equal(out["left"], right.flip(-1)) and torch.equal(out["disparity"], dr.flip(-1))
    assert swap_flip({"left": left})["left"] is left
    far = swap_flip({"left": left, "right": right, "disparity": d, "disparity_right": dr + 5.0, "valid": v,
                     "valid_right": v, "max_disp": 5})
    assert not far["valid"].any()  # right-view GT beyond the range is not supervised


def test_gt_nonoccluded_marks_occluded_strip():
    d = torch.zeros(1, 1, 10)
    d[..., 5:] = 3.0  # foreground on the right half: background pixels 2..4 are hidden in the right view
    dr = torch.zeros(1, 1, 10)
    dr[..., 2:7] = 3.0
    noc = gt_nonoccluded(d, dr)
    assert noc[0, 0, :2].all() and noc[0, 0, 5:].all()


def _one_batch():
    ds = RandomShiftStereo(2, seed=0, height=32, width=64, max_disp=8)
    return collate_pairs([ds[0], ds[1]])


def _fit(loss_fn, params, steps: int, lr: float) -> tuple[float, float]:
    opt = torch.optim.Adam(params, lr=lr)
    first = None
    for _ in range(steps):
        loss = loss_fn()
        first = float(loss.detach()) if first is None else first
        opt.zero_grad()
        loss.backward()
        opt.step()
    return first, float(loss_fn().detach())


@pytest.mark.parametrize("refine_readout", ["residual", "matched"])
def test_overfit_one_batch_dispnet(one_thread, refine_readout):
    torch.manual_seed(0)
    batch = _one_batch()
    module = DispNetModule(max_disp=16, channels=8, refine_readout=refine_readout)
    first, final = _fit(lambda: module.compute(batch)[0], module.parameters(), 60, 3e-3)
    assert final < 0.1 * first and final < 0.5, (first, final)  # multi-scale L1 below half a pixel


def test_dispnet_loss_pixels_nonoccluded_ignores_the_occluded_pixels(one_thread):
    """``loss_pixels="nonoccluded"``: the loss does not depend on the ground truth of occluded pixels (changing it
    there leaves the loss equal) and does on visible ones; with "valid" it depends on both; a bad value is a
    one-line error naming the option."""
    torch.manual_seed(0)
    batch = _one_batch()
    batch["nonoccluded"] = batch["valid"].clone()
    batch["nonoccluded"][..., 20:28] = False  # a band of columns stands for the occluded pixels
    occluded = batch["valid"] & ~batch["nonoccluded"]
    assert occluded.any() and batch["nonoccluded"].any()
    moved_occluded = dict(batch, disparity=torch.where(occluded, batch["disparity"] + 5.0, batch["disparity"]))
    moved_visible = dict(batch, disparity=torch.where(batch["nonoccluded"], batch["disparity"] + 5.0,
                                                      batch["disparity"]))
    for pixels in ("nonoccluded", "valid"):
        torch.manual_seed(0)
        module = DispNetModule(max_disp=16, channels=4, loss_pixels=pixels).eval()
        with torch.no_grad():
            base, occ, vis = (float(module.compute(b)[0]) for b in (batch, moved_occluded, moved_visible))
        assert vis != base
        assert (occ == base) == (pixels == "nonoccluded"), (pixels, base, occ)
    with pytest.raises(StereoInputError, match="loss_pixels: expected 'valid' or 'nonoccluded'"):
        DispNetModule(max_disp=16, channels=4, loss_pixels="visible")


def test_dispnet_refine_radius_and_dilations_reach_the_weights_config(one_thread):
    """A wider local search (``refine_radius``) and the matched read-out (``refine_readout``) are part of the
    network's shape and the 3-D aggregation's spatial dilations (``agg_dilations``) of its maths: the module's
    config carries all three (and leaves each out at its default, so older files read as before), and a network
    built from that config takes the trained tensors and gives the same disparity (one with the default dilations
    does not)."""
    from stereonet.models.weights import build_model

    torch.manual_seed(0)
    module = DispNetModule(max_disp=16, channels=4, matching="census", aggregation="3d", refine_radius=3,
                           agg_dilations=[1, 2, 4], refine_readout="matched").eval()
    config = module.model_config()
    assert config["refine_radius"] == 3 and config["agg_dilations"] == [1, 2, 4]
    assert config["refine_readout"] == "matched"
    default = DispNetModule(max_disp=16, channels=4, matching="census", aggregation="3d").model_config()
    assert not {"refine_radius", "agg_dilations", "refine_readout"} & set(default)
    net = build_model("dispnet", config).eval()
    net.load_state_dict(module.model.state_dict())
    for key in ("refine_radius", "refine_readout"):  # narrower decoder inputs; one-channel residual heads
        with pytest.raises(RuntimeError):
            build_model("dispnet", {k: v for k, v in config.items() if k != key}).load_state_dict(
                module.model.state_dict())
    left, right = torch.rand(1, 3, 32, 64), torch.rand(1, 3, 32, 64)
    undilated = build_model("dispnet", {k: v for k, v in config.items() if k != "agg_dilations"}).eval()
    undilated.load_state_dict(module.model.state_dict())  # the same tensors, other maths
    with torch.no_grad():
        assert torch.equal(net(left, right).disparity, module.model(left, right).disparity)
        assert not torch.allclose(undilated(left, right).disparity, net(left, right).disparity)


def test_overfit_one_batch_siamese(one_thread):
    """The same sampled pairs every step (one batch): the hinge loss goes to zero."""
    torch.manual_seed(0)
    batch = _one_batch()
    module = SiameseModule(channels=16, layers=3, num_samples=64)
    valid = batch["valid"]

    def loss():
        return siamese_pair_loss(module.model, batch["left"], batch["right"], batch["disparity"], valid, 64,
                                 generator=torch.Generator().manual_seed(0))

    first, final = _fit(loss, module.parameters(), 40, 1e-2)
    assert final < 0.05 * first, (first, final)


def test_siamese_module_teacher_stays_out_of_the_checkpoint(tmp_path):
    from stereonet.models.weights import save_weights

    teacher = SiameseNet(channels=8, layers=2)
    path = tmp_path / "teacher.pt"
    save_weights(path, "siamese", {"channels": 8, "layers": 2}, teacher)
    module = SiameseModule(channels=4, layers=2, num_samples=32, teacher=str(path), distill=1.0)
    assert all(k.startswith("model.") for k in module.state_dict())
    assert sum(p.numel() for p in module.parameters()) == sum(p.numel() for p in module.model.parameters())
    batch = _one_batch()
    plain = SiameseModule(channels=4, layers=2, num_samples=32)
    plain.load_state_dict(module.state_dict())
    module.train(), plain.train()
    torch.manual_seed(0)
    with_teacher = module.compute(batch)[0]
    torch.manual_seed(0)
    assert with_teacher > plain.compute(batch)[0]  # same sampled pairs (same seed), plus the squared term
    with pytest.raises(ValueError, match="distill"):
        SiameseModule(distill=-1.0)


def test_training_batches_carry_each_pairs_own_range():
    """RefineModule runs its base matchers with the range a pair was rendered in (what a user passes at inference),
    so the batch must carry it; before, training fell back to the module's max_disp for every pair."""
    from stereonet.training.data import _training_fields

    items = [_training_fields(RandomShiftStereo(1, seed=0, max_disp=m)[0]) for m in (5, 12)]
    assert [it["max_disp"] for it in items] == [5, 12]
    assert collate_pairs(items)["max_disp"] == [5, 12]
    assert "max_disp" not in _training_fields({k: v for k, v in RandomShiftStereo(1)[0].items() if k != "max_disp"})


def test_refine_module_runs_its_bases_with_each_pairs_range(one_thread):
    from stereonet.matchers import learned

    batch = collate_pairs([RandomShiftStereo(1, seed=0, max_disp=m)[0] for m in (5, 12)])
    seen = []
    real = learned.refine_bases

    def spy(bases, left, right, max_disp, **options):
        seen.append(max_disp)
        return real(bases, left, right, max_disp, **options)

    with mock.patch.object(learned, "refine_bases", spy):
        RefineModule(channels=4, dilations=(1,), max_disp=20).compute(batch)
        assert seen == [5, 12]
        seen.clear()
        RefineModule(channels=4, dilations=(1,), max_disp=20, pair_ranges=False).compute(batch)
        assert seen == [20, 20]


def test_aggregated_cost_hinge_scores_the_winner_against_far_disparities():
    cost = torch.zeros(1, 8, 1, 3)
    cost[0, :, 0, 0] = torch.tensor([9.0, 9, 9, 1, 2, 9, 9, 9])  # truth 3.4: minimum within 1 px, far ones 9
    cost[0, :, 0, 1] = torch.tensor([9.0, 9, 9, 5, 9, 9, 9, 4])  # truth 3.0: a far disparity (7) wins
    cost[0, :, 0, 2] = torch.tensor([0.0, 9, 9, 9, 9, 9, 9, 9])  # truth 9.0: outside the volume, left out
    target = torch.tensor([3.4, 3.0, 9.0]).view(1, 1, 1, 3)
    valid = torch.ones(1, 1, 1, 3, dtype=torch.bool)
    # pixel 0: relu(4 + 1 - 9) = 0; pixel 1: relu(4 + 5 - 4) / 4 = 1.25; pixel 2 unused
    assert aggregated_cost_hinge(cost, target, valid, margin=4.0).item() == pytest.approx(1.25 / 2)
    # capped (a ramp): pixel 1's 1.25 counts as at most 1.0
    assert aggregated_cost_hinge(cost, target, valid, margin=4.0, cap=1.0).item() == pytest.approx(1.0 / 2)
    assert aggregated_cost_hinge(cost, target, valid, margin=4.0, cap=2.0).item() == pytest.approx(1.25 / 2)
    with pytest.raises(ValueError, match="cap"):
        aggregated_cost_hinge(cost, target, valid, margin=4.0, cap=0.0)
    valid[0, 0, 0, 1] = False
    assert aggregated_cost_hinge(cost, target, valid, margin=4.0).item() == 0.0
    # 2.0 px from the truth (bin 5 for truth 3.0) counts as far: it must lose by the margin too
    near_miss = torch.full((1, 8, 1, 1), 9.0)
    near_miss[0, 3, 0, 0], near_miss[0, 5, 0, 0] = 1.0, 2.0
    one = aggregated_cost_hinge(near_miss, torch.full((1, 1, 1, 1), 3.0), torch.ones(1, 1, 1, 1, dtype=torch.bool), 4.0)
    assert one.item() == pytest.approx(3.0 / 4)
    with pytest.raises(ValueError, match="margin"):
        aggregated_cost_hinge(cost, target, valid, margin=0.0)


def test_siamese_module_sgm_loss_starts_from_weights_and_trains_through_sgm(tmp_path, one_thread):
    from stereonet.models.weights import save_weights

    start = SiameseNet(channels=4, layers=2)
    path = tmp_path / "start.pt"
    save_weights(path, "siamese", {"channels": 4, "layers": 2}, start)
    module = SiameseModule(channels=4, layers=2, num_samples=32, max_disp=8, init_weights=str(path), sgm_loss=1.0)
    assert all(torch.equal(a, b) for a, b in zip(module.model.state_dict().values(), start.state_dict().values()))
    module.train()
    batch = _one_batch()
    loss, _, extra = module.compute(batch)
    assert "sgm_hinge" in extra and torch.isfinite(loss)
    loss.backward()
    grads = [p.grad for p in module.model.parameters()]
    assert all(g is not None and torch.isfinite(g).all() for g in grads)
    # the aggregated term reaches the tower: its gradient alone is not zero
    module.zero_grad()
    module._sgm_term(batch, batch.get("nonoccluded", batch["valid"])).backward()
    assert sum(float(p.grad.abs().sum()) for p in module.model.parameters()) > 0
    with pytest.raises(ValueError, match="init_weights"):
        SiameseModule(channels=8, layers=2, init_weights=str(path))
    with pytest.raises(ValueError, match="sgm_margin"):
        SiameseModule(sgm_loss=1.0, sgm_margin=0.0)


def test_refine_module_starts_at_sgm_and_learns(one_thread):
    """RefineModule runs sgm on each pair with the pair's own range: the untrained prediction is sgm's filled
    map (base_epe equals the prediction's error); a few steps on one batch lower the loss."""
    torch.manual_seed(0)
    batch = _one_batch()
    module = RefineModule(channels=8, dilations=(1, 2), lr=3e-3)
    loss, pred, extra = module.compute(batch)
    errs = disparity_errors(pred.detach(), batch["disparity"], batch["valid"])
    assert torch.allclose(errs["epe"], extra["base_epe"])
    first, final = _fit(lambda: module.compute(batch)[0], module.parameters(), 30, 3e-3)
    assert final < 0.8 * first, (first, final)


def test_refine_module_selection_starts_at_sgm_and_learns(one_thread):
    """mode="select": the untrained choice is sgm's filled map; the oracle (best candidate per pixel) is never
    worse than sgm's map; a few steps lower the choice loss; the exported config carries the mode."""
    torch.manual_seed(0)
    batch = _one_batch()
    module = RefineModule(channels=8, dilations=(1, 2), mode="select", radii=(1, 3), lr=3e-3)
    loss, pred, extra = module.compute(batch)
    errs = disparity_errors(pred.detach(), batch["disparity"], batch["valid"])
    assert torch.allclose(errs["bad2"], extra["base_bad2"])
    assert extra["oracle_bad2"] <= extra["base_bad2"]
    first, final = _fit(lambda: module.compute(batch)[0], module.parameters(), 40, 1e-2)
    assert final < 0.8 * first, (first, final)
    assert module.model_config() == {"channels": 8, "dilations": [1, 2], "mode": "select", "radii": [1, 3]}
    with pytest.raises(ValueError, match="tolerance"):
        RefineModule(mode="select", tolerance=0.0)
    with pytest.raises(ValueError, match="target"):
        RefineModule(mode="select", target="all")


def test_refine_module_keep_target_is_the_cross_entropy_of_one_candidate(one_thread):
    """target="keep": at the start (all scores equal) the loss is log K exactly, whichever candidate is the
    target; training lowers it."""
    torch.manual_seed(0)
    batch = _one_batch()
    module = RefineModule(channels=8, dilations=(1, 2), mode="select", radii=(1, 3), target="keep")
    loss, _, _ = module.compute(batch)
    assert abs(float(loss.detach()) - math.log(17)) < 1e-5
    first, final = _fit(lambda: module.compute(batch)[0], module.parameters(), 40, 1e-2)
    assert final < first - 0.2, (first, final)  # 0.4 nats in 40 steps measured; a cross-entropy falls slowly


def test_smd_loss_decreases_on_one_batch(one_thread):
    torch.manual_seed(0)
    batch = _one_batch()
    module = SMDModule(max_disp=16, channels=8, lr=3e-3)
    opt = torch.optim.Adam(module.parameters(), lr=3e-3)
    losses = []
    for _ in range(20):
        loss, pred, extra = module.compute(batch)
        losses.append(float(loss.detach()))
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert losses[-1] < 0.5 * losses[0]
    assert pred.shape == batch["disparity"].shape and "nll" in extra


@pytest.mark.parametrize("context, grey", [(0, True), (2, True), (2, False)])
def test_smd_frozen_backbone_trains_the_head_alone(one_thread, tmp_path, context, grey):
    """freeze_backbone: SMD = the given DispNet weights (unchanged by training) + a head learnt by the NLL alone
    (with and without the head's neighbourhood)."""
    from stereonet.models.dispnet import DispNet
    from stereonet.models.weights import save_weights

    torch.manual_seed(0)
    config = {"max_disp": 16, "channels": 8, "aggregation": "2d", "upsample": "select", "matching": "census"}
    path = tmp_path / "dispnet.pt"
    save_weights(path, "dispnet", config, DispNet(**config))
    module = SMDModule(**config, init_backbone=str(path), freeze_backbone=True, lr=3e-3, context=context,
                       context_grey=grey)
    assert module.model_config().get("context", 0) == context  # (files without the key: 0)
    assert module.model_config().get("context_grey", True) == grey
    start = {k: v.clone() for k, v in module.model.backbone.state_dict().items()}
    batch = _one_batch()
    first, final = _fit(lambda: module.compute(batch)[0], [p for p in module.parameters() if p.requires_grad], 20, 3e-3)
    assert final < 0.8 * first
    loss, _, extra = module.compute(batch)
    torch.testing.assert_close(float(loss), float(extra["nll"]))  # the NLL is the whole loss
    for k, v in module.model.backbone.state_dict().items():
        assert torch.equal(v, start[k]), k
    assert all(p.grad is None for p in module.model.backbone.parameters())
    with pytest.raises(ValueError, match="freeze_backbone: needs init_backbone"):
        SMDModule(**config, freeze_backbone=True)
    with pytest.raises(ValueError, match="init_backbone: .*expected"):
        SMDModule(**{**config, "matching": "learned"}, init_backbone=str(path))


def test_atomic_checkpoint_keeps_old_file_on_failure(tmp_path, monkeypatch):
    io = AtomicCheckpointIO()
    path = tmp_path / "last.ckpt"
    io.save_checkpoint({"step": 1}, path)
    assert torch.load(path)["step"] == 1

    def crash(obj, f, *a, **k):
        Path(f).write_bytes(b"half")
        raise KeyboardInterrupt

    monkeypatch.setattr(torch, "save", crash)
    with pytest.raises(KeyboardInterrupt):
        io.save_checkpoint({"step": 2}, path)
    monkeypatch.undo()
    assert torch.load(path)["step"] == 1
    assert [p.name for p in tmp_path.iterdir()] == ["last.ckpt"]


def test_resume_from_last_checkpoint(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    config = next(p for p in CONFIGS if p.stem == "siamese")
    common = ["--config", str(config), *TINY, "--model.init_args.max_disp", "8", "--trainer.logger", "false",
              "--trainer.val_check_interval", "2", "--trainer.enable_progress_bar", "false",
              "--trainer.callbacks.init_args.every_n_train_steps", "2"]
    cli = _cli([*common, "--trainer.max_steps", "2"])
    cli.trainer.fit(cli.model, datamodule=cli.datamodule)
    last = tmp_path / "lightning_logs" / "siamese" / "checkpoints" / "last.ckpt"
    assert last.is_file()
    ckpt = torch.load(last, weights_only=True)
    assert ckpt["global_step"] == 2 and ckpt["stereonet_model"]["model"] == "siamese"
    cli = _cli([*common, "--trainer.max_steps", "4"])
    cli.trainer.fit(cli.model, datamodule=cli.datamodule, ckpt_path="last")
    assert cli.trainer.global_step == 4


def _spy_renders(monkeypatch) -> list[tuple[int, int]]:
    """(seed, difficulty) of every data_gen set the training data module builds, in order."""
    import stereonet.training.data as data_module

    seen: list[tuple[int, int]] = []
    real = data_module._make_dataset

    def spy(source, count, seed, difficulty, *args, **kwargs):
        seen.append((seed, difficulty))
        return real(source, count, seed, difficulty, *args, **kwargs)

    monkeypatch.setattr(data_module, "_make_dataset", spy)
    return seen


def test_resumed_run_continues_the_stream_at_its_step(tmp_path, monkeypatch):
    """A resumed run's first rendered pairs come from the stream of its restored step at its restored difficulty,
    not the first run's pairs again (Lightning starts the loader's stream before on_train_start)."""
    import stereonet.training.data as data_module

    monkeypatch.chdir(tmp_path)
    config = next(p for p in CONFIGS if p.stem == "siamese")
    common = ["--config", str(config), *TINY, "--model.init_args.max_disp", "8", "--trainer.logger", "false",
              "--trainer.val_check_interval", "2", "--trainer.enable_progress_bar", "false",
              "--trainer.callbacks.init_args.every_n_train_steps", "2", "--data.curriculum_fraction", "0.5",
              "--data.source", "data_gen", "--data.supersample", "1"]
    seen = _spy_renders(monkeypatch)
    cli = _cli([*common, "--trainer.max_steps", "2"])
    seed = cli.datamodule.hparams.seed
    cli.trainer.fit(cli.model, datamodule=cli.datamodule)
    first_run = [s for s, _ in seen if s != cli.datamodule.hparams.val_seed]
    assert first_run and set(first_run) == {seed}
    seen.clear()
    cli = _cli([*common, "--trainer.max_steps", "4"])
    cli.trainer.fit(cli.model, datamodule=cli.datamodule, ckpt_path="last")
    resumed = [(s, d) for s, d in seen if s != cli.datamodule.hparams.val_seed]
    assert resumed and all(s == seed + 7919 * 2 for s, _ in resumed)  # the stream of step 2
    top = data_module.max_difficulty("data_gen")
    assert resumed[0][1] == data_module.difficulty_at(2 / 4, top, 0.5, 0)  # the restored level from the first pair


def test_export_bad_input_is_one_line(tmp_path, capsys):
    """python -m stereonet.training.export weights: a missing checkpoint, a file that is not one, a config this
    version cannot build and an output folder that does not exist are one line each, exit 2, nothing written."""
    from stereonet.models.weights import load_weights, save_weights
    from stereonet.training.export import main

    net = DispNetModule(max_disp=16, channels=8).model
    good = tmp_path / "good.pt"
    save_weights(good, "dispnet", {"max_disp": 16, "channels": 8}, net)
    odd = tmp_path / "odd.pt"
    save_weights(odd, "dispnet", {"max_disp": 16, "channels": 8, "no_such_option": 1}, net)
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a checkpoint")
    for ckpt, out, word in ((tmp_path / "missing.ckpt", tmp_path / "a.pt", "not found"),
                            (junk, tmp_path / "b.pt", "not a readable"),
                            (odd, tmp_path / "c.pt", "cannot build"),
                            (good, tmp_path / "no" / "d.pt", "out:")):
        assert main(["weights", str(ckpt), str(out)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and word in err[0], err
        assert not out.exists()
    with pytest.raises(StereoInputError, match="no_such_option"):
        load_weights(odd)
    assert main(["weights", str(good), str(tmp_path / "e.pt")]) == 0 and (tmp_path / "e.pt").is_file()


def test_resuming_another_network_is_one_line(tmp_path, monkeypatch):
    """--ckpt_path of another model's run, or of the same model with other tensor shapes: one line naming the
    networks (or the first tensor that differs) instead of Lightning's mismatch report."""
    monkeypatch.chdir(tmp_path)
    siamese = next(p for p in CONFIGS if p.stem == "siamese")
    common = [*TINY, "--model.init_args.max_disp", "8", "--trainer.logger", "false",
              "--trainer.enable_progress_bar", "false", "--trainer.callbacks.init_args.every_n_train_steps", "1",
              "--trainer.max_steps", "1", "--trainer.val_check_interval", "1"]
    cli = _cli(["--config", str(siamese), *common])
    cli.trainer.fit(cli.model, datamodule=cli.datamodule)
    last = tmp_path / "lightning_logs" / "siamese" / "checkpoints" / "last.ckpt"
    dispnet = next(p for p in CONFIGS if p.stem == "dispnet")
    cli = _cli(["--config", str(dispnet), *common, "--trainer.max_steps", "2"])
    with pytest.raises(StereoInputError, match="holds a 'siamese' network; this config trains a 'dispnet' one"):
        cli.trainer.fit(cli.model, datamodule=cli.datamodule, ckpt_path=str(last))
    cli = _cli(["--config", str(siamese), *common, "--trainer.max_steps", "2", "--model.init_args.channels", "8"])
    with pytest.raises(StereoInputError, match="tensors do not fit") as e:
        cli.trainer.fit(cli.model, datamodule=cli.datamodule, ckpt_path=str(last))
    assert "\n" not in str(e.value)


def test_a_continuation_keeps_the_level_it_reached(tmp_path, monkeypatch):
    """A run resumed with a larger max_steps (its progress pulled back inside the curriculum's ramp) keeps
    rendering at the level the first run reached (saved with the curriculum callback), not easier pairs."""
    import stereonet.training.data as data_module

    monkeypatch.chdir(tmp_path)
    config = next(p for p in CONFIGS if p.stem == "siamese")
    common = ["--config", str(config), *TINY, "--model.init_args.max_disp", "8", "--trainer.logger", "false",
              "--trainer.val_check_interval", "4", "--trainer.enable_progress_bar", "false",
              "--trainer.callbacks.init_args.every_n_train_steps", "4", "--data.curriculum_fraction", "0.5",
              "--data.source", "data_gen", "--data.supersample", "1"]
    seen = _spy_renders(monkeypatch)
    cli = _cli([*common, "--trainer.max_steps", "4"])
    cli.trainer.fit(cli.model, datamodule=cli.datamodule)
    top = data_module.max_difficulty("data_gen")
    assert cli.datamodule.difficulty == top
    seen.clear()
    cli = _cli([*common, "--trainer.max_steps", "40"])  # step 4 of 40: progress 0.1, inside the ramp
    assert data_module.difficulty_at(4 / 40, top, 0.5, 0) < top
    cli.trainer.fit(cli.model, datamodule=cli.datamodule, ckpt_path="last")
    levels = [d for s, d in seen if s != cli.datamodule.hparams.val_seed]
    assert levels and set(levels) == {top}


def test_sample_max_disp_widens_the_range_within_bounds():
    import data_gen
    from stereonet.training.data import sample_max_disp

    g = torch.Generator().manual_seed(0)
    low = data_gen.default_max_disp(1, 256)
    draws = [sample_max_disp("data_gen", 1, 256, 96, g) for _ in range(200)]
    assert min(draws) >= low and max(draws) <= 96 and len(set(draws)) > 10
    capped = [sample_max_disp("data_gen", 0, 128, 500, g) for _ in range(50)]
    assert max(capped) <= 63  # below half the width, as data_gen requires
    assert sample_max_disp("data_gen", 1, 256, None, g) is None
    assert sample_max_disp("random-shift", 1, 256, 96, g) is None
    assert sample_max_disp("data_gen", 4, 256, 8, g) is None  # the difficulty's own range is larger already


@pytest.mark.parametrize("module_cls, options", [(DispNetModule, {}), (SMDModule, {}),
                                                 (DispNetModule, {"matching": "census", "aggregation": "3d"})])
def test_channels_last_training_is_the_same_maths(module_cls, options, one_thread):
    """channels_last only changes the memory layout (of the 2-D convolutions; 3-D ones keep theirs): same loss and
    gradients, and its weights load into a network built in the default layout."""
    torch.manual_seed(0)
    batch = _one_batch()
    plain = module_cls(max_disp=16, channels=8, **options)
    fast = module_cls(max_disp=16, channels=8, channels_last=True, **options)
    fast.load_state_dict(plain.state_dict())
    net = fast.model.backbone if module_cls is SMDModule else fast.model
    assert net.enc1[0][0].weight.is_contiguous(memory_format=torch.channels_last)
    loss_plain, loss_fast = plain.compute(batch)[0], fast.compute(batch)[0]
    torch.testing.assert_close(loss_fast, loss_plain, rtol=1e-5, atol=1e-5)
    loss_plain.backward()
    loss_fast.backward()
    for (name, p), q in zip(plain.named_parameters(), fast.parameters()):
        torch.testing.assert_close(q.grad, p.grad, rtol=1e-4, atol=1e-5, msg=name)
    again = module_cls(max_disp=16, channels=8, **options)
    again.load_state_dict(fast.state_dict())
    torch.testing.assert_close(again.compute(batch)[0], loss_plain, rtol=1e-5, atol=1e-5)


def test_ranks_see_different_pairs():
    import itertools
    import multiprocessing as mp

    from stereonet.training.data import PooledCurriculumStream

    def items(rank: int, world: int) -> list[torch.Tensor]:
        stream = PooledCurriculumStream("data_gen", 3, 32, 64, pool_size=1, reuse=1, augment=False,
                                        difficulty=mp.Value("i", 1), start=mp.Value("l", 0), supersample=1,
                                        rank=rank, world_size=world)
        return [it["left"] for it in itertools.islice(iter(stream), 3)]

    single, r0, r1 = items(0, 1), items(0, 2), items(1, 2)
    # one process renders pair indices 0, 1, 2; two ranks split them: rank 0 -> 0, 2, 4 and rank 1 -> 1, 3, 5
    torch.testing.assert_close(r0[0], single[0])
    torch.testing.assert_close(r1[0], single[1])
    torch.testing.assert_close(r0[1], single[2])
    assert all(not torch.equal(a, b) for a, b in zip(r0, r1))
    with pytest.raises(ValueError, match="rank"):
        PooledCurriculumStream("data_gen", 3, 32, 64, 1, 1, False, mp.Value("i", 1), mp.Value("l", 0), rank=2,
                               world_size=2)


def test_vertical_jitter_shifts_the_right_view_by_a_fraction_of_a_row():
    from stereonet.training.data import vertical_jitter

    ramp = torch.arange(20, dtype=torch.float32).view(1, 20, 1).expand(3, 20, 16).clone()
    item = {"left": ramp.clone(), "right": ramp.clone(), "disparity": torch.ones(1, 20, 16)}
    shifts = []
    for seed in range(8):
        out = vertical_jitter(item, 1.5, torch.Generator().manual_seed(seed))
        diff = out["right"][:, 2:-2] - ramp[:, 2:-2]  # interior rows: exactly dy (bilinear on a ramp)
        assert float(diff.std()) < 1e-4 and abs(float(diff.mean())) <= 1.5
        torch.testing.assert_close(out["left"], ramp)
        shifts.append(float(diff.mean()))
    assert len({round(s, 3) for s in shifts}) == 8  # a new offset every time
    assert vertical_jitter(item, 0.0, torch.Generator()) is item


def test_vertical_warp_varies_the_offset_across_the_image_and_keeps_ground_truth():
    """``warp``: dy = a + b u + c v (u, v in [-1, 1]); on a vertical ramp the interior rows differ from the
    input by exactly that plane; warp 0 consumes no extra random numbers (the stream is unchanged)."""
    from stereonet.training.data import vertical_jitter

    h, w = 24, 20
    ramp = torch.arange(h, dtype=torch.float32).view(1, h, 1).expand(3, h, w).clone()
    item = {"left": ramp.clone(), "right": ramp.clone(), "disparity": torch.ones(1, h, w)}
    g = torch.Generator().manual_seed(3)
    out = vertical_jitter(item, 1.0, g, warp=0.8)
    diff = out["right"][0, 3:-3]  # interior rows: the plane dy(x, y)
    diff = diff - ramp[0, 3:-3]
    u = 2 * torch.arange(w) / (w - 1) - 1
    v = 2 * torch.arange(3, h - 3) / (h - 1) - 1
    A = torch.stack([torch.ones(w * (h - 6)), u.repeat(h - 6), v.repeat_interleave(w)], 1)
    coef = torch.linalg.lstsq(A.double(), diff.reshape(-1, 1).double()).solution.view(-1)
    assert float((A.double() @ coef - diff.reshape(-1).double()).abs().max()) < 1e-4  # exactly a plane
    assert abs(float(coef[0])) <= 1.0 and 0 < abs(float(coef[1])) <= 0.8 and 0 < abs(float(coef[2])) <= 0.8
    torch.testing.assert_close(out["disparity"], item["disparity"])
    plain_a = vertical_jitter(item, 1.0, torch.Generator().manual_seed(5))
    plain_b = vertical_jitter(item, 1.0, torch.Generator().manual_seed(5), warp=0.0)
    torch.testing.assert_close(plain_a["right"], plain_b["right"])


@pytest.mark.parametrize("option", ["shared_material", "weak_background"])
def test_render_probability_reaches_the_rendered_training_pairs_only(option):
    """``--data.shared_material`` (objects re-dressed) and ``--data.weak_background`` (weaker background walls): the
    training stream renders the same pairs with other images (same ground truth); validation pairs are rendered
    without it; a value outside [0, 1] is a one-line error naming the option."""
    from stereonet.checks import StereoInputError
    from stereonet.training.data import SyntheticStereoDataModule

    def first(p):
        dm = SyntheticStereoDataModule(source="data_gen", height=48, width=96, batch_size=1, pool_size=1, reuse=1,
                                       val_pairs=1, supersample=1, augment=False, **{option: p})
        dm.setup("fit")
        dm.set_progress(1.0)
        return next(iter(dm.train_dataloader())), dm.val_items[0]

    (plain, val_plain), (changed, val_changed) = first(0.0), first(1.0)
    torch.testing.assert_close(changed["disparity"], plain["disparity"])
    assert not torch.equal(changed["left"], plain["left"])
    torch.testing.assert_close(val_changed["left"], val_plain["left"])
    with pytest.raises(StereoInputError, match=f"--data.{option}"):
        SyntheticStereoDataModule(source="data_gen", **{option: 1.5})


def test_thin_structures_reach_the_rendered_training_pairs_only():
    """``--data.thin_structures``: the training stream's pairs get rods in front (their disparity only grows where
    it changes), validation pairs are rendered without them, a value outside [0, 1] is one line naming it."""
    from stereonet.checks import StereoInputError
    from stereonet.training.data import SyntheticStereoDataModule

    def first(p):
        dm = SyntheticStereoDataModule(source="data_gen", height=48, width=96, batch_size=1, pool_size=1, reuse=1,
                                       val_pairs=1, supersample=1, augment=False, thin_structures=p)
        dm.setup("fit")
        dm.set_progress(1.0)
        return next(iter(dm.train_dataloader())), dm.val_items[0]

    (plain, val_plain), (thin, val_thin) = first(0.0), first(1.0)
    both = plain["valid"] & thin["valid"]
    moved = (thin["disparity"] - plain["disparity"]).abs() > 1e-3
    assert bool(moved[both].any()) and bool((thin["disparity"] > plain["disparity"])[both & moved].all())
    torch.testing.assert_close(val_thin["left"], val_plain["left"])
    with pytest.raises(StereoInputError, match="--data.thin_structures"):
        SyntheticStereoDataModule(source="data_gen", thin_structures=1.5)


def test_render_scale_renders_larger_and_draws_windows(monkeypatch):
    """``--data.render_scale``: training pairs are rendered that many times larger, with the disparity range drawn
    for the training width, and each draw is a training-size window whose pixels matching outside the window are
    invalid; validation pairs keep their size; 1 renders at the training size; a bad value is one line."""
    import data_gen
    from stereonet.checks import StereoInputError
    from stereonet.training.data import SyntheticStereoDataModule

    rendered = []
    real_init = data_gen.SyntheticStereo.__init__

    def spy(self, *args, **kwargs):
        rendered.append((kwargs.get("height"), kwargs.get("width"), kwargs.get("max_disp")))
        real_init(self, *args, **kwargs)

    monkeypatch.setattr(data_gen.SyntheticStereo, "__init__", spy)

    def items(scale, n=3):
        dm = SyntheticStereoDataModule(source="data_gen", height=32, width=64, batch_size=1, pool_size=2, reuse=1,
                                       val_pairs=1, supersample=1, augment=False, disparity_range=24,
                                       render_scale=scale)
        dm.setup("fit")
        dm.set_progress(1.0)
        it = iter(dm.train_dataloader())
        return [next(it) for _ in range(n)], dm.val_items[0]

    rendered.clear()
    (batches, val) = items(2)
    train_renders = rendered[1:]  # the first is the validation pair
    assert rendered[0][:2] == (32, 64) and val["left"].shape[-2:] == (32, 64)
    assert train_renders and all(r[:2] == (64, 128) for r in train_renders)
    assert all(r[2] is not None and r[2] <= 24 for r in train_renders)  # the crop width's range, in pixels
    xs = torch.arange(64, dtype=torch.float32)
    for b in batches:
        assert b["left"].shape[-2:] == (32, 64) and b["disparity"].shape[-2:] == (32, 64)
        assert bool(((xs - b["disparity"] >= 0) | ~b["valid"]).all())  # matches inside the window
        assert bool((b["nonoccluded"] <= b["valid"]).all())
    plain = items(1)[0]
    monkeypatch.setattr(data_gen.SyntheticStereo, "__init__", real_init)
    again = items(1)[0]
    for a, c in zip(plain, again):
        torch.testing.assert_close(a["left"], c["left"])
    for bad in (0, 1.5, True):
        with pytest.raises(StereoInputError, match="--data.render_scale"):
            SyntheticStereoDataModule(source="data_gen", render_scale=bad)


def test_drop_textures_reaches_the_rendered_training_pairs_only(monkeypatch):
    """``--data.drop_textures``: training pairs are rendered without those texture kinds (data_gen's ``textures``
    option: the level's mix less those kinds), validation pairs with the levels' mixes; an unknown kind, or one that
    would leave a level nothing to draw, is a one-line error naming the option."""
    import data_gen
    from data_gen.scene import DIFFICULTY
    from stereonet.checks import StereoInputError
    from stereonet.training.data import SyntheticStereoDataModule

    seen = []
    real = data_gen.SyntheticStereo

    def spy(*args, **kwargs):
        seen.append(kwargs.get("textures"))
        return real(*args, **kwargs)

    monkeypatch.setattr(data_gen, "SyntheticStereo", spy)

    def first(drop):
        seen.clear()
        dm = SyntheticStereoDataModule(source="data_gen", height=48, width=96, batch_size=1, pool_size=1, reuse=1,
                                       val_pairs=1, supersample=1, augment=False, drop_textures=drop)
        dm.setup("fit")
        dm.set_progress(1.0)
        batch = next(iter(dm.train_dataloader()))
        return batch, dm.val_items[0], list(seen)

    plain, val_plain, seen_plain = first(None)
    textured, val_textured, seen_textured = first(["weak", "flat"])
    assert seen_plain == [None, None]  # validation, then the first training pair: the levels' own mixes
    level4 = {k: w for k, w in DIFFICULTY[4]["textures"].items() if k not in ("weak", "flat")}
    assert seen_textured == [None, level4]  # progress 1: difficulty 4, without weak and flat
    torch.testing.assert_close(val_textured["left"], val_plain["left"])
    for bad in (["marble"], ["bank", "bank_mix"], 3):  # difficulty 0 draws only bank and bank_mix
        with pytest.raises(StereoInputError, match="--data.drop_textures"):
            SyntheticStereoDataModule(source="data_gen", drop_textures=bad)


def test_validation_jitter_is_fixed_per_pair_and_leaves_ground_truth_alone():
    from stereonet.training.data import SyntheticStereoDataModule

    def items(v):
        dm = SyntheticStereoDataModule(source="random-shift", height=24, width=32, val_pairs=4,
                                       val_vertical_jitter=v)
        dm.setup("fit")
        return dm.val_items

    clean, a, b = items(0.0), items(1.0), items(1.0)
    for c, x, y in zip(clean, a, b):
        torch.testing.assert_close(x["right"], y["right"])  # the same offsets in every run
        torch.testing.assert_close(x["left"], c["left"])
        torch.testing.assert_close(x["disparity"], c["disparity"])
    assert sum(not torch.allclose(x["right"], c["right"]) for c, x in zip(clean, a)) >= 3


def test_refine_module_two_maps_start_at_the_first_and_log_both(one_thread):
    """bases=(siamese-census-sgm, sgm): the untrained choice is the first map (base_bad2), the second map's own
    error is logged (base2_bad2), the oracle over both maps' candidates is no worse than either; the exported
    config names the bases."""
    torch.manual_seed(0)
    batch = _one_batch()
    module = RefineModule(channels=8, dilations=(1, 2), mode="select", radii=(1, 3), target="keep",
                          bases=("siamese-census-sgm", "sgm"))
    loss, pred, extra = module.compute(batch)
    errs = disparity_errors(pred.detach(), batch["disparity"], batch["valid"])
    assert torch.allclose(errs["bad2"], extra["base_bad2"])
    assert extra["oracle_bad2"] <= min(extra["base_bad2"], extra["base2_bad2"])
    assert abs(float(loss.detach()) - math.log(34)) < 1e-5
    assert module.model_config()["bases"] == ["siamese-census-sgm", "sgm"]


def test_refine_module_decisive_target_scores_only_the_pixels_where_the_choice_matters(one_thread):
    """target="decisive" with the two maps' own values as the only candidates: the loss at the start is log 2
    (two tied candidates) over the pixels where exactly one map is right; a few steps lower it."""
    torch.manual_seed(0)
    batch = _one_batch()
    kwargs = dict(channels=8, dilations=(1, 2), mode="select", radii=(), bases=("siamese-census-sgm", "sgm"))
    module = RefineModule(target="decisive", **kwargs)
    loss, _, extra = module.compute(batch)
    assert abs(float(loss.detach()) - math.log(2)) < 1e-5
    assert extra["oracle_bad2"] <= min(extra["base_bad2"], extra["base2_bad2"])
    first, final = _fit(lambda: module.compute(batch)[0], module.parameters(), 30, 1e-2)
    assert final < first, (first, final)


def test_refine_module_cross_evidence_starts_at_log_two_and_exports_it(one_thread):
    """evidence="cross": the training step computes the bases' cross costs (untrained: the two candidates tie, loss
    log 2), a few steps lower the loss, and the exported config keeps the option."""
    torch.manual_seed(0)
    batch = _one_batch()
    module = RefineModule(channels=8, dilations=(1, 2), mode="select", radii=(), bases=("siamese-census-sgm", "sgm"),
                          target="decisive", evidence="cross")
    loss, _, _ = module.compute(batch)
    assert abs(float(loss.detach()) - math.log(2)) < 1e-5
    first, final = _fit(lambda: module.compute(batch)[0], module.parameters(), 30, 1e-2)
    assert final < first, (first, final)
    assert module.model_config()["evidence"] == "cross"


def test_balanced_nll_weighs_each_class_equally():
    """Two samples of class 0 and one of class 1: the mean of the two classes' means, not of the three samples;
    one class alone is its plain mean."""
    from stereonet.training.module import balanced_nll

    log_p = torch.tensor([-1.0, -3.0, -8.0])
    assert float(balanced_nll(log_p, torch.tensor([0, 0, 1]))) == pytest.approx((2.0 + 8.0) / 2)
    assert float(balanced_nll(log_p, torch.tensor([1, 1, 1]))) == pytest.approx(4.0)


def test_refine_module_balance_changes_the_loss_and_needs_a_one_target_choice(one_thread):
    """balance=True on the decisive pixels: the untrained tie still costs log 2 per class, so the loss is log 2;
    after a few steps the balanced and plain losses of the same network differ (the classes are not equally
    frequent); balance with target "any" or residual mode is refused naming the option."""
    torch.manual_seed(0)
    batch = _one_batch()
    kwargs = dict(channels=8, dilations=(1, 2), mode="select", radii=(), bases=("siamese-census-sgm", "sgm"),
                  target="decisive")
    module = RefineModule(balance=True, **kwargs)
    loss, _, _ = module.compute(batch)
    assert abs(float(loss.detach()) - math.log(2)) < 1e-5
    first, final = _fit(lambda: module.compute(batch)[0], module.parameters(), 30, 1e-2)
    assert final < first, (first, final)
    plain = RefineModule(**kwargs)
    plain.model.load_state_dict(module.model.state_dict())
    assert abs(float(plain.compute(batch)[0].detach()) - final) > 1e-4
    for bad in (dict(target="any"), dict(mode="residual", target="keep")):
        with pytest.raises(ValueError, match="balance"):
            RefineModule(balance=True, **{**kwargs, **bad})


def test_refine_module_filtered_bases_trains_on_filtered_maps_and_exports_them(one_thread):
    """filtered_bases=("sgm",): the step reads sgm's map after the weighted median (the logged second map's error
    is the filtered map's), the loss falls, and the exported config names the filtered bases."""
    from stereonet.matchers.learned import WMF_RADIUS, WMF_SIGMA_COLOR, refine_bases

    torch.manual_seed(0)
    batch = _one_batch()
    module = RefineModule(channels=8, dilations=(1, 2), mode="select", radii=(), bases=("siamese-census-sgm", "sgm"),
                          target="decisive", filtered_bases=("sgm",))
    _, _, extra = module.compute(batch)
    maps = torch.cat([refine_bases(("siamese-census-sgm", "sgm"), batch["left"][i:i + 1], batch["right"][i:i + 1],
                                   int(batch["max_disp"][i]) if "max_disp" in batch else 64,
                                   wmf=(WMF_RADIUS, WMF_SIGMA_COLOR), wmf_bases=("sgm",))[0]
                      for i in range(batch["left"].shape[0])])
    assert torch.allclose(extra["base2_bad2"], disparity_errors(maps[:, 1:], batch["disparity"], batch["valid"])["bad2"])
    first, final = _fit(lambda: module.compute(batch)[0], module.parameters(), 30, 1e-2)
    assert final < first, (first, final)
    assert module.model_config()["filtered_bases"] == ["sgm"]


def test_refine_checkpoints_record_the_siamese_weights_and_export_keeps_them(tmp_path):
    """RefineModule.trained_on: the digest of the installed siamese.pt when a base is Siamese-based, nothing for
    sgm alone; export_weights copies it from a checkpoint's stereonet_model into the slim file."""
    from stereonet.models.weights import default_weights_path, load_weights, weights_digest
    from stereonet.training.export import export_weights
    from stereonet.training.module import RefineModule

    if not default_weights_path("siamese").is_file():
        pytest.skip("the shipped siamese.pt is not present")
    both = RefineModule(channels=4, dilations=(1,), mode="select", radii=(), bases=("siamese-census-sgm", "sgm"))
    assert both.trained_on() == {"siamese": weights_digest(default_weights_path("siamese"))}
    assert RefineModule(channels=4, dilations=(1,)).trained_on() == {}
    checkpoint: dict = {}
    both.on_save_checkpoint(checkpoint)
    checkpoint["state_dict"] = {f"model.{k}": v for k, v in both.model.state_dict().items()}
    torch.save(checkpoint, tmp_path / "last.ckpt")
    export_weights(tmp_path / "last.ckpt", tmp_path / "refine.pt")
    assert load_weights(tmp_path / "refine.pt")[1]["trained_on"] == both.trained_on()
