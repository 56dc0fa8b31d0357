"""The image-guided weighted median filter (stereonet.select.filters.weighted_median_filter)."""

import pytest
import torch

from stereonet.checks import StereoInputError
from stereonet.select.filters import weighted_median_filter


def _fattened(h=24, w=40, edge=20, band=2):
    """A guide with an intensity step at ``edge`` (dark background left, bright foreground right) and a disparity
    map whose foreground value (10) reaches ``band`` px into the background (2)."""
    guide = torch.full((1, 1, h, w), 0.2)
    guide[..., edge:] = 0.8
    disp = torch.full((1, 1, h, w), 2.0)
    disp[..., edge - band:] = 10.0
    return disp, guide


def test_fattened_band_is_voted_back_to_the_background_and_the_edge_stays_sharp():
    disp, guide = _fattened()
    out = weighted_median_filter(disp, guide, radius=7, sigma_color=0.1)
    assert torch.equal(out[..., :20], torch.full_like(out[..., :20], 2.0))
    assert torch.equal(out[..., 20:], torch.full_like(out[..., 20:], 10.0))
    # without the guide's help (the same colour on both sides) the band is not all recovered: the guide does it
    flat = weighted_median_filter(disp, torch.full_like(guide, 0.5), radius=7, sigma_color=0.1)
    assert bool((flat[..., 18:20] == 10.0).all())


def test_no_discontinuity_means_no_change():
    """A slope (0.5 px per pixel, below the 1 px step) is left exactly as it is."""
    disp = (torch.arange(40, dtype=torch.float32) * 0.5).expand(1, 1, 24, 40).clone()
    guide = torch.rand(1, 3, 24, 40, generator=torch.Generator().manual_seed(0))
    assert torch.equal(weighted_median_filter(disp, guide, radius=4), disp)
    # with a smaller jump the same slope counts as steps and is filtered
    assert not torch.equal(weighted_median_filter(disp, guide, radius=4, jump=0.25, sigma_color=1.0), disp)


def _random_case(g, channels, h, w, with_valid):
    """A random map with a 6 px step at mid-width, a guide with an intensity step there, and optional validity."""
    disp = torch.rand(2, 1, h, w, generator=g) * 4
    disp[..., w // 2:] += 6
    guide = torch.rand(2, channels, h, w, generator=g)
    guide[..., w // 2:] += 0.4
    valid = (torch.rand(2, 1, h, w, generator=g) > 0.3) if with_valid else None
    return disp, guide, valid


@pytest.mark.parametrize("channels,with_valid,radius", [(1, False, 3), (3, True, 5), (3, False, 9)])
def test_numba_equals_torch(channels, with_valid, radius):
    """Equal on shapes smaller and larger than the window, with and without invalid (non-voting) pixels."""
    g = torch.Generator().manual_seed(channels + radius)
    for h, w in ((7, 11), (33, 47)):
        disp, guide, valid = _random_case(g, channels, h, w, with_valid)
        a = weighted_median_filter(disp, guide, radius=radius, sigma_color=0.3, valid=valid, backend="numba")
        b = weighted_median_filter(disp, guide, radius=radius, sigma_color=0.3, valid=valid, backend="torch")
        assert torch.equal(a, b)
        assert not torch.equal(a, disp)  # it did filter


@pytest.mark.parametrize("channels,with_valid,radius,stride,band",
                         [(1, False, 5, 2, None), (3, True, 9, 2, 4), (3, False, 9, 3, 0), (1, True, 4, 3, 6)])
def test_strided_windows_and_bands_numba_equals_torch(channels, with_valid, radius, stride, band):
    """Windows sampled every ``stride`` px and a narrower (or wider) band of filtered pixels: both backends equal on
    shapes below and above the window, on every border; a band of 0 filters only the pixels beside a step."""
    g = torch.Generator().manual_seed(10 * stride + radius)
    for h, w in ((6, 9), (31, 45)):
        disp, guide, valid = _random_case(g, channels, h, w, with_valid)
        kw = dict(radius=radius, sigma_color=0.3, valid=valid, stride=stride, band=band)
        a = weighted_median_filter(disp, guide, backend="numba", **kw)
        assert torch.equal(a, weighted_median_filter(disp, guide, backend="torch", **kw))
        assert not torch.equal(a, disp)
        full = weighted_median_filter(disp, guide, radius=radius, sigma_color=0.3, valid=valid)
        assert not torch.equal(a, full)  # fewer votes or pixels: a different filter


def test_stride_one_and_band_radius_are_the_default_filter():
    disp = 2 + torch.rand(1, 1, 30, 41, generator=torch.Generator().manual_seed(5)) * 0.4  # steps < 1 px
    disp[..., 20:] += 8
    guide = torch.rand(1, 3, 30, 41, generator=torch.Generator().manual_seed(6))
    assert torch.equal(weighted_median_filter(disp, guide, radius=6, stride=1, band=6),
                       weighted_median_filter(disp, guide, radius=6))
    # band 0: only pixels with a step to a 4-neighbour change; the columns away from the step stay as they were
    out = weighted_median_filter(disp, guide, radius=6, band=0)
    assert torch.equal(out[..., :19], disp[..., :19]) and torch.equal(out[..., 21:], disp[..., 21:])
    assert not torch.equal(out, disp)


def test_bad_input_names_the_argument():
    disp, guide = _fattened()
    for kwargs, name in ((dict(radius=0), "radius"), (dict(radius=2.5), "radius"), (dict(sigma_color=0.0), "sigma_color"),
                         (dict(sigma_space=-1.0), "sigma_space"), (dict(jump=-1.0), "jump"),
                         (dict(backend="cuda"), "backend"), (dict(radius=3, stride=4), "stride"),
                         (dict(stride=0), "stride"), (dict(band=-1), "band"), (dict(band=1.5), "band")):
        with pytest.raises(StereoInputError, match=name):
            weighted_median_filter(disp, guide, **kwargs)
    with pytest.raises(StereoInputError, match="guide"):
        weighted_median_filter(disp, guide[..., :-1])


def test_torch_bands_equal_the_whole_image_and_non_finite_values_never_vote():
    """The torch reference in bands of a few rows equals one band (the halo holds every window); NaN and inf
    disparities do not vote (both backends agree) and only change where they sit."""
    from stereonet.select.filters import _weighted_median_torch

    g = torch.Generator().manual_seed(3)
    disp = torch.rand(1, 1, 29, 37, generator=g) * 3
    disp[..., 18:] += 7
    guide = torch.rand(1, 3, 29, 37, generator=g)
    valid = torch.rand(1, 1, 29, 37, generator=g) > 0.2
    whole = _weighted_median_torch(disp, guide, valid, 4, 0.3, 4.0, 1.0, rows=1000)
    for rows in (1, 5, 11):
        assert torch.equal(_weighted_median_torch(disp, guide, valid, 4, 0.3, 4.0, 1.0, rows=rows), whole)
    bad = disp.clone()
    bad[0, 0, 10, 5], bad[0, 0, 20, 25] = float("nan"), float("inf")
    a = weighted_median_filter(bad, guide, radius=4, sigma_color=0.3, backend="numba")
    b = weighted_median_filter(bad, guide, radius=4, sigma_color=0.3, backend="torch")
    assert torch.equal(a, b) and bool(torch.isfinite(a).all())  # the two non-finite pixels get their neighbours' median


def test_absurd_values_do_not_size_the_histogram():
    """A map with a value a billion pixels away from the rest (a range no histogram should span) is filtered by the
    banded reference: the same result as backend="torch", no huge allocation."""
    disp, guide = _fattened()
    disp[0, 0, 3, 3] = 1e9
    out = weighted_median_filter(disp, guide, radius=4, sigma_color=0.1)
    assert torch.equal(out, weighted_median_filter(disp, guide, radius=4, sigma_color=0.1, backend="torch"))
    assert out[0, 0, 3, 3] < 20  # its neighbours outvote it


def test_a_non_finite_guide_is_a_one_line_error():
    """The numba kernel's colour weights assume a finite guide (a NaN used to crash the process)."""
    from stereonet.checks import StereoInputError
    from stereonet.select.filters import weighted_median_filter
    from stereonet.select.lr_check import left_right_check

    guide = torch.rand(1, 3, 24, 48)
    guide[0, 0, 5, 5] = float("nan")
    with pytest.raises(StereoInputError, match="guide"):
        weighted_median_filter(torch.rand(1, 1, 24, 48) * 8, guide)
    with pytest.raises(StereoInputError, match="tol"):
        left_right_check(torch.rand(1, 1, 8, 8), torch.rand(1, 1, 8, 8), tol=float("nan"))
