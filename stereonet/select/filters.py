"""Post-filters for disparity maps: median filter and speckle (small connected component) removal."""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from stereonet.checks import StereoInputError, check_shape, check_window
from stereonet.kernels import use_numba
from stereonet.kernels.filters import median_kernel, speckle_kernel


def median_filter(disp: torch.Tensor, size: int = 3, valid: torch.Tensor | None = None,
                  backend: str = "auto") -> torch.Tensor:
    """Median over a ``size x size`` window (border replicated).

    With ``valid`` given, only valid neighbours vote (a pixel without valid neighbours keeps its value);
    the output is defined everywhere, the mask is for the caller to keep.

    Args:
        disp: :math:`(B, 1, H, W)`.
        size: odd window size.
        valid: optional bool :math:`(B, 1, H, W)`.
        backend: ``"auto"`` (numba for CPU input without gradient), ``"torch"`` (unfold + sort) or ``"numba"``.

    Returns:
        :math:`(B, 1, H, W)`.
    """
    dims = check_shape(disp, ["B", "1", "H", "W"], "disp")
    check_window(size, "size")
    if backend not in ("auto", "torch", "numba"):
        raise StereoInputError(f"backend: expected 'auto', 'torch' or 'numba', got {backend!r}")
    if size == 1:
        return disp
    if valid is not None:
        check_shape(valid, [str(dims["B"]), "1", str(dims["H"]), str(dims["W"])], "valid")
    if use_numba(disp, backend=backend, float32_only=False):
        d = disp.detach().cpu().numpy()
        v = np.ones(d.shape, np.bool_) if valid is None else valid.detach().cpu().numpy()
        out = np.stack([median_kernel(d[b, 0], v[b, 0], size) for b in range(d.shape[0])])[:, None]
        return torch.from_numpy(out).to(disp.device)
    r = size // 2
    patches = F.unfold(F.pad(disp, (r, r, r, r), mode="replicate"), size)  # Bx(size*size)x(H*W)
    if valid is None:
        med = patches.median(dim=1).values
        return med.view_as(disp)
    vpatch = F.unfold(F.pad(valid.to(disp.dtype), (r, r, r, r), mode="replicate"), size) > 0.5
    n_valid = vpatch.sum(1, keepdim=True)
    # invalid samples -> +inf, so the k-th smallest of the valid ones is the median (lower median)
    vals = patches.masked_fill(~vpatch, float("inf")).sort(dim=1).values
    k = ((n_valid - 1).clamp(min=0) // 2)
    med = vals.gather(1, k).squeeze(1)
    med = torch.where(n_valid.squeeze(1) > 0, med, disp.flatten(2).squeeze(1))
    return med.view_as(disp)


def speckle_filter(disp: torch.Tensor, valid: torch.Tensor, max_size: int = 100,
                   max_diff: float = 1.0) -> torch.Tensor:
    """Invalidate speckles: 4-connected regions of valid pixels (neighbours differing by at most
    ``max_diff``) with fewer than ``max_size`` pixels (OpenCV's ``filterSpeckles`` rule).

    Args:
        disp: :math:`(B, 1, H, W)`.
        valid: bool :math:`(B, 1, H, W)`.
        max_size: regions smaller than this are removed (0 disables).
        max_diff: largest disparity step inside a region.

    Returns:
        bool :math:`(B, 1, H, W)` new validity mask (a subset of ``valid``).
    """
    dims = check_shape(disp, ["B", "1", "H", "W"], "disp")
    check_shape(valid, [str(dims["B"]), "1", str(dims["H"]), str(dims["W"])], "valid")
    if max_size < 0 or max_diff < 0:
        raise StereoInputError(f"max_size/max_diff: expected non-negative values, got {max_size}, {max_diff}")
    if max_size == 0:
        return valid.clone()
    d = disp.detach().to("cpu", torch.float32).numpy()
    v = valid.detach().to("cpu").numpy().astype(np.bool_)
    out = np.stack([speckle_kernel(d[b, 0], v[b, 0], int(max_size), float(max_diff)) for b in range(d.shape[0])])
    return torch.from_numpy(out[:, None]).to(valid.device)
