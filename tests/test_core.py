import pytest
import torch

from stereonet import matchers
from stereonet.checks import StereoInputError, check_max_disp, check_shape, check_stereo_inputs, check_window
from stereonet.io.atomic import atomic_path, atomic_write_text
from stereonet.types import Calibration, StereoOutput


def test_stereo_output_checks_shapes():
    d = torch.zeros(1, 1, 4, 5)
    out = StereoOutput(d, torch.ones_like(d, dtype=torch.bool))
    assert out.filled().shape == d.shape
    with pytest.raises(ValueError, match="valid"):
        StereoOutput(d, torch.ones(1, 1, 4, 4, dtype=torch.bool))
    with pytest.raises(TypeError, match="valid"):
        StereoOutput(d, torch.ones_like(d))
    with pytest.raises(ValueError, match="disparity"):
        StereoOutput(torch.zeros(1, 2, 4, 5), torch.ones(1, 2, 4, 5, dtype=torch.bool))


@pytest.mark.parametrize(
    "left,right,max_disp,msg",
    [
        (torch.rand(1, 3, 8, 16), torch.rand(1, 3, 8, 15), 4, "right: expected the same shape"),
        (torch.rand(1, 2, 8, 16), torch.rand(1, 2, 8, 16), 4, "left: expected 1 or 3 channels"),
        (torch.rand(3, 8, 16), torch.rand(3, 8, 16), 4, r"left: expected shape \(B, C, H, W\)"),
        (torch.full((1, 1, 8, 16), float("nan")), torch.rand(1, 1, 8, 16), 4, "left: expected finite"),
        (torch.rand(1, 1, 0, 16), torch.rand(1, 1, 0, 16), 4, "non-empty"),
        (torch.rand(1, 1, 8, 16), torch.rand(1, 1, 8, 16), 16, "max_disp: expected 0 < max_disp < image width"),
        (torch.rand(1, 1, 8, 16), torch.rand(1, 1, 8, 16), 0, "max_disp"),
    ],
)
def test_check_stereo_inputs_rejects(left, right, max_disp, msg):
    with pytest.raises(StereoInputError, match=msg):
        check_stereo_inputs(left, right, max_disp)


def test_check_dtype_and_types():
    with pytest.raises(TypeError, match="left: expected a floating-point"):
        check_stereo_inputs(torch.zeros(1, 1, 4, 8, dtype=torch.uint8), torch.zeros(1, 1, 4, 8, dtype=torch.uint8), 2)
    with pytest.raises(TypeError, match="max_disp"):
        check_max_disp(2.5, 10)
    with pytest.raises(StereoInputError, match="window"):
        check_window(4)
    assert check_shape(torch.zeros(2, 3, 3), ["*", "3", "3"], "K") == {}
    with pytest.raises(StereoInputError, match=r"K: expected shape \(3, 3\), got \(3, 4\)"):
        check_shape(torch.zeros(3, 4), ["3", "3"], "K")


def test_calibration_validates():
    c = Calibration.rectified(500.0, 100.0, 80.0, 0.2, image_size=(200, 160))
    assert c.is_rectified() and c.baseline == pytest.approx(0.2) and c.focal == 500.0
    with pytest.raises(ValueError, match="K1: expected an invertible"):
        Calibration(torch.zeros(3, 3), torch.eye(3), torch.eye(3), torch.zeros(3))
    with pytest.raises(ValueError, match="R: expected shape"):
        Calibration(torch.eye(3), torch.eye(3), torch.eye(2), torch.zeros(3))


def test_registry_lists_valid_names_in_error():
    names = matchers.available()
    assert "opencv-bm" in names and "opencv-sgbm" in names
    with pytest.raises(StereoInputError, match="valid names: .*opencv-sgbm"):
        matchers.get_matcher("no-such-method")


@pytest.mark.parametrize("name", ["opencv-bm", "opencv-sgbm"])
def test_opencv_baselines_recover_constant_disparity(name, textured_pair):
    left, right, d = textured_pair
    out = matchers.match(name, left, right, 16, block_size=9 if name == "opencv-bm" else 5)
    inner = out.disparity[..., 12:-12, 28:-12]
    ok = out.valid[..., 12:-12, 28:-12]
    assert ok.float().mean() > 0.8
    assert (inner[ok] - d).abs().median() < 0.25


def test_atomic_write_leaves_nothing_on_error(tmp_path):
    target = tmp_path / "a.txt"
    atomic_write_text(target, "one")
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text("half")
        raise RuntimeError("interrupted")
    assert target.read_text() == "one"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt"]


def test_atomic_write_respects_umask(tmp_path):
    import os

    target = tmp_path / "b.txt"
    old = os.umask(0o022)
    try:
        atomic_write_text(target, "x")
    finally:
        os.umask(old)
    assert (target.stat().st_mode & 0o777) == 0o644


def test_matcher_inputs_are_checked_once(monkeypatch):
    """The registry checks a pair once (one finiteness pass per image) and the stages below, which call the
    public checking functions, trust those very tensors; a NaN still fails with one line, and a tensor made
    inside the matcher (not the checked object) is checked again."""
    import pytest

    from stereonet import checks, matchers
    from stereonet.checks import StereoInputError

    calls = []
    real = torch.isfinite
    monkeypatch.setattr(checks.torch, "isfinite", lambda x: calls.append(tuple(x.shape)) or real(x))
    left, right = torch.rand(1, 3, 20, 40), torch.rand(1, 3, 20, 40)
    for name in ("sgm", "bm-sad"):
        calls.clear()
        for kw in ({}, {"backend": "torch"}, {"keep_volume": True}):
            calls.clear()
            matchers.match(name, left, right, 8, **kw)
            assert calls == [(), ()], (name, kw, calls)  # left and right, once each (the sum of a finite image)
    bad = left.clone()
    bad[0, 0, 3, 3] = float("nan")
    with pytest.raises(StereoInputError, match="left: expected finite"):
        matchers.match("sgm", bad, right, 8)
    with checks.inputs_checked(left):
        checks.check_finite(left, "left")  # trusted: no pass
        with pytest.raises(StereoInputError, match="copy"):
            checks.check_finite(bad, "copy")
    calls.clear()
    checks.check_finite(left, "left")
    assert calls == [()]  # outside the block it is checked again


def test_check_finite_sum_overflow_falls_back_to_the_elementwise_test():
    """check_finite tests the sum first: finite values whose sum overflows must still pass (elementwise
    fallback), and one NaN or inf among them must still fail."""
    import pytest

    from stereonet.checks import StereoInputError, check_finite

    huge = torch.full((1, 1, 4, 8), 3e38)
    assert not torch.isfinite(huge.sum())
    check_finite(huge, "left")
    for bad in (float("nan"), float("inf"), -float("inf")):
        x = huge.clone()
        x[0, 0, 1, 2] = bad
        with pytest.raises(StereoInputError, match="left: expected finite"):
            check_finite(x, "left")
    x = torch.rand(1, 1, 4, 8)
    x[0, 0, 0, 0], x[0, 0, 0, 1] = float("inf"), -float("inf")  # the sum is NaN, not inf
    with pytest.raises(StereoInputError, match="left: expected finite"):
        check_finite(x, "left")


def test_a_pair_in_eight_bit_units_is_a_one_line_error():
    """float images of 0-255 values ran silently (opencv-sgbm clamped them, changing its answer)."""
    from stereonet.checks import StereoInputError
    from stereonet.matchers import match

    left = torch.rand(1, 3, 24, 48, generator=torch.Generator().manual_seed(0))
    for method in ("sgm", "opencv-sgbm", "bm-sad"):
        with pytest.raises(StereoInputError, match=r"left: expected values in \[0, 1\].*divide by 255"):
            match(method, left * 255, torch.roll(left, -2, -1) * 255, 8)
    match("sgm", left * 1.5, torch.roll(left, -2, -1) * 1.5, 8)  # an overshoot (augmentation, resampling) passes
