"""Winner-takes-all disparity selection and the uniqueness-ratio test."""

from __future__ import annotations

import torch

from stereonet.checks import StereoInputError, check_cost_volume


def wta(cost: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Winner-takes-all: the disparity of the lowest cost per pixel (ties: the smallest disparity).

    Args:
        cost: :math:`(B, D, H, W)`, lower = better.

    Returns:
        ``(disp, min_cost)``: :math:`(B, 1, H, W)` float disparity (integer values, dtype of ``cost``) and
        the minimal cost :math:`(B, 1, H, W)`.
    """
    check_cost_volume(cost)
    min_cost, idx = cost.min(dim=1, keepdim=True)
    return idx.to(cost.dtype), min_cost


def uniqueness_mask(cost: torch.Tensor, disp: torch.Tensor, ratio: float = 0.1) -> torch.Tensor:
    """Uniqueness test (as OpenCV's ``uniquenessRatio`` / 100): the best cost must beat every cost at
    ``|d - disp| > 1`` by a margin: ``best <= (1 - ratio) * second_best``.

    Args:
        cost: :math:`(B, D, H, W)` non-negative costs.
        disp: :math:`(B, 1, H, W)` integer-valued WTA disparity (e.g. from :func:`wta`).
        ratio: margin in [0, 1); 0 accepts every pixel whose best is not tied.

    Returns:
        bool :math:`(B, 1, H, W)`, True = unique.
    """
    check_cost_volume(cost)
    if not 0.0 <= ratio < 1.0:
        raise StereoInputError(f"ratio: expected 0 <= ratio < 1, got {ratio}")
    d = torch.arange(cost.shape[1], device=cost.device).view(1, -1, 1, 1)
    far = (d - disp.round().long()).abs() > 1  # BxDxHxW
    best = cost.gather(1, disp.round().long().clamp(0, cost.shape[1] - 1))
    second = cost.masked_fill(~far, float("inf")).amin(dim=1, keepdim=True)
    return best <= (1.0 - ratio) * second
