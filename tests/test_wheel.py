"""The product installs as a wheel: build it, install it (no dependencies) into a fresh venv whose only other
packages are this environment's third-party ones, and run ``stereonet-infer --method dispnet`` from a folder
outside the checkout. The weights and bundled pairs must come from the wheel (package data)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_wheel_installs_and_runs_a_learned_matcher(tmp_path):
    dist = tmp_path / "dist"
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(dist),
                    str(REPO)], check=True, capture_output=True, timeout=600)
    (wheel,) = dist.glob("stereonet-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    assert {"stereonet/weights/dispnet.pt", "stereonet/weights/siamese.pt", "stereonet/weights/smd.pt",
            "stereonet/data/bundled/middlebury2003/cones/im2.png"} <= set(names)
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    site = Path(subprocess.run([str(venv / "bin" / "python"), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                               check=True, capture_output=True, text=True).stdout.strip())
    # third-party packages from this environment (torch, kornia, ...): a plain path entry, so the editable
    # stereonet of this checkout (activated by a .pth file there) is not on the path
    (site / "third_party.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    subprocess.run([str(venv / "bin" / "python"), "-m", "pip", "install", "--no-deps", "--no-index", "-q", str(wheel)],
                   check=True, capture_output=True, timeout=600)
    work = tmp_path / "work"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "STEREONET_WEIGHTS_DIR")}
    where = subprocess.run([str(venv / "bin" / "python"), "-c", "import stereonet, stereonet.models.weights as w; "
                            "print(stereonet.__file__); print(w.weights_dir())"], cwd=work, env=env, check=True,
                           capture_output=True, text=True).stdout.split()
    assert all(str(venv) in p for p in where), where  # the package and its weights come from the wheel
    cones = Path(where[0]).parent / "data" / "bundled" / "middlebury2003" / "cones"
    proc = subprocess.run([str(venv / "bin" / "stereonet-infer"), str(cones / "im2.png"), str(cones / "im6.png"),
                           "--method", "dispnet", "--max-disp", "64", "--fill", "-o", str(work / "out")], cwd=work, env=env,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    info = json.loads((work / "out" / "info.json").read_text())
    # dispnet fills the pixels its left-right check rejects and filters the map itself: --fill adds nothing (infer.py
    # still leaves out the pixels whose match falls outside the right image's content)
    assert info["method"] == "dispnet" and info["density_before_fill"] == info["density"] > 90
