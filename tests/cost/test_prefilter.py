"""Pre-filters before the census cost (stereonet.cost.prefilter) and sgm's / sgm-refine's prefilter option."""

import pytest
import torch

from stereonet.checks import StereoInputError
from stereonet.cost.prefilter import prefilter_image
from stereonet.matchers import match


def test_vertical_smooths_columns_only_and_binomial_both_axes():
    g = torch.Generator().manual_seed(0)
    rows = torch.rand(1, 1, 9, 1, generator=g).expand(1, 1, 9, 12).clone()  # varies along y only
    cols = torch.rand(1, 1, 1, 12, generator=g).expand(1, 1, 9, 12).clone()  # varies along x only
    assert torch.equal(prefilter_image(cols, "vertical"), cols)  # nothing to smooth along the columns
    out = prefilter_image(rows, "vertical")
    expected = 0.25 * rows[..., torch.clamp(torch.arange(9) - 1, 0, 8), :] + 0.5 * rows \
        + 0.25 * rows[..., torch.clamp(torch.arange(9) + 1, 0, 8), :]  # replicated border
    assert torch.allclose(out, expected, atol=1e-6) and not torch.equal(out, rows)
    both = prefilter_image(cols, "binomial")
    assert not torch.equal(both, cols) and torch.allclose(both.mean(), cols.mean(), atol=0.05)
    colour = torch.rand(2, 3, 9, 12, generator=g)
    assert torch.allclose(prefilter_image(colour, "binomial")[:, 1:2], prefilter_image(colour[:, 1:2], "binomial"))
    assert prefilter_image(colour, None) is colour


def test_bad_prefilter_is_one_line_naming_the_option():
    with pytest.raises(StereoInputError, match="prefilter"):
        prefilter_image(torch.rand(1, 1, 5, 5), "gaussian")
    left = torch.rand(1, 1, 20, 40)
    with pytest.raises(StereoInputError, match="prefilter"):
        match("sgm", left, left, 8, prefilter="median")


def test_sgm_prefilter_reaches_the_cost_only():
    """A pair constant along the columns is unchanged by the vertical filter, so sgm's map is too; a noisy pair's map
    changes, on the numba path and the torch path alike."""
    g = torch.Generator().manual_seed(1)
    base = torch.rand(1, 1, 1, 70, generator=g).expand(1, 1, 24, 70).clone()
    left, right = base[..., 4:], base[..., :-4]
    plain = match("sgm", left, right, 12)
    assert torch.equal(match("sgm", left, right, 12, prefilter="vertical").disparity.nan_to_num(),
                       plain.disparity.nan_to_num())
    noisy_left = (left + 0.05 * torch.randn(left.shape, generator=g)).clamp(0, 1)
    noisy_right = (right + 0.05 * torch.randn(right.shape, generator=g)).clamp(0, 1)
    for backend in ("numba", "torch"):
        a = match("sgm", noisy_left, noisy_right, 12, backend=backend)
        b = match("sgm", noisy_left, noisy_right, 12, backend=backend, prefilter="binomial")
        assert not torch.equal(a.disparity.nan_to_num(), b.disparity.nan_to_num())
