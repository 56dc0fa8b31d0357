import cv2
import numpy as np
import pytest
import torch

from stereonet.io import read_image
from stereonet.viz import (
    KITTI_ERROR_COLORS,
    colorize_disparity,
    error_map,
    panel,
    plot_bars,
    plot_curves,
    save_png,
)


def test_colorize_fixed_scale_and_invalid_black():
    a = np.array([[0.0, 10.0, 20.0, 30.0]])
    b = np.array([[10.0, 10.0, 50.0, 5.0]])
    ca, cb = colorize_disparity(a, 20), colorize_disparity(torch.from_numpy(b)[None, None], 20)
    assert ca.shape == (1, 4, 3) and ca.dtype == np.uint8
    assert (ca[0, 1] == cb[0, 0]).all()                    # same disparity, same colour, whatever the image range
    assert (ca[0, 2] == ca[0, 3]).all() and (ca[0, 3] == cb[0, 2]).all()  # saturates above max_disp
    assert not (ca[0, 0] == ca[0, 2]).all()
    # RGB order and turbo: low = dark blue/purple, high = dark red
    assert ca[0, 0, 2] > ca[0, 0, 0] and ca[0, 2, 0] > ca[0, 2, 2]
    turbo = cv2.applyColorMap(np.array([[128]], np.uint8), cv2.COLORMAP_TURBO)[0, 0, ::-1]
    assert (colorize_disparity(np.array([[10.0]]), 20)[0, 0] == turbo).all()
    v = np.array([[True, False, True, True]])
    c = colorize_disparity(np.array([[1.0, 2.0, np.nan, 4.0]]), 20, v)
    assert (c[0, 1] == 0).all() and (c[0, 2] == 0).all() and c[0, 3].any()
    with pytest.raises(ValueError, match="max_disp"):
        colorize_disparity(a, 0)


def test_error_map_kitti_bins():
    gt = np.array([[10.0, 10.0, 10.0, 100.0, 10.0, 10.0]])
    pred = np.array([[10.0, 12.9, 13.1, 104.0, 80.0, 10.0]])
    valid = np.array([[True, True, True, True, True, False]])
    e = error_map(pred, gt, valid)
    color = {tuple(c): i for i, (_, _, c) in enumerate(KITTI_ERROR_COLORS)}
    # normalised errors: 0 -> bin 0; 2.9/3 = 0.97 -> bin 4; 3.1/3 = 1.03 (and 31% of gt) -> bin 5 (a D1 outlier)
    # 4 px on gt 100: min(1.33, 0.8) = 0.8 -> bin 4 (not an outlier); 70/3 = 23 -> bin 9
    assert [color[tuple(px)] for px in e[0, :5]] == [0, 4, 5, 4, 9]
    assert (e[0, 5] == 0).all()  # invalid GT is black
    missing = error_map(pred, gt, valid, pred_valid=np.array([[False] * 6]))
    assert color[tuple(missing[0, 0])] == 9


def test_panel_layout_and_titles():
    a = np.zeros((40, 30, 3), np.uint8)
    b = torch.ones(1, 20, 10)            # grey float tensor, half the height -> resized to 40 x 20
    out = panel([a, b], ["left", "ground truth"], gap=4)
    title_h = out.shape[0] - 40
    assert title_h > 0 and out.shape[1] == 30 + 4 + 20 and out.dtype == np.uint8
    assert (out[title_h:, :30] == 0).all() and (out[title_h:, 34:] == 255).all()
    assert (out[:title_h, :30] < 128).any()         # text drawn in the title strip
    assert (out[title_h:, 30:34] == 255).all()       # white gap
    untitled = panel([a, a])
    assert untitled.shape == (40, 64, 3)
    with pytest.raises(ValueError, match="titles: expected 2"):
        panel([a, a], ["x"])


def test_save_png_roundtrip(tmp_path):
    img = np.random.default_rng(0).integers(0, 256, (8, 9, 3), dtype=np.uint8)
    save_png(tmp_path / "p.png", img)
    back = (read_image(tmp_path / "p.png")[0].permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)
    assert (back == img).all()
    with pytest.raises(ValueError, match=r"\.png"):
        save_png(tmp_path / "p.jpg", img)


def test_plots_written_atomically(tmp_path):
    plot_bars(tmp_path / "bars.png", ["tsukuba", "venus"], {"sgm": [5.0, 3.0], "bm": [9.0, float("nan")]},
              ylabel="bad-2 (%)", title="bad-2")
    plot_curves(tmp_path / "curve.png", {"sgm": ([0.5, 1, 2, 4], [30, 20, 10, 5])}, "tau", "bad-tau (%)")
    for name in ("bars.png", "curve.png"):
        img = read_image(tmp_path / name)
        assert img.shape[-1] > 300 and img.std() > 0.05
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bars.png", "curve.png"]
    with pytest.raises(ValueError, match=r"series\['sgm'\]: expected 2 values"):
        plot_bars(tmp_path / "x.png", ["a", "b"], {"sgm": [1.0]})
    assert not (tmp_path / "x.png").exists()
