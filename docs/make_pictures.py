"""Regenerate the README pictures in docs/readme/ by running the README's own commands.

    .venv/bin/python docs/make_pictures.py

Runs, from the repository root, the tour commands of README.md (the same list tests/cli/test_readme.py
runs), then copies the pictures they produce into docs/readme/ and renders the point cloud to a PNG.
"""

from __future__ import annotations

import glob
import os
import shlex
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "docs" / "readme"


def tour_commands(readme: Path = REPO / "README.md") -> list[str]:
    """The shell commands of the README block that follows the ``<!-- tour -->`` marker (comments dropped)."""
    text = readme.read_text()
    start = text.index("<!-- tour -->")
    block = text[text.index("```bash", start) + len("```bash"):]
    block = block[:block.index("```")]
    lines = [ln.strip() for ln in block.splitlines()]
    return [ln for ln in lines if ln and not ln.startswith("#")]


def run_tour(workdir: Path, commands: list[str]) -> None:
    """Run the commands with ``workdir`` as the current folder (``python`` = this interpreter, globs expanded,
    the README's ``stereonet/data/bundled`` paths, relative to the repository root where a user runs them,
    pointing at the repository's)."""
    if not (workdir / "stereonet").exists():
        os.symlink(REPO / "stereonet", workdir / "stereonet")
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    for cmd in commands:
        argv = []
        for a in shlex.split(cmd):
            hits = sorted(glob.glob(a, root_dir=workdir)) if any(c in a for c in "*?[") else []
            argv += hits or [a]
        if argv[0] == "python":
            argv[0] = sys.executable
        if argv[1] in ("infer.py", "eval.py"):
            argv[1] = str(REPO / argv[1])
        subprocess.run(argv, cwd=workdir, env=env, check=True)


def render_cloud(ply: Path, png: Path, max_points: int = 60000) -> None:
    """A coloured 3-D scatter of a PLY cloud seen from above-left of the camera (matplotlib, Agg)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from stereonet.io import read_ply
    from stereonet.io.atomic import atomic_path

    points, colors = read_ply(ply)
    rng = np.random.default_rng(0)
    keep = rng.permutation(len(points))[:max_points]
    p, c = points[keep], (colors[keep] / 255.0 if colors is not None else None)
    lo, hi = np.percentile(p, [2, 95], axis=0)  # drop stray far/side points (borders, mismatches) for the scale
    inside = np.all((p >= lo) & (p <= hi), axis=1)
    p, c = p[inside], (c[inside] if c is not None else None)
    fig = Figure(figsize=(8, 6))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1, projection="3d")
    ax.scatter(p[:, 0], p[:, 2], -p[:, 1], c=c, s=1.2, linewidths=0)
    ax.set_box_aspect(tuple(np.ptp(p[:, [0, 2, 1]], axis=0)))  # metric: equal units on every axis
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("depth z [mm]")
    ax.set_zlabel("-y [mm]")
    ax.view_init(elev=20, azim=-60)
    ax.set_title("cloud.ply (metric, coloured)")
    fig.tight_layout()
    with atomic_path(png) as tmp:
        fig.savefig(tmp, format="png", dpi=100)


def main() -> int:
    import importlib.util

    spec = importlib.util.spec_from_file_location("stereonet_bench_script", REPO / "scripts" / "bench.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    shrink_copy = bench.shrink_copy
    from stereonet.io import read_array, write_image

    OUT.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp) / "work"
        work.mkdir()
        run_tour(work, tour_commands())
        wanted = {
            "out/cones/disparity.png": "cones_disparity.png",
            "out/rig/rectified_left.png": "rig_rectified_left.png",
            "out/rig/epipolar_check.png": "rig_epipolar_check.png",
            "out/rig/disparity.png": "rig_disparity.png",
            "out/uncal/epipolar_check.png": "uncal_epipolar_check.png",
            "out/uncal/disparity.png": "uncal_disparity.png",
        }
        for src, dst in wanted.items():
            if (work / src).is_file():
                shutil.copyfile(work / src, OUT / dst)
        for left in sorted(work.glob("gen/*/im0.png"))[:1]:
            write_image(OUT / "rig_left.png", read_array(left))
            write_image(OUT / "rig_right.png", read_array(left.with_name("im1.png")))
        if (work / "out/rig/cloud.ply").is_file():
            render_cloud(work / "out/rig/cloud.ply", OUT / "rig_cloud.png")
        panels = sorted(work.glob("out/eval/*/*.png"))
        if panels:
            shrink_copy(panels[0], OUT / "eval_panel.jpg")
        if (work / "out/eval/bad2.png").is_file():
            shutil.copyfile(work / "out/eval/bad2.png", OUT / "eval_bad2.png")
    print(f"pictures written to {OUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
