"""The one 1-D correlation of learned features along the scanline (DispNet-C, GwcNet, MC-CNN's dot product).

``similarity[b, g, d, y, x] = reduce_{c in group g} feat_left[b, c, y, x] * feat_right[b, c, y, x - d]`` with
``reduce`` the channel mean (DispNet, GwcNet) or sum (the Siamese dot product), ``fill`` where ``x - d < 0``.
:func:`group_correlation_1d` is the implementation; :func:`correlation_1d` is its one-group case, and the
public, checked :func:`stereonet.cost.correlation_similarity` and the Siamese cost ``1 - <f_l, f_r>``
(:func:`stereonet.models.siamese.siamese_cost_volume`, whose CPU path is a numba kernel tested equal to it)
are built on them. Differentiable.
"""

from __future__ import annotations

import torch

from stereonet.checks import StereoInputError


def group_correlation_1d(feat_left: torch.Tensor, feat_right: torch.Tensor, max_disp: int, groups: int = 1,
                         reduce: str = "mean", fill: float = 0.0) -> torch.Tensor:
    """Group-wise 1-D correlation: the channels split into ``groups``, one correlation per group.

    Args:
        feat_left, feat_right: :math:`(B, C, H, W)`, C divisible by ``groups``.
        max_disp: largest disparity in pixels of this feature scale; D = max_disp + 1 levels.
        reduce: ``"mean"`` (default) or ``"sum"`` over each group's channels.
        fill: the value where ``x - d < 0``.

    Returns:
        similarity :math:`(B, G, D, H, W)`; its mean over groups is :func:`correlation_1d`.
    """
    if feat_left.shape != feat_right.shape:
        raise StereoInputError(f"feat_right: expected shape {tuple(feat_left.shape)}, got {tuple(feat_right.shape)}")
    if reduce not in ("mean", "sum"):
        raise StereoInputError(f"reduce: expected 'mean' or 'sum', got {reduce!r}")
    b, c, h, w = feat_left.shape
    if c % groups:
        raise StereoInputError(f"groups: expected a divisor of the {c} feature channels, got {groups}")
    fl = feat_left.view(b, groups, c // groups, h, w)  # BxGx(C/G)xHxW
    fr = feat_right.view(b, groups, c // groups, h, w)
    similarity = feat_left.new_full((b, groups, max_disp + 1, h, w), fill)  # BxGxDxHxW
    for d in range(min(max_disp + 1, w)):
        prod = fl[..., d:] * fr[..., : w - d]
        similarity[:, :, d, :, d:] = prod.mean(dim=2) if reduce == "mean" else prod.sum(dim=2)
    return similarity


def correlation_1d(feat_left: torch.Tensor, feat_right: torch.Tensor, max_disp: int, reduce: str = "mean",
                   fill: float = 0.0) -> torch.Tensor:
    """DispNet 1-D correlation (a similarity volume, higher = better): :func:`group_correlation_1d` with one
    group, :math:`(B, C, H, W)` features -> :math:`(B, D, H, W)`, D = max_disp + 1."""
    return group_correlation_1d(feat_left, feat_right, max_disp, 1, reduce, fill)[:, 0]
