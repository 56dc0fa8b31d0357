"""PenaltyNet (learned SGM penalties), sgm's given penalty maps, and the sgm-penalties matcher."""

from __future__ import annotations

import pytest
import torch

from stereonet.aggregate.sgm import (
    CENSUS_PENALTY_STEP,
    p2_maps,
    quantize_penalty,
    sgm_aggregate,
    sgm_aggregate_maps_torch,
    sgm_directions,
)
from stereonet.checks import StereoInputError
from stereonet.matchers import match
from stereonet.models.penalty import PenaltyNet
from stereonet.models.weights import load_weights, save_weights


def _pair(h=24, w=40, d=3, seed=0):
    g = torch.Generator().manual_seed(seed)
    right = torch.rand(1, 3, h, w + d, generator=g)
    left = right[..., :w].clone()
    right = right[..., d:d + w].clone()  # x_right = x_left - d
    return left, right


def _random_maps(b, paths, h, w, seed=0, low=2.0, high=100.0):
    g = torch.Generator().manual_seed(seed)
    return quantize_penalty(low + (high - low) * torch.rand(b, paths, h, w, generator=g), CENSUS_PENALTY_STEP)


def test_untrained_network_is_sgms_rule_and_penalties_stay_in_range():
    torch.manual_seed(0)
    net = PenaltyNet(channels=4, dilations=(1, 2), paths=8, p2_max=100.0)
    left, _ = _pair()
    b, _, h, w = left.shape
    rule = p2_maps(2.0, 48.0, sgm_directions(8), left, (b, h, w), 20.0, torch.float32, left.device, CENSUS_PENALTY_STEP)
    assert torch.equal(net.penalties(left, rule, 2.0), rule)  # zero head: factor exp(0) = 1
    torch.nn.init.normal_(net.head.weight, std=10.0)  # any factors: clamped to [P1, p2_max]
    with torch.no_grad():
        maps = net.penalties(left, rule, 2.0)
    assert maps.shape == rule.shape and float(maps.min()) >= 2.0 and float(maps.max()) <= 100.0
    assert not torch.equal(maps, rule)
    with pytest.raises(StereoInputError, match="rule"):
        net.penalties(left, rule[:, :4], 2.0)


def test_given_maps_aggregate_the_same_in_torch_and_numba_and_carry_gradients():
    g = torch.Generator().manual_seed(1)
    cost = torch.randint(0, 49, (1, 9, 13, 17), generator=g).float()
    directions = sgm_directions(8)
    maps = _random_maps(1, 8, 13, 17)
    ref = sgm_aggregate(cost, 2.0, 48.0, 8, backend="torch", penalty_step=CENSUS_PENALTY_STEP, p2_maps=maps)
    fast = sgm_aggregate(cost, 2.0, 48.0, 8, backend="numba", penalty_step=CENSUS_PENALTY_STEP, p2_maps=maps)
    assert torch.equal(ref, fast)
    # the maps replace the rule: a constant map of P2 is sgm without the image adaptation
    flat = torch.full_like(maps, 48.0)
    assert torch.equal(sgm_aggregate(cost, 2.0, 48.0, 8, backend="torch", p2_maps=flat),
                       sgm_aggregate(cost, 2.0, 48.0, 8, backend="torch"))
    learned = maps.clone().requires_grad_(True)
    sgm_aggregate_maps_torch(cost, 2.0, learned, directions).amin(1).sum().backward()
    assert learned.grad is not None and float(learned.grad.abs().sum()) > 0
    with pytest.raises(StereoInputError, match="p2_maps"):
        sgm_aggregate(cost, 2.0, 48.0, 8, backend="torch", p2_maps=maps[:, :4])


def test_sgm_with_given_maps_is_the_same_on_every_path():
    """The 16-bit CPU path, the float32 kernel (keep_volume) and the torch backend give the same disparities
    with given maps, and maps equal to the rule give sgm's own result."""
    left, right = _pair(32, 64, 4, seed=2)
    maps = _random_maps(1, 8, 32, 64, seed=3, high=140.0)
    fast = match("sgm", left, right, 16, p2_maps=maps)
    kept = match("sgm", left, right, 16, p2_maps=maps, keep_volume=True)
    ref = match("sgm", left, right, 16, p2_maps=maps, backend="torch")
    assert torch.equal(fast.disparity, kept.disparity) and torch.equal(fast.disparity, ref.disparity)
    assert torch.equal(fast.valid, ref.valid)
    plain = match("sgm", left, right, 16)
    assert not torch.equal(fast.disparity, plain.disparity)
    b, _, h, w = left.shape
    rule = p2_maps(2.0, 48.0, sgm_directions(8), left, (b, h, w), 20.0, torch.float32, left.device, CENSUS_PENALTY_STEP)
    same = match("sgm", left, right, 16, p2_maps=rule)
    assert torch.equal(same.disparity, plain.disparity) and torch.equal(same.valid, plain.valid)
    with pytest.raises(StereoInputError, match="p2_maps"):
        match("sgm", left, right, 16, p2_maps=maps[..., :10])
    with pytest.raises(StereoInputError, match="p2_maps"):
        match("sgm", left, right, 16, p2_maps=torch.ones_like(maps))  # below P1


def test_sgm_penalties_matcher_from_a_weights_file(tmp_path):
    net = PenaltyNet(channels=4, dilations=(1, 2))
    path = tmp_path / "penalty.pt"
    config = {"channels": 4, "dilations": [1, 2], "paths": 8, "p2_max": 144.0}
    save_weights(path, "penalty", config, net)
    loaded, info = load_weights(path, expected="penalty")
    assert info["model"] == "penalty" and isinstance(loaded, PenaltyNet) and loaded.p2_max == 144.0
    left, right = _pair(32, 64, 4, seed=4)
    out = match("sgm-penalties", left, right, 16, checkpoint=str(path))
    plain = match("sgm", left, right, 16)
    assert torch.equal(out.disparity, plain.disparity)  # untrained: exactly sgm
    assert torch.equal(out.valid, plain.valid) and torch.equal(out.confidence, plain.confidence)
    torch.nn.init.normal_(net.head.weight, std=1.0)
    save_weights(path, "penalty", config, net)
    changed = match("sgm-penalties", left, right, 16, checkpoint=str(path))
    assert not torch.equal(changed.disparity, plain.disparity)
    with pytest.raises(StereoInputError, match="paths"):
        match("sgm-penalties", left, right, 16, checkpoint=str(path), paths=4)
    with pytest.raises(StereoInputError, match="p2_maps"):
        match("sgm-penalties", left, right, 16, checkpoint=str(path), p2_maps=None)
    with pytest.raises(StereoInputError, match="backend"):
        match("sgm-penalties", left, right, 16, checkpoint=str(path), backend="onnx")
    with pytest.raises(StereoInputError, match="'penalty'"):
        load_weights(path, expected="siamese")  # a penalty file where another network is expected: named


def test_penalty_module_step_trains_the_network():
    """One training batch: a finite hinge, gradients on the head, and a validation pass with the rule's bad-2."""
    from stereonet.training.module import PenaltyModule

    torch.manual_seed(0)
    module = PenaltyModule(channels=4, dilations=(1,), max_disp=8)
    left, right = _pair(24, 48, 3, seed=5)
    disp = torch.full((1, 1, 24, 48), 3.0)
    batch = {"left": left, "right": right, "disparity": disp, "valid": torch.ones_like(disp, dtype=torch.bool)}
    module.train()
    loss, pred, extra = module.compute(batch)
    assert pred is None and torch.isfinite(loss)
    loss.backward()
    assert float(module.model.head.weight.grad.abs().sum()) > 0
    module.eval()
    with torch.no_grad():
        _, pred, extra = module.compute(batch)
    assert pred.shape == disp.shape and "base_bad2" in extra
    assert module.model_config() == {"channels": 4, "dilations": [1], "paths": 8, "p2_max": 144.0, "inputs": "image"}


def test_disparity_jumps_and_a_network_that_reads_a_first_pass(tmp_path):
    from stereonet.models.penalty import JUMP_CLIP, disparity_jumps

    disp = torch.zeros(1, 1, 5, 6)
    disp[..., 3:] = 20.0  # a vertical depth edge between x = 2 and x = 3
    jumps = disparity_jumps(disp, sgm_directions(8))
    assert jumps.shape == (1, 8, 5, 6)
    assert float(jumps[0, 0, :, 3].min()) == JUMP_CLIP and float(jumps[0, 0, :, 4].max()) == 0.0  # (1, 0): from x-1
    assert float(jumps[0, 1, :, 2].min()) == JUMP_CLIP and float(jumps[0, 1, :, 3].max()) == 0.0  # (-1, 0): from x+1
    assert float(jumps[0, 2].max()) == 0.0  # (0, 1): from y-1, no edge across rows
    net = PenaltyNet(channels=4, dilations=(1,), inputs="image+disparity")
    with pytest.raises(StereoInputError, match="disparity"):
        net(torch.rand(1, 3, 5, 6))
    with pytest.raises(StereoInputError, match="inputs"):
        PenaltyNet(inputs="census")
    path = tmp_path / "penalty.pt"
    config = {"channels": 4, "dilations": [1], "paths": 8, "p2_max": 144.0, "inputs": "image+disparity"}
    save_weights(path, "penalty", config, net)
    left, right = _pair(32, 64, 4, seed=6)
    out = match("sgm-penalties", left, right, 16, checkpoint=str(path))
    plain = match("sgm", left, right, 16)
    assert torch.equal(out.disparity, plain.disparity)  # untrained: exactly sgm, after a first pass
    torch.nn.init.normal_(net.head.weight, std=1.0)
    save_weights(path, "penalty", config, net)
    assert not torch.equal(match("sgm-penalties", left, right, 16, checkpoint=str(path)).disparity, plain.disparity)
    from stereonet.training.module import PenaltyModule

    module = PenaltyModule(channels=4, dilations=(1,), max_disp=8, inputs="image+disparity")
    d = torch.full((1, 1, 32, 64), 4.0)
    batch = {"left": left, "right": right, "disparity": d, "valid": torch.ones_like(d, dtype=torch.bool)}
    loss, _, _ = module.compute(batch)
    loss.backward()
    assert float(module.model.head.weight.grad.abs().sum()) > 0
