"""infer.py: a photo pair in; disparity, depth and a coloured point cloud out.

    python infer.py LEFT RIGHT -o OUT [--method NAME] [--max-disp N] [--calib FILE | --uncalibrated]
                    [--checkpoint CKPT] [--overwrite] [--device cpu] [--fill]

Writes ``OUT/disparity.pfm`` (float, ``inf`` = invalid, left-referenced), ``OUT/disparity.png`` (colour),
``OUT/info.json`` (method, disparity range, timing, what was rectified) and, with a calibration,
``OUT/depth.pfm`` (metric, the unit of the calibration's baseline, ``inf`` = invalid) and ``OUT/cloud.ply``
(binary, coloured, same unit). When the pair is rectified first (``--calib`` of an unrectified rig, or
``--uncalibrated`` from SIFT matches and a robust fundamental matrix), it also writes
``OUT/rectified_left.png``, ``OUT/rectified_right.png`` and ``OUT/epipolar_check.png``, and every map is in
the rectified left frame. An uncalibrated pair has no metric scale, so it gets no depth or cloud.

LEFT/RIGHT may be two files, two folders (images paired in sorted order) or two quoted globs: every pair is
processed with a progress bar into ``OUT/<left file stem>/``. Everything is written into a temporary folder
beside OUT and renamed to OUT at the end, so an interrupted or failed run leaves nothing half-written. In a
batch, a pair that fails is reported (one line) and left out; the others are kept and the exit code is 1.

``--max-disp`` defaults to the calibration's ``ndisp`` when the pair is used as given, else to the 99th
percentile of the horizontal offsets of SIFT matches on the (rectified) pair (or the inlier matches of the
uncalibrated rectification), times 1.2 plus 4 px, rounded up to a multiple of 16 and capped at 256 and the
image width.
The default ``--method`` is the best available: a learned matcher whose weights are present, else ``sgm``,
else ``opencv-sgbm``.
"""

from __future__ import annotations

import glob
import json
import math
import shutil
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from stereonet.checks import StereoInputError
from stereonet.cli.common import USER_ERRORS, OneLineParser, Stopwatch, fail, weights_available

PROG = "infer.py"
IMAGE_EXTS = (".png", ".jpg", ".jpeg", ".ppm", ".pgm", ".bmp", ".tif", ".tiff")
# Preference order for the default method: the order of real-pair bad-2 in BENCHMARKS.md. Our `sgm` is the
# most accurate there and among the fastest; the learned ones follow (used when their weights exist).
PREFERRED = ("sgm", "siamese-sgm", "dispnet", "smd", "siamese", "opencv-sgbm")
MAX_DISP_CAP = 256
MIN_MATCHES = 8
MARGIN = 1.2  # automatic max_disp = largest match disparity * MARGIN + 4 px, rounded up to 16


@dataclass
class Pair:
    left: Path
    right: Path
    name: str  # sub-folder of OUT in a batch ("" for a single pair)


# ------------------------------------------------------------------------------------------ arguments

def find_pairs(left: str, right: str) -> list[Pair]:
    """Two files -> one pair; two folders or two globs -> image files paired in sorted order."""
    lp, rp = Path(left), Path(right)
    if lp.is_file() and rp.is_file():
        return [Pair(lp, rp, "")]

    def listing(arg: str, p: Path, which: str) -> list[Path]:
        if p.is_dir():
            files = sorted(f for f in p.iterdir() if f.suffix.lower() in IMAGE_EXTS and f.is_file())
        elif any(c in arg for c in "*?["):
            files = sorted(Path(f) for f in glob.glob(arg) if Path(f).is_file())
        else:
            raise FileNotFoundError(f"{which}: no such file, folder or glob: {arg}")
        if not files:
            raise FileNotFoundError(f"{which}: no image files in {arg}")
        return files

    lefts, rights = listing(left, lp, "LEFT"), listing(right, rp, "RIGHT")
    if len(lefts) != len(rights):
        raise StereoInputError(f"RIGHT: expected as many images as LEFT ({len(lefts)}), got {len(rights)}")
    names: list[str] = []
    for f in lefts:
        name = f.stem
        while name in names:
            name += "_"
        names.append(name)
    return [Pair(a, b, n) for a, b, n in zip(lefts, rights, names)]


def default_method() -> str:
    """The best available method in PREFERRED order (learned ones only when their weights exist)."""
    from stereonet import matchers

    names = matchers.available()
    for n in PREFERRED:
        if n in names and weights_available(n):
            return n
    return "opencv-sgbm"


# --------------------------------------------------------------------------------------- computation

def read_pair(pair: Pair, device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    """Both images as (1, C, H, W) float on ``device``; a grey image next to a colour one becomes RGB."""
    from stereonet.io import read_image

    left, right = read_image(pair.left), read_image(pair.right)
    if left.shape[-2:] != right.shape[-2:]:
        raise StereoInputError(f"RIGHT: image size {right.shape[-1]}x{right.shape[-2]} ({pair.right}) differs from "
                               f"LEFT {left.shape[-1]}x{left.shape[-2]} ({pair.left})")
    if left.shape[1] != right.shape[1]:
        left, right = left.expand(-1, 3, -1, -1), right.expand(-1, 3, -1, -1)
    return left.contiguous().to(device), right.contiguous().to(device)


def sift_matches(left: torch.Tensor, right: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
    """SIFT matches (:func:`stereonet.features.match_sift`, ratio test, mutual): (N, 2) pixel coordinates each."""
    from stereonet.features import match_sift

    pl, pr = match_sift(left, right, min_matches=0)
    return pl.numpy().reshape(-1, 2), pr.numpy().reshape(-1, 2)


def estimate_max_disp(pl: np.ndarray, pr: np.ndarray, width: int, row_tol: float = 2.0) -> int | None:
    """Disparity range from matches on a rectified pair: 99th percentile of x_l - x_r over matches on the
    same row (|y_l - y_r| <= ``row_tol``), times 1.2 plus 4 px (sparse matches rarely hit the nearest
    surface), rounded up to 16, capped; None with fewer than 8 matches."""
    same_row = np.abs(pl[:, 1] - pr[:, 1]) <= row_tol
    dx = pl[same_row, 0] - pr[same_row, 0]
    if dx.size < MIN_MATCHES:
        return None
    d = max(float(np.percentile(dx, 99)) * MARGIN + 4, 1.0)
    return cap_max_disp(int(16 * math.ceil(d / 16)), width)


def cap_max_disp(max_disp: int, width: int) -> int:
    return int(max(1, min(max_disp, MAX_DISP_CAP, width - 1)))


def epipolar_check_image(left: torch.Tensor, right: torch.Tensor, pl: np.ndarray, pr: np.ndarray,
                         lines: int = 16) -> np.ndarray:
    """Rectified left | right side by side with horizontal lines and SIFT matches (green: same row within
    2 px, red: off the row); the median row error is printed in the corner. Returns uint8 (H, 2W, 3)."""
    import cv2

    from stereonet.io import to_uint8_rgb

    def rgb(img: torch.Tensor) -> np.ndarray:
        a = to_uint8_rgb(img[:1])
        return np.repeat(a[:, :, None], 3, axis=2) if a.ndim == 2 else a

    a, b = rgb(left), rgb(right)
    h, w = a.shape[:2]
    canvas = np.ascontiguousarray(np.concatenate([a, b], axis=1))
    for k in range(1, lines):
        y = int(k * h / lines)
        cv2.line(canvas, (0, y), (2 * w - 1, y), (0, 255, 255) if k % 2 else (255, 0, 255), 1)
    dy = np.abs(pl[:, 1] - pr[:, 1]) if len(pl) else np.zeros(0)
    for (xl, yl), (xr, yr), e in zip(pl, pr, dy):
        c = (0, 200, 0) if e <= 2 else (255, 0, 0)
        cv2.circle(canvas, (int(round(xl)), int(round(yl))), 3, c, 1)
        cv2.circle(canvas, (int(round(xr)) + w, int(round(yr))), 3, c, 1)
    text = f"{len(dy)} matches, median |dy| = {np.median(dy):.2f} px" if len(dy) else "no matches"
    cv2.putText(canvas, text, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(canvas, text, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    return canvas


def check_calibration_size(calib, left: torch.Tensor, path: Path) -> None:
    if calib.image_size is not None and tuple(calib.image_size) != (left.shape[-1], left.shape[-2]):
        w, h = calib.image_size
        raise StereoInputError(f"--calib: {path} is for {w}x{h} images, got {left.shape[-1]}x{left.shape[-2]}")


def process_pair(pair: Pair, out_dir: Path, method: str, options: dict, max_disp: int | None,
                 calib, calib_path: Path | None, uncalibrated: bool, device: torch.device,
                 fill: bool = False) -> dict:
    """Run one pair and write its files into ``out_dir`` (an existing, private folder). Returns the info."""
    from stereonet import matchers, viz
    from stereonet.io import write_disparity_pfm, write_image, write_ply

    left, right = read_pair(pair, device)
    info: dict = {"left": str(pair.left), "right": str(pair.right), "method": method, "rectified": None}
    depth_calib, rect = None, None
    if calib is not None:
        check_calibration_size(calib, left, calib_path)
        depth_calib = calib
    if uncalibrated or (calib is not None and not calib.is_rectified()):
        from stereonet import geometry

        if uncalibrated:
            rect = geometry.rectify_uncalibrated(left, right)
            info["rectified"] = "uncalibrated (SIFT + robust F)"
            depth_calib = None
        else:
            rect = geometry.rectify_calibrated(left, right, calib)
            info["rectified"] = "calibrated"
            depth_calib = rect.calib
        left, right = rect.left.to(device), rect.right.to(device)
        write_image(out_dir / "rectified_left.png", left)
        write_image(out_dir / "rectified_right.png", right)
        pl, pr = sift_matches(left, right)
        write_image(out_dir / "epipolar_check.png", epipolar_check_image(left, right, pl, pr))
        if len(pl):
            info["epipolar_median_row_error_px"] = float(np.median(np.abs(pl[:, 1] - pr[:, 1])))
    width = left.shape[-1]
    if max_disp is None:
        if info["rectified"] is None and depth_calib is not None and depth_calib.ndisp:
            max_disp, source = cap_max_disp(int(depth_calib.ndisp), width), "calibration ndisp"
        elif rect is not None and rect.disparity_range is not None:
            hint = int(16 * math.ceil(max(rect.disparity_range[1] * MARGIN + 4, 1.0) / 16))
            max_disp, source = cap_max_disp(hint, width), "inlier SIFT matches of the rectification"
        else:
            if rect is None:
                pl, pr = sift_matches(left, right)
            max_disp, source = estimate_max_disp(pl, pr, width), "SIFT matches"
            if max_disp is None:
                max_disp, source = cap_max_disp(64, width), "default (too few SIFT matches to estimate)"
        info["max_disp_source"] = source
    info["max_disp"] = int(max_disp)

    fn = matchers.get_matcher(method, **options)
    with torch.no_grad(), Stopwatch() as clock:
        out = fn(left, right, int(max_disp))
    info["seconds"] = clock.seconds
    if fill:
        from stereonet.cli.eval import apply_fill

        info["density_before_fill"] = 100.0 * float(out.valid.float().mean())
        out = apply_fill(out)
    disp, valid = out.disparity[0, 0].float().cpu(), out.valid[0, 0].cpu()
    info["density"] = 100.0 * float(valid.float().mean())
    write_disparity_pfm(out_dir / "disparity.pfm", disp, valid)
    viz.save_png(out_dir / "disparity.png", viz.colorize_disparity(disp.numpy(), max_disp, valid.numpy()))
    if depth_calib is not None:
        from stereonet.geometry import disparity_to_depth, disparity_to_points

        depth = disparity_to_depth(out.disparity.double(), depth_calib, valid=out.valid)  # 0 = no depth
        write_disparity_pfm(out_dir / "depth.pfm", depth[0, 0], depth[0, 0] > 0)
        points, colors = disparity_to_points(out.disparity, out.valid, depth_calib, left)
        write_ply(out_dir / "cloud.ply", points, colors)
        info["points"] = int(len(points))
        info["depth_unit"] = "unit of the calibration baseline"
    from stereonet.io import atomic_write_text

    atomic_write_text(out_dir / "info.json", json.dumps(info, indent=2) + "\n")
    return info


# ------------------------------------------------------------------------------------------------ main

def build_parser() -> OneLineParser:
    p = OneLineParser(prog=PROG, description="Disparity, depth and a point cloud from a stereo pair (or a batch).")
    p.add_argument("left", help="left image, folder of left images, or a quoted glob")
    p.add_argument("right", help="right image, folder of right images, or a quoted glob")
    p.add_argument("-o", "--out", type=Path, required=True, help="output folder (must not exist without --overwrite)")
    p.add_argument("--method", default=None, help="registered matcher (default: the best available)")
    p.add_argument("--max-disp", type=int, default=None, help="disparity range (default: automatic)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--calib", type=Path, default=None,
                   help="Middlebury calib.txt, KITTI calib or OpenCV YAML/JSON stereo calibration")
    g.add_argument("--uncalibrated", action="store_true", help="rectify from SIFT matches (no metric depth)")
    p.add_argument("--checkpoint", type=Path, default=None, help="weights for a learned method")
    p.add_argument("--overwrite", action="store_true", help="replace OUT if it exists")
    p.add_argument("--device", default="cpu", help="torch device (default cpu)")
    p.add_argument("--fill", action="store_true",
                   help="fill invalid pixels (occlusions, LR failures) along scanlines for a dense map")
    p.add_argument("--no-progress", action="store_true", help="no progress bar in batch mode")
    return p


def _prepare(args) -> tuple[list[Pair], str, dict, object, torch.device]:
    """Check every argument before anything is computed or written."""
    from stereonet import matchers

    if args.out.exists() and not args.overwrite:
        raise FileExistsError(f"-o: {args.out} already exists (pass --overwrite to replace it)")
    if args.max_disp is not None and args.max_disp <= 0:
        raise ValueError(f"--max-disp: expected a positive integer, got {args.max_disp}")
    try:
        device = torch.device(args.device)
        torch.empty(0, device=device)
    except (RuntimeError, AssertionError) as e:
        raise ValueError(f"--device: {args.device!r} is not usable here ({str(e).splitlines()[0]})") from None
    pairs = find_pairs(args.left, args.right)
    method = args.method or default_method()
    spec = matchers.spec(method)
    options: dict = {}
    if args.checkpoint is not None:
        if not spec.needs_weights:
            raise ValueError(f"--checkpoint: method {method!r} takes no weights")
        if not args.checkpoint.is_file():
            raise FileNotFoundError(f"--checkpoint: no such file: {args.checkpoint}")
        options["checkpoint"] = str(args.checkpoint)
    elif spec.needs_weights and not weights_available(method):
        raise FileNotFoundError(f"--method {method}: its weights are missing (pass --checkpoint CKPT)")
    calib = None
    if args.calib is not None:
        from stereonet.calibration import read_calibration

        if not args.calib.is_file():
            raise FileNotFoundError(f"--calib: no such file: {args.calib}")
        calib = read_calibration(args.calib)
    return pairs, method, options, calib, device


def _publish(tmp: Path, out: Path) -> None:
    """Move the finished temporary folder to ``out`` (replacing an old ``out`` only now, when all is done)."""
    old = None
    if out.exists():
        old = out.parent / f".{out.name}.old-{tmp.name}"
        out.rename(old)
    tmp.rename(out)
    if old is not None:
        shutil.rmtree(old) if old.is_dir() else old.unlink()


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        pairs, method, options, calib, device = _prepare(args)
    except USER_ERRORS as e:
        return fail(PROG, e)
    except ImportError as e:
        return fail(PROG, f"{e} (this part of stereonet is not installed)")
    out = args.out.resolve()
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.tmp-", dir=out.parent))
    failures: list[str] = []
    try:
        from tqdm import tqdm

        batch = len(pairs) > 1 or pairs[0].name != ""
        for pair in tqdm(pairs, desc="infer", unit="pair", disable=not batch or args.no_progress, file=sys.stderr):
            pair_dir = tmp / pair.name if pair.name else tmp
            pair_dir.mkdir(exist_ok=True)
            try:
                process_pair(pair, pair_dir, method, options, args.max_disp, calib, args.calib,
                             args.uncalibrated, device, args.fill)
            except (*USER_ERRORS, ImportError, RuntimeError) as e:
                if not batch:
                    raise
                fail(PROG, f"{pair.left.name}: {e}", 1)
                failures.append(pair.name)
                shutil.rmtree(pair_dir, ignore_errors=True)
        if len(failures) == len(pairs):
            raise StereoInputError("every pair failed; nothing written")
        _publish(tmp, out)
    except BaseException as e:  # nothing half-written: the temporary folder goes, OUT is untouched
        shutil.rmtree(tmp, ignore_errors=True)
        if isinstance(e, USER_ERRORS):
            return fail(PROG, e)
        if isinstance(e, ImportError):
            return fail(PROG, f"{e} (this part of stereonet is not installed)")
        if isinstance(e, RuntimeError):  # the method itself failed (e.g. out of memory)
            return fail(PROG, f"--method {method}: {e}", 1)
        raise
    if failures:
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
