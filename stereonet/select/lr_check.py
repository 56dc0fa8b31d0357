"""Left-right consistency: right-reference costs from the same volume and the LR check."""

from __future__ import annotations

import torch

from stereonet.checks import check_cost_volume, check_number, check_shape
from stereonet.kernels import use_numba

LR_TOL = 1.0
"""The one left-right rule's tolerance in pixels (``left_right_check``'s default)."""


def right_cost_volume(cost: torch.Tensor) -> torch.Tensor:
    """Right-reference volume from a left-reference one: ``cost_right[:, d, y, x] = cost[:, d, y, x + d]``.

    Positions with ``x + d >= W`` (left pixel outside the image) get ``max(cost) + 1``.

    Args:
        cost: :math:`(B, D, H, W)` left-referenced.

    Returns:
        :math:`(B, D, H, W)` right-referenced (``x_left = x_right + d``).
    """
    check_cost_volume(cost)
    b, n, h, w = cost.shape
    fill = float(cost.detach().amax()) + 1.0
    out = torch.full_like(cost, fill)
    for d in range(n):
        out[:, d, :, : w - d] = cost[:, d, :, d:]
    return out


def wta_right(cost: torch.Tensor) -> torch.Tensor:
    """WTA right-reference disparity of a *left-reference* volume without building the right volume.

    Args:
        cost: :math:`(B, D, H, W)` left-referenced.

    Returns:
        :math:`(B, 1, H, W)` integer-valued right-reference disparity ``disparity_right`` (dtype of cost);
        ties resolve to the smallest disparity. A float32 CPU volume runs the numba kernel
        :func:`stereonet.kernels.select.wta_right_hwd` (one pass, same result).
    """
    check_cost_volume(cost)
    b, n, h, w = cost.shape
    if use_numba(cost):
        from stereonet.kernels.select import wta_right_hwd

        outs = [torch.from_numpy(wta_right_hwd(cost[i].detach().permute(1, 2, 0).contiguous().numpy()))
                for i in range(b)]
        return torch.stack(outs)[:, None]
    best = cost[:, 0].clone()  # BxHxW, d = 0 always valid
    arg = torch.zeros_like(best)
    for d in range(1, min(n, w)):
        cand = cost[:, d, :, d:]
        better = cand < best[..., : w - d]
        best[..., : w - d] = torch.where(better, cand, best[..., : w - d])
        arg[..., : w - d] = torch.where(better, torch.full_like(cand, float(d)), arg[..., : w - d])
    return arg.unsqueeze(1)


def left_right_difference(disp_left: torch.Tensor, disp_right: torch.Tensor) -> torch.Tensor:
    """How far the two views disagree at each left pixel: ``|dL - disp_right(xr)|`` with ``xr = round(x - dL)``,
    ``+inf`` where ``xr`` falls outside the right image or ``dL`` is NaN (NaN where ``disp_right(xr)`` is).

    The quantity :func:`left_right_check` thresholds; on its own a classical confidence for any matcher that can
    run with either view as the reference (lower = more trustworthy).

    Args:
        disp_left: :math:`(B, 1, H, W)` left-reference disparity.
        disp_right: :math:`(B, 1, H, W)` right-reference disparity (``x_left = x_right + d``).

    Returns:
        :math:`(B, 1, H, W)` in the dtype of ``disp_left``.
    """
    dims = check_shape(disp_left, ["B", "1", "H", "W"], "disp_left")
    check_shape(disp_right, [str(dims["B"]), "1", str(dims["H"]), str(dims["W"])], "disp_right")
    diff, inside, _ = _difference(disp_left, disp_right)
    return torch.where(inside, diff, torch.full_like(diff, float("inf")))


def _difference(disp_left: torch.Tensor, disp_right: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Of checked maps: ``|dL - disp_right(xr)|`` (any value where ``xr`` is outside), whether ``xr`` is inside the
    right image, and ``xr`` clamped into it (the gather index)."""
    w = disp_left.shape[-1]
    x = torch.arange(w, device=disp_left.device, dtype=disp_left.dtype).view(1, 1, 1, -1)
    xr = torch.round(x - disp_left)
    inside = (xr >= 0) & (xr <= w - 1)
    idx = torch.nan_to_num(xr, nan=0.0).clamp(0, w - 1).long()  # a NaN disparity matches nothing (inside False)
    return (disp_left - disp_right.gather(3, idx)).abs(), inside, idx


def left_right_check(disp_left: torch.Tensor, disp_right: torch.Tensor, tol: float = LR_TOL,
                     valid_right: torch.Tensor | None = None) -> torch.Tensor:
    """The one left-right consistency rule (matchers, and ground-truth occlusion in the dataset readers and
    the training data).

    A left pixel ``x`` with disparity ``dL`` passes when its match ``xr = round(x - dL)`` is inside the right
    image, the right disparity is known there (``valid_right``, when given) and ``|dL - disp_right(xr)| <= tol``.
    Failing pixels are occluded or mismatched.

    Args:
        disp_left: :math:`(B, 1, H, W)` left-reference disparity.
        disp_right: :math:`(B, 1, H, W)` right-reference disparity (``x_left = x_right + d``).
        tol: tolerance in pixels.
        valid_right: optional bool :math:`(B, 1, H, W)` mask of known right disparities.

    Returns:
        bool :math:`(B, 1, H, W)`, True = consistent.
    """
    dims = check_shape(disp_left, ["B", "1", "H", "W"], "disp_left")
    check_shape(disp_right, [str(dims["B"]), "1", str(dims["H"]), str(dims["W"])], "disp_right")
    check_number(tol, "tol", allow_inf=True)  # px; NaN fails
    diff, inside, idx = _difference(disp_left, disp_right)
    consistent = inside & (diff <= tol)
    if valid_right is not None:
        check_shape(valid_right, [str(dims["B"]), "1", str(dims["H"]), str(dims["W"])], "valid_right")
        consistent &= valid_right.gather(3, idx)
    return consistent
