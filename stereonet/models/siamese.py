"""A Siamese matching-cost network in the style of MC-CNN-fast (Zbontar & LeCun, JMLR 2016).

A few 3x3 convolutions (shared by both images) turn each pixel's neighbourhood into a unit-length feature;
the matching cost of (x, y) in the left image and (x - d, y) in the right one is ``1 - <f_l, f_r>``.
Features are computed once per image, and the cost volume is a batch of dot products. Training uses
pixel pairs sampled from ground truth: positives at the true disparity, negatives a few pixels away.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from stereonet.checks import StereoInputError, check_shape

INVALID_COST = 2.0
"""Cost of a pixel whose match would fall outside the right image: the largest possible 1 - <f_l, f_r>."""


def _grey_standardized(image: torch.Tensor) -> torch.Tensor:
    """(B, C, H, W) in [0, 1] -> (B, 1, H, W) grey, zero mean and unit std per image (as MC-CNN normalises)."""
    grey = image.mean(dim=1, keepdim=True) if image.shape[1] != 1 else image
    mean = grey.mean(dim=(2, 3), keepdim=True)
    std = grey.std(dim=(2, 3), keepdim=True)
    return (grey - mean) / (std + 1e-2)  # 1e-2: keeps flat images finite


class SiameseNet(nn.Module):
    """MC-CNN-fast feature tower.

    Args:
        channels: feature width of every layer.
        layers: number of 3x3 conv layers (receptive field ``2 * layers + 1``).
    """

    def __init__(self, channels: int = 32, layers: int = 4) -> None:
        super().__init__()
        if layers < 1:
            raise ValueError(f"layers: expected >= 1, got {layers}")
        self.channels, self.layers = int(channels), int(layers)
        self.radius = self.layers  # each unpadded 3x3 conv shrinks the map by one pixel per side
        mods: list[nn.Module] = []
        in_ch = 1
        for i in range(self.layers):
            mods.append(nn.Conv2d(in_ch, self.channels, 3))
            if i < self.layers - 1:
                mods.append(nn.ReLU(inplace=True))
            in_ch = self.channels
        self.tower = nn.Sequential(*mods)

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        """Unit-length features :math:`(B, F, H, W)` of an image :math:`(B, C, H, W)` in [0, 1].

        The image is replicate-padded by the receptive radius, so every pixel (borders too) gets a feature
        computed exactly like during training.
        """
        x = _grey_standardized(image)
        x = F.pad(x, (self.radius,) * 4, mode="replicate")
        return F.normalize(self.tower(x), dim=1)


def siamese_cost_volume(feat_left: torch.Tensor, feat_right: torch.Tensor, max_disp: int) -> torch.Tensor:
    """Matching cost ``1 - <f_l(x, y), f_r(x - d, y)>`` for d = 0..max_disp (lower = better).

    Args:
        feat_left, feat_right: unit-length features :math:`(B, F, H, W)`.
    Returns:
        cost :math:`(B, D, H, W)`, D = max_disp + 1, in [0, 2]; :data:`INVALID_COST` where ``x - d < 0``.
    """
    check_shape(feat_left, ["B", "F", "H", "W"], "feat_left")
    if feat_right.shape != feat_left.shape:
        raise StereoInputError(f"feat_right: expected shape {tuple(feat_left.shape)}, got {tuple(feat_right.shape)}")
    b, _, h, w = feat_left.shape
    cost = feat_left.new_full((b, max_disp + 1, h, w), INVALID_COST)  # BxDxHxW
    for d in range(min(max_disp + 1, w)):
        cost[:, d, :, d:] = 1.0 - (feat_left[..., d:] * feat_right[..., : w - d]).sum(dim=1)
    return cost


def _sample_right(feat_right: torch.Tensor, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Bilinearly sample unit features at float pixel positions x, y :math:`(B, N)` -> :math:`(B, F, N)`."""
    _, _, h, w = feat_right.shape
    grid = torch.stack([(2 * x + 1) / w - 1, (2 * y + 1) / h - 1], dim=-1)[:, None]  # Bx1xNx2
    f = F.grid_sample(feat_right, grid, mode="bilinear", padding_mode="border", align_corners=False)[:, :, 0]
    return F.normalize(f, dim=1)


def siamese_pair_loss(feat_left: torch.Tensor, feat_right: torch.Tensor, disparity: torch.Tensor,
                      valid: torch.Tensor, num_samples: int = 1024, margin: float = 0.2,
                      neg_low: float = 1.5, neg_high: float = 8.0, loss: str = "hinge",
                      generator: torch.Generator | None = None) -> torch.Tensor:
    """MC-CNN training loss on pixel pairs sampled from ground truth (a pure function).

    For ``num_samples`` valid left pixels per image: a positive at ``x - d`` and a negative at
    ``x - d + o``, ``|o|`` uniform in [neg_low, neg_high] with random sign (kept inside the image).
    ``loss="hinge"``: ``mean(max(0, margin + s_neg - s_pos))``; ``loss="bce"``: binary cross-entropy on
    the similarities (scaled by 1/margin as logits).

    Args:
        feat_left, feat_right: unit features :math:`(B, F, H, W)`.
        disparity: ground truth :math:`(B, 1, H, W)`; valid: bool :math:`(B, 1, H, W)` (non-occluded pixels).
    Returns:
        scalar loss.
    """
    b, _, h, w = feat_left.shape
    dev = feat_left.device
    x_l = torch.arange(w, device=dev, dtype=feat_left.dtype).expand(h, w)
    ok = valid[:, 0] & (x_l - disparity[:, 0] >= 0)  # BxHxW: the true match lies inside the right image
    weights = ok.reshape(b, -1).to(feat_left.dtype)
    has_any = weights.sum(dim=1) > 0
    if not bool(has_any.any()):
        return feat_left.sum() * 0.0
    weights = weights[has_any] + 0.0
    fl, fr, disp = feat_left[has_any], feat_right[has_any], disparity[has_any]
    idx = torch.multinomial(weights, num_samples, replacement=True, generator=generator)  # BxN
    ys, xs = (idx // w).to(fl.dtype), (idx % w).to(fl.dtype)
    d = disp.reshape(disp.shape[0], -1).gather(1, idx)
    f_left = fl.reshape(fl.shape[0], fl.shape[1], -1).gather(2, idx[:, None].expand(-1, fl.shape[1], -1))  # BxFxN
    offset = torch.empty_like(d).uniform_(neg_low, neg_high, generator=generator)
    sign = torch.where(torch.rand(d.shape, generator=generator, device=dev) < 0.5, -1.0, 1.0).to(d.dtype)
    x_pos = xs - d
    x_neg = x_pos + sign * offset
    x_neg = torch.where((x_neg < 0) | (x_neg > w - 1), x_pos - sign * offset, x_neg).clamp(0, w - 1)
    s_pos = (f_left * _sample_right(fr, x_pos, ys)).sum(dim=1)
    s_neg = (f_left * _sample_right(fr, x_neg, ys)).sum(dim=1)
    if loss == "hinge":
        return F.relu(margin + s_neg - s_pos).mean()
    if loss == "bce":
        logits = torch.cat([s_pos, s_neg]) / margin
        labels = torch.cat([torch.ones_like(s_pos), torch.zeros_like(s_neg)])
        return F.binary_cross_entropy_with_logits(logits, labels)
    raise ValueError(f"loss: expected 'hinge' or 'bce', got {loss!r}")
