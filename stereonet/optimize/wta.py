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


def select_disparity(cost: torch.Tensor, subpixel: str | None = "parabola", uniqueness: float = 0.0,
                     lr_tol: float | None = None, backend: str = "auto"
                     ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """WTA + sub-pixel + uniqueness + right-reference WTA + LR check in one call.

    ``backend="auto"`` runs one numba pass (:mod:`stereonet.optimize._select_numba`) for a float32 CPU
    volume without gradient, else the torch functions :func:`wta`, :func:`~stereonet.optimize.subpixel.
    subpixel_refine`, :func:`uniqueness_mask`, :func:`~stereonet.optimize.lr_check.wta_right` and
    :func:`~stereonet.optimize.lr_check.left_right_check`.

    Args:
        cost: :math:`(B, D, H, W)` left-reference costs.
        subpixel: ``"parabola"``, ``"equiangular"`` or None.
        uniqueness: ratio for :func:`uniqueness_mask` (0 keeps every non-tied pixel).
        lr_tol: LR-check tolerance in pixels on the integer WTA disparities (before sub-pixel refinement,
            so a refined 30.6 is not failed against a right WTA of 30), None = no check (``lr_ok`` all True).
        backend: ``"auto"``, ``"torch"`` or ``"numba"``.

    Returns:
        ``(disp, min_cost, unique, disp_right, lr_ok)``, each :math:`(B, 1, H, W)` (``unique``, ``lr_ok``
        bool; ``disp_right`` integer-valued, right-referenced).
    """
    from stereonet.optimize.lr_check import left_right_check, wta_right
    from stereonet.optimize.subpixel import subpixel_refine

    check_cost_volume(cost)
    methods = {None: 0, "parabola": 1, "equiangular": 2}
    if subpixel not in methods:
        raise StereoInputError(f"subpixel: expected 'parabola', 'equiangular' or None, got {subpixel!r}")
    if not 0.0 <= uniqueness < 1.0:
        raise StereoInputError(f"uniqueness: expected 0 <= uniqueness < 1, got {uniqueness}")
    if backend not in ("auto", "torch", "numba"):
        raise StereoInputError(f"backend: expected 'auto', 'torch' or 'numba', got {backend!r}")
    if lr_tol is not None and lr_tol < 0:
        raise StereoInputError(f"lr_tol: expected a non-negative tolerance or None, got {lr_tol}")
    use_numba = backend == "numba" or (backend == "auto" and cost.device.type == "cpu"
                                       and cost.dtype == torch.float32
                                       and not (torch.is_grad_enabled() and cost.requires_grad))
    if not use_numba:
        disp_int, min_cost = wta(cost)
        unique = uniqueness_mask(cost, disp_int, uniqueness)
        disp = subpixel_refine(cost, disp_int, subpixel) if subpixel is not None else disp_int
        disp_right = wta_right(cost)
        lr_ok = left_right_check(disp_int, disp_right, lr_tol) if lr_tol is not None else torch.ones_like(unique)
        return disp, min_cost, unique, disp_right, lr_ok
    from stereonet.optimize._select_numba import select_hwd

    outs = []
    for b in range(cost.shape[0]):
        vol = cost[b].detach().to("cpu", torch.float32).permute(1, 2, 0).contiguous().numpy()  # HxWxD, no copy
        tol = -1.0 if lr_tol is None else float(lr_tol)
        outs.append([torch.from_numpy(a) for a in select_hwd(vol, methods[subpixel], float(uniqueness), tol)])
    disp, min_cost, unique, disp_right, lr_ok = (
        (torch.stack([o[i] for o in outs]) if len(outs) > 1 else outs[0][i][None])[:, None].to(cost.device)
        for i in range(5))
    return disp.to(cost.dtype), min_cost.to(cost.dtype), unique, disp_right.to(cost.dtype), lr_ok
