"""Winner-takes-all disparity selection and the uniqueness-ratio test."""

from __future__ import annotations

import numpy as np
import torch

from stereonet.checks import StereoInputError, check_cost_volume
from stereonet.kernels import use_numba


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


SUBPIXEL_METHODS = {None: 0, "parabola": 1, "equiangular": 2}


def selection_args(subpixel: str | None, uniqueness: float, lr_tol: float | None) -> tuple[int, float, float]:
    """Validate the selection options; returns the numba kernels' ``(method, ratio, lr_tol)`` codes
    (method 0/1/2 = none/parabola/equiangular, lr_tol -1 = no LR check)."""
    if subpixel not in SUBPIXEL_METHODS:
        raise StereoInputError(f"subpixel: expected 'parabola', 'equiangular' or None, got {subpixel!r}")
    if not 0.0 <= uniqueness < 1.0:
        raise StereoInputError(f"uniqueness: expected 0 <= uniqueness < 1, got {uniqueness}")
    if lr_tol is not None and lr_tol < 0:
        raise StereoInputError(f"lr_tol: expected a non-negative tolerance or None, got {lr_tol}")
    return SUBPIXEL_METHODS[subpixel], float(uniqueness), -1.0 if lr_tol is None else float(lr_tol)


def select_disparity(cost: torch.Tensor, subpixel: str | None = "parabola", uniqueness: float = 0.0,
                     lr_tol: float | None = None, backend: str = "auto"
                     ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """WTA + sub-pixel + uniqueness + right-reference WTA + LR check in one call.

    ``backend="auto"`` runs one numba pass (:mod:`stereonet.kernels.select`) for a float32 CPU
    volume without gradient, else the torch functions :func:`wta`, :func:`~stereonet.select.subpixel.
    subpixel_refine`, :func:`uniqueness_mask`, :func:`~stereonet.select.lr_check.wta_right` and
    :func:`~stereonet.select.lr_check.left_right_check`.

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
    from stereonet.select.lr_check import left_right_check, wta_right
    from stereonet.select.subpixel import subpixel_refine

    check_cost_volume(cost)
    method, ratio, tol = selection_args(subpixel, uniqueness, lr_tol)
    if not use_numba(cost, backend=backend):
        disp_int, min_cost = wta(cost)
        unique = uniqueness_mask(cost, disp_int, uniqueness)
        disp = subpixel_refine(cost, disp_int, subpixel) if subpixel is not None else disp_int
        disp_right = wta_right(cost)
        lr_ok = left_right_check(disp_int, disp_right, lr_tol) if lr_tol is not None else torch.ones_like(unique)
        return disp, min_cost, unique, disp_right, lr_ok
    from stereonet.kernels.select import select_hwd

    outs = []
    for b in range(cost.shape[0]):
        vol = cost[b].detach().to("cpu", torch.float32).permute(1, 2, 0).contiguous().numpy()  # HxWxD, no copy
        outs.append([torch.from_numpy(a) for a in select_hwd(vol, method, ratio, tol)])
    return _stack_selection(outs, cost.dtype, cost.device)


def select_disparity_confidence(cost: torch.Tensor, subpixel: str | None = "parabola", uniqueness: float = 0.0,
                                lr_tol: float | None = None, backend: str = "auto") -> tuple[tuple, torch.Tensor]:
    """:func:`select_disparity` and :func:`~stereonet.select.confidence.cost_margin_confidence`
    (``exclude=1``) of the same volume, in one numba pass for a float32 CPU volume without gradient
    (:func:`stereonet.kernels.select.select_confidence_hwd`, the same numbers as the two calls).

    Returns:
        ``(selection, confidence)``: the 5-tuple of :func:`select_disparity` and :math:`(B, 1, H, W)`
        confidence in [0, 1] (dtype and device of ``cost``).
    """
    from stereonet.select.confidence import cost_margin_confidence

    check_cost_volume(cost)
    method, ratio, tol = selection_args(subpixel, uniqueness, lr_tol)
    if backend not in ("auto", "torch", "numba"):
        raise StereoInputError(f"backend: expected 'auto', 'torch' or 'numba', got {backend!r}")
    numba_path = cost.shape[1] >= 2 and use_numba(cost, backend=backend)
    if not numba_path:
        return (select_disparity(cost, subpixel, uniqueness, lr_tol, backend=backend),
                cost_margin_confidence(cost, backend="torch" if backend == "torch" else "auto"))
    vols = (cost[b].detach().to("cpu", torch.float32).permute(1, 2, 0).contiguous().numpy()  # HxWxD, no copy
            for b in range(cost.shape[0]))
    return _select_confidence_hwd(vols, 1.0, method, ratio, tol, cost.dtype, cost.device)


def select_disparity_confidence_fixed(acc_hwd: list, s: int, subpixel: str | None = "parabola",
                                      uniqueness: float = 0.0, lr_tol: float | None = None,
                                      dtype: torch.dtype = torch.float32,
                                      device: torch.device | str = "cpu") -> tuple[tuple, torch.Tensor]:
    """:func:`select_disparity_confidence` of fixed-point volumes: ``acc_hwd`` a list of B int16
    ``(H, W, D)`` arrays holding ``s * cost`` (:func:`stereonet.aggregate.sgm.sgm_aggregate_fixed_hwd`). The
    same numbers as the float32 volume ``acc / s`` would give (converted exactly, row by row, inside the
    selection pass), without materialising it."""
    method, ratio, tol = selection_args(subpixel, uniqueness, lr_tol)
    return _select_confidence_hwd(acc_hwd, 1.0 / s, method, ratio, tol, dtype, torch.device(device))


def _select_confidence_hwd(vols, inv_scale: float, method: int, ratio: float, tol: float, dtype: torch.dtype,
                           device: torch.device) -> tuple[tuple, torch.Tensor]:
    """The numba pass of both selections above over B ``(H, W, D)`` arrays of costs ``vol * inv_scale``."""
    from stereonet.kernels.select import select_confidence_hwd
    from stereonet.select.confidence import EPS

    outs, confs = [], []
    for vol in vols:
        res = select_confidence_hwd(vol, method, ratio, tol, np.float32(EPS), inv_scale)
        outs.append([torch.from_numpy(a) for a in res[:5]])
        confs.append(torch.from_numpy(res[5]))
    conf = torch.stack(confs)[:, None].to(device=device, dtype=dtype)
    return _stack_selection(outs, dtype, device), conf


def _stack_selection(outs: list, dtype: torch.dtype, device: torch.device) -> tuple:
    """Per-item numpy/torch ``(disp, min_cost, unique, disp_right, lr_ok)`` (H, W) -> batched (B, 1, H, W)."""
    disp, min_cost, unique, disp_right, lr_ok = (
        (torch.stack([torch.as_tensor(o[i]) for o in outs]) if len(outs) > 1
         else torch.as_tensor(outs[0][i])[None])[:, None].to(device) for i in range(5))
    return disp.to(dtype), min_cost.to(dtype), unique, disp_right.to(dtype), lr_ok


def block_select_disparity(left: torch.Tensor, right: torch.Tensor, max_disp: int, cost: str = "sad",
                           window: int = 5, subpixel: str | None = "parabola", uniqueness: float = 0.0,
                           lr_tol: float | None = None, **cost_options
                           ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """``select_disparity(build_cost_volume(left, right, max_disp, cost, window, **cost_options), ...)``
    without building the volume: one fused numba pass per image computes each cost row with sliding
    window sums and selects on it (:func:`stereonet.kernels.block.block_cost_rows`, the same
    arithmetic as the numba volume, so the same result), then the few left-border pixels whose answer
    depends on the out-of-image cost are finished. Memory: O(W * D) per thread instead of O(H * W * D).

    Args:
        left, right: :math:`(B, C, H, W)` float images (checked here; computed in float32 on the CPU).
        max_disp, cost, window, cost_options: as :func:`stereonet.cost.build_cost_volume` (``backend`` and
            ``memory_budget`` are ignored).
        subpixel, uniqueness, lr_tol: as :func:`select_disparity`.

    Returns:
        ``(disp, min_cost, unique, disp_right, lr_ok)`` as :func:`select_disparity`, each
        :math:`(B, 1, H, W)` on the device and in the dtype of ``left``.
    """
    from stereonet.checks import check_stereo_inputs, check_window
    from stereonet.cost.volume import numba_engine_args, out_of_image_cost, run_block_engine
    from stereonet.kernels.block import MODE_SELECT, finish_border_selection

    left, right, max_disp = check_stereo_inputs(left, right, max_disp)
    window = check_window(window)
    method, ratio, tol = selection_args(subpixel, uniqueness, lr_tol)
    for key in ("backend", "memory_budget"):
        cost_options.pop(key, None)
    n_disp = max_disp + 1
    results = [run_block_engine(MODE_SELECT, numba_engine_args(left[b], right[b], cost, window, **cost_options),
                                n_disp, method, ratio, tol) for b in range(left.shape[0])]
    fill = out_of_image_cost([res[1] for res in results])
    outs = []
    for _, _, disp, min_cost, unique, disp_right, lr_ok, strip in results:
        finish_border_selection(disp, min_cost, unique, strip, n_disp, fill, method, ratio)
        outs.append((disp, min_cost, unique, disp_right, lr_ok))
    return _stack_selection(outs, left.dtype, left.device)
