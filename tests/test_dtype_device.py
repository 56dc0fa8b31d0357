"""Every registered matcher follows its input's dtype and device (issue 17 item 6): float32 and float64 on
the CPU, and on a GPU where one exists; every output tensor comes back in the input's dtype and device and
recovers a constant shift."""

from __future__ import annotations

import pytest
import torch

from stereonet import matchers
from stereonet.cli.common import weights_available


def _pair(dtype, device):
    g = torch.Generator().manual_seed(0)
    coarse = torch.rand(1, 3, 12, 34, generator=g)
    big = torch.nn.functional.interpolate(coarse, size=(48, 136), mode="bilinear", align_corners=False)
    big = 0.8 * big + 0.2 * torch.rand(big.shape, generator=g)
    left, right = big[..., 4:124], big[..., 8:128]  # left(x) = right(x - 4): disparity 4 everywhere
    return left.to(dtype=dtype, device=device).contiguous(), right.to(dtype=dtype, device=device).contiguous()


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64], ids=["float32", "float64"])
@pytest.mark.parametrize("name", matchers.available())
def test_matcher_follows_dtype_on_the_cpu(name, dtype, tmp_path):
    _check(name, dtype, "cpu", tmp_path)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no GPU on this machine (runs where torch.cuda.is_available())")
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64], ids=["float32", "float64"])
def test_every_matcher_follows_a_gpu_device(dtype, tmp_path):
    for name in matchers.available():
        _check(name, dtype, "cuda", tmp_path)


def _options(name, tmp_path) -> dict:
    """A learned matcher whose weights the project does not ship (sgm-penalties) runs a default, untrained
    network of its family from a weights file written here: dtype and device do not depend on training."""
    if weights_available(name):
        return {}
    from stereonet.matchers.learned import NETWORK_OF
    from stereonet.models.weights import build_model, save_weights

    network = NETWORK_OF[name]
    path = tmp_path / f"{network}.pt"
    save_weights(path, network, {}, build_model(network, {}))
    return {"checkpoint": str(path)}


def _check(name, dtype, device, tmp_path):
    left, right = _pair(dtype, device)
    out = matchers.match(name, left, right, 16, **_options(name, tmp_path))
    for key in ("disparity", "confidence", "uncertainty", "cost_volume"):
        t = getattr(out, key)
        if t is not None:
            assert t.dtype == dtype and t.device.type == torch.device(device).type, (key, t.dtype, t.device)
    assert out.valid.dtype == torch.bool and out.valid.device.type == torch.device(device).type
    inner = out.valid[..., 8:-8, 24:-8]
    if matchers.spec(name).kind != "learned":  # the classical ones must get this easy pair right
        err = (out.disparity[..., 8:-8, 24:-8] - 4.0).abs()[inner]
        assert inner.float().mean() > 0.5 and float(err.median()) < 0.5, name
