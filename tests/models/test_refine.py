"""RefineNet (the network of sgm-refine) and the sgm-refine matcher."""

from __future__ import annotations

import pytest
import torch

from stereonet.checks import StereoInputError
from stereonet.models.refine import INPUT_CHANNELS, RefineNet
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


def test_sgm_refine_matcher_runs_from_a_weights_file(tmp_path):
    from stereonet.matchers import match
    from stereonet.matchers.learned import sgm_base

    net = RefineNet(channels=4, dilations=(1, 2))
    path = tmp_path / "refine.pt"
    save_weights(path, "refine", {"channels": 4, "dilations": [1, 2]}, net)
    loaded, info = load_weights(path, expected="refine")
    assert info["model"] == "refine" and isinstance(loaded, RefineNet)
    left, right = _pair(32, 64, 4)
    out = match("sgm-refine", left, right, 16, checkpoint=str(path))
    base, valid, _ = sgm_base(left, right, 16)
    assert bool(out.valid.all())
    assert torch.equal(out.disparity, base)  # untrained: sgm's filled map, every pixel
    assert out.confidence is not None and out.confidence.shape == out.disparity.shape
    with pytest.raises(StereoInputError, match="backend"):
        match("sgm-refine", left, right, 16, checkpoint=str(path), backend="onnx")
    with pytest.raises(StereoInputError, match="'refine'"):
        load_weights(path, expected="siamese")  # a refine file where another network is expected: named
