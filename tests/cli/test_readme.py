"""The README's examples run as written: the library block, the tour's first command (fast), the whole tour (slow)."""

from __future__ import annotations

import importlib.util
import json
import os
import shlex
from pathlib import Path

import pytest

from stereonet.cli import infer

REPO = Path(__file__).resolve().parents[2]


def _pictures_module():
    spec = importlib.util.spec_from_file_location("make_pictures", REPO / "docs" / "make_pictures.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _workdir(tmp_path: Path) -> Path:
    """tmp/work with work/stereonet -> the repository's, so the README's paths (relative to the repository
    root: the bundled real pairs) resolve; nothing beside the checkout is needed."""
    work = tmp_path / "work"
    work.mkdir()
    os.symlink(REPO / "stereonet", work / "stereonet")
    return work


def test_readme_opening_is_the_two_commands():
    text = (REPO / "README.md").read_text()
    block = text[text.index("```bash") + 7:]
    lines = [ln.split("#")[0].strip() for ln in block[:block.index("```")].strip().splitlines()]
    assert lines == ["make demo", "make test"]


def test_api_block_runs(monkeypatch, capsys):
    text = (REPO / "README.md").read_text()
    start = text.index("```python", text.index("<!-- api -->")) + len("```python")
    code = text[start:text.index("```", start)]
    monkeypatch.chdir(REPO)
    exec(compile(code, "README.md", "exec"), {})
    printed = capsys.readouterr().out
    assert "opencv-sgbm" in printed and "bad-2 " in printed
    bad2 = float(printed.split("bad-2 ")[1].split(" %")[0])
    assert 0 < bad2 < 40  # SGBM on cones: well below chance


def test_tour_first_command_cones(tmp_path, monkeypatch):
    commands = _pictures_module().tour_commands()
    argv = shlex.split(commands[0])
    assert argv[:2] == ["python", "infer.py"]
    work = _workdir(tmp_path)
    monkeypatch.chdir(work)
    assert infer.main(argv[2:]) == 0
    info = json.loads((work / "out" / "cones" / "info.json").read_text())
    assert info["method"] == infer.default_method() and info["density"] > 50
    assert (work / "out" / "cones" / "disparity.png").is_file()


@pytest.mark.slow
def test_whole_tour(tmp_path):
    mod = _pictures_module()
    work = _workdir(tmp_path)
    mod.run_tour(work, mod.tour_commands())
    rig = work / "out" / "rig"
    assert {"rectified_left.png", "epipolar_check.png", "depth.pfm", "cloud.ply"} <= {p.name for p in rig.iterdir()}
    assert json.loads((rig / "info.json").read_text())["epipolar_median_row_error_px"] < 1.0
    assert (work / "out" / "uncal" / "epipolar_check.png").is_file()
    assert (work / "out" / "eval" / "bad2.png").is_file()
