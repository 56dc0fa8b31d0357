"""Residual vertical misalignment of a rectified pair: measured from SIFT matches, corrected on the right view.

A pair taken as rectified (a calibrated rig whose calibration has drifted, a phone pair rectified from estimated
geometry, a dataset's "imperfect" rectification) often keeps a fraction of a pixel of vertical offset between
corresponding points. Dense matchers search along the scanline only, and half a pixel is enough to cost them much of
their accuracy (model card, thirty-third session: on renders with the right view 0.5 px low, `sgm`'s bad-2 rises from
11.7 to 20.4 %, `sgm-refine`'s from 10.3 to 17.0 %).

The offset is modelled as a plane over the image, ``dy(x, y) = a + b x + c y`` (pixels; a global shift, a small
relative rotation, a small scale difference) at the right view's column ``x`` and the left view's row ``y`` (where
:func:`align_right` applies it: a fit at the left column would leave ``b d`` px at disparity ``d``), fitted by least
squares to the vertical offsets of SIFT matches
(:func:`~stereonet.features.matching.match_sift`) whose horizontal offset is a plausible disparity, with iterated
rejection of outliers (3 robust standard deviations). :func:`align_right` resamples the right view along the columns so
that ``right'(x, y) = right(x, y + dy(x, y))``; the left view, and so the left-view disparity, are unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from stereonet.checks import StereoInputError, check_image_pair

ALIGN_THRESHOLD = 0.25
"""px: :func:`auto_align` corrects a pair whose fitted offset reaches this anywhere in the image (half of the 0.5 px
that measurably hurts every matcher; several times the fit's own error with a few dozen matches)."""

MAX_VERTICAL = 4.0
"""px: matches with a larger vertical offset are not taken as the same point (a pair off by more is not rectified)."""


@dataclass(frozen=True)
class VerticalMisalignment:
    """``dy(x, y) = a + b x + c y`` in pixels (right minus left; ``x`` the right view's column, ``y`` the left view's
    row; pixel centres at integers), from ``matches`` inlier
    matches whose offsets scatter by ``spread`` px (robust standard deviation) around the plane; ``error``: the
    largest standard error of the fitted ``dy`` at the image's corners (px)."""

    a: float
    b: float
    c: float
    matches: int
    spread: float
    error: float

    def dy(self, x, y):
        return self.a + self.b * x + self.c * y

    def largest(self, width: int, height: int) -> float:
        """The largest ``|dy|`` over the image (at one of its corners: the model is a plane)."""
        return max(abs(self.dy(x, y)) for x in (0, width - 1) for y in (0, height - 1))


def estimate_vertical_misalignment(left: torch.Tensor, right: torch.Tensor, max_disp: int | None = None,
                                   min_matches: int = 20) -> VerticalMisalignment | None:
    """The vertical offset plane of a rectified pair (see the module doc) from SIFT matches
    (:func:`~stereonet.features.matching.match_sift`), or None (see :func:`fit_vertical_misalignment`).
    ``left``, ``right``: :math:`(B, C, H, W)` in [0, 1]; the first pair of the batch is measured."""
    from stereonet.features.matching import match_sift

    check_image_pair(left, right)
    p1, p2 = match_sift(left, right, min_matches=0)
    return fit_vertical_misalignment(p1.numpy().reshape(-1, 2), p2.numpy().reshape(-1, 2), left.shape[-1],
                                     left.shape[-2], max_disp, min_matches)


def fit_vertical_misalignment(pts_left: np.ndarray, pts_right: np.ndarray, width: int, height: int,
                              max_disp: int | None = None, min_matches: int = 20) -> VerticalMisalignment | None:
    """The plane ``dy = a + b x + c y`` fitted to matches ``(N, 2)`` (x, y) of a ``width`` x ``height`` pair, or None
    when fewer than ``min_matches`` matches with a plausible disparity (``|x_l - x_r| <= max_disp + 1`` of either
    sign: converging and reversed rigs too; ``max_disp`` None = half the width) and ``|dy| <= 4`` px remain around
    the bulk of the offsets (a textureless pair, or not a rectified one)."""
    if isinstance(min_matches, bool) or not isinstance(min_matches, int) or min_matches < 3:
        raise StereoInputError(f"min_matches: expected an integer >= 3, got {min_matches!r}")
    limit = width / 2 if max_disp is None else float(max_disp)
    p1, p2 = np.asarray(pts_left, np.float64), np.asarray(pts_right, np.float64)
    disp, dy = p1[:, 0] - p2[:, 0], p2[:, 1] - p1[:, 1]
    keep = (np.abs(disp) <= limit + 1.0) & (np.abs(dy) <= MAX_VERTICAL)
    x, y, dy = p2[keep, 0], p1[keep, 1], dy[keep]  # where align_right evaluates it: right column, target row
    if len(dy) < min_matches:
        return None
    inliers = np.abs(dy - np.median(dy)) <= 0.5  # the bulk first: repeated patterns give matches a row or two off
    coef, spread, design = np.zeros(3), 0.0, np.zeros((0, 3))
    for _ in range(5):
        if inliers.sum() < min_matches:
            return None
        design = np.stack([np.ones(inliers.sum()), x[inliers], y[inliers]], 1)
        coef = np.linalg.lstsq(design, dy[inliers], rcond=None)[0]
        residual = dy - (coef[0] + coef[1] * x + coef[2] * y)
        spread = 1.4826 * float(np.median(np.abs(residual[inliers])))
        updated = np.abs(residual) <= max(3.0 * spread, 0.1)
        if np.array_equal(updated, inliers):
            break
        inliers = updated
    if inliers.sum() < min_matches:
        return None
    cov = max(spread, 0.01) ** 2 * np.linalg.pinv(design.T @ design)  # of (a, b, c), from the inliers' scatter
    corners = np.array([[1.0, cx, cy] for cx in (0, width - 1) for cy in (0, height - 1)])
    error = float(np.sqrt(np.einsum("ij,jk,ik->i", corners, cov, corners)).max())
    return VerticalMisalignment(float(coef[0]), float(coef[1]), float(coef[2]), int(inliers.sum()), spread, error)


def align_right(right: torch.Tensor, model: VerticalMisalignment) -> torch.Tensor:
    """``right`` :math:`(B, C, H, W)` resampled along its columns (bicubic, which blurs less than bilinear; border
    replicated; clamped to the input's range against the cubic's overshoot) so that its point ``(x, y + dy(x, y))``
    lands on row ``y``: the pair's vertical offset removed, the horizontal one kept."""
    _, _, h, w = right.shape
    ys, xs = torch.meshgrid(torch.arange(h, dtype=torch.float64), torch.arange(w, dtype=torch.float64),
                            indexing="ij")
    src_y = ys + model.dy(xs, ys)
    grid = torch.stack([(2 * xs + 1) / w - 1, (2 * src_y + 1) / h - 1], -1).to(right.dtype).to(right.device)
    out = F.grid_sample(right, grid.expand(right.shape[0], h, w, 2), mode="bicubic", padding_mode="border",
                        align_corners=False)
    return out.clamp(float(right.min()), float(right.max()))


def needs_alignment(model: VerticalMisalignment | None, width: int, height: int,
                    threshold: float = ALIGN_THRESHOLD) -> bool:
    """Whether the fitted offset, less twice its standard error, reaches ``threshold`` px somewhere in the image (a
    clear offset, not the scatter of a few matches)."""
    if not threshold >= 0:
        raise StereoInputError(f"threshold: expected a value >= 0 pixels, got {threshold!r}")
    return model is not None and model.largest(width, height) - 2.0 * model.error >= threshold


def auto_align(left: torch.Tensor, right: torch.Tensor, max_disp: int | None = None,
               threshold: float = ALIGN_THRESHOLD) -> tuple[torch.Tensor, VerticalMisalignment | None, bool]:
    """``(right', model, corrected)``: the right view aligned by :func:`align_right` when :func:`needs_alignment`,
    else ``right`` itself (also when no model could be fitted: ``model`` None)."""
    model = estimate_vertical_misalignment(left, right, max_disp)
    if not needs_alignment(model, right.shape[-1], right.shape[-2], threshold):
        return right, model, False
    return align_right(right, model), model, True
