"""``python -m data_gen``: write synthetic pairs in the Middlebury 2014 layout, or benchmark the renderer.

One folder per pair, named after the pair (``synth_{rect|unrect}_d{difficulty}_s{seed}_{index:06d}``)::

    im0.png, im1.png        left / right images (8-bit RGB)
    disp0GT.pfm, disp1GT.pfm  left / right disparity (inf = unknown); unrectified rigs: horizontal component
                              of the ground-truth correspondence
    mask0nocc.png           255 = visible in both views, 128 = occluded in the right view, 0 = no ground truth
    calib.txt               Middlebury format: cam0, cam1, doffs, baseline (mm), width, height, ndisp
    calib.yaml              (unrectified) OpenCV FileStorage: K1, D1, K2, D2, R, T (X_r = R X_l + T), image size
    correspondences.npy     (unrectified) float32 (N, 4) rows (x1, y1, x2, y2), pixels seen in both views
    correspondences.csv     (unrectified) the same rows on an 8-pixel grid (x1, y1 multiples of 8)

Each pair is written into a hidden temporary folder and renamed into place, so an interrupted run leaves
only complete pairs; a rerun skips the pairs that exist.
"""

from __future__ import annotations

import argparse
import io
import logging
import os
import shutil
import sys
import time
from pathlib import Path

import numpy as np
import torch

from data_gen.pair import check_render_args, pair_name, render_pair
from data_gen.scene import MAX_DIFFICULTY, check_probability, check_textures

log = logging.getLogger(__name__)

PAIR_FILES = ("im0.png", "im1.png", "disp0GT.pfm", "disp1GT.pfm", "mask0nocc.png", "calib.txt")
UNRECTIFIED_FILES = ("calib.yaml", "correspondences.npy", "correspondences.csv")
CSV_STRIDE = 8


def _matrix_text(K: np.ndarray) -> str:
    rows = ["{:.6f} {:.6f} {:.6f}".format(*row) for row in np.asarray(K, dtype=np.float64)]
    return "[" + "; ".join(rows) + "]"


def middlebury_calib_text(pair: dict) -> str:
    """Middlebury 2014 ``calib.txt`` of a rendered pair (baseline in mm, the scene unit)."""
    calib = pair["calib"]
    K1, K2 = calib.K1.numpy(), calib.K2.numpy()
    w, h = calib.image_size
    disp = pair["disparity"][pair["valid"]]
    vmin = float(disp.min()) if disp.numel() else 0.0
    vmax = float(disp.max()) if disp.numel() else 0.0
    return (f"cam0={_matrix_text(K1)}\ncam1={_matrix_text(K2)}\ndoffs={K2[0, 2] - K1[0, 2]:.6f}\n"
            f"baseline={calib.baseline:.6f}\nwidth={w}\nheight={h}\nndisp={pair['max_disp']}\nisint=0\n"
            f"vmin={int(np.floor(vmin))}\nvmax={int(np.ceil(vmax))}\ndyavg=0\ndymax=0\n")


def correspondences(pair: dict) -> np.ndarray:
    """float32 :math:`(N, 4)` rows ``(x1, y1, x2, y2)`` of the left pixels seen in both views."""
    seen = (pair["valid"] & ~pair["occlusion"])[0]
    ys, xs = torch.nonzero(seen, as_tuple=True)
    x2 = pair["correspondence"][0][seen]
    y2 = pair["correspondence"][1][seen]
    return torch.stack([xs.float(), ys.float(), x2, y2], dim=-1).numpy().astype(np.float32)


def write_pair(folder: Path, pair: dict, rectified: bool) -> None:
    """Write one pair's files into ``folder`` (each file atomically)."""
    from stereonet.calibration import write_opencv_calibration
    from stereonet.io import atomic_write_bytes, atomic_write_text, write_image, write_pfm

    folder.mkdir(parents=True, exist_ok=True)
    write_image(folder / "im0.png", pair["left"])
    write_image(folder / "im1.png", pair["right"])
    for name, disp, valid in (("disp0GT.pfm", pair["disparity"], pair["valid"]),
                              ("disp1GT.pfm", pair["disparity_right"], pair["valid_right"])):
        d = torch.where(valid, disp, torch.full_like(disp, float("inf")))[0].numpy().astype(np.float32)
        write_pfm(folder / name, d)
    mask = np.zeros(pair["valid"].shape[1:], dtype=np.uint8)
    valid = pair["valid"][0].numpy()
    occ = pair["occlusion"][0].numpy()
    mask[valid & ~occ] = 255
    mask[valid & occ] = 128
    write_image(folder / "mask0nocc.png", mask)
    atomic_write_text(folder / "calib.txt", middlebury_calib_text(pair))
    if not rectified:
        write_opencv_calibration(folder / "calib.yaml", pair["calib"])
        rows = correspondences(pair)
        buf = io.BytesIO()
        np.save(buf, rows)
        atomic_write_bytes(folder / "correspondences.npy", buf.getvalue())
        on_grid = rows[(rows[:, 0] % CSV_STRIDE == 0) & (rows[:, 1] % CSV_STRIDE == 0)]
        lines = ["x1,y1,x2,y2"] + [f"{a:.0f},{b:.0f},{c:.6f},{d:.6f}" for a, b, c, d in on_grid]
        atomic_write_text(folder / "correspondences.csv", "\n".join(lines) + "\n")


def generate(out: str | os.PathLike, count: int, seed: int = 0, difficulty: int = 2, rectified: bool = True,
             height: int = 256, width: int = 512, supersample: int = 2, progress: bool = True,
             **render_options) -> list[Path]:
    """Write pairs ``0..count-1`` under ``out`` (skipping complete ones); returns all pair folders."""
    from tqdm import tqdm

    if isinstance(count, bool) or not isinstance(count, int) or count < 1:
        raise ValueError(f"count: expected an integer >= 1, got {count!r}")
    check_render_args(seed, 0, difficulty, height, width, supersample, render_options.get("max_disp"),
                      render_options.get("baseline"), render_options.get("num_objects"))
    for option in ("shared_material", "weak_background", "thin_structures"):
        check_probability(render_options.get(option, 0.0), option)
    textures = check_textures(render_options.get("textures"))
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"out: {out} is an existing file; expected a folder (new or existing)")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError, PermissionError) as e:
        raise ValueError(f"out: cannot create the folder {out} ({e.strerror or e})") from None
    folders = []
    for index in tqdm(range(count), desc="data_gen", unit="pair", disable=not progress):
        name = pair_name(seed, index, difficulty, rectified, render_options.get("shared_material", 0.0),
                         textures, render_options.get("weak_background", 0.0),
                         render_options.get("thin_structures", 0.0))
        final = out / name
        folders.append(final)
        if final.is_dir():
            continue  # renamed into place only when complete
        for stale in out.glob(f".tmp-{name}-*"):
            shutil.rmtree(stale, ignore_errors=True)
        tmp = out / f".tmp-{name}-{os.getpid()}"
        try:
            pair = render_pair(seed, index, difficulty, height, width, rectified, supersample, **render_options)
            write_pair(tmp, pair, rectified)
            os.rename(tmp, final)
        finally:
            if tmp.exists():
                shutil.rmtree(tmp, ignore_errors=True)
    return folders


def bench(count: int = 10, height: int = 256, width: int = 512, supersample: int = 2,
          difficulty: int = MAX_DIFFICULTY, min_objects: int = 10) -> dict:
    """Pairs per second on one core (``torch.set_num_threads(1)``), CPU time of this process.

    The texture bank and the compiled kernels are loaded first (once per process, reported separately); then
    it renders ``count`` pairs at ``difficulty`` with at least ``min_objects`` objects each. CPU time (not wall
    time) is reported as the primary number because the machine may be shared; both are returned.
    """
    from data_gen.scene import DIFFICULTY
    from data_gen.textures import warm_bank

    torch.set_num_threads(1)
    t0 = time.process_time()
    warm_bank()
    bank_seconds = time.process_time() - t0
    t0 = time.process_time()
    render_pair(1234, 10 ** 6, difficulty, 32, 64, True, supersample)  # load / compile the numba kernels
    render_pair(1234, 10 ** 6, difficulty, 32, 64, False, supersample)
    warmup_seconds = time.process_time() - t0
    lo, hi = DIFFICULTY[difficulty]["objects"]
    objects = []
    cpu0, wall0 = time.process_time(), time.perf_counter()
    for i in range(count):
        n = max(min_objects, lo + i % (hi - lo + 1))
        pair = render_pair(1234, i, difficulty, height, width, True, supersample, num_objects=n)
        objects.append(len(pair["scene"].objects) - pair["scene"].num_background)
    cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    result = dict(pairs=count, height=height, width=width, supersample=supersample, difficulty=difficulty,
                  mean_objects=float(np.mean(objects)), cpu_seconds_per_pair=cpu / count,
                  pairs_per_cpu_second=count / cpu, wall_seconds_per_pair=wall / count,
                  bank_warmup_cpu_seconds=bank_seconds, kernel_warmup_cpu_seconds=warmup_seconds)
    result.update(_dispnet_step_seconds(height, width))
    if "dispnet_step_cpu_seconds" in result:
        result["dispnet_step_over_render"] = result["dispnet_step_cpu_seconds"] / result["cpu_seconds_per_pair"]
    return result


def _dispnet_step_seconds(height: int, width: int, batch: int = 1, steps: int = 3) -> dict:
    """CPU seconds of one DispNet training step (forward, L1 loss, backward, Adam) if the model exists."""
    try:
        from stereonet.models.dispnet import DispNet
    except Exception as e:  # the learned-model module may not exist yet
        log.info("no DispNet to compare against: %s", e)
        return {}
    net = DispNet()
    opt = torch.optim.Adam(net.parameters(), lr=1e-4)
    left = torch.rand(batch, 3, height, width)
    right = torch.rand(batch, 3, height, width)
    target = torch.rand(batch, 1, height, width) * 32

    def step():
        opt.zero_grad()
        loss = (net(left, right).disparity - target).abs().mean()
        loss.backward()
        opt.step()

    step()
    t0 = time.process_time()
    for _ in range(steps):
        step()
    return {"dispnet_step_cpu_seconds": (time.process_time() - t0) / steps, "dispnet_batch": batch}


class _OneLineParser(argparse.ArgumentParser):
    """argparse whose errors are one line (``prog: error: ...``), exit 2."""

    def error(self, message: str):
        sys.stderr.write(f"{self.prog}: error: {' '.join(message.split())}\n")
        raise SystemExit(2)


def build_parser() -> argparse.ArgumentParser:
    p = _OneLineParser(prog="python -m data_gen", description=__doc__.split("\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", help="output folder (one sub-folder per pair)")
    p.add_argument("--count", type=int, default=10, help="number of pairs (indices 0..count-1)")
    p.add_argument("--seed", type=int, default=0, help="dataset seed (pairs are a pure function of seed, index)")
    p.add_argument("--difficulty", type=int, default=2, help=f"curriculum level 0..{MAX_DIFFICULTY}")
    p.add_argument("--unrectified", action="store_true", help="random unrectified rigs; also write calib.yaml "
                   "and ground-truth correspondences")
    p.add_argument("--height", type=int, default=256)
    p.add_argument("--width", type=int, default=512)
    p.add_argument("--supersample", type=int, default=2, help="rays per pixel side for anti-aliasing")
    p.add_argument("--max-disp", type=int, default=None, help="disparity range (default: the difficulty's)")
    p.add_argument("--shared-material", type=float, default=0.0,
                   help="probability that an object takes the look of the surface behind it (depth edges without "
                        "a colour edge; default 0)")
    p.add_argument("--weak-background", type=float, default=0.0,
                   help="probability that the background walls get a weaker texture (default 0)")
    p.add_argument("--thin-structures", type=float, default=0.0,
                   help="probability that a scene gets a few thin rods: poles, branches, cables (default 0)")
    p.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    p.add_argument("--bench", action="store_true", help="measure pairs per second on one core and exit")
    p.add_argument("--bench-count", type=int, default=10, help="pairs rendered by --bench")
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.bench:
        r = bench(args.bench_count, args.height, args.width, args.supersample)
        lines = [f"data_gen bench: {r['pairs']} pairs {r['height']}x{r['width']}, supersample {r['supersample']}, "
                 f"difficulty {r['difficulty']}, {r['mean_objects']:.1f} objects/pair, 1 thread",
                 f"  {r['pairs_per_cpu_second']:.2f} pairs/s per core ({1000 * r['cpu_seconds_per_pair']:.0f} ms CPU "
                 f"per pair; wall {1000 * r['wall_seconds_per_pair']:.0f} ms; once per process: texture bank "
                 f"{r['bank_warmup_cpu_seconds']:.1f} s, kernels {r['kernel_warmup_cpu_seconds']:.1f} s)"]
        if "dispnet_step_over_render" in r:
            lines.append(f"  one DispNet training step (batch {r['dispnet_batch']}, same size): "
                         f"{1000 * r['dispnet_step_cpu_seconds']:.0f} ms CPU = "
                         f"{r['dispnet_step_over_render']:.2f} x the time to render one pair")
        else:
            lines.append("  (stereonet.models.dispnet not available: no training-step comparison)")
        sys.stdout.write("\n".join(lines) + "\n")
        return 0
    if not args.out:
        parser.error("--out: required unless --bench is given")
    try:
        folders = generate(args.out, args.count, args.seed, args.difficulty, not args.unrectified, args.height,
                           args.width, args.supersample, progress=not args.no_progress, max_disp=args.max_disp,
                           shared_material=args.shared_material, weak_background=args.weak_background,
                           thin_structures=args.thin_structures)
    except (ValueError, TypeError) as e:
        parser.error(str(e))
    sys.stdout.write(f"{len(folders)} pairs in {args.out}\n")
    return 0
