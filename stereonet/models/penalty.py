"""Learned SGM penalties (SGM-Net style, Seki and Pollefeys 2017): a small network that sets ``sgm``'s large-jump
penalty ``P2(p, r)`` for every pixel ``p`` and path direction ``r`` from the left image.

``sgm`` lowers ``P2`` across intensity edges by a fixed rule (``P2 / (1 + alpha |dI|)``, never below ``P1``;
:func:`stereonet.aggregate.sgm.p2_maps`), which cannot tell an object's outline from a texture edge. The network
reads the standardised grey left image (:func:`~stereonet.models.layers.standardize_image`, so it sees the same
statistics on any photo) through a few dilated 3x3 convolutions and returns one log-factor per direction; the
penalty is the fixed rule's times ``exp`` of it, kept in ``[P1, p2_max]``::

    P2(p, r) = clamp(rule(p, r) * exp(bound * tanh(a_r(p) / bound)), P1, p2_max)

The last layer starts at zero, so an untrained network is exactly ``sgm``'s rule. Trained through the
differentiable torch SGM on data_gen pairs only (:class:`stereonet.training.module.PenaltyModule`); served by the
``sgm-penalties`` matcher (``sgm`` with these maps, its CPU 16-bit kernel unchanged).
"""

from __future__ import annotations

import torch
from torch import nn

from stereonet.aggregate.sgm import predecessor_slices, sgm_directions
from stereonet.checks import StereoInputError
from stereonet.models.layers import standardize_image

INPUTS = ("image", "image+disparity")
"""What a PenaltyNet reads: the grey left image, or also a first ``sgm`` pass (:func:`disparity_jumps`)."""
JUMP_CLIP = 8.0
"""Disparity jumps (px) larger than this read as this much (a jump is a jump)."""

LOG_BOUND = 3.0
"""Largest change of the penalty by the network, as a log-factor (``exp(3)`` ~ 20x either way, before the clamp)."""


class PenaltyNet(nn.Module):
    """Per-pixel, per-direction log-factors of ``sgm``'s large-jump penalty (see the module doc).

    Args:
        channels: width of every hidden layer.
        dilations: one 3x3 convolution per entry, with that dilation (zero-padded, same size).
        paths: the SGM paths the factors are for (4, 8 or 16; one output channel each, in
            :func:`stereonet.aggregate.sgm.sgm_directions` order).
        p2_max: the largest penalty it may set (cost units; 144 Hamming bits keeps ``sgm``'s 16-bit kernel exact
            for its 7x7 census: 8 paths x 16 x (49 + 144) < 2^15).
        inputs: ``"image"`` (SGM-Net: the left image only) or ``"image+disparity"``: also a first ``sgm`` pass,
            as its disparity jump to the predecessor along every path direction (:func:`disparity_jumps`) and its
            validity, so that the network sees where that pass puts depth edges.
    """

    def __init__(self, channels: int = 16, dilations: tuple[int, ...] | list[int] = (1, 2, 4, 1),
                 paths: int = 8, p2_max: float = 144.0, inputs: str = "image") -> None:
        super().__init__()
        if channels < 1:
            raise StereoInputError(f"channels: expected >= 1, got {channels}")
        if not dilations or any(int(d) < 1 for d in dilations):
            raise StereoInputError(f"dilations: expected a non-empty list of integers >= 1, got {list(dilations)}")
        if paths not in (4, 8, 16):
            raise StereoInputError(f"paths: expected 4, 8 or 16, got {paths!r}")
        if not p2_max > 0:
            raise StereoInputError(f"p2_max: expected > 0, got {p2_max!r}")
        if inputs not in INPUTS:
            raise StereoInputError(f"inputs: expected one of {', '.join(INPUTS)}, got {inputs!r}")
        self.p2_max, self.inputs = float(p2_max), inputs
        self.channels, self.dilations, self.paths = int(channels), tuple(int(d) for d in dilations), int(paths)
        mods: list[nn.Module] = []
        c_in = 1 if inputs == "image" else 2 + self.paths
        for d in self.dilations:
            mods += [nn.Conv2d(c_in, self.channels, 3, padding=d, dilation=d), nn.ReLU(inplace=True)]
            c_in = self.channels
        self.body = nn.Sequential(*mods)
        self.head = nn.Conv2d(self.channels, self.paths, 3, padding=1)
        nn.init.zeros_(self.head.weight)
        nn.init.zeros_(self.head.bias)

    def forward(self, image: torch.Tensor, disparity: torch.Tensor | None = None,
                valid: torch.Tensor | None = None) -> torch.Tensor:
        """``image`` :math:`(B, C, H, W)` in [0, 1] (and, for ``inputs="image+disparity"``, the first pass's filled
        ``disparity`` and its ``valid`` mask, :math:`(B, 1, H, W)`) -> bounded log-factors :math:`(B, paths, H, W)`."""
        x = standardize_image(image, grey=True)
        if self.inputs == "image+disparity":
            if disparity is None or valid is None:
                raise StereoInputError("disparity: this penalty network reads a first sgm pass; pass disparity and valid")
            x = torch.cat([x, disparity_jumps(disparity.to(x.dtype), sgm_directions(self.paths)) / JUMP_CLIP,
                           valid.to(x.dtype)], 1)
        a = self.head(self.body(x))
        return LOG_BOUND * torch.tanh(a / LOG_BOUND)

    def penalties(self, image: torch.Tensor, rule: torch.Tensor, P1: float, disparity: torch.Tensor | None = None,
                  valid: torch.Tensor | None = None) -> torch.Tensor:
        """The learned ``P2`` maps :math:`(B, paths, H, W)`: ``rule`` (:func:`~stereonet.aggregate.sgm.p2_maps`
        of the same directions) times the network's factors, clamped to ``[P1, p2_max]``."""
        if rule.shape[1] != self.paths:
            raise StereoInputError(f"rule: expected {self.paths} direction maps, got {rule.shape[1]}")
        factors = self(image, disparity, valid).to(rule.dtype)
        return torch.clamp(rule * torch.exp(factors), min=float(P1), max=self.p2_max)


def disparity_jumps(disparity: torch.Tensor, directions) -> torch.Tensor:
    """``min(|d(p) - d(p - r)|, JUMP_CLIP)`` for every direction ``r = (dx, dy)`` (predecessor ``(y - dy, x - dx)``),
    :math:`(B, 1, H, W)` -> :math:`(B, R, H, W)`; 0 where the predecessor is outside the image."""
    b, _, h, w = disparity.shape
    out = disparity.new_zeros((b, len(directions), h, w))
    d = disparity[:, 0]
    for i, (dx, dy) in enumerate(directions):
        ys, xs, yp, xp = predecessor_slices(dx, dy, h, w)
        out[:, i, ys, xs] = (d[:, ys, xs] - d[:, yp, xp]).abs().clamp(max=JUMP_CLIP)
    return out
