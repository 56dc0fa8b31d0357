"""LightningModules of the learned matchers: one ``_shared_step(batch, stage)`` per model family.

Batches are dicts ``{"left", "right", "disparity", "valid", ...}`` (B first). Every module logs
``{stage}/loss``, ``{stage}/epe`` and ``{stage}/bad2`` (and per-scale values where the model has scales), and
on the first validation batch TensorBoard images of the left view, ground truth, prediction and error.
Networks are stateless; losses are the pure functions of :mod:`stereonet.training.losses`.
"""

from __future__ import annotations

import math
from typing import Any

import lightning as L
import numpy as np
import torch
from torch import nn

from stereonet.checks import StereoInputError
from stereonet.models.dispnet import DispNet
from stereonet.models.penalty import PenaltyNet
from stereonet.models.refine import RefineNet, first_argmax
from stereonet.models.siamese import SiameseNet, siamese_cost_volume, siamese_pair_loss
from stereonet.models.smd import SMDNet
from stereonet.models.weights import load_weights
from stereonet.training.callbacks import trainer_progress
from stereonet.training.curriculum import training_progress
from stereonet.training.losses import (
    aggregated_cost_hinge,
    coarse_to_fine_weights,
    disparity_errors,
    edge_weights,
    mixture_nll,
    multiscale_l1_loss,
)


def _colorize(disp: torch.Tensor, max_disp: float, valid: torch.Tensor | None = None) -> np.ndarray:
    """(H, W) disparity -> (H, W, 3) uint8, through stereonet.viz when available."""
    d = disp.detach().float().cpu().numpy()
    v = None if valid is None else valid.cpu().numpy().astype(bool)
    try:
        from stereonet.viz import colorize_disparity

        return colorize_disparity(d, max_disp, v)
    except ImportError:  # viz not installed: a grey ramp is enough for TensorBoard
        g = (np.clip(d / max(max_disp, 1e-6), 0, 1) * 255).astype(np.uint8)
        return np.repeat(g[..., None], 3, axis=2)


def _error_image(pred: torch.Tensor, gt: torch.Tensor, valid: torch.Tensor) -> np.ndarray:
    p, g = (t.detach().float().cpu().numpy() for t in (pred, gt))
    v = valid.cpu().numpy().astype(bool)
    try:
        from stereonet.viz import error_map

        return error_map(p, g, v)
    except ImportError:
        e = (np.clip(np.abs(p - g) / 4.0, 0, 1) * 255 * v).astype(np.uint8)
        return np.repeat(e[..., None], 3, axis=2)


class StereoModule(L.LightningModule):
    """Shared training logic; subclasses set ``self.model`` and implement :meth:`compute`.

    Args:
        lr: AdamW learning rate (100-step linear warm-up, then cosine decay to 5% over the progress).
        weight_decay: AdamW weight decay.
        schedule_steps: horizon of every schedule (LR, loss weights) when ``trainer.max_steps`` is unset.
    """

    model_name = ""

    def __init__(self, lr: float = 1e-3, weight_decay: float = 1e-4, schedule_steps: int = 5000) -> None:
        super().__init__()
        self.model: torch.nn.Module
        self._channels_last = False  # set by use_channels_last

    # -- the model card that goes into every checkpoint, read by stereonet.models.weights.load_weights
    def model_config(self) -> dict:
        raise NotImplementedError

    def trained_on(self) -> dict:
        """Other shipped weights this network reads the outputs of: {network: its weights_digest}."""
        return {}

    def on_save_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        checkpoint["stereonet_model"] = {"model": self.model_name, "config": self.model_config()}
        trained_on = self.trained_on()
        if trained_on:
            checkpoint["stereonet_model"]["trained_on"] = trained_on

    def on_load_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        """A checkpoint of another network (``--ckpt_path`` of another config's run) is one line naming both
        networks, before Lightning's tensor-by-tensor mismatch report; an older checkpoint without the record
        loads as before."""
        held = checkpoint.get("stereonet_model", {})
        if held.get("model", self.model_name) != self.model_name:
            raise StereoInputError(f"--ckpt_path: the checkpoint holds a {held['model']!r} network; this config "
                                   f"trains a {self.model_name!r} one")
        ours = {name: tuple(t.shape) for name, t in self.state_dict().items()}
        theirs = {name: tuple(t.shape) for name, t in checkpoint.get("state_dict", {}).items()}
        if theirs and ours != theirs:
            differ = sorted(set(ours) ^ set(theirs)) or sorted(k for k in ours if ours[k] != theirs[k])
            raise StereoInputError(f"--ckpt_path: the checkpoint's {held.get('model', 'network')!r} tensors do not "
                                   f"fit this config's ({len(differ)} differ, e.g. {differ[0]!r}; checkpoint config "
                                   f"{held.get('config')}, this config {self.model_config()})")

    @property
    def progress(self) -> float:
        """Training progress in [0, 1]: steps over ``max_steps`` or time over ``max_time``, the larger."""
        if self._trainer is None:
            return training_progress(self.global_step, -1, self.hparams.schedule_steps)
        return trainer_progress(self.trainer, self.hparams.schedule_steps)

    def use_channels_last(self, enabled: bool) -> None:
        """Keep the conv weights and the input images in the channels-last (NHWC) memory format.

        Same maths, different layout: oneDNN's CPU convolutions skip a reorder per call, which made a DispNet
        training step (batch 4, 128x256, 2 threads) about 13 % faster here. Saved weights load either way.
        """
        self._channels_last = bool(enabled)
        if enabled:  # the 2-D convolutions' weights (3-D aggregation keeps its layout)
            for module in self.model.modules():
                if isinstance(module, (nn.Conv2d, nn.ConvTranspose2d)):
                    module.to(memory_format=torch.channels_last)

    def _images(self, batch: dict) -> tuple[torch.Tensor, torch.Tensor]:
        """The batch's (left, right), in the memory format chosen by :meth:`use_channels_last`."""
        left, right = batch["left"], batch["right"]
        if self._channels_last:
            left = left.contiguous(memory_format=torch.channels_last)
            right = right.contiguous(memory_format=torch.channels_last)
        return left, right

    def compute(self, batch: dict) -> tuple[torch.Tensor, torch.Tensor, dict[str, torch.Tensor]]:
        """(loss, full-resolution prediction (B,1,H,W) or None if not computed, extra scalars to log)."""
        raise NotImplementedError

    def _shared_step(self, batch: dict, stage: str) -> torch.Tensor:
        loss, pred, extra = self.compute(batch)
        bs = batch["left"].shape[0]
        on_step = stage == "train"
        self.log(f"{stage}/loss", loss.detach(), prog_bar=True, batch_size=bs, on_step=on_step, on_epoch=not on_step)
        for k, v in extra.items():
            self.log(f"{stage}/{k}", v, batch_size=bs, on_step=on_step, on_epoch=not on_step)
        if pred is None:  # a model that predicts densely only outside training (Siamese)
            return loss
        errors = disparity_errors(pred.detach(), batch["disparity"], batch["valid"])
        self.log(f"{stage}/epe", errors["epe"], prog_bar=True, batch_size=bs, on_step=on_step, on_epoch=not on_step)
        self.log(f"{stage}/bad2", errors["bad2"], batch_size=bs, on_step=on_step, on_epoch=not on_step)
        if stage == "val" and not getattr(self, "_images_logged", True):
            self._images_logged = True
            self._log_images(batch, pred)
        return loss

    def training_step(self, batch: dict, batch_idx: int) -> torch.Tensor:
        return self._shared_step(batch, "train")

    def validation_step(self, batch: dict, batch_idx: int) -> None:
        self._shared_step(batch, "val")

    def on_validation_epoch_start(self) -> None:
        self._images_logged = False

    def _log_images(self, batch: dict, pred: torch.Tensor) -> None:
        logger = self.logger
        if logger is None or not hasattr(logger.experiment, "add_image"):
            return
        gt, valid = batch["disparity"][0, 0], batch["valid"][0, 0]
        top = float(gt[valid].max()) if bool(valid.any()) else 1.0
        left = (batch["left"][0].detach().float().clamp(0, 1).cpu().numpy().transpose(1, 2, 0) * 255).astype(np.uint8)
        if left.shape[2] == 1:
            left = np.repeat(left, 3, axis=2)
        images = {"left": left, "gt": _colorize(gt, top, valid), "prediction": _colorize(pred[0, 0], top),
                  "error": _error_image(pred[0, 0], gt, valid)}
        for name, img in images.items():
            logger.experiment.add_image(f"val/{name}", img, self.global_step, dataformats="HWC")

    def configure_optimizers(self):
        opt = torch.optim.AdamW(self.parameters(), lr=self.hparams.lr, weight_decay=self.hparams.weight_decay)
        warmup = 100

        def factor(step: int) -> float:  # cosine over the training progress (steps or time, see progress)
            if step < warmup:
                return (step + 1) / warmup
            return 0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * self.progress))

        sched = torch.optim.lr_scheduler.LambdaLR(opt, factor)
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "step"}}


def _dispnet_config(max_disp: int, channels: int, aggregation: str, upsample: str, matching: str,
                    refine_radius: int = 2, agg_dilations=(1, 1, 1), refine_readout: str = "residual",
                    volume: str = "coarse") -> dict:
    """A DispNet network config (also SMD's backbone part), with ``matching``, ``refine_radius``, ``agg_dilations``,
    ``refine_readout`` and ``volume`` only when they differ from their defaults ("learned", 2, (1, 1, 1), "residual",
    "coarse"; so the weight files written before an option stay as they were; files without a key have its default)."""
    config = {"max_disp": max_disp, "channels": channels, "aggregation": aggregation, "upsample": upsample}
    if matching != "learned":
        config["matching"] = matching
    if refine_radius != 2:
        config["refine_radius"] = refine_radius
    if tuple(agg_dilations) != (1, 1, 1):
        config["agg_dilations"] = list(agg_dilations)
    if refine_readout != "residual":
        config["refine_readout"] = refine_readout
    if volume != "coarse":
        config["volume"] = volume
    return config


class DispNetModule(StereoModule):
    """Trains :class:`~stereonet.models.dispnet.DispNet` with the coarse-to-fine multi-scale L1 loss.

    Args:
        max_disp, channels, aggregation, upsample, matching, refine_radius, agg_dilations, refine_readout, volume:
            the network's (see DispNet).
        scale_weight_width: std (in scale steps) of the moving loss-weight bump.
        match_weight: weight of the L1 loss on the correlation's soft-argmin at 1/4 (``out.matched``), which
            makes the shared features learn to match instead of the decoder learning a prior.
        loss_pixels: which ground-truth pixels both losses count: "valid" (every one) or "nonoccluded" (only those
            visible in both views, the batch's ``nonoccluded``: an occluded pixel has no match to learn). The logged
            errors count every valid pixel either way.
        lr, weight_decay, schedule_steps: see :class:`StereoModule`.
        channels_last: train in the channels-last memory format (see :meth:`StereoModule.use_channels_last`).
    """

    model_name = "dispnet"

    def __init__(self, max_disp: int = 96, channels: int = 16, scale_weight_width: float = 1.0,
                 match_weight: float = 0.5, lr: float = 1e-3, weight_decay: float = 1e-4,
                 schedule_steps: int = 5000, aggregation: str = "2d", upsample: str = "bilinear",
                 channels_last: bool = False, matching: str = "learned", refine_radius: int = 2,
                 agg_dilations: list[int] | tuple[int, int, int] = (1, 1, 1),
                 refine_readout: str = "residual", loss_pixels: str = "valid", volume: str = "coarse") -> None:
        if loss_pixels not in ("valid", "nonoccluded"):
            raise StereoInputError(f"loss_pixels: expected 'valid' or 'nonoccluded', got {loss_pixels!r}")
        super().__init__(lr, weight_decay, schedule_steps)
        self.save_hyperparameters()
        self.model = DispNet(max_disp=max_disp, channels=channels, aggregation=aggregation, upsample=upsample,
                             matching=matching, refine_radius=refine_radius, agg_dilations=tuple(agg_dilations),
                             refine_readout=refine_readout, volume=volume)
        self.use_channels_last(channels_last)

    def model_config(self) -> dict:
        hp = self.hparams
        return _dispnet_config(hp.max_disp, hp.channels, hp.aggregation, hp.upsample, hp.matching,
                               hp.get("refine_radius", 2), hp.get("agg_dilations", (1, 1, 1)),
                               hp.get("refine_readout", "residual"), hp.get("volume", "coarse"))

    def forward(self, left: torch.Tensor, right: torch.Tensor):
        return self.model(left, right)

    def compute(self, batch: dict):
        out = self.model(*self._images(batch))
        weights = coarse_to_fine_weights(self.progress, len(out.pyramid), self.hparams.scale_weight_width)
        counted = (batch["valid"] if self.hparams.get("loss_pixels", "valid") == "valid"
                   else batch.get("nonoccluded", batch["valid"]))
        loss, per_scale = multiscale_l1_loss(out.pyramid, batch["disparity"], counted, weights)
        match_l1, _ = multiscale_l1_loss([out.matched], batch["disparity"], counted, [1.0])
        loss = loss + self.hparams.match_weight * match_l1
        extra = {"match_epe": disparity_errors(out.matched.detach(), batch["disparity"], batch["valid"])["epe"]}
        for scale, pred in zip(DispNet.scales, out.pyramid):
            errs = disparity_errors(pred.detach(), batch["disparity"], batch["valid"])
            extra[f"epe_s{scale}"] = errs["epe"]
            extra[f"bad2_s{scale}"] = errs["bad2"]
        return loss, out.disparity, extra


class SMDModule(StereoModule):
    """Trains :class:`~stereonet.models.smd.SMDNet`: mixture NLL + ``backbone_weight`` x multi-scale L1.

    Args:
        max_disp, channels, hidden, aggregation, upsample, matching: the network's (see SMDNet).
        backbone_weight: weight of the backbone's multi-scale L1 loss.
        init_backbone: optional DispNet weights (slim .pt or .ckpt) to start the backbone from.
        match_weight: as :class:`DispNetModule`'s, on the backbone.
        edge_weight: weight of the mixture NLL within 1 px of a ground-truth depth edge (1 = uniform); SMD-Nets
            trains its head on points sampled half near edges, where the bimodal output matters.
        channels_last: as :class:`DispNetModule`'s.
        detach_anchor: stop the mixture NLL's gradient at the backbone disparity the two modes are offsets from
            (:meth:`~stereonet.models.smd.SMDNet.query`), so that only the backbone's own L1 losses train its
            disparity and the NLL reaches the backbone through its features; same network, same inference.
        freeze_backbone: keep the ``init_backbone`` weights fixed and train the head alone by the mixture NLL (the
            backbone's L1 losses are then not computed): SMD is that very backbone plus the head, so the head's
            effect on edges is measured against the backbone trained without it. Needs ``init_backbone``.
        context, context_grey: the head's neighbourhood reach in pixels (0: off) and whether it includes the grey
            level (see :class:`~stereonet.models.smd.SMDNet`).
    """

    model_name = "smd"

    def __init__(self, max_disp: int = 96, channels: int = 16, hidden: tuple[int, ...] = (32, 16),
                 backbone_weight: float = 0.5, init_backbone: str | None = None, scale_weight_width: float = 1.0,
                 match_weight: float = 0.5, lr: float = 1e-3, weight_decay: float = 1e-4, schedule_steps: int = 5000,
                 aggregation: str = "2d", upsample: str = "bilinear", edge_weight: float = 1.0,
                 channels_last: bool = False, detach_anchor: bool = False, matching: str = "learned",
                 freeze_backbone: bool = False, context: int = 0, context_grey: bool = True) -> None:
        super().__init__(lr, weight_decay, schedule_steps)
        if edge_weight < 1.0:
            raise StereoInputError(f"edge_weight: expected >= 1, got {edge_weight}")
        if freeze_backbone and not init_backbone:
            raise StereoInputError("freeze_backbone: needs init_backbone (the DispNet weights to keep fixed)")
        self.save_hyperparameters()
        self.model = SMDNet(max_disp=max_disp, channels=channels, hidden=tuple(hidden), aggregation=aggregation,
                            upsample=upsample, matching=matching, context=context, context_grey=context_grey)
        if init_backbone:
            backbone, info = load_weights(init_backbone, expected="dispnet")
            wanted = _dispnet_config(max_disp, channels, aggregation, upsample, matching)
            if dict(info["config"]) != wanted:
                raise StereoInputError(f"init_backbone: {init_backbone!r} holds a DispNet with config {info['config']}, "
                                 f"expected {wanted}")
            self.model.backbone.load_state_dict(backbone.state_dict())
        if freeze_backbone:
            self.model.backbone.requires_grad_(False)
        self.use_channels_last(channels_last)

    def model_config(self) -> dict:
        hp = self.hparams
        config = {**_dispnet_config(hp.max_disp, hp.channels, hp.aggregation, hp.upsample, hp.matching),
                  "hidden": list(hp.hidden)}
        if hp.context:  # (files without these keys: 0, and the grey level included)
            config["context"] = hp.context
            if not hp.context_grey:
                config["context_grey"] = False
        return config

    def forward(self, left: torch.Tensor, right: torch.Tensor):
        return self.model(left, right)

    def compute(self, batch: dict):
        out = self.model(*self._images(batch), detach_anchor=self.hparams.detach_anchor)
        weight = None
        if self.hparams.edge_weight != 1.0:
            weight = edge_weights(batch["disparity"], batch["valid"], self.hparams.edge_weight)
        nll = mixture_nll(out.mixture, batch["disparity"], batch["valid"], weight)
        backbone_err = disparity_errors(out.backbone.disparity.detach(), batch["disparity"], batch["valid"])
        extra = {"nll": nll.detach(), "backbone_epe": backbone_err["epe"],
                 "uncertainty": out.uncertainty.detach().mean()}
        if self.hparams.freeze_backbone:  # the backbone is fixed: the head's NLL is the whole loss
            return nll, out.disparity, extra
        weights = coarse_to_fine_weights(self.progress, len(out.backbone.pyramid), self.hparams.scale_weight_width)
        l1, _ = multiscale_l1_loss(out.backbone.pyramid, batch["disparity"], batch["valid"], weights)
        match_l1, _ = multiscale_l1_loss([out.backbone.matched], batch["disparity"], batch["valid"], [1.0])
        l1 = l1 + self.hparams.match_weight * match_l1
        return nll + self.hparams.backbone_weight * l1, out.disparity, extra


class SiameseModule(StereoModule):
    """Trains :class:`~stereonet.models.siamese.SiameseNet` on pixel pairs sampled from ground truth.

    Validation predicts by winner-takes-all on the dot-product cost volume up to ``max_disp``.

    Args:
        channels, layers, inputs, census_window: the network's (see SiameseNet).
        loss: "hinge" (margin ranking) or "bce".
        margin, neg_low, neg_high, num_samples: see :func:`~stereonet.models.siamese.siamese_pair_loss`.
        max_disp: disparity range of the validation WTA.
        teacher: optional weights file of a trained Siamese tower (any width/depth), kept frozen and outside
            the checkpoint's state; with ``distill > 0`` the loss also pulls this network's similarities
            towards the teacher's on the sampled pairs (see :func:`~stereonet.models.siamese.siamese_pair_loss`).
        distill: weight of that term (0: plain MC-CNN training).
        init_weights: optional weights file of a Siamese tower of the same shape to start from (fine-tuning a
            data_gen-trained tower) instead of a random initialisation; a resumed run's checkpoint overrides it.
        sgm_loss: weight of a second term that trains the tower for ``siamese-census-sgm`` rather than for
            winner-takes-all on patches (0: off): the whole training pairs' learned cost volume is mixed with
            ``sgm``'s census as that matcher mixes it (``learned_weight``), aggregated by ``sgm``'s 8-path SGM with
            its penalties (the differentiable torch reference, :func:`~stereonet.aggregate.sgm.sgm_aggregate_torch`),
            and :func:`~stereonet.training.losses.aggregated_cost_hinge` asks the aggregated cost within 1 px of the
            truth to undercut every disparity >= 2 px away by ``sgm_margin`` (Hamming bits of the aggregated cost)
            on the non-occluded pixels. About 3.5 s per batch of 4 at 96x192 on 2 threads (measured alone).
        sgm_margin, learned_weight: see ``sgm_loss``.
        edge_share, edge_radius: training steps only: the share of samples drawn near depth edges, with the other
            side's disparity as their negative (:func:`~stereonet.models.siamese.sample_training_pixels`; 0 = off).
    """

    model_name = "siamese"

    def __init__(self, channels: int = 32, layers: int = 4, loss: str = "hinge", margin: float = 0.2,
                 neg_low: float = 1.5, neg_high: float = 8.0, num_samples: int = 256, max_disp: int = 64,
                 lr: float = 1e-3, weight_decay: float = 0.0, schedule_steps: int = 5000,
                 teacher: str | None = None, distill: float = 0.0, init_weights: str | None = None,
                 sgm_loss: float = 0.0, sgm_margin: float = 16.0, learned_weight: float = 0.9,
                 inputs: str = "grey", census_window: int = 5, edge_share: float = 0.0,
                 edge_radius: int = 4) -> None:
        super().__init__(lr, weight_decay, schedule_steps)
        self.save_hyperparameters()
        if not 0.0 <= edge_share <= 1.0 or edge_radius < 1:
            raise StereoInputError(f"edge_share, edge_radius: expected a share in [0, 1] and >= 1 px, got {edge_share}, "
                             f"{edge_radius}")
        if loss not in ("hinge", "bce"):
            raise StereoInputError(f"loss: expected 'hinge' or 'bce', got {loss!r}")
        if distill < 0:
            raise StereoInputError(f"distill: expected >= 0, got {distill}")
        if sgm_loss < 0 or not sgm_margin > 0 or not 0 <= learned_weight <= 1:
            raise StereoInputError(f"sgm_loss, sgm_margin, learned_weight: expected >= 0, > 0 and in [0, 1], got "
                             f"{sgm_loss}, {sgm_margin}, {learned_weight}")
        self.model = SiameseNet(channels=channels, layers=layers, inputs=inputs, census_window=census_window)
        if init_weights is not None:
            start, _ = load_weights(init_weights, expected="siamese")
            if self._shape(start) != self._shape(self.model):
                raise StereoInputError(f"init_weights: {init_weights} holds a tower of {self._shape(start)}, "
                                 f"expected {self._shape(self.model)}")
            self.model.load_state_dict(start.state_dict())
        self._teacher: list[torch.nn.Module] = []  # a list hides it from state_dict, optimiser and device moves
        if teacher is not None and distill > 0:
            net, _ = load_weights(teacher, expected="siamese")
            self._teacher.append(net.requires_grad_(False).eval())

    @staticmethod
    def _shape(net: SiameseNet) -> str:
        census = f" on {net.inputs} {net.census_window}x{net.census_window}" if net.inputs != "grey" else ""
        return f"{net.channels} channels x {net.layers} layers{census}"

    def model_config(self) -> dict:
        config = {"channels": self.hparams.channels, "layers": self.hparams.layers}
        if self.hparams.get("inputs", "grey") != "grey":  # grey files keep the older config
            config.update(inputs=self.hparams.inputs, census_window=self.hparams.census_window)
        return config

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        return self.model(image)

    def compute(self, batch: dict):
        hp = self.hparams
        valid = batch.get("nonoccluded", batch["valid"])
        teacher = None
        if self._teacher and self.training:
            teacher = self._teacher[0] = self._teacher[0].to(batch["left"].device)
        loss = siamese_pair_loss(self.model, batch["left"], batch["right"], batch["disparity"], valid,
                                 hp.num_samples, hp.margin, hp.neg_low, hp.neg_high, hp.loss,
                                 teacher=teacher, distill=hp.distill,
                                 edge_share=hp.get("edge_share", 0.0) if self.training else 0.0,
                                 edge_radius=hp.get("edge_radius", 4))
        if self.training and hp.get("sgm_loss", 0.0) > 0:
            sgm_term = self._sgm_term(batch, valid)
            return loss + hp.sgm_loss * sgm_term, None, {"sgm_hinge": sgm_term.detach()}
        if self.training:  # dense matching only where it is reported (validation): it costs more than the loss
            return loss, None, {}
        with torch.no_grad():
            b = batch["left"].shape[0]
            feats = self.model(torch.cat([batch["left"], batch["right"]]))  # 2BxFxHxW: one pass for both views
            max_disp = min(hp.max_disp, batch["left"].shape[-1] - 1)
            cost = siamese_cost_volume(feats[:b], feats[b:], max_disp)
            pred = cost.argmin(dim=1, keepdim=True).to(feats.dtype)
        return loss, pred, {}

    def _sgm_term(self, batch: dict, valid: torch.Tensor) -> torch.Tensor:
        """The ``sgm_loss`` term of a training batch (see the class doc)."""
        # matchers sit above models; only training reaches up
        from stereonet.aggregate.sgm import CENSUS_PENALTY_STEP, sgm_aggregate_torch
        from stereonet.cost.volume import build_cost_volume
        from stereonet.matchers.learned import census_mix_weights
        from stereonet.matchers.local import SGM_DEFAULTS

        hp = self.hparams
        left, right = batch["left"], batch["right"]
        b = left.shape[0]
        max_disp = min(hp.max_disp, left.shape[-1] - 1)
        feats = self.model(torch.cat([left, right]))
        learned = siamese_cost_volume(feats[:b], feats[b:], max_disp, backend="torch").clamp(max=2.0)
        with torch.no_grad():
            census = build_cost_volume(left, right, max_disp, cost="census", window=1,
                                       census_window=SGM_DEFAULTS["census_window"]).contiguous()
        w_census, w_learned = census_mix_weights(hp.learned_weight)  # as siamese-census-sgm mixes them
        mixed = w_census * census + w_learned * learned
        agg = sgm_aggregate_torch(mixed, SGM_DEFAULTS["P1"], SGM_DEFAULTS["P2"], paths=SGM_DEFAULTS["paths"],
                                  image=left, p2_alpha=SGM_DEFAULTS["p2_alpha"], penalty_step=CENSUS_PENALTY_STEP)
        return aggregated_cost_hinge(agg, batch["disparity"], valid, hp.sgm_margin)


class PenaltyModule(StereoModule):
    """Trains :class:`~stereonet.models.penalty.PenaltyNet` (learned ``P2`` maps) through ``sgm``'s aggregation.

    Each batch: ``sgm``'s own pixelwise census cost of the training pair (no gradient; the census window, ``P1``,
    ``P2`` and ``p2_alpha`` of :data:`~stereonet.matchers.local.SGM_DEFAULTS`), the network's penalty maps (the
    edge-adapted rule times its factors, in ``[P1, p2_max]``), ``sgm``'s 8-path recurrence in torch with those
    maps (:func:`~stereonet.aggregate.sgm.sgm_aggregate_maps_torch`, differentiable in the maps), and
    :func:`~stereonet.training.losses.aggregated_cost_hinge` (margin ``margin`` bits: the aggregated cost within
    1 px of the truth must undercut every disparity >= 2 px away) on the non-occluded pixels. The cost is fixed,
    so the network can only trade smoothness against the data term. Validation predicts by winner-takes-all on
    the same aggregate (``val/epe``, ``val/bad2``) and logs ``val/base_bad2``, the same with the fixed rule (the
    untrained network), so the curve shows the gain over ``sgm``'s penalties. About 0.5-1 s per batch of 4 at
    96x192 on 2 threads. With ``inputs="image+disparity"`` each pair first runs ``sgm`` (its CPU kernels, no
    gradient, the pair's own range) as the ``sgm-penalties`` matcher does at inference.

    Args:
        channels, dilations, inputs: the network's (see PenaltyNet; paths are ``sgm``'s).
        p2_max: the largest penalty (bits); at most 144 keeps ``sgm``'s 16-bit kernel exact for 7x7 census.
        margin: the hinge margin in bits of the aggregated cost.
        loss_cap: each pixel's hinge term at most this (None: the plain hinge). The first run (plain hinge) lowered
            every penalty as the renders got harder while the validation WTA got worse: a plain hinge lets the
            pixels that are wrong by far dominate, and lowering all penalties shrinks their violations; capped,
            such a pixel counts as one error (docs/experiments/sgm_penalties.txt).
        max_disp: disparity range for pairs that carry none (data_gen pairs carry their own; a batch's cost volume
            spans the largest range of its pairs, the first sgm pass each pair's own, as at inference).
    """

    model_name = "penalty"

    def __init__(self, channels: int = 16, dilations: tuple[int, ...] = (1, 2, 4, 1), p2_max: float = 144.0,
                 margin: float = 16.0, max_disp: int = 64, lr: float = 1e-3, weight_decay: float = 1e-4,
                 schedule_steps: int = 5000, inputs: str = "image", loss_cap: float | None = None) -> None:
        super().__init__(lr, weight_decay, schedule_steps)
        # matchers sit above models; only training reaches up
        from stereonet.matchers.local import SGM_DEFAULTS

        if not margin > 0:
            raise StereoInputError(f"margin: expected > 0 bits, got {margin!r}")
        if not p2_max >= SGM_DEFAULTS["P2"]:
            raise StereoInputError(f"p2_max: expected >= sgm's P2 ({SGM_DEFAULTS['P2']}), got {p2_max!r}")
        self.save_hyperparameters()
        self.model = PenaltyNet(channels=channels, dilations=tuple(dilations), paths=SGM_DEFAULTS["paths"],
                                p2_max=p2_max, inputs=inputs)

    def model_config(self) -> dict:
        return {"channels": self.hparams.channels, "dilations": list(self.hparams.dilations),
                "paths": self.model.paths, "p2_max": float(self.hparams.p2_max), "inputs": self.model.inputs}

    def compute(self, batch: dict):
        from stereonet.aggregate.sgm import (
            CENSUS_PENALTY_STEP,
            p2_maps,
            sgm_aggregate_maps_torch,
            sgm_directions,
        )
        from stereonet.cost.volume import build_cost_volume
        from stereonet.matchers.local import SGM_DEFAULTS

        hp = self.hparams
        left, right = batch["left"], batch["right"]
        b, _, h, w = left.shape
        own = batch.get("max_disp")
        max_disp = max(int(r) for r in own) if own else hp.max_disp
        max_disp = max(1, min(max_disp, w - 1))
        P1, P2, alpha = SGM_DEFAULTS["P1"], SGM_DEFAULTS["P2"], SGM_DEFAULTS["p2_alpha"]
        directions = sgm_directions(SGM_DEFAULTS["paths"])
        with torch.no_grad():
            census = build_cost_volume(left, right, max_disp, cost="census", window=1,
                                       census_window=SGM_DEFAULTS["census_window"]).contiguous()
            rule = p2_maps(P1, P2, directions, left, (b, h, w), alpha, census.dtype, census.device,
                           CENSUS_PENALTY_STEP)
        first = valid_first = None
        if self.model.inputs == "image+disparity":  # a first sgm pass per pair, with its own range, as inference
            from stereonet.matchers.learned import sgm_base

            ranges = [max(1, min(int(r), w - 1)) for r in own] if own else [max_disp] * b
            with torch.no_grad():
                parts = [sgm_base(left[i:i + 1], right[i:i + 1], ranges[i])[:2] for i in range(b)]
            first, valid_first = (torch.cat(t) for t in zip(*parts))
        maps = self.model.penalties(left, rule, P1, first, valid_first)
        agg = sgm_aggregate_maps_torch(census, P1, maps, directions)
        valid = batch.get("nonoccluded", batch["valid"])
        loss = aggregated_cost_hinge(agg, batch["disparity"], valid, hp.margin, cap=hp.get("loss_cap"))
        extra = {"p2_mean": maps.detach().mean()}
        if self.training:
            return loss, None, extra
        pred = agg.detach().argmin(dim=1, keepdim=True).to(left.dtype)
        with torch.no_grad():
            base = sgm_aggregate_maps_torch(census, P1, rule, directions).argmin(dim=1, keepdim=True).to(left.dtype)
        extra["base_bad2"] = disparity_errors(base, batch["disparity"], batch["valid"])["bad2"]
        return loss, pred, extra


TARGETS = ("any", "keep", "decisive")
"""RefineModule's select-mode targets."""


def balanced_nll(log_p: torch.Tensor, classes: torch.Tensor) -> torch.Tensor:
    """Class-balanced negative log-likelihood: the mean over the classes present in ``classes`` of the mean of
    ``-log_p`` over that class's samples (each class weighs the same whatever its share). 1-D inputs, one per
    sample; at least one sample."""
    present, inverse, counts = torch.unique(classes, return_inverse=True, return_counts=True)
    weights = 1.0 / (counts[inverse].to(log_p.dtype) * len(present))
    return -(log_p * weights).sum()


class RefineModule(StereoModule):
    """Trains :class:`~stereonet.models.refine.RefineNet` on the classical ``sgm``'s maps of the training pairs.

    Each step runs ``sgm`` (no gradient, its CPU kernels) on the batch's images exactly as the ``sgm-refine``
    matcher does at inference (:func:`stereonet.matchers.learned.sgm_base`: filled disparity, validity,
    cost-margin confidence). ``mode="residual"`` fits the refined map to the ground truth with a smooth L1 loss on
    every ground-truth pixel (occluded ones too: they are where the classical fill is weakest). ``mode="select"``
    maximises the probability (softmax over the candidates' scores) of choosing a candidate within ``tolerance``
    pixels of the ground truth, on the pixels that have one: with ``target="any"`` the loss is the log of the
    probability summed over every right candidate (the choice among them left free); with ``target="keep"`` it
    is the cross-entropy of one target per pixel, the pixel's own value when it is right, else the right candidate
    closest to the ground truth; ``target="decisive"`` is "keep" on the pixels where some candidates are right and
    some are not (where every candidate is right the choice changes nothing, and those pixels, most of an image,
    otherwise teach only "keep the first map"). "keep" matches what inference does (the top-scoring candidate): under "any" the
    mass can sit on a set of right candidates while a single wrong one scores highest (the first select run). ``base_epe`` and ``base_bad2`` log the classical map's own
    errors, so the curve shows the gain over ``sgm``; ``oracle_bad2`` (select) the best any choice could do.

    Args:
        channels, dilations, mode, radii, evidence: the network's (see RefineNet).
        max_disp: disparity range given to ``sgm`` for pairs that carry none (data_gen pairs carry their own
            ``max_disp``, the range they were rendered in, which is what a user passes at inference).
        tolerance: ``select`` only: a candidate within this many pixels of the ground truth counts as right.
        target: ``select`` only: "any", "keep" or "decisive" (see above).
        bases: the matchers whose maps the network reads (RefineNet's ``bases``; each runs on every training pair,
            ``siamese-census-sgm`` with the shipped Siamese weights, frozen).
        pair_ranges: run the base matchers with each pair's own ``max_disp`` where the batch carries it (True) or
            with ``max_disp`` for every pair (False: how the seventeenth session's ``refine.pt`` was trained, when
            training batches did not carry the field).
        filtered_bases: the bases whose maps the network reads after sgm-refine's weighted median (RefineNet's
            ``filtered_bases``; each training pair's maps are filtered as at inference).
        balance: ``select`` with target "keep" or "decisive" only: weigh the target classes (which candidate is the
            target) equally in each batch, the loss being the mean over the classes present of each class's mean
            cross-entropy (False: every pixel counts once, so the classes count by their frequency).
        lr, weight_decay, schedule_steps: see :class:`StereoModule`.
    """

    model_name = "refine"

    def __init__(self, channels: int = 16, dilations: tuple[int, ...] = (1, 2, 4, 8, 1), max_disp: int = 64,
                 mode: str = "residual", radii: tuple[int, ...] = (1, 3, 9, 27), tolerance: float = 1.0,
                 target: str = "any", bases: tuple[str, ...] = ("sgm",), lr: float = 1e-3, weight_decay: float = 1e-4,
                 schedule_steps: int = 5000, evidence: str = "pixel", pair_ranges: bool = True,
                 balance: bool = False, filtered_bases: tuple[str, ...] = ()) -> None:
        super().__init__(lr, weight_decay, schedule_steps)
        if not tolerance > 0:
            raise StereoInputError(f"tolerance: expected > 0 pixels, got {tolerance!r}")
        if target not in TARGETS:
            raise StereoInputError(f"target: expected one of {', '.join(TARGETS)}, got {target!r}")
        if balance and (mode != "select" or target == "any"):
            raise StereoInputError(f"balance: needs mode 'select' with target 'keep' or 'decisive', got mode {mode!r}, "
                             f"target {target!r}")
        self.save_hyperparameters()
        self.model = RefineNet(channels=channels, dilations=tuple(dilations), mode=mode, radii=tuple(radii),
                               bases=tuple(bases), evidence=evidence, filtered_bases=tuple(filtered_bases))

    def model_config(self) -> dict:
        config = {"channels": self.hparams.channels, "dilations": list(self.hparams.dilations)}
        if self.hparams.mode != "residual":  # residual files keep the first run's config
            config.update(mode=self.hparams.mode, radii=list(self.hparams.radii))
        if tuple(self.hparams.bases) != ("sgm",):
            config.update(bases=list(self.hparams.bases))
        if self.hparams.get("evidence", "pixel") != "pixel":  # older files have no such key
            config.update(evidence=self.hparams.evidence)
        if tuple(self.hparams.get("filtered_bases", ())):  # older files have no such key
            config.update(filtered_bases=list(self.hparams.filtered_bases))
        return config

    def trained_on(self) -> dict:
        """The shipped Siamese weights whose maps the Siamese bases gave this network (sgm-refine warns when the
        installed file differs: stereonet.matchers.learned.check_trained_on)."""
        from stereonet.models.weights import default_weights_path, weights_digest

        path = default_weights_path("siamese")
        if not any(b.startswith("siamese") for b in self.hparams.bases) or not path.is_file():
            return {}
        return {"siamese": weights_digest(path)}

    def compute(self, batch: dict):
        # matchers sit above models; only training reaches up
        from stereonet.matchers.learned import WMF_RADIUS, WMF_SIGMA_COLOR, refine_bases

        left, right = batch["left"], batch["right"]
        b, w = left.shape[0], left.shape[-1]
        own = batch.get("max_disp") if self.hparams.get("pair_ranges", True) else None
        ranges = own or [self.hparams.max_disp] * b  # each pair's own range, as eval.py gives
        ranges = [max(1, min(int(r), w - 1)) for r in ranges]
        cross = self.model.evidence == "cross"
        with torch.no_grad():
            filtered = self.model.filtered_bases
            wmf = (WMF_RADIUS, WMF_SIGMA_COLOR) if filtered else None
            parts = [refine_bases(self.model.bases, left[i:i + 1], right[i:i + 1], ranges[i], cross=cross, wmf=wmf,
                                  wmf_bases=filtered) for i in range(b)]
            base, valid, confidence, *costs = (torch.cat(t) for t in zip(*parts))
        gt, gt_valid = batch["disparity"], batch["valid"]
        scale = torch.tensor(ranges, dtype=left.dtype)
        extra = {}
        if self.hparams.mode == "select":
            scores, candidates = self.model.scores(left, right, base, valid, confidence, scale,
                                                   costs[0] if cross else None)
            right_ones = (candidates - gt).abs() <= self.hparams.tolerance
            usable = gt_valid[:, 0] & right_ones.any(1)
            if self.hparams.target == "decisive":  # only where the choice matters: some candidates right, some not
                usable &= ~right_ones.all(1)
            index = None
            if self.hparams.target in ("keep", "decisive"):  # own value if right, else the closest right candidate
                closest = (candidates - gt).abs().argmin(1)
                index = torch.where(right_ones[:, 0], torch.zeros_like(closest), closest)
                log_p = torch.log_softmax(scores, 1).gather(1, index[:, None])[:, 0]
            else:
                log_p = torch.logsumexp(scores.masked_fill(~right_ones, -1e4), 1) - torch.logsumexp(scores, 1)
            if not bool(usable.any()):
                loss = scores.sum() * 0.0
            elif self.hparams.get("balance", False):
                loss = balanced_nll(log_p[usable], index[usable])
            else:
                loss = -log_p[usable].mean()
            pred = candidates.gather(1, first_argmax(scores))
            oracle = candidates.gather(1, (candidates - gt).abs().argmin(1, keepdim=True))
            extra["oracle_bad2"] = disparity_errors(oracle, gt, gt_valid)["bad2"]
        else:
            pred = self.model(left, right, base, valid, confidence, scale)
            loss = torch.nn.functional.smooth_l1_loss(pred[gt_valid], gt[gt_valid]) if bool(gt_valid.any()) \
                else pred.sum() * 0.0
        for m in range(1, base.shape[1]):  # the further maps' own errors (the first is base_*)
            extra[f"base{m + 1}_bad2"] = disparity_errors(base[:, m:m + 1], gt, gt_valid)["bad2"]
        errs = disparity_errors(base[:, :1], gt, gt_valid)
        return loss, pred, {"base_epe": errs["epe"], "base_bad2": errs["bad2"], **extra}
