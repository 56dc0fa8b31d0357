"""Model files: build a network from its name and config, load/save weights with clear errors.

Two formats are read:
  * slim weight files (``stereonet/weights/<name>.pt``): ``{"format": FORMAT, "model": name, "config": {...},
    "state_dict": {...}}`` written by :func:`save_weights` (or ``python -m stereonet.training.export``);
  * Lightning checkpoints (``*.ckpt``) written by ``train.py``: the LightningModule stores the same
    ``{"model", "config"}`` under ``checkpoint["stereonet_model"]`` and the network's tensors under
    ``state_dict`` with the prefix ``model.``.

This module does not import Lightning (the registry uses it at inference time).
"""

from __future__ import annotations

import os
from pathlib import Path

import torch
from torch import nn

from stereonet.checks import StereoInputError
from stereonet.io.atomic import atomic_path
from stereonet.models.dispnet import DispNet
from stereonet.models.penalty import PenaltyNet
from stereonet.models.refine import RefineNet
from stereonet.models.siamese import SiameseNet
from stereonet.models.smd import SMDNet

FORMAT = "stereonet-weights-v1"
MODEL_CLASSES: dict[str, type[nn.Module]] = {"dispnet": DispNet, "smd": SMDNet, "siamese": SiameseNet,
                                             "refine": RefineNet, "penalty": PenaltyNet}
WEIGHTS_DIR_ENV = "STEREONET_WEIGHTS_DIR"


def weights_dir() -> Path:
    """Folder of the shipped weights: ``$STEREONET_WEIGHTS_DIR``, else the package data folder
    ``stereonet/weights`` (found with :mod:`importlib.resources`, so an installed wheel has them too)."""
    env = os.environ.get(WEIGHTS_DIR_ENV)
    if env:
        return Path(env)
    from importlib.resources import files

    return Path(str(files("stereonet") / "weights"))


def default_weights_path(model: str) -> Path:
    """``weights/<model>.pt`` if present, else ``weights/<model>.ckpt`` (which may not exist either)."""
    slim = weights_dir() / f"{model}.pt"
    return slim if slim.exists() else weights_dir() / f"{model}.ckpt"


def weights_digest(path: str | os.PathLike) -> str:
    """SHA-256 of a weights file's network tensors (names, dtypes, shapes and values, in name order): the same for
    the same weights however the file was written (a slim file, a checkpoint, other metadata)."""
    import hashlib

    net, _ = load_weights(path)
    digest = hashlib.sha256()
    for name, tensor in sorted(net.state_dict().items()):
        t = tensor.detach().cpu().contiguous()
        digest.update(f"{name}:{t.dtype}:{tuple(t.shape)};".encode())
        digest.update(t.numpy().tobytes())
    return digest.hexdigest()


def build_model(model: str, config: dict) -> nn.Module:
    """Instantiate the network called ``model`` ("dispnet", "smd", "siamese", "refine", "penalty") with keyword ``config``."""
    if model not in MODEL_CLASSES:
        raise StereoInputError(f"model: unknown network {model!r}; valid names: {', '.join(MODEL_CLASSES)}")
    return MODEL_CLASSES[model](**config)


def _read(path: Path) -> dict:
    if not path.is_file():
        raise FileNotFoundError(
            f"checkpoint: weights file {str(path)!r} not found; train one with `python train.py fit --config "
            f"configs/<model>.yaml` and export it, or pass checkpoint=PATH")
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # corrupt file, or a pickle with arbitrary objects: refuse to execute it
        raise StereoInputError(f"checkpoint: {str(path)!r} is not a readable stereonet weights file ({e})") from e
    if not isinstance(data, dict) or ("stereonet_model" not in data and data.get("format") != FORMAT):
        raise StereoInputError(f"checkpoint: {str(path)!r} is not a stereonet weights file or checkpoint "
                               f"(no model name/config inside)")
    return data


def load_weights(path: str | os.PathLike, expected: str | None = None) -> tuple[nn.Module, dict]:
    """Load a slim weights file or a Lightning checkpoint; returns (network in eval mode, info dict).

    Raises FileNotFoundError when ``path`` is missing, StereoInputError when it holds another model than
    ``expected`` or tensors of the wrong shape (the message names both).
    """
    path = Path(path)
    data = _read(path)
    if "stereonet_model" in data:  # Lightning checkpoint
        info = data["stereonet_model"]
        state = {k[len("model."):]: v for k, v in data["state_dict"].items() if k.startswith("model.")}
    else:
        info = {"model": data["model"], "config": data["config"]}
        state = data["state_dict"]
    if expected is not None and info["model"] != expected:
        raise StereoInputError(f"checkpoint: expected a {expected!r} model, got a {info['model']!r} one in {str(path)!r}")
    try:
        net = build_model(info["model"], dict(info["config"]))
    except TypeError as e:  # a config key this version's network does not take (a newer or older file)
        raise StereoInputError(f"checkpoint: {str(path)!r} holds a {info['model']!r} network whose config "
                               f"{sorted(info['config'])} this version cannot build ({e})") from e
    try:
        net.load_state_dict(state, strict=True)
    except RuntimeError as e:
        raise StereoInputError(f"checkpoint: {str(path)!r} does not fit a {info['model']!r} network with config "
                               f"{info['config']}: {e}") from e
    net.eval()
    return net, {**info, **{k: v for k, v in data.items() if k in ("trained", "notes", "trained_on")}}


def save_weights(path: str | os.PathLike, model: str, config: dict, net: nn.Module, **extra) -> None:
    """Write a slim weights file atomically (float32 tensors, no optimizer state)."""
    state = {k: v.detach().cpu().float().clone() if v.is_floating_point() else v.detach().cpu().clone()
             for k, v in net.state_dict().items()}
    with atomic_path(path) as tmp:
        torch.save({"format": FORMAT, "model": model, "config": config, "state_dict": state, **extra}, tmp)
