"""An SMD-Nets-style head (Tosi et al., CVPR 2021) on the DispNet backbone.

For every query point (continuous image coordinates) the head samples the backbone's decoder features and
its disparity bilinearly, and a small MLP predicts a bimodal Laplacian mixture

    p(d) = pi / (2 b1) exp(-|d - mu1| / b1) + (1 - pi) / (2 b2) exp(-|d - mu2| / b2).

The output disparity is the mode with the higher density (a sharp choice at depth edges instead of an
average of foreground and background), the network's uncertainty is that mode's scale ``b`` (the ``smd`` matcher
reports :func:`error_probability` instead, which also weighs the other mode). Because queries are
continuous, the disparity can be produced at any output size, e.g. higher than the input.

``context > 0`` also shows the head a neighbourhood of each query point (:func:`neighbourhood`): the backbone's
disparity and the left image's standardised grey level at offsets ``0, ±1, ±2, ±4, ...`` (input pixels, up to
``±context`` on each axis), each relative to the point's own value. A per-point head sees only the features and
the disparity *at* the point, so at a blurred depth edge it cannot tell which disparities lie on either side
or on which side of the image's intensity edge the point is; with the neighbourhood it can place each mode on
one side (``context_grey=False``: the disparity alone). The samples are bilinear at continuous positions, so any
output scale still works.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from stereonet.checks import StereoInputError
from stereonet.models.dispnet import DispNet, DispNetOutput, run_padded
from stereonet.models.layers import InputPadder, standardize_image

MIN_SCALE = 0.05
"""Smallest Laplacian scale b in pixels: keeps the NLL bounded (b -> 0 would give -inf) and is finer than
any ground truth's sub-pixel precision, so it never limits accuracy."""


@dataclass
class MixtureParams:
    """Per-query bimodal Laplacian mixture, each tensor :math:`(B, 1, Hq, Wq)`, disparities in input pixels."""

    mu1: torch.Tensor
    mu2: torch.Tensor
    b1: torch.Tensor
    b2: torch.Tensor
    pi: torch.Tensor  # weight of mode 1; mode 2 has 1 - pi

    def mode_disparity(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The mode with the higher density and its scale: ((B,1,Hq,Wq) disparity, (B,1,Hq,Wq) b)."""
        first = self.pi / self.b1 >= (1 - self.pi) / self.b2  # peak density pi / (2 b) of each mode
        return torch.where(first, self.mu1, self.mu2), torch.where(first, self.b1, self.b2)


def error_probability(mix: MixtureParams, disparity: torch.Tensor, tau: float = 2.0) -> torch.Tensor:
    """``P(|X - disparity| > tau)`` for X distributed as the mixture ``mix`` (same units as ``disparity``): the
    probability, under the head's own prediction, that an answer is off by more than ``tau``. Unlike the chosen
    mode's scale it also counts the other mode's weight and distance (a pixel whose second mode is heavy and far is
    ambiguous however narrow the first is); it is the ranking of bad-``tau`` errors a calibrated mixture would
    give (the ``smd`` matcher's uncertainty, chosen on data_gen: docs/experiments/smd_uncertainty.txt)."""

    def tail(mu: torch.Tensor, b: torch.Tensor) -> torch.Tensor:  # P(|X_k - d| > tau), X_k ~ Laplace(mu, b)
        hi, lo = disparity + tau, disparity - tau
        above = torch.where(hi >= mu, 0.5 * torch.exp(-(hi - mu) / b), 1 - 0.5 * torch.exp((hi - mu) / b))
        below = torch.where(lo <= mu, 0.5 * torch.exp((lo - mu) / b), 1 - 0.5 * torch.exp(-(lo - mu) / b))
        return above + below

    return (mix.pi * tail(mix.mu1, mix.b1) + (1 - mix.pi) * tail(mix.mu2, mix.b2)).clamp(0.0, 1.0)


@dataclass
class SMDOutput:
    """What :class:`SMDNet` returns (same structure in train and eval).

    Attributes:
        disparity: mode of the mixture at the query grid :math:`(B, 1, Hq, Wq)`, in pixels of the *query* grid.
        uncertainty: Laplacian scale of the chosen mode :math:`(B, 1, Hq, Wq)`, same unit.
        mixture: the mixture parameters at the query grid, same unit.
        backbone: the DispNet output at the input resolution.
    """

    disparity: torch.Tensor
    uncertainty: torch.Tensor
    mixture: MixtureParams
    backbone: DispNetOutput


def query_grid(batch: int, height: int, width: int, device=None, dtype=None) -> torch.Tensor:
    """Normalised sampling grid :math:`(B, H, W, 2)` of the pixel centres of an ``height x width`` image.

    With ``align_corners=False`` these coordinates address the same physical points in feature maps of any
    resolution, so the grid queries the backbone at a finer (or coarser) resolution than its input.
    """
    ys = (torch.arange(height, device=device, dtype=dtype) + 0.5) * (2.0 / height) - 1.0
    xs = (torch.arange(width, device=device, dtype=dtype) + 0.5) * (2.0 / width) - 1.0
    grid = torch.stack(torch.meshgrid(xs, ys, indexing="xy"), dim=-1)  # HxWx2, (x, y) order
    return grid.unsqueeze(0).expand(batch, -1, -1, -1)


def context_offsets(context: int) -> list[tuple[int, int]]:
    """The (dx, dy) offsets in input pixels of a ``context`` neighbourhood, the centre left out: every pair of
    ``0, ±1, ±2, ±4, ...`` up to ``±context`` (``[]`` for 0). ``context=4``: 7 x 7 - 1 = 48 offsets."""
    steps = [0] + [s * k for k in (1 << i for i in range(max(int(context), 0).bit_length())) if k <= context
                   for s in (-1, 1)]
    steps.sort()
    return [(dx, dy) for dy in steps for dx in steps if (dx, dy) != (0, 0)]


def neighbourhood(maps: torch.Tensor, grid: torch.Tensor, offsets: list[tuple[int, int]]) -> torch.Tensor:
    r"""Each channel of ``maps`` :math:`(B, C, H, W)` sampled (bilinear, border) at the query points ``grid``
    :math:`(B, Hq, Wq, 2)` shifted by every ``(dx, dy)`` of ``offsets`` (pixels of ``maps``), minus its value at
    the point itself: :math:`(B, C \cdot K, Hq, Wq)`, the C channels of offset 0 first, then offset 1, ..."""
    h, w = maps.shape[-2:]
    one = grid.new_ones(())  # (an exported graph traces h, w as sizes: the step follows the input's size)
    step = torch.stack([2.0 / (one * w), 2.0 / (one * h)])  # one pixel in normalised coordinates, (x, y)
    sample = lambda g: F.grid_sample(maps, g, mode="bilinear", padding_mode="border", align_corners=False)
    centre = sample(grid)
    return torch.cat([sample(grid + step * grid.new_tensor([dx, dy])) - centre for dx, dy in offsets], dim=1)


class SMDNet(nn.Module):
    """DispNet backbone + continuous bimodal mixture head.

    Args:
        max_disp, channels, aggregation, upsample, matching: as :class:`DispNet`.
        hidden: widths of the MLP's hidden layers.
        context: reach in input pixels of the neighbourhood the head also sees (module doc; 0: the point only).
        context_grey: whether that neighbourhood includes the left image's grey level (False: the backbone's
            disparity alone, a cue that means the same on renders and photos, where depth and intensity edges part).
    """

    stride = DispNet.stride

    def __init__(self, max_disp: int = 96, channels: int = 16, hidden: tuple[int, ...] = (32, 16),
                 aggregation: str = "2d", upsample: str = "bilinear", matching: str = "learned",
                 context: int = 0, context_grey: bool = True) -> None:
        super().__init__()
        if isinstance(context, bool) or not isinstance(context, int) or context < 0:
            raise ValueError(f"context: expected an integer >= 0 (pixels), got {context!r}")
        self.backbone = DispNet(max_disp=max_disp, channels=channels, aggregation=aggregation,
                                upsample=upsample, matching=matching)
        self.max_disp = self.backbone.max_disp
        self.context, self.context_grey = context, bool(context_grey)
        self.offsets = context_offsets(context)
        c = self.backbone.channels
        in_ch = c // 2 + c + 2 * c + 1  # features at strides 1, 2, 4 + the backbone disparity
        in_ch += (2 if self.context_grey else 1) * len(self.offsets)  # + the neighbourhood's disparity (and grey)
        layers: list[nn.Module] = []
        for width in hidden:
            layers += [nn.Conv2d(in_ch, width, 1), nn.LeakyReLU(0.1, inplace=True)]
            in_ch = width
        layers.append(nn.Conv2d(in_ch, 5, 1))
        self.mlp = nn.Sequential(*layers)  # a per-point MLP written as 1x1 convolutions

    def query(self, backbone: DispNetOutput, grid: torch.Tensor, detach_anchor: bool = False,
              left: torch.Tensor | None = None) -> MixtureParams:
        """Mixture at continuous points ``grid`` :math:`(B, Hq, Wq, 2)` (normalised, align_corners=False).

        Returned disparities are in pixels of the backbone's input resolution. The two modes are offsets from the
        backbone's disparity (the anchor); ``detach_anchor`` (training only, same values) stops the mixture's
        gradient there, so that the head's loss reaches the backbone through its features only. ``left``: the
        backbone's left input :math:`(B, C, H, W)` in [0, 1], needed (only) when ``context > 0`` with ``context_grey``.
        """
        sample = lambda x: F.grid_sample(x, grid, mode="bilinear", padding_mode="border", align_corners=False)
        anchor = backbone.disparity.detach() if detach_anchor else backbone.disparity
        disp = sample(anchor)  # Bx1xHqxWq
        unit = self.backbone.disp_unit
        inputs = [sample(backbone.features[s]) for s in (1, 2, 4)] + [disp / self.max_disp]
        if self.offsets:
            maps = [anchor / unit]
            if self.context_grey:
                if left is None or left.shape[-2:] != anchor.shape[-2:]:
                    raise StereoInputError(f"left: expected the backbone's left input of size {tuple(anchor.shape[-2:])}"
                                           f" (context {self.context}), got {None if left is None else tuple(left.shape)}")
                maps.append(standardize_image(left, grey=True))
            inputs.append(neighbourhood(torch.cat(maps, dim=1), grid, self.offsets))
        raw = self.mlp(torch.cat(inputs, dim=1))  # Bx5xHqxWq
        return MixtureParams(
            mu1=disp + raw[:, 0:1] * unit,
            mu2=disp + raw[:, 1:2] * unit,
            b1=F.softplus(raw[:, 2:3]) + MIN_SCALE,
            b2=F.softplus(raw[:, 3:4]) + MIN_SCALE,
            pi=torch.sigmoid(raw[:, 4:5]),
        )

    def forward(self, left: torch.Tensor, right: torch.Tensor,
                output_size: tuple[int, int] | None = None, detach_anchor: bool = False) -> SMDOutput:
        """left, right :math:`(B, C, H, W)`, H, W multiples of the stride; ``output_size`` (Hq, Wq) defaults
        to (H, W). Disparities are returned in pixels of the output grid (scaled by Wq / W). ``detach_anchor``:
        see :meth:`query`."""
        backbone = self.backbone(left, right)
        b, _, h, w = left.shape
        hq, wq = output_size if output_size is not None else (h, w)
        grid = query_grid(b, hq, wq, device=left.device, dtype=left.dtype)
        mix = self.query(backbone, grid, detach_anchor, left)
        scale = wq / w
        if scale != 1.0:
            mix = MixtureParams(mix.mu1 * scale, mix.mu2 * scale, mix.b1 * scale, mix.b2 * scale, mix.pi)
        disparity, uncertainty = mix.mode_disparity()
        return SMDOutput(disparity=disparity, uncertainty=uncertainty, mixture=mix, backbone=backbone)


def padded_query_grid(batch: int, height: int, width: int, padder: InputPadder, upsample: float = 1.0,
                      device=None, dtype=None) -> torch.Tensor:
    """Query grid :math:`(B, round(H * upsample), round(W * upsample), 2)` over the unpadded ``height x width``
    image, in the normalised coordinates of the map ``padder`` padded it to (so nothing is cropped)."""
    hp, wp = height + padder.pad_h, width + padder.pad_w
    grid = query_grid(batch, round(height * upsample), round(width * upsample), device=device, dtype=dtype).clone()
    grid[..., 0] = (grid[..., 0] + 1.0) * (width / wp) - 1.0
    grid[..., 1] = (grid[..., 1] + 1.0) * (height / hp) - 1.0
    return grid


def mixture_outputs(mix: MixtureParams, scale: float, with_mixture: bool = False):
    """What :func:`predict_smd` returns for the mixture ``mix`` (input pixels) on an output grid of ``scale``
    times the input width: (disparity, uncertainty[, params]) in pixels of the output grid."""
    disparity, uncertainty = mix.mode_disparity()
    if not with_mixture:
        return disparity * scale, uncertainty * scale
    params = {"mu1": mix.mu1 * scale, "mu2": mix.mu2 * scale, "b1": mix.b1 * scale, "b2": mix.b2 * scale,
              "pi": mix.pi}
    return disparity * scale, uncertainty * scale, params


@torch.no_grad()
def predict_smd(net: SMDNet, left: torch.Tensor, right: torch.Tensor, upsample: float = 1.0,
                with_mixture: bool = False):
    """(disparity, uncertainty), each :math:`(B, 1, round(H*upsample), round(W*upsample))`, for any H, W.

    With ``with_mixture`` a third element holds the mixture ``{"mu1", "mu2", "b1", "b2", "pi"}`` on the
    same grid (disparities and scales in pixels of the output grid).

    The input is padded to the stride; the query grid covers only the unpadded image, so nothing is cropped
    and ``upsample > 1`` gives a super-resolved disparity (values in pixels of the output grid).
    """
    backbone, padder = run_padded(net.backbone, left, right)
    b, _, h, w = left.shape
    grid = padded_query_grid(b, h, w, padder, upsample, device=left.device, dtype=left.dtype)
    left_p = padder.pad(left)[0] if net.offsets and net.context_grey else None  # (run_padded checked the pair)
    return mixture_outputs(net.query(backbone, grid, left=left_p), grid.shape[2] / w, with_mixture)
