"""Runnable examples of active stereo: ``python -m stereonet.active.demo structured-light|laser|align -o OUT``.

* ``structured-light`` — a textureless (or ``--scene repetitive``) room seen by a rectified pair, matched by
  the same matcher with the dot projector off and on (pictures of both, metrics), then the left camera and
  the projector alone: Gray code + phase shift decoded and triangulated (depth map, error map, point cloud).
* ``laser`` — a laser sheet swept across the scene; stripe image, range image, error map, point cloud.
* ``align`` — range scans from several viewpoints with noise and partial overlap, registered by ICP from a
  perturbed guess (point-to-point and point-to-plane), merged into one coloured point cloud.

Every run writes ``OUT/metrics.json`` with the numbers it reports, PNG pictures and PLY clouds.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch

from data_gen import Camera
from stereonet.active.icp import (
    align_scans,
    merge_scans,
    relative_pose,
    rotation_error_deg,
    rotation_matrix,
)
from stereonet.active.laser import laser_scan
from stereonet.active.render import render_captures, render_range_scan
from stereonet.active.scenes import make_rig, make_scene
from stereonet.active.structured_light import (
    coded_light_scan,
    gray_code_patterns,
    phase_shift_patterns,
    random_dot_pattern,
    render_active_pair,
)
from stereonet.active.triangulate import depth_to_points
from stereonet.checks import StereoInputError
from stereonet.io import atomic_write_text, write_ply

log = logging.getLogger(__name__)


def _viz():
    from stereonet import viz

    return viz


def _depth_png(depth: torch.Tensor, valid: torch.Tensor, lo: float, hi: float) -> np.ndarray:
    """Depth in colour on a fixed scale (near = warm), invalid black."""
    import cv2

    d = depth.detach().to(torch.float64).reshape(depth.shape[-2:]).numpy()
    v = valid.reshape(depth.shape[-2:]).numpy()
    x = np.clip((hi - d) / max(hi - lo, 1e-9), 0, 1)
    rgb = cv2.applyColorMap((x * 255).astype(np.uint8), cv2.COLORMAP_TURBO)[:, :, ::-1].copy()
    rgb[~v] = 0
    return rgb


def _depth_error_png(depth: torch.Tensor, valid: torch.Tensor, gt: torch.Tensor, scale: float) -> np.ndarray:
    """|depth - gt| on a 0..scale grey-to-red ramp; invalid pixels blue-black, pixels without GT black."""
    e = (depth.reshape(gt.shape).to(torch.float64) - gt).abs().numpy()
    v = valid.reshape(gt.shape).numpy() & (gt.numpy() > 0)
    x = np.clip(e / scale, 0, 1)
    rgb = np.zeros((*gt.shape, 3), np.uint8)
    rgb[..., 0] = (255 * np.where(v, np.maximum(x, 0.15), 0)).astype(np.uint8)
    rgb[..., 1] = (255 * np.where(v, 0.15 * (1 - x), 0)).astype(np.uint8)
    rgb[..., 2] = np.where(v, 0, np.where(gt.numpy() > 0, 60, 0)).astype(np.uint8)
    return rgb


def _write_json(path: Path, data: dict) -> None:
    atomic_write_text(path, json.dumps(data, indent=2, sort_keys=True) + "\n")


def _cloud(depth, valid, camera: Camera, image: torch.Tensor):
    """Camera-frame points and uint8 colours of valid depth pixels."""
    d = depth.reshape(camera.height, camera.width)
    v = valid.reshape(camera.height, camera.width)
    pts = depth_to_points(d, v, camera.K)
    col = (image[0].permute(1, 2, 0)[v] * 255 + 0.5).clamp(0, 255).to(torch.uint8)
    return pts, col


# ------------------------------------------------------------------------------------------ structured light


def run_structured_light(out: Path, scene_kind: str = "textureless", seed: int = 0, width: int = 320,
                         height: int = 240, method: str = "opencv-sgbm", pictures: bool = True) -> dict:
    """Passive vs active (dot projector) stereo with ``method``, and camera + projector coded-light depth."""
    from stereonet.matchers import match
    from stereonet.metrics import evaluate

    viz = _viz()
    out.mkdir(parents=True, exist_ok=True)
    scene = make_scene(scene_kind, seed)
    rig = make_rig(width, height, focal=300.0 * width / 320, baseline=0.2)
    max_disp = rig.max_disp()
    dots = random_dot_pattern(rig.projector.height, rig.projector.width, density=0.08, dot_sigma=1.0, seed=seed)
    metrics: dict = {"scene": scene_kind, "seed": seed, "method": method, "max_disp": max_disp}
    panels = []
    for name, pat in (("passive", None), ("active", dots)):
        t0 = time.perf_counter()
        pair = render_active_pair(scene, rig, pat, seed=seed)
        t1 = time.perf_counter()
        res = match(method, pair.left, pair.right, max_disp)
        t2 = time.perf_counter()
        m = evaluate(res.disparity, pair.disparity, pair.valid, res.valid, occlusion=pair.occlusion, see=False)
        m.update(render_seconds=t1 - t0, match_seconds=t2 - t1)
        metrics[name] = m
        if pictures:
            viz.save_png(out / f"left_{name}.png", pair.left[0])
            viz.save_png(out / f"right_{name}.png", pair.right[0])
            dcol = viz.colorize_disparity(res.disparity[0, 0], max_disp, res.valid[0, 0])
            viz.save_png(out / f"disparity_{name}.png", dcol)
            err = viz.error_map(res.disparity[0, 0], pair.disparity[0, 0], pair.valid[0, 0], res.valid[0, 0])
            panels += [pair.left[0], dcol, err]
    if pictures:
        gt = viz.colorize_disparity(pair.disparity[0, 0], max_disp, pair.valid[0, 0])
        viz.save_png(out / "disparity_gt.png", gt)
        titles = [f"passive left ({scene_kind})", f"{method} passive bad2={metrics['passive']['bad2_noc']:.1f}%",
                  "passive error", "dot projector on", f"{method} active bad2={metrics['active']['bad2_noc']:.1f}%",
                  "active error"]
        viz.save_png(out / "active_vs_passive.png", viz.panel(panels, titles))
        viz.save_png(out / "pattern_dots.png", dots)
    # camera + projector: the projector is the second "camera"
    coded = {}
    for cmethod in ("gray", "gray+phase"):
        t0 = time.perf_counter()
        scan = coded_light_scan(scene, rig.left, rig.projector, method=cmethod, period=16, unit=4, seed=seed)
        e = scan.errors()
        e["seconds"] = time.perf_counter() - t0
        coded[cmethod] = e
        if pictures:
            tag = cmethod.replace("+", "_")
            gt_d = scan.view.depth
            viz.save_png(out / f"coded_{tag}_depth.png", _depth_png(scan.depth, scan.valid, 1.0, 3.5))
            viz.save_png(out / f"coded_{tag}_error.png", _depth_error_png(scan.depth, scan.valid, gt_d, 0.02))
            pts, col = _cloud(scan.depth, scan.valid, rig.left, scan.captures[-1:])
            write_ply(out / f"cloud_coded_{tag}.ply", pts, col)
    metrics["coded_light"] = coded
    if pictures:
        hp, wp = rig.projector.height, rig.projector.width
        viz.save_png(out / "pattern_gray_bit3.png", gray_code_patterns(hp, wp, unit=8)[6])
        viz.save_png(out / "pattern_phase0.png", phase_shift_patterns(hp, wp, 16)[0])
        viz.save_png(out / "coded_gt_depth.png", _depth_png(scan.view.depth, scan.view.hit, 1.0, 3.5))
    _write_json(out / "metrics.json", metrics)
    return metrics


# ------------------------------------------------------------------------------------------ laser


def run_laser(out: Path, seed: int = 0, width: int = 320, height: int = 240, angles: int = 160,
              scene_kind: str = "textured", pictures: bool = True) -> dict:
    """Sweep a laser sheet from 0.5 m right of the camera over ``angles`` steps; range image vs GT depth."""
    viz = _viz()
    out.mkdir(parents=True, exist_ok=True)
    scene = make_scene(scene_kind, seed)
    cam = Camera.pinhole(300.0 * width / 320, width, height)
    origin = (0.5, -0.05, 0.0)
    # sheet angles covering the camera's view between 1 and 3.5 m
    t0 = time.perf_counter()
    scan = laser_scan(scene, cam, origin, torch.linspace(-42.0, 12.0, angles), seed=seed)
    metrics = {"scene": scene_kind, "seed": seed, "angles": angles, **scan.errors(),
               "seconds": time.perf_counter() - t0}
    if pictures:
        k = angles // 2
        viz.save_png(out / "stripe_example.png", scan.stripes.on[k, 0])
        viz.save_png(out / "laser_range_image.png", _depth_png(scan.range_image, scan.valid, 1.0, 3.5))
        viz.save_png(out / "laser_gt_depth.png", _depth_png(scan.depth_map_gt, scan.depth_map_gt > 0, 1.0, 3.5))
        viz.save_png(out / "laser_error.png", _depth_error_png(scan.range_image, scan.valid, scan.depth_map_gt, 0.01))
        write_ply(out / "cloud_laser.ply", scan.points, None)
    _write_json(out / "metrics.json", metrics)
    return metrics


# ------------------------------------------------------------------------------------------ alignment


def orbit_cameras(count: int = 4, spread_deg: float = 40.0, radius: float = 2.2, width: int = 200,
                  height: int = 150, focal: float = 200.0) -> list[Camera]:
    """``count`` cameras on an arc of ``spread_deg`` around the scene centre, all looking at it."""
    centre = torch.tensor([0.0, 0.1, 2.2], dtype=torch.float64)
    cams = []
    for yaw in torch.linspace(-spread_deg / 2, spread_deg / 2, count).tolist():
        a = math.radians(yaw)
        eye = centre + radius * torch.tensor([math.sin(a), -0.15, -math.cos(a)], dtype=torch.float64)
        cams.append(Camera.pinhole(focal, width, height, eye=eye.tolist(), target=centre.tolist()))
    return cams


def feature_chain_guess(data: list) -> tuple[list, list]:
    """Initial poses into scan 0's frame from SIFT matches between consecutive scans, chained:
    ``T_0i = T_0(i-1) T_(i-1)i`` (each link from :func:`~stereonet.active.icp.feature_guess`)."""
    from stereonet.active.icp import feature_guess

    Rs, ts = [torch.eye(3, dtype=torch.float64)], [torch.zeros(3, dtype=torch.float64)]
    for i in range(1, len(data)):
        R, t, _ = feature_guess(data[i - 1], data[i], seed=i)
        Rs.append(Rs[-1] @ R)
        ts.append(Rs[-2] @ t + ts[-1])
    return Rs, ts


def run_align(out: Path, seed: int = 0, scans: int = 4, noise_std: float = 0.002, init_rot_deg: float = 4.0,
              init_trans: float = 0.05, width: int = 200, height: int = 150, pictures: bool = True,
              init: str = "perturbed") -> dict:
    """Render ``scans`` noisy range scans, guess their poses, align by ICP, merge to PLY.

    ``init="perturbed"``: each true pose rotated by ``init_rot_deg`` about a random axis and shifted by
    ``init_trans``; ``init="features"``: chained SIFT-match + RANSAC guesses (:func:`feature_chain_guess`).
    """
    if init not in ("perturbed", "features"):
        raise StereoInputError(f"init: expected 'perturbed' or 'features', got {init!r}")
    out.mkdir(parents=True, exist_ok=True)
    scene = make_scene("textured", seed)
    cams = orbit_cameras(scans, width=width, height=height, focal=200.0 * width / 200)
    data = [render_range_scan(scene, c, noise_std=noise_std, seed=seed * 100 + i, max_range=4.0)
            for i, c in enumerate(cams)]
    gt = [relative_pose(data[0].R, data[0].t, s.R, s.t) for s in data]
    g = torch.Generator().manual_seed(int(seed) + 7)
    init_R, init_t = [], []
    for R, t in gt:
        axis = torch.randn(3, generator=g, dtype=torch.float64)
        init_R.append(rotation_matrix(axis / axis.norm() * math.radians(init_rot_deg)) @ R)
        d = torch.randn(3, generator=g, dtype=torch.float64)
        init_t.append(t + init_trans * d / d.norm())
    if init == "features":
        init_R, init_t = feature_chain_guess(data)
    metrics: dict = {"seed": seed, "scans": scans, "noise_std": noise_std, "init": init,
                     "init_rot_deg": init_rot_deg if init == "perturbed" else None,
                     "init_trans": init_trans if init == "perturbed" else None,
                     "points": [int(s.points.shape[0]) for s in data]}
    for method in ("point_to_point", "point_to_plane"):
        t0 = time.perf_counter()
        al = align_scans([s.points for s in data], init_R, init_t, method=method, voxel=0.02,
                         max_iterations=100 if method == "point_to_point" else 50)
        rows = []
        for i in range(1, scans):
            r = al.results[i - 1]
            rows.append({"scan": i, "rot_err_deg": rotation_error_deg(al.R[i], gt[i][0]),
                         "trans_err": float((al.t[i] - gt[i][1]).norm()), "rmse": r.rmse,
                         "overlap": r.overlap, "iterations": r.iterations, "converged": r.converged})
        metrics[method] = {"seconds": time.perf_counter() - t0, "scans": rows,
                           "max_rot_err_deg": max(x["rot_err_deg"] for x in rows),
                           "max_trans_err": max(x["trans_err"] for x in rows),
                           "mean_rmse": sum(x["rmse"] for x in rows) / len(rows)}
        if pictures:
            pts, col = merge_scans([s.points for s in data], [s.colors for s in data], al.R, al.t, voxel=0.005)
            write_ply(out / f"merged_{method}.ply", pts, col)
    metrics["init_errors"] = [{"scan": i, "rot_err_deg": rotation_error_deg(init_R[i], gt[i][0]),
                        "trans_err": float((init_t[i] - gt[i][1]).norm())} for i in range(1, scans)]
    if pictures:
        pts, col = merge_scans([s.points for s in data], [s.colors for s in data], init_R, init_t, voxel=0.005)
        write_ply(out / "merged_initial_guess.ply", pts, col)
        viz = _viz()
        views = [render_captures(scene, c).images[0] for c in cams]
        viz.save_png(out / "scan_views.png", viz.panel(views, [f"scan {i}" for i in range(scans)]))
    _write_json(out / "metrics.json", metrics)
    return metrics


# ------------------------------------------------------------------------------------------ CLI


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m stereonet.active.demo", description=__doc__.split("\n\n")[0])
    p.add_argument("demo", choices=["structured-light", "laser", "align"])
    p.add_argument("-o", "--out", required=True, type=Path, help="output folder (created)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--width", type=int, default=None, help="camera width (height follows 4:3)")
    p.add_argument("--scene", default=None, help="structured-light: textureless|repetitive|textured")
    p.add_argument("--method", default="opencv-sgbm", help="structured-light: registered matcher name")
    p.add_argument("--angles", type=int, default=160, help="laser: number of sheet positions")
    p.add_argument("--scans", type=int, default=4, help="align: number of range scans")
    p.add_argument("--init", choices=["perturbed", "features"], default="perturbed",
                   help="align: initial guess from perturbed true poses or from SIFT matches + RANSAC")
    a = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    torch.set_num_threads(1)  # small tensors: thread hand-offs cost more than they save on a busy CPU
    if a.demo == "structured-light":
        w = a.width or 320
        m = run_structured_light(a.out, a.scene or "textureless", a.seed, w, w * 3 // 4, a.method)
        summary = (f"{a.method} bad-2 (noc) passive {m['passive']['bad2_noc']:.1f}% -> active "
                   f"{m['active']['bad2_noc']:.1f}%; coded light gray+phase median depth error "
                   f"{1000 * m['coded_light']['gray+phase']['median_abs_err']:.2f} mm")
    elif a.demo == "laser":
        w = a.width or 320
        m = run_laser(a.out, a.seed, w, w * 3 // 4, a.angles, a.scene or "textured")
        summary = (f"laser: {m['points']} stripe points, median {1000 * m['median_abs_err']:.2f} mm, "
                   f"p95 {1000 * m['p95_abs_err']:.2f} mm")
    else:
        w = a.width or 200
        m = run_align(a.out, a.seed, a.scans, width=w, height=w * 3 // 4, init=a.init)
        summary = (f"ICP point-to-plane: max rotation error {m['point_to_plane']['max_rot_err_deg']:.3f} deg, "
                   f"max translation error {1000 * m['point_to_plane']['max_trans_err']:.2f} mm")
    sys.stdout.write(summary + f"\nwrote {a.out}\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
