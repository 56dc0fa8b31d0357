"""infer.py: the contract files, depth consistent with the calibration, batch mode, rectification, bad input."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from stereonet.cli import infer

REPO = Path(__file__).resolve().parents[2]
FOCAL, BASELINE, DOFFS, SHIFT = 100.0, 0.2, 3.0, 6


def textured_pair(seed: int = 0, h: int = 80, w: int = 160) -> tuple[np.ndarray, np.ndarray]:
    """A blurred-noise colour texture and its copy shifted left by SHIFT px (constant disparity SHIFT)."""
    rng = np.random.default_rng(seed)
    big = cv2.GaussianBlur(rng.random((h, w + 32, 3)).astype(np.float32), (0, 0), 1.2)
    big = (255 * (big - big.min()) / (big.max() - big.min())).astype(np.uint8)
    return big[:, 16:16 + w].copy(), big[:, 16 + SHIFT:16 + SHIFT + w].copy()


def write_calib(path: Path, w: int = 160, h: int = 80, ndisp: int = 16) -> Path:
    cam0 = f"[{FOCAL} 0 {w / 2}; 0 {FOCAL} {h / 2}; 0 0 1]"
    cam1 = f"[{FOCAL} 0 {w / 2 + DOFFS}; 0 {FOCAL} {h / 2}; 0 0 1]"
    path.write_text(f"cam0={cam0}\ncam1={cam1}\ndoffs={DOFFS}\nbaseline={BASELINE}\nwidth={w}\nheight={h}\n"
                    f"ndisp={ndisp}\n")
    return path


@pytest.fixture
def pair_files(tmp_path) -> tuple[Path, Path]:
    left, right = textured_pair()
    lp, rp = tmp_path / "left.png", tmp_path / "right.png"
    cv2.imwrite(str(lp), left)
    cv2.imwrite(str(rp), right)
    return lp, rp


def run_main(capsys, *args) -> tuple[int, str]:
    code = infer.main([str(a) for a in args] + ["--no-progress"])
    return code, capsys.readouterr().err


def one_line_error(err: str) -> str:
    lines = [x for x in err.strip().splitlines() if x]
    assert len(lines) == 1, err
    assert lines[0].startswith("infer.py: error:") and "Traceback" not in err
    return lines[0]


def test_rectified_pair_with_calibration_writes_contract_files(pair_files, tmp_path, capsys):
    from stereonet.io import read_disparity, read_pfm, read_ply

    out = tmp_path / "out"
    calib = write_calib(tmp_path / "calib.txt")
    code, err = run_main(capsys, *pair_files, "-o", out, "--method", "opencv-sgbm", "--calib", calib)
    assert code == 0, err
    assert {"disparity.pfm", "disparity.png", "depth.pfm", "cloud.ply", "info.json"} <= {p.name for p in out.iterdir()}
    assert not any(p.name.startswith(".") for p in tmp_path.iterdir())  # no temporary folder left behind
    disp, valid = read_disparity(out / "disparity.pfm")
    assert disp.shape == (80, 160) and valid.mean() > 0.5
    assert np.median(disp[valid]) == pytest.approx(SHIFT, abs=0.5)
    depth = read_pfm(out / "depth.pfm")
    both = valid & np.isfinite(depth)
    np.testing.assert_allclose(depth[both], FOCAL * BASELINE / (disp[both] + DOFFS), rtol=1e-4)
    points, colors = read_ply(out / "cloud.ply")
    assert points.shape == (int(both.sum()), 3) and colors.shape == points.shape and colors.dtype == np.uint8
    info = json.loads((out / "info.json").read_text())
    assert info["max_disp"] == 16 and info["max_disp_source"] == "calibration ndisp" and info["rectified"] is None
    png = cv2.imread(str(out / "disparity.png"))
    assert png.shape == (80, 160, 3)


def test_no_calibration_no_depth_and_auto_max_disp(pair_files, tmp_path, capsys):
    out = tmp_path / "out"
    code, err = run_main(capsys, *pair_files, "-o", out, "--method", "opencv-bm")
    assert code == 0, err
    names = {p.name for p in out.iterdir()}
    assert {"disparity.pfm", "disparity.png"} <= names and not {"depth.pfm", "cloud.ply"} & names
    info = json.loads((out / "info.json").read_text())
    assert info["max_disp"] % 16 == 0 and 16 <= info["max_disp"] <= 64


def test_fill_makes_dense(pair_files, tmp_path, capsys):
    from stereonet.io import read_disparity

    code, err = run_main(capsys, *pair_files, "-o", tmp_path / "out", "--method", "opencv-bm", "--max-disp", "16",
                         "--fill")
    assert code == 0, err
    _, valid = read_disparity(tmp_path / "out" / "disparity.pfm")
    info = json.loads((tmp_path / "out" / "info.json").read_text())
    assert valid.all() and info["density"] == 100 and info["density_before_fill"] < 100


def test_estimate_max_disp_from_offsets():
    pl = np.array([[50.0 + i, 10.0 + i] for i in range(20)])
    pr = pl - np.array([[20.0, 0.0]])
    assert infer.estimate_max_disp(pl, pr, width=640) == 32  # 20 * 1.2 + 4 = 28 -> 32
    assert infer.estimate_max_disp(pl, pr + np.array([[-300.0, 0.0]]), width=640) == 256  # capped
    assert infer.estimate_max_disp(pl[:3], pr[:3], width=640) is None  # too few matches
    off_row = pr + np.array([[0.0, 5.0]])
    assert infer.estimate_max_disp(pl, off_row, width=640) is None


def test_batch_of_folders(tmp_path, capsys):
    ldir, rdir = tmp_path / "L", tmp_path / "R"
    ldir.mkdir()
    rdir.mkdir()
    for i, name in enumerate(["a", "b"]):
        left, right = textured_pair(seed=i)
        cv2.imwrite(str(ldir / f"{name}.png"), left)
        cv2.imwrite(str(rdir / f"{name}_r.png"), right)
    out = tmp_path / "out"
    code, err = run_main(capsys, ldir, rdir, "-o", out, "--method", "opencv-sgbm", "--max-disp", "16")
    assert code == 0, err
    assert sorted(p.name for p in out.iterdir()) == ["a", "b"]
    assert all((out / n / "disparity.pfm").is_file() for n in ("a", "b"))


def test_existing_output_needs_overwrite(pair_files, tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("old")
    code, err = run_main(capsys, *pair_files, "-o", out, "--method", "opencv-bm", "--max-disp", "16")
    assert code == 2 and "--overwrite" in one_line_error(err)
    assert (out / "keep.txt").read_text() == "old"
    code, err = run_main(capsys, *pair_files, "-o", out, "--method", "opencv-bm", "--max-disp", "16", "--overwrite")
    assert code == 0, err
    assert not (out / "keep.txt").exists() and (out / "disparity.pfm").is_file()


@pytest.mark.parametrize("case", ["mismatched", "unreadable", "calib-size", "missing", "checkpoint", "method",
                                  "scale", "alpha", "min-disp"])
def test_bad_input_one_line_and_nothing_written(case, pair_files, tmp_path, capsys):
    lp, rp = pair_files
    extra: list = ["--method", "opencv-sgbm", "--max-disp", "16"]
    needle = {"mismatched": "size", "unreadable": "right", "calib-size": "--calib", "missing": "LEFT",
              "checkpoint": "--checkpoint", "method": "valid names", "scale": "--scale", "alpha": "--alpha",
              "min-disp": "--min-disp"}[case]
    if case == "mismatched":
        cv2.imwrite(str(rp), np.zeros((40, 160, 3), np.uint8))
    elif case == "unreadable":
        rp.write_bytes(b"\x89PNG\r\n\x1a\nnot really a png")
    elif case == "calib-size":
        extra += ["--calib", write_calib(tmp_path / "calib.txt", w=320, h=160)]
    elif case == "missing":
        lp = tmp_path / "nope.png"
    elif case == "checkpoint":
        ckpt = tmp_path / "w.ckpt"
        ckpt.write_bytes(b"0")
        extra += ["--checkpoint", ckpt]
    elif case == "method":
        extra = ["--method", "no-such-method"]
    elif case == "scale":
        extra += ["--scale", "1.5"]
    elif case == "alpha":
        extra += ["--alpha", "-0.1"]
    elif case == "min-disp":
        extra += ["--min-disp", "16"]
    out = tmp_path / "out"
    code, err = run_main(capsys, lp, rp, "-o", out, *extra)
    assert code == 2
    assert needle in one_line_error(err)
    assert not out.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".out")]


def test_uncalibrated_rectifies_a_rotated_pair(shared_data, tmp_path, capsys):
    """Cones with the right view rotated by 2 degrees and shifted down: --uncalibrated must restore rows."""
    from stereonet.io import read_disparity

    scene = shared_data / "middlebury2003" / "cones"
    half = lambda img: cv2.resize(img, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)  # faster test
    left, right = half(cv2.imread(str(scene / "im2.png"))), half(cv2.imread(str(scene / "im6.png")))
    h, w = right.shape[:2]
    M = cv2.getRotationMatrix2D((w / 2, h / 2), 2.0, 1.0)
    M[1, 2] += 4
    cv2.imwrite(str(tmp_path / "left.png"), left)
    cv2.imwrite(str(tmp_path / "right.png"), cv2.warpAffine(right, M, (w, h), borderMode=cv2.BORDER_REFLECT))
    out = tmp_path / "out"
    code, err = run_main(capsys, tmp_path / "left.png", tmp_path / "right.png", "-o", out, "--uncalibrated",
                         "--method", "opencv-sgbm")
    assert code == 0, err
    names = {p.name for p in out.iterdir()}
    assert {"rectified_left.png", "rectified_right.png", "epipolar_check.png", "disparity.pfm"} <= names
    assert not {"depth.pfm", "cloud.ply"} & names  # no metric scale without calibration
    info = json.loads((out / "info.json").read_text())
    assert info["epipolar_median_row_error_px"] < 1.0
    assert 16 <= info["max_disp"] <= 64
    disp, valid = read_disparity(out / "disparity.pfm")
    content = 1.0 - info["padding_percent"] / 100.0  # the rectified frame's share with source content
    assert 0.3 < content < 1.0
    assert 0.5 * content < valid.mean() <= content  # padding is never an answer
    rectified = cv2.imread(str(out / "rectified_left.png"))
    assert not valid[(rectified == 0).all(axis=2)[: valid.shape[0], : valid.shape[1]]].mean() > 0.05


def test_too_few_matches_is_refused(tmp_path, capsys):
    flat = np.full((64, 128, 3), 128, np.uint8)
    cv2.imwrite(str(tmp_path / "l.png"), flat)
    cv2.imwrite(str(tmp_path / "r.png"), flat)
    code, err = run_main(capsys, tmp_path / "l.png", tmp_path / "r.png", "-o", tmp_path / "out", "--uncalibrated",
                         "--method", "opencv-bm")
    assert code == 2 and "matches" in one_line_error(err)
    assert not (tmp_path / "out").exists()


def test_script_wrapper_in_process(pair_files, tmp_path, monkeypatch):
    """infer.py (the top-level script) calls the same main and exits with its code."""
    import runpy

    monkeypatch.setattr(sys, "argv", ["infer.py", *map(str, pair_files), "-o", str(tmp_path / "o"), "--method",
                                      "opencv-bm", "--max-disp", "16"])
    with pytest.raises(SystemExit) as exit_info:
        runpy.run_path(str(REPO / "infer.py"), run_name="__main__")
    assert exit_info.value.code == 0
    assert (tmp_path / "o" / "disparity.png").is_file()


@pytest.mark.slow
def test_script_wrapper_runs(pair_files, tmp_path):
    r = subprocess.run([sys.executable, str(REPO / "infer.py"), *map(str, pair_files), "-o", str(tmp_path / "o"),
                        "--method", "opencv-bm", "--max-disp", "16"], capture_output=True, text=True, cwd=REPO,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "o" / "disparity.png").is_file()


def test_default_method_is_registered():
    from stereonet import matchers

    name = infer.default_method()
    assert name in matchers.available()
    assert not matchers.spec(name).needs_weights or infer.weights_available(name)


def test_missing_weights_is_one_line(pair_files, tmp_path, capsys, monkeypatch):
    from stereonet import matchers

    def learned(left, right, max_disp, checkpoint=None):
        raise AssertionError("must not run without weights")

    monkeypatch.setitem(matchers._REGISTRY, "weightless-test",
                        matchers.MatcherSpec("weightless-test", learned, "learned", "x", needs_weights=True))
    monkeypatch.setenv("STEREONET_WEIGHTS_DIR", str(tmp_path / "no-weights"))
    out = tmp_path / "out"
    code, err = run_main(capsys, *pair_files, "-o", out, "--method", "weightless-test")
    assert code == 2 and "weights" in one_line_error(err)
    assert not out.exists()
    code, err = run_main(capsys, *pair_files, "-o", out, "--method", "weightless-test", "--checkpoint",
                         tmp_path / "absent.ckpt")
    assert code == 2 and "--checkpoint" in one_line_error(err)


def test_batch_of_globs(tmp_path, capsys):
    for i in range(2):
        left, right = textured_pair(seed=i)
        cv2.imwrite(str(tmp_path / f"scene{i}_L.png"), left)
        cv2.imwrite(str(tmp_path / f"scene{i}_R.png"), right)
    out = tmp_path / "out"
    code, err = run_main(capsys, tmp_path / "*_L.png", tmp_path / "*_R.png", "-o", out, "--method", "opencv-bm",
                         "--max-disp", "16")
    assert code == 0, err
    assert sorted(p.name for p in out.iterdir()) == ["scene0_L", "scene1_L"]


def test_confidence_and_depth_outputs_with_units(pair_files, tmp_path, capsys):
    from stereonet.io import read_disparity, read_pfm
    from stereonet.io.image import read_array

    out = tmp_path / "out"
    code, err = run_main(capsys, *pair_files, "-o", out, "--method", "sgm", "--calib", write_calib(tmp_path / "c.txt"))
    assert code == 0, err
    names = {p.name for p in out.iterdir()}
    assert {"confidence.pfm", "confidence.png", "depth_mm.png", "depth.png"} <= names
    conf = read_pfm(out / "confidence.pfm")
    disp, valid = read_disparity(out / "disparity.pfm")
    assert conf.shape == disp.shape and conf.min() >= 0 and conf.max() <= 1
    assert (conf[~valid] == 0).all() and conf[valid].mean() > 0.05
    info = json.loads((out / "info.json").read_text())
    assert info["units"]["depth"] == "mm"  # Middlebury calib.txt: baseline in mm
    depth = read_pfm(out / "depth.pfm")
    mm = read_array(out / "depth_mm.png")
    assert mm.dtype == np.uint16 and mm.shape == depth.shape
    has = np.isfinite(depth)
    assert (mm[~has] == 0).all()
    np.testing.assert_allclose(mm[has], np.clip(np.round(depth[has]), 0, 65535), atol=0.51)
    assert read_array(out / "depth.png").shape[1] > depth.shape[1]  # the colour bar beside the map


def test_cloud_min_confidence_keeps_the_sure_pixels(pair_files, tmp_path, capsys):
    """--cloud-min-confidence C: cloud.ply keeps the valid pixels whose confidence.pfm is at least C (filled ones,
    confidence 0, go); 0 keeps every valid pixel; a value outside [0, 1] is one line."""
    from stereonet.io import read_pfm, read_ply

    calib = write_calib(tmp_path / "c.txt")
    common = [*pair_files, "--method", "sgm", "--calib", calib, "--fill"]
    code, err = run_main(capsys, *common, "-o", tmp_path / "all")
    assert code == 0, err
    code, err = run_main(capsys, *common, "-o", tmp_path / "sure", "--cloud-min-confidence", "0.3")
    assert code == 0, err
    every, _ = read_ply(tmp_path / "all" / "cloud.ply")
    sure, _ = read_ply(tmp_path / "sure" / "cloud.ply")
    conf = read_pfm(tmp_path / "sure" / "confidence.pfm")
    info = json.loads((tmp_path / "sure" / "info.json").read_text())
    assert len(sure) == int((conf >= 0.3).sum()) == info["points"] and 0 < len(sure) < len(every)
    assert info["cloud_min_confidence"] == 0.3
    code, err = run_main(capsys, *common, "-o", tmp_path / "bad", "--cloud-min-confidence", "1.5")
    assert code == 2 and "--cloud-min-confidence" in one_line_error(err) and not (tmp_path / "bad").exists()


def test_scale_halves_the_disparity(pair_files, tmp_path, capsys):
    from stereonet.io import read_disparity

    out = tmp_path / "out"
    code, err = run_main(capsys, *pair_files, "-o", out, "--method", "sgm", "--scale", "0.5", "--max-disp", "16")
    assert code == 0, err
    disp, valid = read_disparity(out / "disparity.pfm")
    assert disp.shape == (40, 80)
    assert np.median(disp[valid]) == pytest.approx(SHIFT / 2, abs=0.5)
    info = json.loads((out / "info.json").read_text())
    assert info["scale"] == {"factor": 0.5, "input_size": [160, 80], "processed_size": [80, 40]}


def test_negative_disparities_with_min_disp(tmp_path, capsys):
    from stereonet.io import read_disparity

    left, right = textured_pair()
    lp, rp = tmp_path / "l.png", tmp_path / "r.png"
    cv2.imwrite(str(lp), right)  # swapped views: every disparity is -SHIFT
    cv2.imwrite(str(rp), left)
    out = tmp_path / "out"
    code, err = run_main(capsys, lp, rp, "-o", out, "--method", "sgm", "--min-disp", "-16", "--max-disp", "8")
    assert code == 0, err
    disp, valid = read_disparity(out / "disparity.pfm")
    assert valid.mean() > 0.5
    assert np.median(disp[valid]) == pytest.approx(-SHIFT, abs=0.5)
    assert json.loads((out / "info.json").read_text())["min_disp"] == -16


def test_unrectified_pair_given_as_rectified_warns(tmp_path, capsys):
    left, right = textured_pair(h=160, w=200)
    right = np.roll(right, 4, axis=0)  # 4 rows off: not a rectified pair
    lp, rp = tmp_path / "l.png", tmp_path / "r.png"
    cv2.imwrite(str(lp), left)
    cv2.imwrite(str(rp), right)
    out = tmp_path / "out"
    code, err = run_main(capsys, lp, rp, "-o", out, "--method", "opencv-sgbm", "--max-disp", "16", "--no-align")
    assert code == 0
    assert "warning" in err and "off-row" in err
    info = json.loads((out / "info.json").read_text())
    assert info["epipolar_median_row_error_px"] == pytest.approx(4, abs=0.5)
    assert any("--calib" in w for w in info["warnings"])
    # the same pair with the vertical alignment (the default): the offset is corrected, so no stale warning
    code, err = run_main(capsys, lp, rp, "-o", tmp_path / "aligned", "--method", "opencv-sgbm", "--max-disp", "16")
    info = json.loads((tmp_path / "aligned" / "info.json").read_text())
    assert code == 0 and info["vertical_offset"]["corrected"] and "looks unrectified" not in err
    assert info["epipolar_median_row_error_px"] < 0.5 and not any("--calib" in w for w in info["warnings"])
    cv2.imwrite(str(rp), textured_pair(h=160, w=200)[1])  # rectified: no warning
    code, err = run_main(capsys, lp, rp, "-o", tmp_path / "rectified", "--method", "opencv-sgbm", "--max-disp", "16")
    assert code == 0 and "warning" not in err
    # the same pair in the other order: every match lies to the right in RIGHT
    code, err = run_main(capsys, rp, lp, "-o", tmp_path / "swapped", "--method", "opencv-sgbm", "--max-disp", "16")
    assert code == 0 and "look swapped" in err
    code, err = run_main(capsys, rp, lp, "-o", tmp_path / "negative", "--method", "sgm", "--min-disp", "-16",
                         "--max-disp", "8")
    assert code == 0 and "look swapped" not in err  # negative disparities asked for


def test_unrectified_rig_padding_alpha_and_rectified_calibration(tmp_path, capsys):
    """data_gen's unrectified rig: padding never valid (even with --fill), --alpha 0 crops it away,
    the rectified rig is saved, and the cloud can be had in the original left-camera frame."""
    from stereonet.io import read_disparity, read_ply

    gen = tmp_path / "gen"
    subprocess.run([sys.executable, "-m", "data_gen", "--out", str(gen), "--count", "1", "--seed", "3",
                    "--unrectified", "--height", "128", "--width", "256"], check=True, capture_output=True)
    scene = next(p for p in gen.iterdir() if p.is_dir())
    args = [scene / "im0.png", scene / "im1.png", "--calib", scene / "calib.yaml", "--method", "sgm",
            "--max-disp", "64"]
    code, err = run_main(capsys, *args, "-o", tmp_path / "a1", "--fill", "--unit", "m")
    assert code == 0, err
    info = json.loads((tmp_path / "a1" / "info.json").read_text())
    assert info["padding_percent"] > 1.0
    disp, valid = read_disparity(tmp_path / "a1" / "disparity.pfm")
    assert valid.mean() <= 1.0 - info["padding_percent"] / 100 + 1e-6  # filled, but not into the padding
    fs = cv2.FileStorage(str(tmp_path / "a1" / "rectified_calib.yaml"), cv2.FILE_STORAGE_READ)
    K, Q, R1 = fs.getNode("K").mat(), fs.getNode("Q").mat(), fs.getNode("R1").mat()
    assert K.shape == (3, 3) and Q.shape == (4, 4) and fs.getNode("baseline").real() > 0
    fs.release()
    code, err = run_main(capsys, *args, "-o", tmp_path / "a0", "--alpha", "0")
    assert code == 0, err
    assert json.loads((tmp_path / "a0" / "info.json").read_text())["padding_percent"] < info["padding_percent"]
    code, err = run_main(capsys, *args, "-o", tmp_path / "orig", "--fill", "--unit", "m", "--cloud-frame", "original")
    assert code == 0, err
    rect_pts, _ = read_ply(tmp_path / "a1" / "cloud.ply")
    orig_pts, _ = read_ply(tmp_path / "orig" / "cloud.ply")
    np.testing.assert_allclose(orig_pts, rect_pts @ R1, rtol=1e-4, atol=1e-4)  # X_orig = R1^T X_rect
    assert json.loads((tmp_path / "orig" / "info.json").read_text())["cloud_frame"] == "original left camera"


def _write_yaml_calib(path: Path, K1, K2, R, T, size, d1=None, d2=None) -> Path:
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_FORMAT_YAML)
    for name, value in (("K1", K1), ("K2", K2), ("R", R), ("T", np.asarray(T, dtype=np.float64).reshape(3, 1))):
        fs.write(name, np.asarray(value, dtype=np.float64))
    for name, value in (("D1", d1), ("D2", d2)):
        if value is not None:
            fs.write(name, np.asarray(value, dtype=np.float64))
    fs.write("image_width", int(size[0]))
    fs.write("image_height", int(size[1]))
    fs.release()
    return path


def test_reversed_rectified_rig_is_matched_mirrored(tmp_path, capsys):
    """A rectified pair given right view first (its calibration puts the second camera on the left):
    detected, said in info.json, and matched so that the first image stays the reference (its own GT)."""
    from stereonet.io import read_disparity

    gen = tmp_path / "gen"
    subprocess.run([sys.executable, "-m", "data_gen", "--out", str(gen), "--count", "1", "--seed", "3",
                    "--height", "128", "--width", "256"], check=True, capture_output=True)
    scene = next(p for p in gen.iterdir() if p.is_dir())
    K = np.array([[200.0, 0, 128], [0, 200.0, 64], [0, 0, 1]])
    calib = _write_yaml_calib(tmp_path / "reversed.yaml", K, K, np.eye(3), [0.1, 0, 0], (256, 128))
    code, err = run_main(capsys, scene / "im1.png", scene / "im0.png", "--calib", calib, "--method", "sgm",
                         "--max-disp", "64", "-o", tmp_path / "rev", "--unit", "m")
    assert code == 0, err
    info = json.loads((tmp_path / "rev" / "info.json").read_text())
    assert info["reversed_rig"] is True and any("reversed rig" in w for w in info["warnings"])
    assert "reversed rig" in err
    disp, valid = read_disparity(tmp_path / "rev" / "disparity.pfm")
    gt, gt_valid = read_disparity(scene / "disp1GT.pfm")  # the first image's (= right view's) ground truth
    both = valid & gt_valid
    assert both.mean() > 0.5
    assert np.mean(np.abs(disp[both] - gt[both]) > 2) < 0.15  # bad-2 of a correct match; garbage is > 0.5
    depth, has = read_disparity(tmp_path / "rev" / "depth.pfm")
    np.testing.assert_allclose(depth[has & both], 200.0 * 0.1 / disp[has & both], rtol=1e-4)
    normal = tmp_path / "normal"
    code, err = run_main(capsys, scene / "im0.png", scene / "im1.png", "--method", "sgm", "--max-disp", "64",
                         "-o", normal)
    assert code == 0 and json.loads((normal / "info.json").read_text())["reversed_rig"] is False


def test_reversed_unrectified_rig_stays_upright(tmp_path, capsys):
    """data_gen's unrectified rig given in the other order (the calibration inverted accordingly): the
    rectified frame stays upright (no 180-degree turn), and the cloud agrees with the forward run's."""
    from stereonet.calibration import read_calibration
    from stereonet.geometry import is_reversed_rig, stereo_rectify
    from stereonet.io import read_ply

    gen = tmp_path / "gen"
    subprocess.run([sys.executable, "-m", "data_gen", "--out", str(gen), "--count", "1", "--seed", "3",
                    "--unrectified", "--height", "128", "--width", "256"], check=True, capture_output=True)
    scene = next(p for p in gen.iterdir() if p.is_dir())
    c = read_calibration(scene / "calib.yaml")
    R, t = c.R.numpy(), c.t.numpy()
    inverse = _write_yaml_calib(tmp_path / "inverse.yaml", c.K2.numpy(), c.K1.numpy(), R.T, -R.T @ t,
                                c.image_size, None if c.dist2 is None else c.dist2.numpy(),
                                None if c.dist1 is None else c.dist1.numpy())
    rc = read_calibration(inverse)
    assert is_reversed_rig(rc) and not is_reversed_rig(c)
    rect = stereo_rectify(rc)
    assert rect.reversed and float(rect.R1[0, 0]) > 0.9 and float(rect.R1[1, 1]) > 0.9  # upright, not turned
    assert float(rect.P2[0, 3]) > 0 and rect.calib.baseline > 0
    common = ["--method", "sgm", "--max-disp", "64", "--unit", "m", "--cloud-frame", "original"]
    code, err = run_main(capsys, scene / "im0.png", scene / "im1.png", "--calib", scene / "calib.yaml", *common,
                         "-o", tmp_path / "fwd")
    assert code == 0, err
    code, err = run_main(capsys, scene / "im1.png", scene / "im0.png", "--calib", inverse, *common,
                         "-o", tmp_path / "rev")
    assert code == 0, err
    info = json.loads((tmp_path / "rev" / "info.json").read_text())
    assert info["reversed_rig"] is True and info["epipolar_median_row_error_px"] < 1.0
    from stereonet.io import read_disparity

    fs = cv2.FileStorage(str(tmp_path / "rev" / "rectified_calib.yaml"), cv2.FILE_STORAGE_READ)
    Q, flag = fs.getNode("Q").mat(), int(fs.getNode("reversed").real())
    fs.release()
    disp, valid = read_disparity(tmp_path / "rev" / "disparity.pfm")
    depth, has = read_disparity(tmp_path / "rev" / "depth.pfm")
    v, u = np.nonzero(valid & has)
    X = np.stack([u, v, disp[v, u], np.ones_like(u)]).astype(np.float64)
    X = Q @ X
    assert flag == 1 and np.allclose(X[2] / X[3], depth[v, u], rtol=1e-3)  # Q applies to disparity.pfm as written
    fwd, _ = read_ply(tmp_path / "fwd" / "cloud.ply")  # first camera = data_gen's left camera
    rev, _ = read_ply(tmp_path / "rev" / "cloud.ply")  # first camera = data_gen's right camera
    fwd_in_right = fwd @ R.T + t  # X_r = R X_l + t
    assert len(rev) > 0.5 * len(fwd)
    from scipy.spatial import cKDTree

    depth = float(np.median(fwd[:, 2]))
    near = cKDTree(fwd_in_right).query(rev[::10])[0]
    assert np.median(near) < 0.02 * depth  # the same surfaces (measured: 0.8 %)
    turned = cKDTree(fwd_in_right * [-1, -1, 1]).query(rev[::10])[0]  # what a 180-degree turn would give
    assert np.median(turned) > 3 * np.median(near)


@pytest.mark.parametrize("error", [ValueError, TypeError, IndexError])
def test_an_internal_error_is_a_traceback_not_exit_2(pair_files, tmp_path, capsys, monkeypatch, error):
    """Only input and file errors (StereoInputError, OSError kinds) are one line + exit 2; a bug inside a
    matcher (a plain ValueError or TypeError included) propagates with its traceback."""
    from stereonet import matchers

    def buggy(left, right, max_disp):
        raise error("an internal bug")

    monkeypatch.setitem(matchers._REGISTRY, "buggy-test", matchers.MatcherSpec("buggy-test", buggy, "classical", "x"))
    with pytest.raises(error, match="internal bug"):
        infer.main([str(pair_files[0]), str(pair_files[1]), "-o", str(tmp_path / "out"), "--method", "buggy-test",
                    "--no-progress"])
    from stereonet.checks import StereoInputError

    def bad_input(left, right, max_disp):
        raise StereoInputError("max_disp: expected something else")

    monkeypatch.setitem(matchers._REGISTRY, "buggy-test", matchers.MatcherSpec("buggy-test", bad_input, "classical", "x"))
    code, err = run_main(capsys, *pair_files, "-o", tmp_path / "out2", "--method", "buggy-test")
    assert code == 2 and "max_disp" in one_line_error(err)


def _unrectified_rig(tmp_path: Path, count: int) -> list[Path]:
    gen = tmp_path / "gen"
    subprocess.run([sys.executable, "-m", "data_gen", "--out", str(gen), "--count", str(count), "--seed", "3",
                    "--unrectified", "--height", "96", "--width", "192", "--no-progress"], check=True,
                   capture_output=True)
    return sorted(p for p in gen.iterdir() if p.is_dir())


def test_fixed_rig_batch_computes_the_rectification_once(tmp_path, capsys, monkeypatch):
    """Three frames of one calibrated rig (folders): the maps are made for the first pair only and reused,
    and the results equal those of three single runs."""
    import shutil as sh

    from stereonet import geometry
    from stereonet.io import read_disparity

    scenes = _unrectified_rig(tmp_path, 3)
    calib = scenes[0] / "calib.yaml"  # one --calib for every frame, as for a fixed rig
    for side, name in (("L", "im0.png"), ("R", "im1.png")):
        (tmp_path / side).mkdir()
        for i, sc in enumerate(scenes):
            sh.copy(sc / name, tmp_path / side / f"f{i}.png")
    calls = []
    real_maps = geometry.rectify.rectification_maps
    monkeypatch.setattr(geometry.rectify, "rectification_maps", lambda *a, **k: calls.append(1) or real_maps(*a, **k))
    common = ["--calib", calib, "--method", "bm-sad", "--max-disp", "48"]
    code, err = run_main(capsys, tmp_path / "L", tmp_path / "R", "-o", tmp_path / "batch", *common)
    assert code == 0, err
    assert len(calls) == 2  # left and right maps, once for the batch
    infos = [json.loads((tmp_path / "batch" / f"f{i}" / "info.json").read_text()) for i in range(3)]
    assert [i["rectification_maps"] for i in infos] == ["computed"] + ["reused (fixed rig, computed once)"] * 2
    code, err = run_main(capsys, tmp_path / "L" / "f2.png", tmp_path / "R" / "f2.png", "-o", tmp_path / "one", *common)
    assert code == 0, err
    a, va = read_disparity(tmp_path / "batch" / "f2" / "disparity.pfm")
    b, vb = read_disparity(tmp_path / "one" / "disparity.pfm")
    assert np.array_equal(va, vb) and np.array_equal(a[va], b[vb])


def test_two_videos_are_processed_frame_by_frame(tmp_path, capsys):
    """LEFT/RIGHT as two video files: one output folder per frame, with a progress bar; a frame-count
    mismatch or an undecodable video is one line, exit 2."""
    frames = [textured_pair(seed) for seed in range(3)]
    paths = {}
    for k, side in enumerate(("left", "right")):
        path = tmp_path / f"{side}.avi"
        vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 5, (160, 80))
        assert vw.isOpened()
        for pair in frames:
            vw.write(pair[k])
        vw.release()
        paths[side] = path
    code, err = run_main(capsys, paths["left"], paths["right"], "-o", tmp_path / "out", "--method", "bm-sad",
                         "--max-disp", "16", "--calib", write_calib(tmp_path / "calib.txt"))
    assert code == 0, err
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["frame_000000", "frame_000001", "frame_000002"]
    from stereonet.io import read_disparity

    for i in range(3):
        disp, valid = read_disparity(tmp_path / "out" / f"frame_{i:06d}" / "disparity.pfm")
        assert valid.mean() > 0.5 and abs(np.median(disp[valid]) - SHIFT) < 0.5  # the constant shift, per frame
    short = tmp_path / "short.avi"
    vw = cv2.VideoWriter(str(short), cv2.VideoWriter_fourcc(*"MJPG"), 5, (160, 80))
    vw.write(frames[0][1])
    vw.release()
    code, err = run_main(capsys, paths["left"], short, "-o", tmp_path / "bad")
    assert code == 2 and "frames" in one_line_error(err) and not (tmp_path / "bad").exists()
    broken = tmp_path / "broken.mp4"
    broken.write_bytes(b"not a video at all")
    code, err = run_main(capsys, paths["left"], broken, "-o", tmp_path / "bad")
    assert code == 2 and "RIGHT" in one_line_error(err)
    code, err = run_main(capsys, paths["left"], tmp_path / "calib.txt", "-o", tmp_path / "bad")
    assert code == 2 and "video" in one_line_error(err)


def test_output_scale_queries_the_smd_head_on_a_finer_grid(tmp_path, capsys):
    """--output-scale 2 with smd: the maps come out at twice the size, disparities in pixels of that grid
    (about twice the 1x run's), depth from the correspondingly scaled calibration; a method without a
    continuous head refuses the option in one line."""
    from stereonet import matchers
    from stereonet.cli.common import weights_available
    from stereonet.io import read_disparity, read_image, write_image

    if "smd" not in matchers.available() or not weights_available("smd"):
        pytest.skip("smd weights are not installed")
    import torch.nn.functional as F

    cones = REPO / "stereonet" / "data" / "bundled" / "middlebury2003" / "cones"
    for name in ("im2.png", "im6.png"):
        img = F.interpolate(read_image(cones / name), size=(94, 112), mode="area")
        write_image(tmp_path / name, img)
    common = [tmp_path / "im2.png", tmp_path / "im6.png", "--method", "smd", "--max-disp", "24",
              "--calib", write_calib(tmp_path / "calib.txt", w=112, h=94, ndisp=24)]
    code, err = run_main(capsys, *common, "-o", tmp_path / "x1")
    assert code == 0, err
    code, err = run_main(capsys, *common, "-o", tmp_path / "x2", "--output-scale", "2")
    assert code == 0, err
    d1, v1 = read_disparity(tmp_path / "x1" / "disparity.pfm")
    d2, v2 = read_disparity(tmp_path / "x2" / "disparity.pfm")
    assert d1.shape == (94, 112) and d2.shape == (188, 224)
    ratio = np.median(d2[v2]) / np.median(d1[v1])
    assert 1.8 < ratio < 2.2, ratio
    info = json.loads((tmp_path / "x2" / "info.json").read_text())
    assert info["output_scale"] == 2.0 and info["output_size"] == [224, 188]
    z1, h1 = read_disparity(tmp_path / "x1" / "depth.pfm")
    z2, h2 = read_disparity(tmp_path / "x2" / "depth.pfm")
    assert abs(np.median(z2[h2]) / np.median(z1[h1]) - 1) < 0.1  # the same scene depth at either scale
    code, err = run_main(capsys, *common[:2], "--method", "sgm", "-o", tmp_path / "bad", "--output-scale", "2")
    assert code == 2 and "--output-scale" in one_line_error(err)


def test_memory_budget_bad_values_are_one_line(pair_files, tmp_path, capsys):
    code, err = run_main(capsys, *pair_files, "-o", tmp_path / "a", "--method", "sgm", "--memory-budget", "0")
    assert code == 2 and "--memory-budget" in one_line_error(err)
    code, err = run_main(capsys, *pair_files, "-o", tmp_path / "b", "--method", "sgm", "--memory-budget", "0.01")
    assert code == 2 and "too small" in one_line_error(err) and not (tmp_path / "b").exists()
    code, err = run_main(capsys, *pair_files, "-o", tmp_path / "c", "--method", "sgm")
    assert code == 0 and json.loads((tmp_path / "c" / "info.json").read_text())["memory"]["strips"] == 1


def test_a_residual_vertical_offset_is_corrected_unless_no_align(tmp_path, capsys):
    """The right view 1.5 rows low (a rectification's residual error): infer.py fits the offset to its SIFT matches,
    says so in one line, records it, and the map is better than with --no-align; an aligned pair is left alone."""
    from stereonet.io import read_disparity

    left, right = textured_pair(seed=3, h=120, w=200)
    rows = np.arange(120, dtype=np.float32)
    map_y = np.repeat(np.clip(rows - 1.5, 0, 119)[:, None], 200, 1)
    map_x = np.repeat(np.arange(200, dtype=np.float32)[None], 120, 0)
    low = cv2.remap(right, map_x, map_y.astype(np.float32), cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)
    lp, rp, ap = tmp_path / "l.png", tmp_path / "r.png", tmp_path / "a.png"
    cv2.imwrite(str(lp), left)
    cv2.imwrite(str(rp), low)
    cv2.imwrite(str(ap), right)
    errors = {}
    for name, extra in (("aligned", []), ("kept", ["--no-align"])):
        out = tmp_path / name
        code, err = run_main(capsys, lp, rp, "-o", out, "--method", "sgm", "--max-disp", "16", *extra)
        assert code == 0, err
        info = json.loads((out / "info.json").read_text())
        disp, valid = read_disparity(out / "disparity.pfm")
        errors[name] = float(np.mean(valid[10:-10, 20:-10] & (np.abs(disp[10:-10, 20:-10] - SHIFT) <= 0.5)))
        if extra:
            assert "vertical_offset" not in info and "aligned" not in err
        else:
            assert "right view aligned" in err
            offset = info["vertical_offset"]
            assert offset["corrected"] and all(v == pytest.approx(1.5, abs=0.1) for v in offset["px_at_corners"])
    assert errors["aligned"] > errors["kept"] + 0.3, errors  # more pixels within 0.5 px of the truth
    code, err = run_main(capsys, lp, ap, "-o", tmp_path / "plain", "--method", "sgm", "--max-disp", "16")
    info = json.loads((tmp_path / "plain" / "info.json").read_text())
    assert code == 0 and "aligned" not in err and not info["vertical_offset"]["corrected"]


def test_prefilter_reaches_census_matchers_and_is_refused_elsewhere(pair_files, tmp_path, capsys):
    from stereonet.io import read_disparity

    maps = {}
    for name, extra in (("plain", []), ("smoothed", ["--prefilter", "binomial"])):
        code, err = run_main(capsys, *pair_files, "-o", tmp_path / name, "--method", "sgm", "--max-disp", "16", *extra)
        assert code == 0, err
        maps[name] = read_disparity(tmp_path / name / "disparity.pfm")[0]
    assert not np.array_equal(np.nan_to_num(maps["plain"], posinf=0), np.nan_to_num(maps["smoothed"], posinf=0))
    code, err = run_main(capsys, *pair_files, "-o", tmp_path / "bm", "--method", "opencv-bm", "--prefilter", "vertical")
    assert code == 2 and "--prefilter" in one_line_error(err) and not (tmp_path / "bm").exists()


def test_wmf_radius_reaches_the_matchers_that_filter_and_is_refused_elsewhere(pair_files, tmp_path, capsys):
    """``--wmf-radius`` sets the weighted median of the matchers that have one: sgm's opt-in filter changes its map;
    dispnet with 0 leaves its left-right rejections invalid (dense by default); a method without the
    filter or a negative radius is a one-line error naming the option, nothing written."""
    from stereonet.io import read_disparity

    maps, infos = {}, {}
    for name, extra in (("sgm", ["--method", "sgm"]), ("sgm9", ["--method", "sgm", "--wmf-radius", "9"]),
                        ("dispnet", ["--method", "dispnet"]), ("dispnet0", ["--method", "dispnet", "--wmf-radius", "0"])):
        code, err = run_main(capsys, *pair_files, "-o", tmp_path / name, "--max-disp", "16", *extra)
        assert code == 0, err
        maps[name] = read_disparity(tmp_path / name / "disparity.pfm")[0]
        infos[name] = json.loads((tmp_path / name / "info.json").read_text())
    assert not np.array_equal(np.nan_to_num(maps["sgm"], posinf=0), np.nan_to_num(maps["sgm9"], posinf=0))
    assert infos["dispnet0"]["density"] < infos["dispnet"]["density"]
    for extra, message in ((["--method", "opencv-bm", "--wmf-radius", "5"], "has no weighted median"),
                           (["--method", "sgm", "--wmf-radius", "-1"], "expected an integer >= 0")):
        code, err = run_main(capsys, *pair_files, "-o", tmp_path / "bad", *extra)
        line = one_line_error(err)
        assert code == 2 and "--wmf-radius" in line and message in line and not (tmp_path / "bad").exists()


def test_every_wmf_method_takes_the_option():
    import inspect

    from stereonet import matchers

    assert {m for m in matchers.available() if "wmf_radius" in inspect.signature(matchers.spec(m).fn).parameters} \
        == set(infer.WMF_METHODS)


def test_every_prefilter_method_takes_the_option():
    from stereonet import matchers

    left = torch.rand(1, 1, 24, 48, generator=torch.Generator().manual_seed(0))
    for method in infer.PREFILTER_METHODS:
        if method == "sgm-penalties":
            continue  # no shipped weights; it passes its options to sgm's
        out = matchers.match(method, left, left, 8, prefilter="vertical")
        assert out.disparity.shape == (1, 1, 24, 48)


def test_content_valid_drops_matches_on_padding_only():
    """Padding (no source content) is never an answer; a match beyond the right image's border is the matcher's
    call, as on an unpadded pair (so padding or --min-disp does not change it)."""
    h, w = 2, 10
    left_content = torch.ones(h, w, dtype=torch.bool)
    left_content[:, -1] = False  # the left image's own padding
    right_content = torch.ones(h, w, dtype=torch.bool)
    right_content[:, :3] = False  # padding on the right image's left side (shift_right with min_disp 3)
    disp = torch.zeros(1, 1, h, w)
    disp[0, 0, 0, 5] = 4.0  # -> x 1: padding
    disp[0, 0, 0, 2] = 6.0  # -> x -4: beyond the border, not padding
    disp[0, 0, 1, 8] = 2.0  # -> x 6: content
    disp[0, 0, 1, 7] = -3.0  # -> x 10: beyond the right border
    out = infer.content_valid(disp, left_content, right_content)[0, 0]
    assert not out[0, 5] and out[0, 2] and out[1, 8] and out[1, 7]
    assert not out[:, 0:3][disp[0, 0, :, 0:3] == 0].any()  # zero disparity onto the padding columns
    assert not out[:, -1].any()


def test_output_under_an_existing_file_is_one_line(pair_files, tmp_path, capsys):
    lp, rp = pair_files
    code, err = run_main(capsys, lp, rp, "-o", lp / "out", "--method", "sgm", "--max-disp", "16")
    assert code == 2 and "-o" in one_line_error(err)
    code, err = run_main(capsys, lp, rp, "-o", lp, "--method", "sgm", "--max-disp", "16")  # OUT itself a file
    assert code == 2 and "-o" in one_line_error(err) and lp.is_file()


def test_bad_input_leaves_no_new_parent_folders(pair_files, tmp_path, capsys):
    _, rp = pair_files
    fake = tmp_path / "fake.png"
    fake.write_text("not an image")
    code, err = run_main(capsys, fake, rp, "-o", tmp_path / "new1" / "new2" / "out", "--method", "sgm",
                         "--max-disp", "16")
    assert code == 2 and one_line_error(err)
    assert not (tmp_path / "new1").exists()


def test_left_folder_with_right_file_names_the_file(pair_files, tmp_path, capsys):
    lp, rp = pair_files
    folder = tmp_path / "lefts"
    folder.mkdir()
    (folder / "a.png").write_bytes(lp.read_bytes())
    code, err = run_main(capsys, folder, rp, "-o", tmp_path / "out", "--method", "sgm", "--max-disp", "16")
    line = one_line_error(err)
    assert code == 2 and line.startswith("infer.py: error: RIGHT: expected a folder or glob") and str(rp) in line


@pytest.mark.parametrize("extra", [["--max-disp", "200"], ["--max-disp", "16", "--min-disp", "-150"]])
def test_search_range_wider_than_the_image_names_the_options(pair_files, tmp_path, capsys, extra):
    lp, rp = pair_files  # 160 px wide
    code, err = run_main(capsys, lp, rp, "-o", tmp_path / "out", "--method", "sgm", *extra)
    assert code == 2 and "--max-disp/--min-disp" in one_line_error(err)
    assert not (tmp_path / "out").exists()


def test_inputs_inside_out_or_twice_are_refused(pair_files, tmp_path, capsys):
    lp, rp = pair_files
    code, err = run_main(capsys, lp, rp, "-o", tmp_path, "--overwrite", "--method", "sgm", "--max-disp", "16")
    assert code == 2 and "holds the input" in one_line_error(err) and lp.is_file() and rp.is_file()
    code, err = run_main(capsys, lp, lp, "-o", tmp_path / "out", "--method", "sgm", "--max-disp", "16")
    assert code == 2 and "same file as LEFT" in one_line_error(err) and not (tmp_path / "out").exists()


def test_output_folder_has_the_usual_mode(pair_files, tmp_path, capsys):
    import os

    lp, rp = pair_files
    code, _ = run_main(capsys, lp, rp, "-o", tmp_path / "out", "--method", "bm-sad", "--max-disp", "16")
    mask = os.umask(0)
    os.umask(mask)
    assert code == 0 and (tmp_path / "out").stat().st_mode & 0o777 == 0o777 & ~mask


def test_depth_beyond_the_uint16_range_is_no_depth(tmp_path, capsys):
    from stereonet.io import read_array

    left, right = textured_pair()
    lp, rp = tmp_path / "l.png", tmp_path / "r.png"
    cv2.imwrite(str(lp), left)
    cv2.imwrite(str(rp), right)
    calib = tmp_path / "calib.txt"  # baseline 2 km: every depth (f B / d ~ 33 km) beyond 65.535 m
    calib.write_text(write_calib(tmp_path / "c.txt").read_text().replace(f"baseline={BASELINE}", "baseline=2000"))
    code, err = run_main(capsys, lp, rp, "-o", tmp_path / "out", "--calib", calib, "--unit", "m", "--method", "sgm",
                         "--max-disp", "16")
    assert code == 0 and "beyond 65.535 m" in err
    assert (read_array(tmp_path / "out" / "depth_mm.png") == 0).all()



def test_transparent_pixels_are_never_an_answer(tmp_path, capsys):
    """An RGBA pair whose first 20 columns are transparent (black, alpha 0): no answer there, even with --fill."""
    from stereonet.io import read_disparity

    left, right = textured_pair()
    alpha = np.full(left.shape[:2], 255, np.uint8)
    alpha[:, :20] = 0
    lp, rp = tmp_path / "l.png", tmp_path / "r.png"
    cv2.imwrite(str(lp), np.dstack([left * (alpha[..., None] > 0), alpha]))
    cv2.imwrite(str(rp), np.dstack([right, np.full_like(alpha, 255)]))
    code, err = run_main(capsys, lp, rp, "-o", tmp_path / "out", "--method", "sgm", "--max-disp", "16", "--fill")
    assert code == 0 and "transparent pixels" in err
    disp, valid = read_disparity(tmp_path / "out" / "disparity.pfm")
    assert not valid[:, :20].any() and valid[:, 40:].mean() > 0.9


@pytest.mark.parametrize("suffix", [".yaml", ".json", ".xml"])
def test_calibration_unit_is_read_from_every_opencv_format(tmp_path, suffix):
    """The unit stereonet-calibrate stores is found in a YAML, JSON or XML file (XML's was missed: no
    depth_mm.png and units 'unknown')."""
    from stereonet.cli.infer import calibration_unit

    path = tmp_path / f"rig{suffix}"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("K1", np.eye(3))
    fs.write("unit", "mm")
    fs.release()
    assert calibration_unit(path) == "mm"


def test_folders_pair_by_the_numbers_in_their_names(tmp_path):
    """Folders numbered alike pair by number (left_10 with right_10 whatever the sort order); a shot missing on
    one side is one line naming the unpaired files instead of shifting every later pair; two independent
    numberings (two phones) pair in sorted order."""
    from stereonet.checks import StereoInputError
    from stereonet.cli.infer import find_pairs

    def folder(name, stems):
        d = tmp_path / name
        d.mkdir()
        for s in stems:
            (d / f"{s}.png").write_bytes(b"")
        return str(d)

    pairs = find_pairs(folder("l1", ["left_1", "left_10", "left_2"]),
                       folder("r1", ["right_01", "right_02", "right_10"]))
    assert [(p.left.stem, p.right.stem) for p in pairs] == [("left_1", "right_01"), ("left_10", "right_10"),
                                                            ("left_2", "right_02")]
    with pytest.raises(StereoInputError, match="without a partner: left_03.png, right_06.png"):
        find_pairs(folder("l2", [f"left_0{i}" for i in (1, 2, 3, 4, 5)]),
                   folder("r2", [f"right_0{i}" for i in (1, 2, 4, 5, 6)]))
    pairs = find_pairs(folder("l3", ["IMG_1000", "IMG_1001"]), folder("r3", ["IMG_5000", "IMG_5001"]))
    assert [(p.left.stem, p.right.stem) for p in pairs] == [("IMG_1000", "IMG_5000"), ("IMG_1001", "IMG_5001")]
