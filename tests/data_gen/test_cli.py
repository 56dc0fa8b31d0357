"""python -m data_gen: Middlebury 2014 layout, calibration files, atomic pairs and resume."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest
import torch

import data_gen
from data_gen.cli import PAIR_FILES, UNRECTIFIED_FILES, main, pair_name


def test_cli_writes_middlebury_layout_readable_by_stereonet(tmp_path):
    from stereonet.calibration import read_calibration
    from stereonet.io import read_image, read_pfm

    assert main(["--out", str(tmp_path), "--count", "2", "--seed", "3", "--difficulty", "1", "--height", "48",
                 "--width", "96", "--no-progress"]) == 0
    folders = sorted(p for p in tmp_path.iterdir())
    assert [f.name for f in folders] == [pair_name(3, i, 1, True) for i in range(2)]
    for f in folders:
        assert sorted(os.listdir(f)) == sorted(PAIR_FILES)
    pair = data_gen.render_pair(3, 1, difficulty=1, height=48, width=96)
    disp = read_pfm(folders[1] / "disp0GT.pfm")
    np.testing.assert_allclose(disp, pair["disparity"][0].numpy(), rtol=1e-6)
    left = read_image(folders[1] / "im0.png")
    assert left.shape == (1, 3, 48, 96) and (left[0] - pair["left"]).abs().max() <= 1 / 255 + 1e-6
    mask = read_image(folders[1] / "mask0nocc.png")[0, 0].numpy() * 255
    np.testing.assert_array_equal(np.round(mask) == 128, pair["occlusion"][0].numpy())
    calib = read_calibration(folders[1] / "calib.txt")
    assert calib.ndisp == pair["max_disp"]
    np.testing.assert_allclose(calib.K1.numpy(), pair["calib"].K1.numpy(), rtol=1e-6)
    assert abs(calib.baseline - pair["calib"].baseline) < 1e-4


def test_cli_unrectified_writes_opencv_calibration_and_correspondences(tmp_path):
    from stereonet.calibration import read_calibration

    assert main(["--out", str(tmp_path), "--count", "1", "--seed", "2", "--unrectified", "--height", "48",
                 "--width", "96", "--no-progress"]) == 0
    folder = tmp_path / pair_name(2, 0, 2, False)
    assert set(UNRECTIFIED_FILES) <= set(os.listdir(folder))
    pair = data_gen.render_pair(2, 0, rectified=False, height=48, width=96)
    calib = read_calibration(folder / "calib.yaml")
    for name in ("K1", "K2", "R", "t"):
        np.testing.assert_allclose(getattr(calib, name).numpy(), getattr(pair["calib"], name).numpy(), atol=1e-9)
    rows = np.load(folder / "correspondences.npy")
    assert rows.shape[1] == 4 and len(rows) == int((pair["valid"] & ~pair["occlusion"]).sum())
    csv = np.loadtxt(folder / "correspondences.csv", delimiter=",", skiprows=1, ndmin=2)
    assert len(csv) > 0 and np.all(csv[:, :2] % 8 == 0)
    x1, y1 = rows[0, :2].astype(int)
    np.testing.assert_allclose(rows[0, 2:], pair["correspondence"][:, y1, x1].numpy(), rtol=1e-6)


def test_cli_resumes_and_leaves_only_complete_pairs(tmp_path):
    args = ["--out", str(tmp_path), "--seed", "0", "--difficulty", "0", "--height", "32", "--width", "64",
            "--no-progress"]
    assert main(args + ["--count", "2"]) == 0
    first = tmp_path / pair_name(0, 0, 0, True)
    stamp = (first / "im0.png").stat().st_mtime_ns
    # an interrupted run leaves a hidden temporary folder behind; it is not a pair and is cleaned up
    stale = tmp_path / f".tmp-{pair_name(0, 2, 0, True)}-99999"
    stale.mkdir()
    (stale / "im0.png").write_bytes(b"partial")
    assert main(args + ["--count", "3"]) == 0
    assert (first / "im0.png").stat().st_mtime_ns == stamp  # skipped, not rewritten
    assert not stale.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == [pair_name(0, i, 0, True) for i in range(3)]


def test_cli_shared_material_names_its_pairs_apart(tmp_path):
    folders = main(["--out", str(tmp_path), "--count", "1", "--no-progress", "--height", "48", "--width", "96",
                    "--supersample", "1", "--shared-material", "0.5"])
    assert folders == 0 and [p.name for p in tmp_path.iterdir()] == [pair_name(0, 0, 2, True, 0.5)]
    assert pair_name(0, 0, 2, True, 0.5).endswith("_m0.5") and pair_name(0, 0, 2, True) != pair_name(0, 0, 2, True, 0.5)


def test_cli_weak_background_and_thin_structures_name_their_pairs(tmp_path):
    code = main(["--out", str(tmp_path), "--count", "1", "--no-progress", "--height", "48", "--width", "96",
                 "--supersample", "1", "--weak-background", "1", "--thin-structures", "0.5"])
    name = pair_name(0, 0, 2, True, weak_background=1.0, thin_structures=0.5)
    assert code == 0 and [p.name for p in tmp_path.iterdir()] == [name] and name.endswith("_w1_r0.5")


@pytest.mark.parametrize("args,param", [(["--difficulty", "9"], "difficulty"), (["--count", "0"], "count"),
                                        (["--max-disp", "500"], "max_disp"),
                                        (["--shared-material", "1.5"], "shared_material"),
                                        (["--thin-structures", "-1"], "thin_structures"),
                                        (["--weak-background", "2"], "weak_background")])
def test_cli_bad_input_exits_with_a_message(tmp_path, capsys, args, param):
    with pytest.raises(SystemExit) as exc:
        main(["--out", str(tmp_path), "--count", "1", "--no-progress", *args])
    assert exc.value.code == 2 and param in capsys.readouterr().err
    assert not any(tmp_path.iterdir())


@pytest.mark.slow
def test_module_entry_point_runs():
    proc = subprocess.run([sys.executable, "-m", "data_gen", "--help"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0 and "--unrectified" in proc.stdout


@pytest.mark.slow
def test_bench_reports_pairs_per_second():
    r = data_gen.cli.bench(count=2, height=64, width=128)
    assert r["pairs_per_cpu_second"] > 0 and r["mean_objects"] >= 10
    torch.set_num_threads(2)


@pytest.mark.parametrize("where", ["file", "under-file"])
def test_cli_out_that_is_a_file_is_one_line(tmp_path, capsys, where):
    existing = tmp_path / "taken.txt"
    existing.write_text("keep me")
    out = existing if where == "file" else existing / "sub"
    with pytest.raises(SystemExit) as exc:
        main(["--out", str(out), "--count", "1", "--no-progress"])
    err = capsys.readouterr().err.strip().splitlines()
    assert exc.value.code == 2 and len(err) == 1 and "out" in err[0] and str(existing) in err[0], err
    assert existing.read_text() == "keep me" and sorted(p.name for p in tmp_path.iterdir()) == ["taken.txt"]
