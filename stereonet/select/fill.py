"""Textbook occlusion filling along scanlines."""

from __future__ import annotations

import torch

from stereonet.checks import StereoInputError, check_shape

FILL_RULES = ("background", "left")


def scanline_fill(disp: torch.Tensor, valid: torch.Tensor, rule: str = "background") -> torch.Tensor:
    """The one scanline fill, on any :math:`(..., W)` tensors (``valid`` bool), unchecked; see
    :func:`fill_occlusions` for the ``"background"`` rule. ``"left"`` (the scanline DP's rule): each invalid
    pixel takes the nearest valid pixel on its left, or on its right at the left border; a row without any
    valid pixel takes its last pixel's value."""
    w = disp.shape[-1]
    x = torch.arange(w, device=disp.device).expand_as(disp)
    left_idx = torch.where(valid, x, torch.full_like(x, -1)).cummax(dim=-1).values  # last valid at or before x
    if rule == "left":
        first_valid = torch.where(valid, x, torch.full_like(x, w)).amin(dim=-1, keepdim=True).clamp(max=w - 1)
        return disp.gather(-1, torch.where(left_idx >= 0, left_idx, first_valid.expand_as(left_idx)))
    right_idx = torch.where(valid, x, torch.full_like(x, w)).flip(-1).cummin(dim=-1).values.flip(-1)
    has_left, has_right = left_idx >= 0, right_idx < w
    from_left = disp.gather(-1, left_idx.clamp(min=0))
    from_right = disp.gather(-1, right_idx.clamp(max=w - 1))
    inf = torch.full_like(disp, float("inf"))
    cand = torch.minimum(torch.where(has_left, from_left, inf), torch.where(has_right, from_right, inf))
    cand = torch.where(has_left | has_right, cand, torch.zeros_like(disp))
    return torch.where(valid, disp, cand)


def fill_occlusions(disp: torch.Tensor, valid: torch.Tensor, rule: str = "background") -> torch.Tensor:
    """Fill invalid pixels along each scanline with the background (smaller) neighbouring disparity.

    Exact rule, per row: for each run of invalid pixels, take the nearest valid pixel to its left
    (``x`` smaller) and to its right; the run gets the *smaller* of their two disparities (occluded pixels
    belong to the background). In a left-reference map the pixels seen only by the left camera lie just
    left of a foreground object's left edge, so their background neighbour is the valid pixel *before*
    them on the scanline (smaller x) and the rule picks it (smaller disparity); a mismatched run to the
    right of an object symmetrically takes the valid pixel after it. A run touching the image border has only
    one valid neighbour and takes it; a row without any valid pixel becomes 0. ``rule="left"`` is the
    scanline DP's fill instead (:func:`scanline_fill`).

    Args:
        disp: :math:`(B, 1, H, W)` disparity.
        valid: bool :math:`(B, 1, H, W)`.
        rule: ``"background"`` (default, the textbook rule above) or ``"left"``.

    Returns:
        :math:`(B, 1, H, W)` filled disparity (valid pixels unchanged).
    """
    dims = check_shape(disp, ["B", "1", "H", "W"], "disp")
    check_shape(valid, [str(dims["B"]), "1", str(dims["H"]), str(dims["W"])], "valid")
    if valid.dtype != torch.bool:
        raise TypeError(f"valid: expected dtype torch.bool, got {valid.dtype}")
    if rule not in FILL_RULES:
        raise StereoInputError(f"rule: expected one of {', '.join(FILL_RULES)}, got {rule!r}")
    return scanline_fill(disp, valid, rule)
