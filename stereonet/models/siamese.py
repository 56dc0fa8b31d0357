"""A Siamese matching-cost network in the style of MC-CNN-fast (Zbontar & LeCun, JMLR 2016).

A few 3x3 convolutions (shared by both images) turn each pixel's neighbourhood into a unit-length feature;
the matching cost of (x, y) in the left image and (x - d, y) in the right one is ``1 - <f_l, f_r>``.
Features are computed once per image, and the cost volume is a batch of dot products. Training uses
pixel pairs sampled from ground truth: positives at the true disparity, negatives a few pixels away.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from stereonet.checks import StereoInputError, check_shape
from stereonet.cost.census import census_signs
from stereonet.cost.correlation import correlation_1d
from stereonet.kernels import use_numba
from stereonet.models.layers import standardize_image

INVALID_COST = 2.0
"""Cost of a pixel whose match would fall outside the right image: the largest possible 1 - <f_l, f_r>."""

INPUTS = ("grey", "census", "grey+census")
"""What the tower's first convolution reads (``inputs`` of :class:`SiameseNet`)."""

PRECISIONS = ("auto", "float32", "bfloat16")
"""Arithmetic of the feature tower at inference (``precision`` option of the Siamese matchers)."""


def native_bfloat16() -> bool:
    """Whether this CPU multiplies bfloat16 in hardware (AVX512-BF16 or AMX), so that oneDNN's bfloat16
    convolutions run about twice as fast as float32 ones; elsewhere bfloat16 is emulated and slower."""
    try:
        return bool(torch.cpu._is_avx512_bf16_supported() or torch.cpu._is_amx_tile_supported())
    except (AttributeError, RuntimeError):  # private probes: an older or newer torch without them
        return False


def tower_dtype(precision: str, device: torch.device | str = "cpu") -> torch.dtype:
    """The dtype the tower runs in for ``precision``: ``"auto"`` is bfloat16 on a CPU with native bfloat16
    (:func:`native_bfloat16`) and float32 elsewhere (other CPUs, GPUs)."""
    if precision not in PRECISIONS:
        raise StereoInputError(f"precision: expected one of {', '.join(map(repr, PRECISIONS))}, got {precision!r}")
    if precision == "auto":
        return torch.bfloat16 if torch.device(device).type == "cpu" and native_bfloat16() else torch.float32
    return getattr(torch, precision)


class SiameseNet(nn.Module):
    """MC-CNN-fast feature tower.

    Args:
        channels: feature width of every layer.
        layers: number of 3x3 conv layers.
        inputs: ``"grey"`` (the standardised grey image, MC-CNN's input), ``"census"``: the first convolution
            reads the ``census_window**2 - 1`` census comparisons of each pixel with its neighbours
            (:func:`~stereonet.cost.census.census_signs`, ±1 / sqrt(n)) instead of the grey level, so the features
            cannot depend on the image's intensities beyond their local order; or ``"grey+census"``: both (the grey
            level as one more channel before the comparisons).
        census_window: odd census window of the census inputs (>= 3).

    The receptive field is ``2 * radius + 1`` with ``radius = layers`` (grey) or ``layers + census_window // 2``.
    """

    def __init__(self, channels: int = 32, layers: int = 4, inputs: str = "grey", census_window: int = 5) -> None:
        super().__init__()
        if layers < 1:
            raise StereoInputError(f"layers: expected >= 1, got {layers}")
        if inputs not in INPUTS:
            raise StereoInputError(f"inputs: expected one of {', '.join(map(repr, INPUTS))}, got {inputs!r}")
        if inputs != "grey" and (isinstance(census_window, bool) or not isinstance(census_window, int)
                                   or census_window < 3 or census_window % 2 == 0):
            raise StereoInputError(f"census_window: expected an odd integer >= 3, got {census_window!r}")
        self.channels, self.layers, self.inputs = int(channels), int(layers), inputs
        self.census_window = int(census_window) if inputs != "grey" else 0
        self.census_radius = self.census_window // 2
        # each unpadded 3x3 conv shrinks the map by one pixel per side, and so does each census ring
        self.radius = self.layers + self.census_radius
        mods: list[nn.Module] = []
        in_ch = (inputs != "census") + (self.census_window ** 2 - 1 if inputs != "grey" else 0)
        for i in range(self.layers):
            mods.append(nn.Conv2d(in_ch, self.channels, 3))
            if i < self.layers - 1:
                mods.append(nn.ReLU(inplace=True))
            in_ch = self.channels
        self.tower = nn.Sequential(*mods)

    def _first_input(self, padded: torch.Tensor) -> torch.Tensor:
        """The first convolution's input from the padded standardised grey image: itself, or (census inputs)
        the census comparisons of the pixels whose whole census window lies inside it (``census_radius`` fewer
        per side), after the grey level of those pixels for ``"grey+census"``."""
        if self.inputs == "grey":
            return padded
        signs = census_signs(padded, self.census_window, pad=False)
        if self.inputs == "census":
            return signs
        r = self.census_radius
        return torch.cat([padded[..., r:padded.shape[-2] - r, r:padded.shape[-1] - r], signs], dim=1)

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        """Unit-length features :math:`(B, F, H, W)` of an image :math:`(B, C, H, W)` in [0, 1].

        The image is replicate-padded by the receptive radius, so every pixel (borders too) gets a feature
        computed exactly like during training. Each convolution runs in the dtype of its weights (see
        :meth:`with_tower_dtype`); standardisation, padding and the normalisation run in the image's dtype,
        and the features come back in it.
        """
        x = standardize_image(image, grey=True)
        h = self._first_input(F.pad(x, (self.radius,) * 4, mode="replicate"))
        for module in self.tower:
            if isinstance(module, nn.Conv2d):
                h = h.to(module.weight.dtype)
            h = module(h)
        return F.normalize(h.to(x.dtype), dim=1)

    def with_tower_dtype(self, dtype: torch.dtype) -> SiameseNet:
        """This network with every convolution but the first in ``dtype`` (in place; returns self). The first
        one (one grey input channel, ~1 % of the multiply-adds) keeps its dtype: rounding the standardised
        image to bfloat16 was the largest error (unit features off by up to 0.03, against 0.005 from the
        other layers in bfloat16; one data_gen pair, 256x512)."""
        convs = [m for m in self.tower if isinstance(m, nn.Conv2d)]
        for conv in convs[1:]:
            conv.to(dtype)
        return self

    def patch_features(self, image: torch.Tensor, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """Unit features :math:`(B, F, N)` of the pixels at float positions ``x, y`` :math:`(B, N)`.

        Equal to sampling :meth:`forward`'s map at integer positions (same standardisation and replicate
        padding); fractional x interpolates the image bilinearly (sub-pixel positives).
        """
        b, n = x.shape
        grey = F.pad(standardize_image(image, grey=True), (self.radius,) * 4, mode="replicate")  # Bx1x(H+2r)x(W+2r)
        hp, wp = grey.shape[-2:]
        offs = torch.arange(-self.radius, self.radius + 1, device=x.device)
        k = offs.numel()
        # bilinear by hand rather than grid_sample: at integer positions the weights are exactly 1 and 0, so a
        # patch holds the padded image's own values (grid_sample's coordinate round trip is off by ~1e-7, enough
        # to break the exact ties of replicate padding that census comparisons see)
        x0, y0 = x.floor(), y.floor()
        fx, fy = (x - x0)[:, :, None, None], (y - y0)[:, :, None, None]  # BxNx1x1
        cols = (x0.long() + self.radius)[:, :, None] + offs  # BxNxK (padded coordinates)
        rows = (y0.long() + self.radius)[:, :, None] + offs
        flat = grey.reshape(b, hp * wp)

        def corner(dy: int, dx: int) -> torch.Tensor:  # BxNxKxK values at (rows + dy, cols + dx), border-clamped
            r = (rows + dy).clamp(0, hp - 1)[:, :, :, None]
            c = (cols + dx).clamp(0, wp - 1)[:, :, None, :]
            return flat.gather(1, (r * wp + c).reshape(b, -1)).reshape(b, n, k, k)

        patches = ((1 - fy) * ((1 - fx) * corner(0, 0) + fx * corner(0, 1))
                   + fy * ((1 - fx) * corner(1, 0) + fx * corner(1, 1)))
        patches = patches.reshape(b * n, 1, k, k)  # (B*N)x1xKxK
        feats = F.normalize(self.tower(self._first_input(patches)).reshape(b, n, -1), dim=2)  # BxNxF
        return feats.transpose(1, 2)


def siamese_cost_volume(feat_left: torch.Tensor, feat_right: torch.Tensor, max_disp: int,
                        backend: str = "auto") -> torch.Tensor:
    """Matching cost ``1 - <f_l(x, y), f_r(x - d, y)>`` for d = 0..max_disp (lower = better).

    Args:
        feat_left, feat_right: unit-length features :math:`(B, F, H, W)`.
        backend: ``"auto"`` (the numba kernel for float32 CPU features without gradient, else torch),
            ``"torch"`` or ``"numba"`` (equal to float32 rounding, ~1e-6: the two sum the products in different orders).
    Returns:
        cost :math:`(B, D, H, W)`, D = max_disp + 1, in [0, 2]; :data:`INVALID_COST` where ``x - d < 0``.
        The numba result is a permuted view of a ``(B, H, W, D)`` buffer (what SGM's kernel reads).
    """
    check_shape(feat_left, ["B", "F", "H", "W"], "feat_left")
    if feat_right.shape != feat_left.shape:
        raise StereoInputError(f"feat_right: expected shape {tuple(feat_left.shape)}, got {tuple(feat_right.shape)}")
    b, _, h, w = feat_left.shape
    if use_numba(feat_left, feat_right, backend=backend):
        from stereonet.kernels.cost import feature_cost_hwd

        def hwf(t: torch.Tensor) -> np.ndarray:  # (F, H, W) -> (H, W, F); no copy for channels-last features
            return np.ascontiguousarray(t.detach().to("cpu", torch.float32).permute(1, 2, 0).numpy())

        vols = [torch.from_numpy(feature_cost_hwd(hwf(feat_left[i]), hwf(feat_right[i]), max_disp + 1,
                                                  np.float32(INVALID_COST))) for i in range(b)]
        return (torch.stack(vols) if b > 1 else vols[0][None]).permute(0, 3, 1, 2)  # BxHxWxD seen as BxDxHxW
    return 1.0 - correlation_1d(feat_left, feat_right, max_disp, reduce="sum", fill=1.0 - INVALID_COST)


def edge_maps(disparity: torch.Tensor, valid: torch.Tensor, radius: int) -> tuple[torch.Tensor, torch.Tensor]:
    """``(near, other)`` :math:`(B, 1, H, W)`: ``near`` marks the valid pixels within ``radius`` px (Chebyshev) of
    a depth discontinuity (:func:`stereonet.metrics.depth_discontinuities`, 1 px); ``other`` is, per pixel, the
    valid disparity in its ``(2 radius + 1)²`` window that differs most from its own (the other side of the edge)."""
    from stereonet.metrics import depth_discontinuities

    k = 2 * radius + 1
    edges = depth_discontinuities(disparity, valid)
    near = (F.max_pool2d(edges.to(disparity.dtype), k, 1, radius) > 0) & valid
    big = torch.finfo(disparity.dtype).max
    high = F.max_pool2d(disparity.masked_fill(~valid, -big), k, 1, radius)
    low = -F.max_pool2d((-disparity).masked_fill(~valid, -big), k, 1, radius)
    other = torch.where(high - disparity >= disparity - low, high, low)
    return near, other


def sample_training_pixels(disparity: torch.Tensor, valid: torch.Tensor, num_samples: int, neg_low: float,
                           neg_high: float, generator: torch.Generator | None = None, edge_share: float = 0.0,
                           edge_radius: int = 4):
    """Sample MC-CNN training triplets from ground truth.

    For ``num_samples`` valid left pixels per image (whose true match lies inside the right image): the
    left position (x, y), the positive right position ``x - d`` and a negative ``x - d + o`` with ``|o|``
    uniform in [neg_low, neg_high] and a random sign (flipped if it leaves the image).

    ``edge_share > 0`` (depth-edge training): that share of each image's samples is drawn from the valid pixels
    within ``edge_radius`` px of a depth discontinuity (:func:`edge_maps`; from all valid pixels in an image that
    has none), and their negative is the match at the disparity of the other side of the edge (the window's valid
    disparity farthest from the pixel's own) when that lies at least ``neg_low`` px from the true match and inside
    the image, else the random one. This is the decision a depth edge asks of the features: a patch that straddles
    the edge must match at its own surface's disparity, not at the other one's (the edge-fattening error). With
    ``edge_share = 0`` nothing more is drawn (the same stream as before the option existed).

    Args:
        disparity: :math:`(B, 1, H, W)`; valid: bool :math:`(B, 1, H, W)` (non-occluded pixels).
    Returns:
        ``(keep, x, y, x_pos, x_neg)``: ``keep`` bool :math:`(B,)` (images with at least one valid pixel),
        the others :math:`(B', N)` float pixel coordinates of the kept images.
    """
    b, _, h, w = disparity.shape
    dev, dtype = disparity.device, disparity.dtype
    x_l = torch.arange(w, device=dev, dtype=dtype).expand(h, w)
    ok = valid[:, 0] & (x_l - disparity[:, 0] >= 0)  # BxHxW: the true match lies inside the right image
    weights = ok.reshape(b, -1).to(dtype)
    keep = weights.sum(dim=1) > 0
    if not bool(keep.any()):
        empty = disparity.new_zeros(0, num_samples)
        return keep, empty, empty, empty, empty
    n_edge = round(edge_share * num_samples) if edge_share > 0 else 0
    idx = weights.new_zeros(int(keep.sum()), 0, dtype=torch.long)
    if num_samples > n_edge:
        idx = torch.multinomial(weights[keep], num_samples - n_edge, replacement=True, generator=generator)  # BxN
    if n_edge:
        near, other = edge_maps(disparity, valid, edge_radius)
        w_edge = (ok & near[:, 0]).reshape(b, -1).to(dtype)[keep]
        w_edge = torch.where(w_edge.sum(dim=1, keepdim=True) > 0, w_edge, weights[keep])
        idx = torch.cat([torch.multinomial(w_edge, n_edge, replacement=True, generator=generator), idx], dim=1)
    ys, xs = (idx // w).to(dtype), (idx % w).to(dtype)
    d = disparity[keep].reshape(int(keep.sum()), -1).gather(1, idx)
    offset = torch.rand(d.shape, generator=generator, device=dev, dtype=dtype) * (neg_high - neg_low) + neg_low
    sign = torch.where(torch.rand(d.shape, generator=generator, device=dev) < 0.5, -1.0, 1.0).to(dtype)
    x_pos = xs - d
    x_neg = x_pos + sign * offset
    x_neg = torch.where((x_neg < 0) | (x_neg > w - 1), x_pos - sign * offset, x_neg).clamp(0, w - 1)
    if n_edge:  # the first n_edge samples: the other side's disparity as the negative where it is usable
        d_other = other[keep].reshape(int(keep.sum()), -1).gather(1, idx[:, :n_edge])
        x_other = xs[:, :n_edge] - d_other
        usable = ((d_other - d[:, :n_edge]).abs() >= neg_low) & (x_other >= 0) & (x_other <= w - 1)
        x_neg[:, :n_edge] = torch.where(usable, x_other, x_neg[:, :n_edge])
    return keep, xs, ys, x_pos, x_neg


def matching_loss(s_pos: torch.Tensor, s_neg: torch.Tensor, margin: float = 0.2, loss: str = "hinge") -> torch.Tensor:
    """MC-CNN loss on similarities of positive and negative pairs (any equal shapes).

    ``"hinge"``: ``mean(max(0, margin + s_neg - s_pos))``; ``"bce"``: binary cross-entropy with the
    similarities scaled by ``1 / margin`` as logits (positives labelled 1, negatives 0).
    """
    if loss == "hinge":
        return F.relu(margin + s_neg - s_pos).mean()
    if loss == "bce":
        logits = torch.cat([s_pos.flatten(), s_neg.flatten()]) / margin
        labels = torch.cat([torch.ones_like(s_pos.flatten()), torch.zeros_like(s_neg.flatten())])
        return F.binary_cross_entropy_with_logits(logits, labels)
    raise StereoInputError(f"loss: expected 'hinge' or 'bce', got {loss!r}")


def siamese_pair_loss(net: SiameseNet, left: torch.Tensor, right: torch.Tensor, disparity: torch.Tensor,
                      valid: torch.Tensor, num_samples: int = 512, margin: float = 0.2, neg_low: float = 1.5,
                      neg_high: float = 8.0, loss: str = "hinge",
                      generator: torch.Generator | None = None, teacher: SiameseNet | None = None,
                      distill: float = 0.0, edge_share: float = 0.0, edge_radius: int = 4) -> torch.Tensor:
    """MC-CNN training loss on patches sampled from ground truth (see :func:`sample_training_pixels`).

    Only the sampled patches go through the network (as MC-CNN trains), so a step costs
    ``3 * num_samples`` patch evaluations per image instead of two dense feature maps.

    With a ``teacher`` (another, frozen tower) and ``distill > 0``, the loss adds ``distill`` times the mean
    squared difference between the network's similarities and the teacher's on the same positive and negative
    pairs (relational distillation: feature widths may differ, similarities are comparable).
    ``edge_share``, ``edge_radius``: depth-edge samples and negatives (:func:`sample_training_pixels`).

    Args:
        left, right: images :math:`(B, C, H, W)`; disparity :math:`(B, 1, H, W)`; valid bool :math:`(B, 1, H, W)`.
    Returns:
        scalar loss (0 with a gradient path when no pixel is valid).
    """
    keep, xs, ys, x_pos, x_neg = sample_training_pixels(disparity, valid, num_samples, neg_low, neg_high,
                                                        generator, edge_share, edge_radius)
    if xs.numel() == 0:
        return sum(p.sum() for p in net.parameters()) * 0.0
    f_left = net.patch_features(left[keep], xs, ys)  # BxFxN
    f_pos = net.patch_features(right[keep], x_pos, ys)
    f_neg = net.patch_features(right[keep], x_neg, ys)
    s_pos, s_neg = (f_left * f_pos).sum(1), (f_left * f_neg).sum(1)
    out = matching_loss(s_pos, s_neg, margin, loss)
    if teacher is not None and distill > 0:
        with torch.no_grad():
            t_left = teacher.patch_features(left[keep], xs, ys)
            t_pos = (t_left * teacher.patch_features(right[keep], x_pos, ys)).sum(1)
            t_neg = (t_left * teacher.patch_features(right[keep], x_neg, ys)).sum(1)
        out = out + distill * 0.5 * (F.mse_loss(s_pos, t_pos) + F.mse_loss(s_neg, t_neg))
    return out
