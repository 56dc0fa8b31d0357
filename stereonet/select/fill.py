"""Textbook occlusion filling along scanlines."""

from __future__ import annotations

import torch

from stereonet.checks import check_shape


def fill_occlusions(disp: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """Fill invalid pixels along each scanline with the background (smaller) neighbouring disparity.

    Exact rule, per row: for each run of invalid pixels, take the nearest valid pixel to its left
    (``x`` smaller) and to its right; the run gets the *smaller* of their two disparities (occluded pixels
    belong to the background). In a left-reference map the pixels seen only by the left camera lie just
    left of a foreground object's left edge, so their background neighbour is the valid pixel *before*
    them on the scanline (smaller x) and the rule picks it (smaller disparity); a mismatched run to the
    right of an object symmetrically takes the valid pixel after it. A run touching the image border has only one valid
    neighbour and takes it; a row without any valid pixel becomes 0.

    Args:
        disp: :math:`(B, 1, H, W)` disparity.
        valid: bool :math:`(B, 1, H, W)`.

    Returns:
        :math:`(B, 1, H, W)` filled disparity (valid pixels unchanged).
    """
    dims = check_shape(disp, ["B", "1", "H", "W"], "disp")
    check_shape(valid, [str(dims["B"]), "1", str(dims["H"]), str(dims["W"])], "valid")
    if valid.dtype != torch.bool:
        raise TypeError(f"valid: expected dtype torch.bool, got {valid.dtype}")
    w = dims["W"]
    x = torch.arange(w, device=disp.device).expand_as(disp)
    left_idx = torch.where(valid, x, torch.full_like(x, -1)).cummax(dim=3).values  # last valid at or before x
    right_idx = torch.where(valid, x, torch.full_like(x, w)).flip(3).cummin(dim=3).values.flip(3)
    has_left, has_right = left_idx >= 0, right_idx < w
    from_left = disp.gather(3, left_idx.clamp(min=0))
    from_right = disp.gather(3, right_idx.clamp(max=w - 1))
    inf = torch.full_like(disp, float("inf"))
    cand = torch.minimum(torch.where(has_left, from_left, inf), torch.where(has_right, from_right, inf))
    cand = torch.where(has_left | has_right, cand, torch.zeros_like(disp))
    return torch.where(valid, disp, cand)
