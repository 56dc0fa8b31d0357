"""Training losses as pure functions (no module state), and the metrics logged during training.

Metrics here run under ``no_grad`` and are never used as losses; the benchmark metrics live in
:mod:`stereonet.metrics`.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from stereonet.models.smd import MixtureParams


def masked_l1(pred: torch.Tensor, target: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """Mean ``|pred - target|`` over ``valid`` pixels; all :math:`(B, 1, H, W)`. 0 (with grad) if none valid."""
    n = valid.sum()
    diff = (pred - target).abs() * valid
    return diff.sum() / n.clamp(min=1)


def upsample_to(pred: torch.Tensor, height: int, width: int) -> torch.Tensor:
    """Bilinearly resize a prediction whose values are already in full-resolution pixels (no value rescale)."""
    if pred.shape[-2:] == (height, width):
        return pred
    return F.interpolate(pred, size=(height, width), mode="bilinear", align_corners=False)


def multiscale_l1_loss(pyramid: list[torch.Tensor], disparity: torch.Tensor, valid: torch.Tensor,
                       weights: list[float]) -> tuple[torch.Tensor, list[torch.Tensor]]:
    """DispNet multi-scale loss: sum_s weights[s] * L1(upsample(pyramid[s]), GT) over valid pixels.

    Args:
        pyramid: predictions coarse to fine, each :math:`(B, 1, H/s, W/s)` in full-resolution pixels.
        disparity, valid: ground truth and bool mask :math:`(B, 1, H, W)`.
        weights: one weight per scale.
    Returns:
        (total loss, per-scale unweighted L1 losses).
    """
    if len(weights) != len(pyramid):
        raise ValueError(f"weights: expected {len(pyramid)} values (one per scale), got {len(weights)}")
    h, w = disparity.shape[-2:]
    per_scale = [masked_l1(upsample_to(p, h, w), disparity, valid) for p in pyramid]
    total = sum(wt * l for wt, l in zip(weights, per_scale))
    return total, per_scale


def coarse_to_fine_weights(progress: float, n_scales: int, width: float = 1.0, floor: float = 0.05) -> list[float]:
    """Multi-scale loss weights that move from the coarsest scale (progress 0) to the finest (progress 1).

    A Gaussian bump of std ``width`` (in scale steps) centred at ``progress * (n_scales - 1)`` plus ``floor``,
    normalised to sum 1. Index 0 is the coarsest scale.
    """
    centre = min(max(progress, 0.0), 1.0) * (n_scales - 1)
    raw = [math.exp(-0.5 * ((i - centre) / width) ** 2) + floor for i in range(n_scales)]
    total = sum(raw)
    return [r / total for r in raw]


def bimodal_laplacian_nll(mu1: torch.Tensor, mu2: torch.Tensor, b1: torch.Tensor, b2: torch.Tensor,
                          pi: torch.Tensor, target: torch.Tensor, valid: torch.Tensor,
                          weight: torch.Tensor | None = None) -> torch.Tensor:
    """Mean negative log-likelihood of ``target`` under a bimodal Laplacian mixture, over ``valid`` pixels.

    ``p(d) = pi/(2 b1) exp(-|d-mu1|/b1) + (1-pi)/(2 b2) exp(-|d-mu2|/b2)``; every argument :math:`(B, 1, H, W)`,
    ``b1, b2 > 0``, ``pi`` in (0, 1). Computed with logsumexp (stable for small b). ``weight`` (same shape,
    >= 0) makes it a weighted mean over the valid pixels.
    """
    eps = torch.finfo(pi.dtype).eps  # keeps log(pi) finite when the sigmoid saturates
    log_p1 = torch.log(pi.clamp(min=eps)) - torch.log(2 * b1) - (target - mu1).abs() / b1
    log_p2 = torch.log((1 - pi).clamp(min=eps)) - torch.log(2 * b2) - (target - mu2).abs() / b2
    nll = -torch.logsumexp(torch.stack([log_p1, log_p2]), dim=0)
    valid_f = valid.to(nll.dtype)
    if weight is not None:
        valid_f = valid_f * weight.to(nll.dtype)
    return (nll * valid_f).sum() / valid_f.sum().clamp(min=1e-6)


def edge_weights(target: torch.Tensor, valid: torch.Tensor, edge_weight: float, width: int = 3) -> torch.Tensor:
    """Per-pixel loss weights :math:`(B, 1, H, W)`: ``edge_weight`` within a ``width`` x ``width`` box of a
    ground-truth depth discontinuity (a jump > 1 px), 1 elsewhere (SMD-Nets samples half of its training
    points near such edges; weighting is the dense equivalent)."""
    from stereonet.metrics import depth_discontinuities

    edges = depth_discontinuities(target.detach(), valid, threshold=1.0, dilation=width)
    return 1.0 + (float(edge_weight) - 1.0) * edges.to(target.dtype)


def mixture_nll(mix: MixtureParams, target: torch.Tensor, valid: torch.Tensor,
                weight: torch.Tensor | None = None) -> torch.Tensor:
    """:func:`bimodal_laplacian_nll` of a :class:`~stereonet.models.smd.MixtureParams`."""
    return bimodal_laplacian_nll(mix.mu1, mix.mu2, mix.b1, mix.b2, mix.pi, target, valid, weight)


@torch.no_grad()
def disparity_errors(pred: torch.Tensor, target: torch.Tensor, valid: torch.Tensor) -> dict[str, torch.Tensor]:
    """End-point error (mean |pred - GT| over valid pixels) and bad-2 (% of valid pixels with error > 2 px).

    pred, target, valid: :math:`(B, 1, H, W)`; a coarser prediction whose values are already in the target's
    pixels (a pyramid level) is upsampled bilinearly first.
    """
    pred = upsample_to(pred, target.shape[-2], target.shape[-1])
    err = (pred - target).abs()[valid]
    if err.numel() == 0:
        zero = pred.new_zeros(())
        return {"epe": zero, "bad2": zero}
    return {"epe": err.mean(), "bad2": (err > 2.0).float().mean() * 100.0}


def aggregated_cost_hinge(cost: torch.Tensor, target: torch.Tensor, valid: torch.Tensor, margin: float,
                          near: float = 1.0, far: float = 2.0, cap: float | None = None) -> torch.Tensor:
    """Hinge on a (for instance SGM-aggregated) cost volume: the winner-takes-all choice should fall near the
    ground truth.

    Per valid pixel, ``relu(margin + min_{|d - gt| < near} C(d) - min_{|d - gt| >= far} C(d)) / margin``: the best
    cost among the disparities within ``near`` px of the truth must undercut every disparity at least ``far`` px
    away by ``margin`` (cost units). Disparities in between are neither; pixels whose truth lies outside the
    volume's range are left out. ``cap``: each pixel's term is at most this (a ramp: a pixel that is wrong by
    more than ``(cap - 1) * margin`` counts as one error and pulls no further; None = the plain hinge). ``cost`` :math:`(B, D, H, W)`, lower = better; ``target``, ``valid``
    :math:`(B, 1, H, W)`. Returns the mean over the used pixels (0 when there are none).
    """
    if not margin > 0 or not 0 < near <= far or not (cap is None or cap > 0):
        raise ValueError(f"margin, near, far, cap: expected margin > 0, 0 < near <= far and cap > 0 or None, got "
                         f"{margin}, {near}, {far}, {cap}")
    d = torch.arange(cost.shape[1], device=cost.device, dtype=cost.dtype).view(1, -1, 1, 1)
    dist = (d - target).abs()  # BxDxHxW
    inf = torch.tensor(float("inf"), device=cost.device, dtype=cost.dtype)
    good = torch.where(dist < near, cost, inf).amin(1, keepdim=True)
    bad = torch.where(dist >= far, cost, inf).amin(1, keepdim=True)
    used = valid & torch.isfinite(good) & torch.isfinite(bad) & (target <= cost.shape[1] - 1)
    if not bool(used.any()):
        return cost.new_zeros(()) * cost.sum()  # keeps the graph
    terms = torch.relu(margin + good - bad)[used] / margin
    return (terms if cap is None else terms.clamp(max=cap)).mean()
