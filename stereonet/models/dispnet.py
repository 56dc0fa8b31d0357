"""A small DispNet-style correlation U-Net (Mayer et al., CVPR 2016), sized for CPU training.

Shared encoder on both images down to 1/4, a 1-D correlation along the scanline at 1/4 resolution,
an encoder on [correlation, left features] down to 1/16, and a decoder with skip connections that predicts
disparity at every scale (1/16, 1/8, 1/4, 1/2, 1/1). The 1/16 and 1/8 predictions are regressed from the
decoder (as in DispNet); from 1/4 on, each prediction is a residual on a coarser one, and the 1/4 one starts
from a soft-argmin over the (lightly aggregated) correlation, so that the network matches from its first
training step and the decoder only learns corrections (our change to DispNet for short CPU training).
The 1/2 and 1/1 decoder stages also see a *local* correlation: shared features of the right view, warped
by the upsampled coarser disparity, are correlated with the left features at ``±refine_radius`` pixels of
that scale (as in the refinement stages of DispNet-CSS / PWC-Net), so the fine residuals are matched, not
guessed from the image.
With ``upsample="select"`` the coarse disparity is not upsampled bilinearly before those stages: each fine
pixel chooses (softmax) among the 3x3 coarse neighbours of its parent cell and the bilinear value, by the
correlation of the left features with the right ones warped by each candidate plus a learned context term
(a PatchMatch/HITNet-style propagation written as a soft selection). A pixel beside a depth edge can then
take the foreground's or the background's disparity instead of a blend of both, which is what makes edges
sharp; the local-correlation residual follows as before.
With ``refine_readout="matched"`` the 1/2 and 1/1 corrections are not regressed freely from the decoder features:
each is the soft-argmax of that stage's local correlation plus learned logits (a matched read-out, as the 1/4 start
is one), so a fine correction is always a match within ``±refine_radius`` pixels of that scale.
Every disparity in the output is in pixels of the *input* resolution, left-referenced.

The network needs its input padded to a multiple of :attr:`DispNet.stride`; :func:`predict_disparity`
pads and unpads (never crops).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from stereonet.aggregate.soft import soft_argmax
from stereonet.checks import StereoInputError, check_image_pair
from stereonet.cost.census import census_signs, to_grey
from stereonet.cost.correlation import correlation_1d, group_correlation_1d
from stereonet.models.layers import (
    InputPadder,
    PlaneConv3d,
    conv3d_block,
    conv_block,
    local_correlation,
    standardize_image,
    unit_channels,
    upconv_block,
    warped_correlation,
)


@dataclass
class DispNetOutput:
    """What :class:`DispNet` returns, the same structure in train and eval mode.

    Attributes:
        disparity: full-resolution prediction :math:`(B, 1, H, W)`.
        pyramid: predictions coarse to fine, scales 1/16, 1/8, 1/4, 1/2, 1/1, each :math:`(B, 1, H/s, W/s)`,
            values in pixels of the full resolution.
        features: decoder features ``{1: (B, C0, H, W), 2: (B, C1, H/2, W/2), 4: (B, C2, H/4, W/4)}`` keyed by
            stride (used by the SMD head).
        matched: the soft-argmin of the correlation at 1/4, :math:`(B, 1, H/4, W/4)` in input pixels (the
            start of the 1/4 prediction; trained with its own loss so the features learn to match).
    """

    disparity: torch.Tensor
    pyramid: list[torch.Tensor]
    features: dict[int, torch.Tensor]
    matched: torch.Tensor


def _mean2x2(x: torch.Tensor) -> torch.Tensor:
    """2x2 area downsampling of :math:`(B, C, H, W)` (H, W even) as fixed-order elementwise sums."""
    return ((x[..., 0::2, 0::2] + x[..., 0::2, 1::2]) + (x[..., 1::2, 0::2] + x[..., 1::2, 1::2])) * 0.25


def _up2(x: torch.Tensor) -> torch.Tensor:
    return F.interpolate(x, scale_factor=2.0, mode="bilinear", align_corners=False)


class DispNet(nn.Module):
    """DispNet-C style network.

    Args:
        max_disp: largest disparity (input pixels) the correlation layer covers; the correlation at 1/4 has
            ``max_disp // 4 + 1`` channels. Larger disparities cannot be matched (see ``predict_disparity``).
        channels: base width ``c``; encoder widths are c, 2c, 4c, 6c.
        refine_radius: half-width (pixels of each scale) of the local correlations at 1/2 and 1/1.
        aggregation: how the 1/4 correlation is turned into the soft-argmin start: "2d" (2-D convolutions with
            the disparities as channels) or "3d" (a group-wise correlation volume, ``groups`` groups,
            aggregated by three 3x3x3 convolutions as in GwcNet; much better matching for little time).
        groups: channel groups of the "3d" correlation (of the 2c learned channels, or of the census comparisons).
        agg_dilations: the spatial dilations of the "3d" aggregation's three 3x3x3 convolutions (default (1, 1, 1):
            a reach of 7 cells of 1/4 = 28 input px; (1, 2, 4) reaches 15 cells for the same parameters).
        upsample: how each coarser disparity reaches the 1/2 and 1/1 stages: "bilinear" or "select" (a
            matched soft choice among the 3x3 coarse neighbours and the bilinear value; sharp edges).
        matching: what every correlation compares: "learned" (the shared encoder's unit-length features) or
            "census" (:func:`~stereonet.cost.census.census_signs` of the grey image, ``census_window`` square,
            at each scale of the area-downsampled grey image: fixed features that no training data can bias;
            the encoder then runs on the left image only, as context).
        refine_readout: how the 1/2 and 1/1 stages correct the disparity they receive: "residual" (a free
            regression from the decoder features, DispNet's) or "matched" (the soft-argmax over the local
            correlation's ``2 refine_radius + 1`` shifts of the correlation plus learned logits, the logits' layer
            zero at the start: a correction that is always a match within reach; needs ``refine_radius >= 1``).
        volume: what the 1/4 matching volume compares (``matching="census"`` only for the last two): "coarse" (the
            features at 1/4, DispNet's), "pooled" (the full-resolution features compared at every integer disparity,
            each group's correlation averaged over the 4x4 input pixels of a 1/4 cell and maximised over the 4
            disparities of each level, :func:`pooled_group_correlation`: a 1/4 cell's evidence from the image's fine
            texture, which the 1/4 census of the area-downsampled image averages away) or "both" (the two volumes'
            groups side by side, ``2 groups`` channels into the "3d" aggregation; the plain correlation is their mean).
    """

    stride = 16
    scales = (16, 8, 4, 2, 1)

    def __init__(self, max_disp: int = 96, channels: int = 16, refine_radius: int = 2,
                 aggregation: str = "2d", groups: int = 4, upsample: str = "bilinear",
                 matching: str = "learned", agg_dilations: tuple[int, int, int] | list[int] = (1, 1, 1),
                 refine_readout: str = "residual", volume: str = "coarse") -> None:
        super().__init__()
        if max_disp < 4:
            raise StereoInputError(f"max_disp: expected >= 4, got {max_disp}")
        if aggregation not in ("2d", "3d"):
            raise StereoInputError(f"aggregation: expected '2d' or '3d', got {aggregation!r}")
        if upsample not in ("bilinear", "select"):
            raise StereoInputError(f"upsample: expected 'bilinear' or 'select', got {upsample!r}")
        if matching not in ("learned", "census"):
            raise StereoInputError(f"matching: expected 'learned' or 'census', got {matching!r}")
        matched_channels = self.census_window ** 2 - 1 if matching == "census" else 2 * channels
        if groups < 1 or matched_channels % groups:
            raise StereoInputError(f"groups: expected a divisor of the {matched_channels} matching channels "
                                   f"({'census comparisons' if matching == 'census' else '2 * channels'}), "
                                   f"got {groups}")
        if refine_radius < 0:
            raise StereoInputError(f"refine_radius: expected >= 0, got {refine_radius}")
        if refine_readout not in ("residual", "matched"):
            raise StereoInputError(f"refine_readout: expected 'residual' or 'matched', got {refine_readout!r}")
        if refine_readout == "matched" and refine_radius < 1:
            raise StereoInputError(f"refine_radius: refine_readout='matched' needs >= 1, got {refine_radius}")
        if volume not in ("coarse", "pooled", "both"):
            raise StereoInputError(f"volume: expected 'coarse', 'pooled' or 'both', got {volume!r}")
        if volume != "coarse" and matching != "census":
            raise StereoInputError(f"volume: {volume!r} needs matching='census', got matching={matching!r}")
        agg_dilations = tuple(agg_dilations)
        if len(agg_dilations) != 3 or not all(isinstance(s, int) and not isinstance(s, bool) and s >= 1
                                              for s in agg_dilations):
            raise StereoInputError(f"agg_dilations: expected three integers >= 1, got {agg_dilations!r}")
        if aggregation == "2d" and agg_dilations != (1, 1, 1):
            raise StereoInputError(f"agg_dilations: only aggregation='3d' has them, got {agg_dilations!r} with '2d'")
        self.max_disp = int(max_disp)
        self.channels = int(channels)
        self.refine_radius = int(refine_radius)
        self.agg_dilations = agg_dilations
        self.aggregation, self.groups = aggregation, int(groups)
        self.upsample = upsample
        self.matching = matching
        self.refine_readout = refine_readout
        self.volume = volume
        c = self.channels
        r = 2 * self.refine_radius + 1  # channels of each local correlation
        self.corr_disp = self.max_disp // 4
        d4 = self.corr_disp + 1
        self.disp_unit = self.max_disp / 8.0  # predictor outputs are scaled by this (keeps raw outputs ~1)
        # shared encoder, both images: 1/1 (matching features only), 1/2 and 1/4
        self.enc0 = nn.Sequential(conv_block(3, c // 2), conv_block(c // 2, c // 2))
        self.enc1 = nn.Sequential(conv_block(3, c, 5, stride=2), conv_block(c, c))
        self.enc2 = nn.Sequential(conv_block(c, 2 * c, 3, stride=2), conv_block(2 * c, 2 * c))
        # left-only after the correlation: 1/8 and 1/16
        self.redir = conv_block(2 * c, c, 1)
        self.corr_scale = nn.Parameter(torch.tensor(10.0))  # cosine similarity -> soft-argmin logits
        self.local_scale = nn.Parameter(torch.tensor(10.0))  # the same for the local correlations
        if aggregation == "2d":  # disparities as channels of 2-D convolutions
            self.corr_agg = nn.Sequential(conv_block(d4, d4), nn.Conv2d(d4, d4, 3, padding=1))
        else:  # group-wise correlation volume aggregated by 3-D convolutions over (disparity, y, x)
            g = self.groups
            s0, s1, s2 = agg_dilations
            g_in = 2 * g if volume == "both" else g
            self.corr_agg = nn.Sequential(conv3d_block(g_in, 8, s0), conv3d_block(8, 8, s1), PlaneConv3d(8, 1, s2))
        self.enc3 = nn.Sequential(conv_block(d4 + c, 4 * c, 3, stride=2), conv_block(4 * c, 4 * c))
        self.enc4 = nn.Sequential(conv_block(4 * c, 6 * c, 3, stride=2), conv_block(6 * c, 6 * c))
        # decoder
        self.pred4 = nn.Conv2d(6 * c, 1, 3, padding=1)
        self.up3 = upconv_block(6 * c, 4 * c)
        self.dec3 = conv_block(4 * c + 4 * c + 1, 4 * c)
        self.pred3 = nn.Conv2d(4 * c, 1, 3, padding=1)
        self.up2 = upconv_block(4 * c, 2 * c)
        self.dec2 = conv_block(2 * c + 2 * c + d4 + 1, 2 * c)
        self.pred2 = nn.Conv2d(2 * c, 1, 3, padding=1)
        self.up1 = upconv_block(2 * c, c)
        self.dec1 = nn.Sequential(conv_block(c + c + r + 1, c), conv_block(c, c))
        k_out = r if refine_readout == "matched" else 1  # the 1/2 and 1/1 heads: logits or a residual
        self.pred1 = nn.Conv2d(c, k_out, 3, padding=1)
        self.up0 = upconv_block(c, c // 2)
        self.dec0 = nn.Sequential(conv_block(c // 2 + 3 + r + 1, c // 2), conv_block(c // 2, c // 2))
        self.pred0 = nn.Conv2d(c // 2, k_out, 3, padding=1)
        self.refine_unit = 2.0  # the 1/2 and 1/1 residuals: raw outputs ~1 = 2 input pixels
        if refine_readout == "matched":  # logits added to each local correlation: zero at the start
            for head in (self.pred1, self.pred0):
                nn.init.zeros_(head.weight)
                nn.init.zeros_(head.bias)
        if upsample == "select":  # context logits of the candidate choice at 1/2 and 1/1
            k = self.num_candidates
            self.select1 = nn.Sequential(conv_block(c + c + 2 * k, c), nn.Conv2d(c, k, 3, padding=1))
            self.select0 = nn.Sequential(conv_block(c // 2 + c // 2 + 2 * k, c // 2), nn.Conv2d(c // 2, k, 3, padding=1))
            for head in (self.select1, self.select0):  # start as pure matching: logits = correlation
                nn.init.zeros_(head[-1].weight)
                nn.init.zeros_(head[-1].bias)
            self.select_scale = nn.Parameter(torch.tensor(10.0))

    num_candidates = 10  # 3x3 coarse neighbours + the bilinear value
    census_window = 5  # of matching="census", at every scale

    def _census_features(self, left: torch.Tensor, right: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """Census signs of both views at 1/1, 1/2 and 1/4 (the grey image area-downsampled to each scale),
        each :math:`(2B, n, H/s, W/s)`, left views first, as the unit-length matching features of each scale.

        The grey image (:func:`~stereonet.cost.census.to_grey`) and its 2x2 means are fixed-order elementwise sums,
        so that an exported graph (onnxruntime) computes the same census bits."""
        both = torch.cat([left, right], dim=0)
        if both.shape[1] == 1:  # as standardize_image: a grey pair is three equal channels (the same bits as a
            both = both.expand(-1, 3, -1, -1)  # graph that receives it expanded)
        grey = to_grey(both)
        half = _mean2x2(grey)
        return tuple(census_signs(g, self.census_window) for g in (grey, half, _mean2x2(half)))

    def _group_volume(self, n0: torch.Tensor, n2: torch.Tensor, b: int) -> torch.Tensor:
        """The 1/4 group volume of ``volume="pooled"`` or ``"both"`` from the census features at 1/1 (``n0``) and 1/4
        (``n2``), both :math:`(2B, n, H/s, W/s)` left views first; :math:`(B, G', D4, H/4, W/4)`."""
        with torch.no_grad():  # fixed features: nothing to learn through the comparisons
            pooled = pooled_group_correlation(n0[:b], n0[b:], self.max_disp, self.groups, 4)
        if self.volume == "pooled":
            return pooled
        return torch.cat([group_correlation_1d(n2[:b], n2[b:], self.corr_disp, self.groups), pooled], dim=1)

    def _select_up(self, coarse: torch.Tensor, unit_left: torch.Tensor, unit_right: torch.Tensor,
                   context: torch.Tensor, scale: int, head: nn.Module) -> torch.Tensor:
        """Upsample ``coarse`` :math:`(B, 1, h, w)` (input pixels) x2 by a matched soft choice.

        Candidates of each fine pixel: the 3x3 coarse neighbours of its parent cell and the bilinear value.
        Logits: cosine similarity of the unit-length features ``unit_left`` with ``unit_right`` warped by each
        candidate (features at the fine scale, ``scale`` input pixels per feature pixel) times a learned
        temperature, plus ``head`` on [context, similarities, candidate offsets]. Returns :math:`(B, 1, 2h, 2w)`.
        """
        b, _, h, w = coarse.shape
        neigh = F.unfold(F.pad(coarse, (1, 1, 1, 1), mode="replicate"), 3).view(b, 9, h, w)
        base = _up2(coarse)
        cands = torch.cat([F.interpolate(neigh, scale_factor=2.0, mode="nearest"), base], dim=1)  # BxKx2hx2w
        # The similarities are constants for training: the choice learns through its weights, the features
        # learn to match from the local correlations and the 1/4 soft-argmin (no gradient here saves ~3/4
        # of this function's training time).
        with torch.no_grad():  # mean over channels of unit vectors x C = cosine similarity
            corr = warped_correlation(unit_left, unit_right, cands / scale) * unit_left.shape[1]  # BxKx2hx2w
        offsets = (cands - base).detach() / self.refine_unit
        logits = corr * self.select_scale + head(torch.cat([context, corr, offsets], dim=1))
        return (logits.softmax(dim=1) * cands).sum(dim=1, keepdim=True)

    def _local_cost(self, unit_left: torch.Tensor, unit_right: torch.Tensor, disp: torch.Tensor,
                    scale: int) -> torch.Tensor:
        """Local correlation at one scale: unit-length features :math:`(B, C, h, w)`, ``disp``
        :math:`(B, 1, h, w)` in input pixels; returns :math:`(B, 2r+1, h, w)` logits (scaled correlation)."""
        return local_correlation(unit_left, unit_right, disp / scale, self.refine_radius) * self.local_scale

    def _correction(self, head: nn.Module, x: torch.Tensor, local: torch.Tensor, scale: int) -> torch.Tensor:
        """The 1/2 or 1/1 stage's correction :math:`(B, 1, h, w)` in input pixels (``scale`` input pixels per
        pixel of the stage): ``head``'s free residual, or the soft-argmax over the local correlation's shifts of
        ``local`` + ``head``'s logits (``refine_readout="matched"``)."""
        if self.refine_readout == "residual":
            return head(x) * self.refine_unit
        return (soft_argmax(local + head(x)) - self.refine_radius) * scale

    def forward(self, left: torch.Tensor, right: torch.Tensor) -> DispNetOutput:
        """left, right: :math:`(B, C, H, W)` in [0, 1], H and W multiples of :attr:`stride`."""
        h, w = left.shape[-2:]
        if h % self.stride or w % self.stride:
            raise StereoInputError(f"left: expected H and W multiples of {self.stride} (use predict_disparity to pad), "
                             f"got {tuple(left.shape)}")
        x_left = standardize_image(left)
        b = left.shape[0]
        if self.matching == "census":  # fixed matching features; the encoder is context for the left view
            e0, e1 = self.enc0(x_left), self.enc1(x_left)
            e2 = self.enc2(e1)
            n0, n1, n2 = self._census_features(left, right)
        else:  # 2BxCxHxW: one pass of the shared encoder over both views
            both = torch.cat([x_left, standardize_image(right)], dim=0)
            e0, e1 = self.enc0(both), self.enc1(both)
            e2 = self.enc2(e1)
            n0, n1, n2 = unit_channels(e0), unit_channels(e1), unit_channels(e2)  # normalised once per scale
        e1_l, e2_l = e1[:b], e2[:b]
        if self.volume != "coarse":
            gwc = self._group_volume(n0, n2, b)  # BxG'xD4xH/4xW/4
            corr = gwc.mean(dim=1)
            agg = self.corr_agg(corr) if self.aggregation == "2d" else self.corr_agg(gwc * self.groups)[:, 0]
            logits = corr * self.corr_scale + agg
        elif self.aggregation == "2d":
            corr = correlation_1d(n2[:b], n2[b:], self.corr_disp)  # BxD4xH/4xW/4
            logits = corr * self.corr_scale + self.corr_agg(corr)
        else:
            gwc = group_correlation_1d(n2[:b], n2[b:], self.corr_disp,
                                       self.groups)  # BxGxD4xH/4xW/4
            corr = gwc.mean(dim=1)  # the plain correlation (mean over all channels), BxD4xH/4xW/4
            logits = corr * self.corr_scale + self.corr_agg(gwc * self.groups)[:, 0]
        d_match = soft_argmax(logits) * 4.0  # Bx1xH/4xW/4, input pixels
        e3 = self.enc3(torch.cat([corr, self.redir(e2_l)], dim=1))
        e4 = self.enc4(e3)

        d4 = self.pred4(e4) * self.disp_unit
        x3 = self.dec3(torch.cat([self.up3(e4), e3, _up2(d4)], dim=1))
        d3 = _up2(d4) + self.pred3(x3) * self.disp_unit
        x2 = self.dec2(torch.cat([self.up2(x3), e2_l, corr, _up2(d3)], dim=1))
        d2 = d_match + self.pred2(x2) * self.disp_unit
        u1 = self.up1(x2)
        if self.upsample == "select":
            d1_init = self._select_up(d2, n1[:b], n1[b:], torch.cat([u1, e1_l], dim=1), 2, self.select1)
        else:
            d1_init = _up2(d2)
        local1 = self._local_cost(n1[:b], n1[b:], d1_init, 2)  # Bx(2r+1)xH/2xW/2
        x1 = self.dec1(torch.cat([u1, e1_l, local1, d1_init / self.disp_unit], dim=1))
        d1 = d1_init + self._correction(self.pred1, x1, local1, 2)
        u0 = self.up0(x1)
        if self.upsample == "select":
            d0_init = self._select_up(d1, n0[:b], n0[b:], torch.cat([u0, e0[:b]], dim=1), 1, self.select0)
        else:
            d0_init = _up2(d1)
        local0 = self._local_cost(n0[:b], n0[b:], d0_init, 1)  # Bx(2r+1)xHxW
        x0 = self.dec0(torch.cat([u0, x_left, local0, d0_init / self.disp_unit], dim=1))
        d0 = d0_init + self._correction(self.pred0, x0, local0, 1)
        return DispNetOutput(disparity=d0, pyramid=[d4, d3, d2, d1, d0], features={1: x0, 2: x1, 4: x2},
                             matched=d_match)


def pooled_group_correlation(feat_left: torch.Tensor, feat_right: torch.Tensor, max_disp: int, groups: int,
                             pool: int) -> torch.Tensor:
    """Group-wise 1-D correlation at full resolution pooled to ``1/pool`` (``volume="pooled"`` of :class:`DispNet`).

    Level ``k`` of the result (``k = 0 .. max_disp // pool``, disparity ``pool k`` input pixels) is, per group, the
    maximum over the integer disparities ``d`` of ``pool k - pool // 2 .. pool k + pool // 2 - 1`` (within ``0 ..
    max_disp``) of the group's correlation at ``d`` (:func:`~stereonet.cost.correlation.group_correlation_1d`'s
    values, 0 where ``x - d < 0``) averaged over each ``pool x pool`` cell. One level at a time, so memory stays at a
    few full-resolution planes whatever ``max_disp``.

    Args:
        feat_left, feat_right: :math:`(B, C, H, W)`, C divisible by ``groups``, H and W multiples of ``pool``.

    Returns:
        :math:`(B, G, max_disp // pool + 1, H / pool, W / pool)`.
    """
    b, c, h, w = feat_left.shape
    if feat_right.shape != feat_left.shape:
        raise StereoInputError(f"feat_right: expected shape {tuple(feat_left.shape)}, got {tuple(feat_right.shape)}")
    if c % groups or h % pool or w % pool:
        raise StereoInputError(f"feat_left: expected C divisible by groups={groups} and H, W by pool={pool}, "
                               f"got {tuple(feat_left.shape)}")
    fl = feat_left.view(b, groups, c // groups, h, w)
    fr = feat_right.view(b, groups, c // groups, h, w)
    levels = max_disp // pool + 1
    out = feat_left.new_zeros((b, groups, levels, h // pool, w // pool))
    for k in range(levels):
        best = None
        for d in range(max(pool * k - pool // 2, 0), min(pool * k + pool // 2 - 1, max_disp, w - 1) + 1):
            sim = F.pad((fl[..., d:] * fr[..., : w - d]).mean(dim=2), (d, 0))  # BxGxHxW, 0 where x < d
            pooled = F.avg_pool2d(sim, pool)
            best = pooled if best is None else torch.maximum(best, pooled)
        if best is not None:
            out[:, :, k] = best
    return out


def run_padded(net: nn.Module, left: torch.Tensor, right: torch.Tensor):
    """Pad ``left``/``right`` :math:`(B, C, H, W)` to ``net.stride`` and run ``net``; returns (output, padder).

    The caller unpads what it needs with ``padder.unpad`` (outputs are at the padded size).
    """
    left, right = check_image_pair(left, right)
    padder = InputPadder(left.shape[-2], left.shape[-1], net.stride)
    left_p, right_p = padder.pad(left, right)
    return net(left_p, right_p), padder


@torch.no_grad()
def predict_disparity(net: DispNet, left: torch.Tensor, right: torch.Tensor) -> torch.Tensor:
    """Full-resolution disparity :math:`(B, 1, H, W)` for any H, W (padded to the stride, then unpadded)."""
    out, padder = run_padded(net, left, right)
    return padder.unpad(out.disparity)
