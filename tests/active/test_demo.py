"""The three demos run end to end on tiny images and write what they promise."""

from __future__ import annotations

import json

import pytest

from stereonet.active.demo import main
from stereonet.io import read_ply


def test_demo_laser_small(tmp_path):
    assert main(["laser", "-o", str(tmp_path), "--width", "64", "--angles", "30"]) == 0
    m = json.loads((tmp_path / "metrics.json").read_text())
    assert m["points"] > 100 and m["median_abs_err"] < 0.02
    pts, _ = read_ply(tmp_path / "cloud_laser.ply")
    assert pts.shape == (m["points"], 3)
    for name in ("stripe_example.png", "laser_range_image.png", "laser_error.png"):
        assert (tmp_path / name).stat().st_size > 0


@pytest.mark.slow
def test_demo_structured_light_small(tmp_path):
    assert main(["structured-light", "-o", str(tmp_path), "--width", "96"]) == 0
    m = json.loads((tmp_path / "metrics.json").read_text())
    assert m["active"]["bad2_noc"] < m["passive"]["bad2_noc"]
    assert m["coded_light"]["gray+phase"]["wrong_code"] == 0.0
    assert (tmp_path / "active_vs_passive.png").exists() and (tmp_path / "cloud_coded_gray_phase.ply").exists()


@pytest.mark.slow
def test_demo_align_small(tmp_path):
    assert main(["align", "-o", str(tmp_path), "--width", "80", "--scans", "3"]) == 0
    m = json.loads((tmp_path / "metrics.json").read_text())
    assert m["point_to_plane"]["max_rot_err_deg"] < 1.0
    pts, col = read_ply(tmp_path / "merged_point_to_plane.ply")
    assert pts.shape[0] > 1000 and col is not None
