"""The "Proven by" items on data_gen's unrectified rigs (ground truth from data_gen's own camera model), with
OpenCV's stereoRectify / stereoRectifyUncalibrated through the same test in the same run."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import pytest
import torch

from stereonet.geometry import rectify_calibrated, rectify_points

_LIB = Path(__file__).resolve().parents[2] / "scripts" / "rectify_bench_lib.py"  # tooling, outside the package
_spec = importlib.util.spec_from_file_location("rectify_bench_lib", _LIB)
bench = importlib.util.module_from_spec(_spec)
sys.modules.setdefault("rectify_bench_lib", bench)  # dataclasses look their module up there
_spec.loader.exec_module(bench)
rendered_benchmark, rig_benchmark, summarize = bench.rendered_benchmark, bench.rig_benchmark, bench.summarize


def _by_method(rows):
    return {s["method"]: s for s in summarize(rows)}


def test_rectification_on_50_data_gen_rigs(one_thread):
    rows = rig_benchmark(rigs=50, seed=0, count=120)
    s = _by_method(rows)
    assert all(v["rigs"] == 50 for v in s.values())
    for method in ("ours-calibrated", "opencv-stereoRectify"):
        assert s[method]["median_dy"] < 0.1 and s[method]["max_dy"] < 0.5, s[method]
    # noisy "SIFT-like" matches: sigma 0.5 px and 20 % outliers; about half the rigs have lens distortion too
    assert s["ours-uncalibrated"]["median_dy"] < 0.5, s["ours-uncalibrated"]
    assert s["ours-uncalibrated"]["worst_rig_median"] < 1.0
    assert math.isfinite(s["opencv-stereoRectifyUncalibrated"]["median_dy"])  # reported beside ours
    # triangulation of the exact correspondences reproduces data_gen's depth
    assert max(r["triangulation_rel_err"] for r in rows) < 1e-3


@pytest.mark.slow
def test_rendered_unrectified_pairs(one_thread):
    """Rendered pairs: every valid pixel's GT correspondence, real SIFT matches on the rendered images, and
    triangulation against the rendered depth map."""
    rows, tri = rendered_benchmark(pairs=3, seed=0)
    assert tri["max_rel_depth_err"] < 1e-3, tri
    s = _by_method(rows)
    for method in ("ours-calibrated", "opencv-stereoRectify"):
        assert s[method]["median_dy"] < 0.1 and s[method]["max_dy"] < 0.5, s[method]
    assert s["ours-uncalibrated"]["median_dy"] < 0.5, s["ours-uncalibrated"]


@pytest.mark.slow
def test_rectified_rendered_images_agree_at_correspondences(one_thread):
    """Photometrically clean render: after calibrated rectification the two images have the same colour at
    the rectified ground-truth correspondences (which share a row)."""
    import data_gen

    item = data_gen.render_pair(
        0,
        3,
        difficulty=1,
        height=120,
        width=160,
        rectified=False,
        supersample=1,
        noise=False,
        photometric=False,
        blur=False,
        specular=False,
    )
    left, right = item["left"][None].double(), item["right"][None].double()
    rect = rectify_calibrated(left, right, item["calib"])
    ok = item["valid"][0] & ~item["occlusion"][0]
    ys, xs = torch.nonzero(ok, as_tuple=True)
    q1 = rectify_points(torch.stack([xs, ys], -1).double(), rect, "left")
    q2 = rectify_points(item["correspondence"][:, ys, xs].T.double(), rect, "right")
    assert float((q1[:, 1] - q2[:, 1]).abs().max()) < 1e-3

    def sample(img, q):  # bilinear, pixel centres at integers
        grid = torch.stack([q[:, 0] / (img.shape[-1] - 1), q[:, 1] / (img.shape[-2] - 1)], -1) * 2 - 1
        return torch.nn.functional.grid_sample(img, grid[None, None], align_corners=True)[0, :, 0].T

    a, b = sample(rect.left, q1), sample(rect.right, q2)
    diff = (a - b).abs().mean(-1)
    shuffled = (a - b[torch.randperm(len(b), generator=torch.Generator().manual_seed(0))]).abs().mean(-1)
    assert float(diff.median()) < 0.03 and float(diff.median()) < 0.2 * float(shuffled.median())
