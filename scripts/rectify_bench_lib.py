"""Library of scripts/bench_rectify.py (benchmark tooling, outside the package; tests/geometry/test_data_gen_rigs.py
loads it by path). Rectification benchmark on data_gen's unrectified rigs: ours vs OpenCV, calibrated and uncalibrated.

For every rig (``data_gen.sample_rig`` with the same random stream as ``data_gen.render_pair(seed, index,
rectified=False)``) we draw 3D points with disparities in the rig's range, project them with **data_gen's own
camera model** (independent of ours) into both images — the ground-truth correspondences — and measure the row
error ``|y_left - y_right|`` of those correspondences after rectification:

- ``ours-calibrated``: :func:`stereonet.geometry.stereo_rectify` (method "kornia");
- ``opencv-stereoRectify``: ``cv2.stereoRectify`` (CALIB_ZERO_DISPARITY, alpha = 1);
- ``ours-uncalibrated``: robust F (our RANSAC) from noisy matches (Gaussian noise ``sigma`` px, a fraction of
  random outliers: "SIFT-like") + Hartley's homographies (:func:`stereo_rectify_uncalibrated`);
- ``opencv-stereoRectifyUncalibrated``: ``cv2.findFundamentalMat(FM_RANSAC)`` on the same matches +
  ``cv2.stereoRectifyUncalibrated``.

:func:`rendered_benchmark` does the same on fully rendered pairs (``data_gen.render_pair``): every valid
pixel's ground-truth correspondence, real SIFT matches for the uncalibrated methods, and the triangulation
error against the rendered depth.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch

from stereonet.geometry.rectify import (
    apply_homography,
    rectify_points,
    stereo_rectify,
    stereo_rectify_uncalibrated,
)
from stereonet.geometry.triangulate import triangulate
from stereonet.types import Calibration

__all__ = [
    "METHODS",
    "RigCase",
    "data_gen_case",
    "format_table",
    "rendered_benchmark",
    "rig_benchmark",
    "summarize",
]

METHODS = ("ours-calibrated", "opencv-stereoRectify", "ours-uncalibrated", "opencv-stereoRectifyUncalibrated")


@dataclass
class RigCase:
    """One unrectified rig with exact correspondences: ``points`` (left camera frame, mm) project to ``pts1``
    in the left and ``pts2`` in the right image (pixels as the distorted lenses record them)."""

    name: str
    calib: Calibration
    points: torch.Tensor
    pts1: torch.Tensor
    pts2: torch.Tensor
    extra: dict = field(default_factory=dict)


def data_gen_case(seed: int, index: int, height: int = 240, width: int = 320, count: int = 400) -> RigCase:
    """The rig of ``data_gen.render_pair(seed, index, height=height, width=width, rectified=False)`` and
    ``count`` ground-truth correspondences projected by data_gen's camera model."""
    import data_gen

    rng = np.random.default_rng(np.random.SeedSequence([seed, index]))
    rig = data_gen.sample_rig(rng, height, width, rectified=False)
    max_disp = data_gen.default_max_disp(2, width)
    calib = data_gen.calibration_of(rig, max_disp)
    g = np.random.default_rng(np.random.SeedSequence([seed, index, 1]))
    kept: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]] = []
    total = 0
    while total < count:
        n = 4 * count
        x, y = g.uniform(0, width - 1, n), g.uniform(0, height - 1, n)
        d = g.uniform(2.0, max_disp, n)
        z = rig.focal * rig.baseline / d
        xn, yn = rig.left.pixel_to_normalized(x, y)
        X = torch.from_numpy(np.stack([xn * z, yn * z, z], -1))
        p1, _ = rig.left.project(X)
        p2, z2 = rig.right.project(X)
        ok = (z2 > 0) & (p2[:, 0] >= 0) & (p2[:, 0] <= width - 1) & (p2[:, 1] >= 0) & (p2[:, 1] <= height - 1)
        kept.append((X[ok], p1[ok], p2[ok]))
        total += int(ok.sum())
    X, p1, p2 = (torch.cat([k[i] for k in kept])[:count] for i in range(3))
    return RigCase(f"data_gen_unrect_s{seed}_{index:06d}", calib, X, p1, p2)


def _sift_like(case: RigCase, sigma: float, outliers: float, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    n1 = case.pts1 + sigma * torch.randn(case.pts1.shape, generator=g, dtype=torch.float64)
    n2 = case.pts2 + sigma * torch.randn(case.pts2.shape, generator=g, dtype=torch.float64)
    k = int(round(outliers * len(n2)))
    w, h = case.calib.image_size
    bad = torch.randperm(len(n2), generator=g)[:k]
    n2[bad] = torch.rand(k, 2, generator=g, dtype=torch.float64) * torch.tensor([w - 1.0, h - 1.0])
    return n1, n2


def _row_error_h(H1: np.ndarray | torch.Tensor, H2, gt1: torch.Tensor, gt2: torch.Tensor) -> torch.Tensor:
    a = apply_homography(torch.as_tensor(H1, dtype=torch.float64), gt1)
    b = apply_homography(torch.as_tensor(H2, dtype=torch.float64), gt2)
    return (a[:, 1] - b[:, 1]).abs()


def _evaluate(case: RigCase, matches: tuple[torch.Tensor, torch.Tensor], seed: int) -> dict[str, tuple]:
    """{method: (row errors (N,) tensor, seconds)} for one case."""
    import cv2

    out: dict[str, tuple] = {}
    gt1, gt2 = case.pts1, case.pts2
    for method, name in (("kornia", "ours-calibrated"), ("opencv", "opencv-stereoRectify")):
        t0 = time.perf_counter()
        rect = stereo_rectify(case.calib, method=method)
        sec = time.perf_counter() - t0
        dy = (rectify_points(gt1, rect, "left")[:, 1] - rectify_points(gt2, rect, "right")[:, 1]).abs()
        out[name] = (dy, sec)
    n1, n2 = matches
    w, h = case.calib.image_size
    # the uncalibrated methods see distorted pixels: with lens distortion a single F is only approximate
    t0 = time.perf_counter()
    rect = stereo_rectify_uncalibrated(n1, n2, (w, h), seed=seed)
    sec = time.perf_counter() - t0
    out["ours-uncalibrated"] = (_row_error_h(rect.H1, rect.H2, gt1, gt2), sec)
    t0 = time.perf_counter()
    a, b = n1.numpy(), n2.numpy()
    F, mask = cv2.findFundamentalMat(a, b, cv2.FM_RANSAC, 1.0, 0.999)
    inl = mask[:, 0].astype(bool)
    ok, H1, H2 = cv2.stereoRectifyUncalibrated(a[inl], b[inl], F[:3], (w, h))
    sec = time.perf_counter() - t0
    dy = _row_error_h(H1, H2, gt1, gt2) if ok else torch.full((len(gt1),), float("inf"), dtype=torch.float64)
    out["opencv-stereoRectifyUncalibrated"] = (dy, sec)
    return out


def _row(rig: str, method: str, dy: torch.Tensor, seconds: float, **extra) -> dict:
    """One result row: row-error statistics of one method on one rig (``pooled`` keeps every |dy|)."""
    return dict(
        rig=rig,
        method=method,
        median_dy=float(dy.median()),
        p95_dy=float(torch.quantile(dy, 0.95)),
        max_dy=float(dy.max()),
        seconds=seconds,
        pooled=dy,
        **extra,
    )


def rig_benchmark(
    rigs: int = 50,
    seed: int = 0,
    height: int = 240,
    width: int = 320,
    count: int = 400,
    sigma: float = 0.5,
    outliers: float = 0.2,
) -> list[dict]:
    """Per-rig, per-method rows ``{"rig", "method", "distorted", "median_dy", "p95_dy", "max_dy", "seconds",
    "triangulation_rel_err", "pooled"}`` on data_gen rigs ``0..rigs-1`` of ``seed`` (about half of them have
    radial lens distortion: the uncalibrated methods then also carry the error of a single F for a distorted
    pair, so ``distorted`` is recorded). ``triangulation_rel_err`` is the largest relative depth error of our
    DLT triangulation of the exact correspondences against data_gen's depth; ``pooled`` holds every |dy|."""
    rows: list[dict] = []
    for index in range(rigs):
        case = data_gen_case(seed, index, height, width, count)
        matches = _sift_like(case, sigma, outliers, seed * 100003 + index)
        tri = triangulate(case.pts1, case.pts2, case.calib)
        tri_err = float(((tri.points[:, 2] - case.points[:, 2]).abs() / case.points[:, 2]).max())
        distorted = case.calib.dist1 is not None and bool((case.calib.dist1.abs() > 0).any())
        for method, (dy, sec) in _evaluate(case, matches, index).items():
            rows.append(_row(case.name, method, dy, sec, distorted=distorted, triangulation_rel_err=tri_err))
    return rows


def summarize(rows: list[dict]) -> list[dict]:
    """One row per method: rigs, pooled median / 95th percentile / max |dy| (px), median of per-rig medians,
    worst per-rig median, mean seconds per rig."""
    out = []
    for method in dict.fromkeys(r["method"] for r in rows):
        mine = [r for r in rows if r["method"] == method]
        pooled = torch.cat([r["pooled"] for r in mine])
        out.append(
            dict(
                method=method,
                rigs=len(mine),
                median_dy=float(pooled.median()),
                p95_dy=float(torch.quantile(pooled, 0.95)),
                max_dy=float(pooled.max()),
                worst_rig_median=max(r["median_dy"] for r in mine),
                seconds=float(np.mean([r["seconds"] for r in mine])),
            )
        )
    return out


def format_table(summary: list[dict], title: str) -> str:
    head = (
        f"{'method':34s} {'rigs':>4s} {'median|dy|':>11s} {'p95|dy|':>9s} {'max|dy|':>9s} "
        f"{'worst rig med':>13s} {'s/rig':>7s}"
    )
    lines = [title, head, "-" * len(head)]
    for s in summary:
        lines.append(
            f"{s['method']:34s} {s['rigs']:4d} {s['median_dy']:11.2e} {s['p95_dy']:9.2e} {s['max_dy']:9.2e} "
            f"{s['worst_rig_median']:13.2e} {s['seconds']:7.3f}"
        )
    return "\n".join(lines)


def rendered_benchmark(
    pairs: int = 3, seed: int = 0, height: int = 160, width: int = 224, difficulty: int = 2
) -> tuple[list[dict], dict]:
    """Rendered unrectified pairs: GT correspondence of every valid, non-occluded left pixel; real SIFT
    matches for the uncalibrated methods. Returns (per-pair rows as :func:`rig_benchmark`, triangulation stats
    ``{"max_rel_depth_err", "median_rel_depth_err"}`` against the rendered depth)."""
    import data_gen
    from stereonet.features import match_sift

    rows: list[dict] = []
    rel_errs = []
    for index in range(pairs):
        item = data_gen.render_pair(
            seed, index, difficulty=difficulty, height=height, width=width, rectified=False, supersample=1
        )
        ok = item["valid"][0] & ~item["occlusion"][0]
        ys, xs = torch.nonzero(ok, as_tuple=True)
        gt1 = torch.stack([xs, ys], -1).double()
        gt2 = item["correspondence"][:, ys, xs].T.double()
        depth = item["depth"][0, ys, xs].double()
        case = RigCase(item["name"], item["calib"], torch.zeros(0, 3), gt1, gt2)
        tri = triangulate(gt1, gt2, case.calib)
        rel_errs.append((tri.points[:, 2] - depth).abs() / depth)
        left, right = item["left"][None], item["right"][None]
        matches = match_sift(left, right)
        for method, (dy, sec) in _evaluate(case, matches, index).items():
            rows.append(_row(case.name, method, dy, sec, matches=int(len(matches[0]))))
    rel = torch.cat(rel_errs)
    return rows, {"max_rel_depth_err": float(rel.max()), "median_rel_depth_err": float(rel.median())}
