"""Residual vertical misalignment of a rectified pair (stereonet.geometry.align)."""

import numpy as np
import pytest
import torch

from stereonet.checks import StereoInputError
from stereonet.geometry.align import (
    VerticalMisalignment,
    align_right,
    auto_align,
    fit_vertical_misalignment,
    needs_alignment,
)


def _matches(a, b, c, n=200, seed=0, outliers=0, disp_range=(2, 30), sign=1.0):
    """Matches whose right row is the left row plus ``a + b x_r + c y_l`` (x_r: the right view's column, where a
    roll of the right view acts), plus 0.05 px noise; ``sign`` -1: a reversed rig (negative disparities)."""
    rng = np.random.default_rng(seed)
    left = np.stack([rng.uniform(0, 300, n), rng.uniform(0, 200, n)], 1)
    x_r = left[:, 0] - sign * rng.uniform(*disp_range, n)
    right = np.stack([x_r, left[:, 1] + a + b * x_r + c * left[:, 1] + rng.normal(0, 0.05, n)], 1)
    if outliers:  # repeated patterns: a row or two off
        right[:outliers, 1] += rng.choice([-2.0, 1.5, 2.5], outliers)
    return left, right


def test_the_plane_is_recovered_despite_outliers_and_implausible_matches_are_ignored():
    left, right = _matches(0.6, 0.002, -0.001, outliers=40)
    left = np.concatenate([left, [[100.0, 50.0], [150.0, 60.0]]])
    right = np.concatenate([right, [[30.0, 50.0], [150.0, 70.0]]])  # 70 px apart; 10 rows off
    model = fit_vertical_misalignment(left, right, 300, 200, max_disp=40)
    assert model.a == pytest.approx(0.6, abs=0.03) and model.b == pytest.approx(0.002, abs=2e-4)
    assert model.c == pytest.approx(-0.001, abs=3e-4) and model.matches <= 160 and model.error < 0.05
    assert needs_alignment(model, 300, 200)
    assert fit_vertical_misalignment(left[:10], right[:10], 300, 200) is None  # too few matches
    left_m, mirrored = _matches(0.6, 0.002, -0.001, outliers=40, sign=-1.0)  # a reversed rig
    mirrored_model = fit_vertical_misalignment(left_m, mirrored, 300, 200, max_disp=40)
    assert mirrored_model.a == pytest.approx(0.6, abs=0.03) and mirrored_model.b == pytest.approx(0.002, abs=2e-4)


def test_the_plane_is_fitted_where_align_right_applies_it():
    """A roll of the right view (dy grows with its own column) at disparities up to 120 px: the plane is fitted at
    the right column, so it explains the offsets to the noise (a fit at the left column left b d = 0.6 px)."""
    left, right = _matches(0.2, 0.005, 0.0, disp_range=(0, 120))
    model = fit_vertical_misalignment(left, right, 300, 200, max_disp=128)
    assert model.b == pytest.approx(0.005, abs=2e-4) and model.a == pytest.approx(0.2, abs=0.03)
    assert model.spread < 0.08  # the 0.05 px noise, not the disparity-dependent part


def test_an_aligned_pair_is_not_corrected_and_a_scattered_fit_is_not_trusted():
    left, right = _matches(0.0, 0.0, 0.0, seed=1)
    assert not needs_alignment(fit_vertical_misalignment(left, right, 300, 200), 300, 200)
    loose = VerticalMisalignment(0.3, 0.0, 0.0, 20, 0.5, 0.2)  # 0.3 px, but +- 0.2: not clear
    assert not needs_alignment(loose, 300, 200)
    assert needs_alignment(VerticalMisalignment(0.3, 0.0, 0.0, 20, 0.5, 0.01), 300, 200)
    assert not needs_alignment(None, 300, 200)
    with pytest.raises(StereoInputError, match="threshold"):
        needs_alignment(loose, 300, 200, threshold=-1)
    with pytest.raises(StereoInputError, match="min_matches"):
        fit_vertical_misalignment(left, right, 300, 200, min_matches=2)


def test_align_right_undoes_a_vertical_shift_and_auto_align_measures_it():
    g = torch.Generator().manual_seed(0)
    base = torch.nn.functional.avg_pool2d(torch.rand(1, 1, 140, 220, generator=g), 3, 1, 1)
    base = (base - base.min()) / (base.max() - base.min())
    left = base[..., 10:130, 10:210].contiguous()
    right = base[..., 12:132, 14:214].contiguous()  # 4 px disparity; a left point sits 2 rows higher in the right
    model = VerticalMisalignment(-2.0, 0.0, 0.0, 100, 0.0, 0.0)
    moved = align_right(right, model)
    assert torch.allclose(moved[..., 2:, :], base[..., 12:130, 14:214], atol=1e-5)  # integer shift: exact
    fixed, fitted, corrected = auto_align(left, right, max_disp=16)
    assert corrected and fitted.a == pytest.approx(-2.0, abs=0.15) and abs(fitted.b) < 0.005
    assert (fixed[..., 5:-5, 5:-5] - moved[..., 5:-5, 5:-5]).abs().mean() < 0.02
    same, _, corrected = auto_align(left, base[..., 10:130, 14:214].contiguous(), max_disp=16)
    assert not corrected
