"""Learned residual refinement of a classical disparity map (the ``sgm-refine`` matcher).

A small context network reads what the classical matcher knows and where it is unsure, and adds a residual:

* the left image (grey, standardised as every network here sees it),
* the photometric residual ``left - right warped by d`` (standardised grey): where it is large, ``d`` is wrong,
* the disparity ``d / max_disp`` (scale-free across image sizes and disparity ranges),
* the matcher's validity (1 where it passed its left-right and uniqueness checks, 0 where ``d`` was filled),
* the matcher's confidence in [0, 1] (SGM's cost margin).

Five 3x3 convolutions with dilations 1, 2, 4, 8, 1 (the context module of Yu & Koltun, 2016) give a ~37-pixel
support at full resolution, enough to carry a surface across an occlusion or a weakly textured patch; the last
convolution starts at zero, so an untrained network returns the classical map unchanged and training starts
from the classical matcher's accuracy, not from zero. The network is stateless (no loss in ``forward``).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from stereonet.checks import StereoInputError
from stereonet.models.layers import standardize_image, warp_right

INPUT_CHANNELS = 5
"""left, photometric residual, d / max_disp, validity, confidence."""


class RefineNet(nn.Module):
    """Residual refinement of a disparity map.

    Args:
        channels: width of every hidden layer.
        dilations: one 3x3 convolution per entry, with that dilation (zero-padded, same size).
    """

    def __init__(self, channels: int = 16, dilations: tuple[int, ...] | list[int] = (1, 2, 4, 8, 1)) -> None:
        super().__init__()
        if channels < 1:
            raise StereoInputError(f"channels: expected >= 1, got {channels}")
        if not dilations or any(int(d) < 1 for d in dilations):
            raise StereoInputError(f"dilations: expected a non-empty list of integers >= 1, got {list(dilations)}")
        self.channels, self.dilations = int(channels), tuple(int(d) for d in dilations)
        mods: list[nn.Module] = [nn.Conv2d(INPUT_CHANNELS, self.channels, 3, padding=1), nn.ReLU(inplace=True)]
        for d in self.dilations:
            mods += [nn.Conv2d(self.channels, self.channels, 3, padding=d, dilation=d), nn.ReLU(inplace=True)]
        self.body = nn.Sequential(*mods)
        self.head = nn.Conv2d(self.channels, 1, 3, padding=1)
        nn.init.zeros_(self.head.weight)
        nn.init.zeros_(self.head.bias)

    def inputs(self, left: torch.Tensor, right: torch.Tensor, disparity: torch.Tensor, valid: torch.Tensor,
               confidence: torch.Tensor, max_disp: float | torch.Tensor) -> torch.Tensor:
        """The five input planes :math:`(B, 5, H, W)` (see the module docstring)."""
        grey_l = standardize_image(left, grey=True)
        grey_r = standardize_image(right, grey=True)
        residual = grey_l - warp_right(grey_r, disparity)
        return torch.cat([grey_l, residual, disparity / _range(max_disp, disparity), valid.to(left.dtype),
                          confidence.to(left.dtype)], 1)

    def forward(self, left: torch.Tensor, right: torch.Tensor, disparity: torch.Tensor, valid: torch.Tensor,
                confidence: torch.Tensor, max_disp: float | torch.Tensor) -> torch.Tensor:
        """Refined disparity :math:`(B, 1, H, W)` >= 0 from images :math:`(B, C, H, W)` in [0, 1] and the
        classical matcher's filled disparity, validity and confidence :math:`(B, 1, H, W)`; ``max_disp`` the
        range the map was searched in (a number, or one per item)."""
        x = self.inputs(left, right, disparity, valid, confidence, max_disp)
        step = self.head(self.body(x))
        return F.relu(disparity + step)  # the residual in pixels: most corrections are a few pixels


def _range(max_disp: float | torch.Tensor, like: torch.Tensor) -> float | torch.Tensor:
    """``max_disp`` (one number, or one per batch item :math:`(B,)`) as a divisor >= 1 broadcastable to ``like``."""
    if isinstance(max_disp, torch.Tensor):
        return max_disp.to(like).clamp(min=1.0).view(-1, 1, 1, 1)
    return max(float(max_disp), 1.0)
