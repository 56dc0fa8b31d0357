"""infer.py: a photo pair in; disparity, depth and a coloured point cloud out.

    python infer.py LEFT RIGHT -o OUT [--method NAME] [--max-disp N] [--calib FILE | --uncalibrated]
                    [--checkpoint CKPT] [--overwrite] [--device cpu] [--fill]
                    [--backend torch|onnx [--onnx-model FILE]]

Writes ``OUT/disparity.pfm`` (float, ``inf`` = invalid, left-referenced), ``OUT/disparity.png`` (colour),
``OUT/info.json`` (method, disparity range, timing, what was rectified) and, with a calibration,
``OUT/depth.pfm`` (metric, the unit of the calibration's baseline, ``inf`` = invalid) and ``OUT/cloud.ply``
(binary, coloured, same unit). When the pair is rectified first (``--calib`` of an unrectified rig, or
``--uncalibrated`` from SIFT matches and a robust fundamental matrix), it also writes
``OUT/rectified_left.png``, ``OUT/rectified_right.png`` and ``OUT/epipolar_check.png``, and every map is in
the rectified left frame. An uncalibrated pair has no metric scale, so it gets no depth or cloud.

LEFT/RIGHT may be two files, two folders (images paired in sorted order), two quoted globs or two video
files (frame i with frame i): every pair is processed with a progress bar into ``OUT/<left file stem>/``
(``OUT/frame_NNNNNN/`` for videos). With ``--calib`` such a batch is a fixed rig: the rectification (geometry,
maps, padding masks) is computed for the first pair and reused for every other (info.json
``rectification_maps``). Everything is written into a temporary folder
beside OUT and renamed to OUT at the end, so an interrupted or failed run leaves nothing half-written. In a
batch, a pair that fails is reported (one line) and left out; the others are kept and the exit code is 1.

``--max-disp`` defaults to the calibration's ``ndisp`` when the pair is used as given, else to the 99th
percentile of the horizontal offsets of SIFT matches on the (rectified) pair (or the inlier matches of the
uncalibrated rectification), times 1.2 plus 4 px, rounded up to a multiple of 16 and capped at 256 and the
image width.
The default ``--method`` is ``sgm`` (the first registered name of ``PREFERRED`` whose weights, if it needs any, are
installed): the most accurate classical method at about OpenCV SGBM's speed; ``--method sgm-refine`` is more accurate
on the real pairs of BENCHMARKS.md at several times the time.

A residual vertical offset of the (rectified) pair, fitted as a plane to its SIFT matches
(:mod:`stereonet.geometry.align`), is removed from the right view when it is clearly 0.25 px or more somewhere
(info.json ``vertical_offset``; ``--no-align`` keeps the pair as given).
"""

from __future__ import annotations

import glob
import inspect
import json
import math
import shutil
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from stereonet.checks import StereoInputError
from stereonet.cli.common import (
    USER_ERRORS,
    OneLineParser,
    Stopwatch,
    check_output_path,
    fail,
    weights_available,
)
from stereonet.measure import reuse_freed_memory
from stereonet.tiling import DEFAULT_BUDGET_MIB

PROG = "infer.py"
IMAGE_EXTS = (".png", ".jpg", ".jpeg", ".ppm", ".pgm", ".bmp", ".tif", ".tiff")
VIDEO_EXTS = (".mp4", ".avi", ".mov", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg")
# Preference order for the default method: the order of real-pair bad-2 in BENCHMARKS.md. Our `sgm` is the
# most accurate there and among the fastest; the learned ones follow (used when their weights exist).
PREFERRED = ("sgm", "siamese-sgm", "dispnet", "smd", "siamese", "opencv-sgbm")
PREFILTER_METHODS = ("sgm", "siamese-census-sgm", "sgm-refine", "sgm-penalties")  # census matchers with `prefilter`
WMF_METHODS = ("dispnet", "smd", "sgm-refine", "sgm")  # matchers with `wmf_radius` (tested to take it)
MAX_DISP_CAP = 256
MIN_MATCHES = 8
MARGIN = 1.2  # automatic max_disp = largest match disparity * MARGIN + 4 px, rounded up to 16


@dataclass
class Pair:
    left: Path
    right: Path
    name: str  # sub-folder of OUT in a batch ("" for a single pair)
    frame: int | None = None  # frame index when LEFT/RIGHT are two videos


def video_frame_count(path: Path, which: str) -> int:
    """Frames in a video file (OpenCV's count, checked by reading the last frame); one-line error otherwise."""
    import cv2

    cap = cv2.VideoCapture(str(path))
    try:
        if not cap.isOpened():
            raise StereoInputError(f"{which}: cannot open {path} as a video (OpenCV could not decode it)")
        n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        while n > 0:  # containers may over-count: the last readable frame decides
            cap.set(cv2.CAP_PROP_POS_FRAMES, n - 1)
            if cap.read()[0]:
                break
            n -= 1
        if n <= 0:
            raise StereoInputError(f"{which}: no readable frame in the video {path}")
        return n
    finally:
        cap.release()


class _VideoFrames:
    """Sequential frame reader per video file (one open capture each; seeks only when a frame is skipped)."""

    def __init__(self) -> None:
        self.open: dict[Path, list] = {}

    def read(self, path: Path, index: int) -> torch.Tensor:
        import cv2

        cap, pos = self.open.get(path, (None, -1))
        if cap is None:
            cap = cv2.VideoCapture(str(path))
        if pos != index:
            cap.set(cv2.CAP_PROP_POS_FRAMES, index)
        ok, frame = cap.read()
        if not ok:
            raise StereoInputError(f"{path}: cannot read frame {index}")
        self.open[path] = [cap, index + 1]
        rgb = frame[..., ::-1] if frame.ndim == 3 else frame[..., None]
        return torch.from_numpy(np.ascontiguousarray(rgb)).permute(2, 0, 1)[None].float() / 255.0

    def close(self) -> None:
        for cap, _ in self.open.values():
            cap.release()
        self.open.clear()


VIDEO_FRAMES = _VideoFrames()


# ------------------------------------------------------------------------------------------ arguments

def _frame_number(path: Path) -> str | None:
    """The last run of digits in a file's stem, without leading zeros (``left_05`` -> ``5``), or None."""
    import re

    runs = re.findall(r"\d+", path.stem)
    return str(int(runs[-1])) if runs else None


def find_pairs(left: str, right: str) -> list[Pair]:
    """Two files -> one pair; two videos -> one pair per frame; two folders or two globs -> image files paired
    by the number in their names when both sides are numbered alike (``left_05``/``right_05``; a number on
    only one side is bad input naming it, so a shot deleted from one folder cannot shift every later pair),
    else in sorted order (e.g. two cameras numbering their files independently)."""
    lp, rp = Path(left), Path(right)
    videos = [p.suffix.lower() in VIDEO_EXTS for p in (lp, rp)]
    if lp.is_file() and rp.is_file() and any(videos):
        if not all(videos):
            raise StereoInputError(f"{'RIGHT' if videos[0] else 'LEFT'}: expected a video like "
                                   f"{'LEFT' if videos[0] else 'RIGHT'} ({(lp if videos[0] else rp).name}), got "
                                   f"{(rp if videos[0] else lp).name}")
        n, m = video_frame_count(lp, "LEFT"), video_frame_count(rp, "RIGHT")
        if n != m:
            raise StereoInputError(f"RIGHT: expected as many frames as LEFT ({n}), got {m} in {rp}")
        return [Pair(lp, rp, f"frame_{i:06d}", frame=i) for i in range(n)]
    if lp.is_file() and rp.is_file():
        return [Pair(lp, rp, "")]

    if lp.is_file() != rp.is_file() and (lp.is_dir() or rp.is_dir()):
        file_arg, folder_arg = ("LEFT", "RIGHT") if lp.is_file() else ("RIGHT", "LEFT")
        raise StereoInputError(f"{file_arg}: expected a folder or glob like {folder_arg} (one pair: two files), "
                               f"got the file {lp if lp.is_file() else rp}")

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
    keys_l, keys_r = [_frame_number(f) for f in lefts], [_frame_number(f) for f in rights]
    if None not in keys_l + keys_r and len(set(keys_l)) == len(lefts) and len(set(keys_r)) == len(rights):
        common = set(keys_l) & set(keys_r)
        if common and (len(common) < len(lefts) or len(common) < len(rights)):  # numbered alike, some unmatched
            alone_l = [f.name for f, k in zip(lefts, keys_l) if k not in common]
            alone_r = [f.name for f, k in zip(rights, keys_r) if k not in common]
            raise StereoInputError(
                f"RIGHT: expected an image with the same number for every LEFT image (pairs are matched by the "
                f"numbers in their names); without a partner: {', '.join((alone_l + alone_r)[:4])}"
                + (" ..." if len(alone_l) + len(alone_r) > 4 else ""))
        if common:
            by_key = dict(zip(keys_r, rights))
            rights = [by_key[k] for k in keys_l]
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

    if pair.frame is not None:
        left, right = VIDEO_FRAMES.read(pair.left, pair.frame), VIDEO_FRAMES.read(pair.right, pair.frame)
    else:
        left, right = read_image(pair.left), read_image(pair.right)
    if left.shape[-2:] != right.shape[-2:]:
        raise StereoInputError(f"RIGHT: image size {right.shape[-1]}x{right.shape[-2]} ({pair.right}) differs from "
                               f"LEFT {left.shape[-1]}x{left.shape[-2]} ({pair.left})")
    if left.shape[1] != right.shape[1]:
        left, right = left.expand(-1, 3, -1, -1), right.expand(-1, 3, -1, -1)
    return left.contiguous().to(device), right.contiguous().to(device)


def read_alpha(path: Path) -> torch.Tensor | None:
    """The alpha channel of a PNG with one (colour or grey + alpha; the header says so without decoding) as a
    (H, W) bool mask, True = opaque (alpha > 0); None for every other file."""
    try:
        with open(path, "rb") as f:
            head = f.read(26)
    except OSError:
        return None
    if len(head) < 26 or not head.startswith(b"\x89PNG\r\n\x1a\n") or head[25] not in (4, 6):
        return None
    from stereonet.io import read_array

    arr = read_array(path)
    return torch.from_numpy(np.ascontiguousarray(arr[..., -1] > 0)) if arr.ndim == 3 and arr.shape[2] in (2, 4) else None


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


@dataclass
class Settings:
    """The per-run options of :func:`process_pair` beyond the method (defaults = the plain run)."""

    fill: bool = False
    scale: float = 1.0
    min_disp: int = 0
    alpha: float = 1.0
    unit: str | None = None  # unit of the calibration's baseline; None = unknown
    cloud_frame: str = "rectified"
    cloud_min_confidence: float = 0.0  # cloud.ply keeps the valid pixels with at least this confidence (0: all)
    output_scale: float = 1.0  # the matcher's output grid / the processed images (SMD's continuous head)
    memory_budget: float = float(DEFAULT_BUDGET_MIB)  # MiB a matcher call may use; larger pairs run in strips
    align: bool = True  # correct a residual vertical offset of the (rectified) right view (stereonet.geometry.align)
    # a fixed rig's rectification (geometry, maps, content masks), computed for the first pair of a batch
    rig_cache: dict = field(default_factory=dict)


def scale_pair(left: torch.Tensor, right: torch.Tensor, calib, scale: float):
    """Downscale both images by ``scale`` (area averaging) and the calibration with them (pixel centres:
    ``x' = (x + 0.5) s - 0.5``; distortion is in normalised coordinates and stays). Returns (left, right, calib)."""
    import torch.nn.functional as F

    h, w = left.shape[-2:]
    size = (max(8, round(h * scale)), max(8, round(w * scale)))
    left, right = F.interpolate(left, size=size, mode="area"), F.interpolate(right, size=size, mode="area")
    return left, right, resize_calibration(calib, (w, h), (size[1], size[0]))


def resize_calibration(calib, size: tuple[int, int], new_size: tuple[int, int]):
    """The calibration of images resampled from ``size`` to ``new_size`` (both (W, H)); pixel centres map as
    ``x' = (x + 0.5) s - 0.5``, distortion (normalised coordinates) stays. None stays None."""
    if calib is None:
        return None
    from dataclasses import replace

    sx, sy = new_size[0] / size[0], new_size[1] / size[1]
    S = torch.tensor([[sx, 0.0, (sx - 1) / 2], [0.0, sy, (sy - 1) / 2], [0.0, 0.0, 1.0]], dtype=torch.float64)
    return replace(calib, K1=S @ calib.K1, K2=S @ calib.K2, image_size=tuple(new_size), doffs=calib.doffs * sx,
                   ndisp=None if not calib.ndisp else math.ceil(calib.ndisp * sx))


def shift_right(right: torch.Tensor, content: torch.Tensor, min_disp: int) -> tuple[torch.Tensor, torch.Tensor]:
    """``right'(u) = right(u - min_disp)``, so disparities ``d >= min_disp`` become ``d - min_disp >= 0``;
    the columns shifted in are padding (``content`` False). ``content`` is the right image's (H, W) mask."""
    out, mask = torch.zeros_like(right), torch.zeros_like(content)
    w = right.shape[-1]
    m = int(min_disp)
    if m >= 0:
        out[..., m:], mask[:, m:] = right[..., : w - m], content[:, : w - m]
    else:
        out[..., : w + m], mask[:, : w + m] = right[..., -m:], content[:, -m:]
    return out, mask


def content_valid(disp: torch.Tensor, left_content: torch.Tensor, right_content: torch.Tensor) -> torch.Tensor:
    """Pixels whose left pixel has source content and whose match ``x - d`` does not land on padding of the
    (matcher's) right image. disp :math:`(1, 1, H, W)`, masks (H, W) bool -> (1, 1, H, W) bool.

    A match beyond the right image's border is not padding: whether such a pixel is an answer is the matcher's
    call (the classical ones reject it, the dense networks extrapolate), as on an unpadded pair, so padding or
    ``--min-disp`` never changes it."""
    h, w = left_content.shape
    x = torch.arange(w, device=disp.device).view(1, w).expand(h, w)
    d = torch.nan_to_num(disp[0, 0].float(), nan=0.0, posinf=0.0, neginf=0.0)
    xr = torch.round(x - d).long()
    inside = (xr >= 0) & (xr < w)
    rows = torch.arange(h, device=disp.device).view(h, 1).expand(h, w)
    hit = right_content[rows, xr.clamp(0, w - 1)] | ~inside
    return (left_content & hit)[None, None]


def mirror_output(out):
    """A matcher's output on a mirrored pair, flipped back (every per-pixel tensor, along x)."""
    import dataclasses

    changes = {f.name: getattr(out, f.name).flip(-1) for f in dataclasses.fields(out)
               if isinstance(getattr(out, f.name), torch.Tensor) and getattr(out, f.name).dim() == 4}
    return dataclasses.replace(out, **changes)


def write_rectified_calibration(path: Path, rect, unit: str | None) -> None:
    """The rectified rig as OpenCV FileStorage YAML: K (shared), baseline, R1, R2, P1, P2, Q, size."""
    import cv2

    from stereonet.io.atomic import atomic_path

    with atomic_path(path) as tmp:
        fs = cv2.FileStorage(str(tmp), cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_FORMAT_YAML)
        h, w = rect.left.shape[-2:]
        fs.write("image_width", int(w))
        fs.write("image_height", int(h))
        fs.write("K", rect.calib.K1.numpy())
        fs.write("baseline", float(rect.calib.baseline))
        fs.write("baseline_unit", unit or "unknown (the unit of the calibration's T)")
        reversed_rig = bool(getattr(rect, "reversed", False))
        for name in ("R1", "R2", "P1", "P2", "Q"):
            value = getattr(rect, name)
            if value is not None:
                value = np.asarray(value, dtype=np.float64)
                if name == "Q" and reversed_rig:  # OpenCV's Q is for its negative d; disparity.pfm holds -d
                    value = value @ np.diag([1.0, 1.0, -1.0, 1.0])
                fs.write(name, value)
        fs.write("reversed", int(reversed_rig))
        fs.write("convention", "X_rect_left = R1 X_left; X_rect_right = R2 X_right; [X Y Z W]^T = Q [u v d 1]^T "
                 "with d as in disparity.pfm" + (" (x_second - x_first > 0: the second camera sits to the left; "
                                                  "P2 keeps OpenCV's signed baseline)" if reversed_rig else ""))
        fs.release()


MM_PER_UNIT = {"mm": 1.0, "cm": 10.0, "m": 1000.0}


def align_vertically(left, right, right_content, pl: np.ndarray, pr: np.ndarray, max_disp: int | None, info: dict,
                     pair: Pair):
    """The residual vertical offset of the (rectified) pair, fitted to its SIFT matches
    (:func:`~stereonet.geometry.align.fit_vertical_misalignment`), written to ``info["vertical_offset"]``; when it
    is clear (:func:`~stereonet.geometry.align.needs_alignment`) the right view, its content mask and the matches'
    right rows are corrected (one line on stderr says so). Returns ``(right, right_content, pr)``."""
    from stereonet.geometry.align import align_right, fit_vertical_misalignment, needs_alignment

    h, w = left.shape[-2:]
    model = fit_vertical_misalignment(pl, pr, w, h, max_disp) if len(pl) else None
    if model is None:
        info["vertical_offset"] = None
        return right, right_content, pr
    corrected = needs_alignment(model, w, h)
    info["vertical_offset"] = {"px_at_corners": [round(model.dy(x, y), 3) for y in (0, h - 1) for x in (0, w - 1)],
                               "plane_a_b_c": [model.a, model.b, model.c], "standard_error_px": model.error,
                               "matches": model.matches, "corrected": corrected}
    if not corrected:
        return right, right_content, pr
    right = align_right(right, model)
    right_content = align_right(right_content[None, None].float(), model)[0, 0] > 0.5
    pr = pr.copy()
    pr[:, 1] -= model.dy(pr[:, 0], pl[:, 1])  # the model's x is the right view's column
    print(f"{PROG}: {pair.left.name}: right view aligned: it was up to {model.largest(w, h):.2f} px off-row (a plane "
          f"fitted to {model.matches} SIFT matches; --no-align keeps it as it is)", file=sys.stderr)
    return right, right_content, pr


def rectified_pair_warnings(pl: np.ndarray, pr: np.ndarray, info: dict, negative_allowed: bool = False) -> list[str]:
    """What the SIFT matches ``pl``/``pr`` (after any vertical alignment) say about a pair given as rectified:
    rows that still disagree (it needs --calib or --uncalibrated), matches that mostly lie to the right in the
    second image (LEFT and RIGHT swapped: every disparity would be negative; not with ``negative_allowed``, i.e. a
    negative --min-disp), or too few matches to check.
    Sets ``info["epipolar_median_row_error_px"]`` (None when unchecked)."""
    info["epipolar_median_row_error_px"] = None
    if len(pl) < MIN_MATCHES:
        return [f"only {len(pl)} SIFT matches (fewer than {MIN_MATCHES}): rectification, the vertical alignment and "
                "the order of the views could not be checked"]
    warnings = []
    row_error = float(np.median(np.abs(pl[:, 1] - pr[:, 1])))
    info["epipolar_median_row_error_px"] = row_error
    if row_error > 1.0:
        what = "after the vertical alignment, " if (info.get("vertical_offset") or {}).get("corrected") else ""
        warnings.append(f"the pair looks unrectified: {what}SIFT matches are {row_error:.1f} px off-row (median); "
                        "pass --calib FILE or --uncalibrated to rectify it first")
    dx = pl[:, 0] - pr[:, 0]
    if not negative_allowed and float(np.mean(dx < -0.5)) >= SWAPPED_SHARE:
        warnings.append(f"LEFT and RIGHT look swapped: {100 * float(np.mean(dx < -0.5)):.0f} % of the SIFT matches lie "
                        f"further right in RIGHT (median disparity {float(np.median(dx)):.1f} px); pass the images in "
                        "the other order (or --min-disp for a pair with negative disparities)")
    return warnings


SWAPPED_SHARE = 0.8
"""Share of SIFT matches with a negative disparity above which a pair given as rectified looks swapped."""


def process_pair(pair: Pair, out_dir: Path, method: str, options: dict, max_disp: int | None,
                 calib, calib_path: Path | None, uncalibrated: bool, device: torch.device,
                 fill: bool = False, settings: Settings | None = None) -> dict:
    """Run one pair and write its files into ``out_dir`` (an existing, private folder). Returns the info."""
    from stereonet import matchers, viz
    from stereonet.io import write_disparity_pfm, write_image, write_pfm, write_ply

    st = settings or Settings(fill=fill)
    left, right = read_pair(pair, device)
    alphas = [None, None] if pair.frame is not None else [read_alpha(pair.left), read_alpha(pair.right)]
    info: dict = {"left": str(pair.left), "right": str(pair.right), "method": method,
                  "backend": options.get("backend", "torch"), "frame": pair.frame, "rectified": None,
                  "units": {"disparity": "px of the images processed (after --scale)", "confidence": "1 (0..1)"},
                  "warnings": []}
    if calib is not None:
        check_calibration_size(calib, left, calib_path)
    if st.scale != 1.0:
        h0, w0 = left.shape[-2:]
        left, right, calib = scale_pair(left, right, calib, st.scale)
        info["scale"] = {"factor": st.scale, "input_size": [int(w0), int(h0)],
                         "processed_size": [int(left.shape[-1]), int(left.shape[-2])]}
    if any(a is not None for a in alphas):  # transparent pixels (alpha 0) are no content, as padding is not
        import torch.nn.functional as F

        alphas = [torch.ones(left.shape[-2:]) if a is None else
                  F.interpolate(a[None, None].float(), size=tuple(left.shape[-2:]), mode="area")[0, 0] for a in alphas]
        info["warnings"].append("transparent pixels (alpha 0) are treated as no content: never an answer")
    depth_calib, rect = calib, None
    h, w = left.shape[-2:]
    left_content = torch.ones(h, w, dtype=torch.bool, device=device)
    right_content = left_content.clone()
    if uncalibrated or (calib is not None and not calib.is_rectified()):
        from stereonet import geometry

        prepared = None  # (rectification, left content, right content) of a fixed rig's earlier pair
        if uncalibrated:
            rect = geometry.rectify_uncalibrated(left, right, alpha=st.alpha)
            info["rectified"] = "uncalibrated (SIFT + robust F)"
            info["rectification_notes"] = list(rect.notes)  # already on stderr (the geometry's logger)
            depth_calib = None
        else:
            key = ("calibrated", h, w, st.alpha)  # one --calib for the whole batch: a fixed rig
            prepared = st.rig_cache.get(key)
            rect = geometry.rectify_calibrated(left, right, calib, alpha=st.alpha,
                                               prepared=None if prepared is None else prepared[0])
            info["rectified"] = "calibrated"
            info["rectification_maps"] = "computed" if prepared is None else "reused (fixed rig, computed once)"
            depth_calib = rect.calib
            write_rectified_calibration(out_dir / "rectified_calib.yaml", rect, st.unit)
        if prepared is not None:
            left_content, right_content = prepared[1], prepared[2]
        else:
            left_content = geometry.content_mask(rect.maps[0], w, h).to(device)
            right_content = geometry.content_mask(rect.maps[1], w, h).to(device)
            if not uncalibrated:
                from dataclasses import replace as _replace

                st.rig_cache[key] = (_replace(rect, left=None, right=None), left_content, right_content)
        if alphas[0] is not None:  # the transparent pixels, carried through the rectification
            left_content = left_content & (geometry.warp_image(alphas[0][None, None], source_map=rect.maps[0])[0, 0]
                                           > 0.5).to(device)
            right_content = right_content & (geometry.warp_image(alphas[1][None, None], source_map=rect.maps[1])[0, 0]
                                             > 0.5).to(device)
        left, right = rect.left.to(device), rect.right.to(device)
        info["alpha"] = st.alpha
        info["padding_percent"] = 100.0 * (1.0 - float(left_content.float().mean()))
        write_image(out_dir / "rectified_left.png", left)
        write_image(out_dir / "rectified_right.png", right)
        pl, pr = sift_matches(left, right)
        write_image(out_dir / "epipolar_check.png", epipolar_check_image(left, right, pl, pr))
        if len(pl):
            info["epipolar_median_row_error_px"] = float(np.median(np.abs(pl[:, 1] - pr[:, 1])))
        given_rectified = False
    else:  # given as rectified: checked against its SIFT matches below
        pl, pr = sift_matches(left, right)
        given_rectified = True
        if alphas[0] is not None:
            left_content, right_content = (alphas[0] > 0.5).to(device), (alphas[1] > 0.5).to(device)
    if st.align:
        right, right_content, pr = align_vertically(left, right, right_content, pl, pr, max_disp, info, pair)
    if given_rectified:
        info["warnings"].extend(rectified_pair_warnings(pl, pr, info, negative_allowed=st.min_disp < 0))
    # a rig whose second camera sits on the left: matches lie at x + d, so the pair is matched mirrored
    # (both images flipped left-right: the first stays the reference, the outputs stay upright)
    from stereonet.geometry import is_reversed_rig

    mirror = bool(rect.reversed) if rect is not None else (
        calib is not None and calib.is_rectified() and is_reversed_rig(calib))
    if mirror:
        info["reversed_rig"] = True
        if rect is None:  # a rectified rig with t = (+B, 0, 0): depth of the mirrored disparity x2 - x1
            import dataclasses

            depth_calib = dataclasses.replace(calib, t=-calib.t, doffs=-float(calib.doffs))
        info["warnings"].append("reversed rig: the second camera sits to the left of the first (the files may "
                                "be given in the other order); matched mirrored, the first image stays the "
                                "reference, disparity = x_second - x_first > 0")
        if len(pl):
            pl, pr = pl.copy(), pr.copy()
            pl[:, 0], pr[:, 0] = left.shape[-1] - 1 - pl[:, 0], left.shape[-1] - 1 - pr[:, 0]
    else:
        info["reversed_rig"] = False
    colours = left
    if mirror:
        left, right = left.flip(-1), right.flip(-1)
        left_content, right_content = left_content.flip(-1), right_content.flip(-1)
    width = left.shape[-1]
    if max_disp is None:
        if info["rectified"] is None and depth_calib is not None and depth_calib.ndisp:
            max_disp, source = cap_max_disp(int(depth_calib.ndisp), width), "calibration ndisp"
        elif rect is not None and rect.disparity_range is not None:
            hint = int(16 * math.ceil(max(rect.disparity_range[1] * MARGIN + 4, 1.0) / 16))
            max_disp, source = cap_max_disp(hint, width), "inlier SIFT matches of the rectification"
        else:
            max_disp, source = estimate_max_disp(pl, pr, width), "SIFT matches"
            if max_disp is None:
                max_disp, source = cap_max_disp(64, width), "default (too few SIFT matches to estimate)"
        info["max_disp_source"] = source
    info["max_disp"] = int(max_disp)
    min_disp = int(st.min_disp)
    if min_disp >= max_disp:
        raise StereoInputError(f"--min-disp: expected less than the maximum disparity {max_disp}, got {min_disp}")
    if width < 2:
        raise StereoInputError(f"LEFT: expected an image at least 2 px wide to match, got {width} px"
                               + (f" after --scale {st.scale}" if st.scale != 1 else ""))
    if max_disp - min_disp >= width:
        raise StereoInputError(f"--max-disp/--min-disp: expected a search range (max - min = {max_disp - min_disp} "
                               f"px) narrower than the image ({width} px wide as matched)")
    info["min_disp"] = min_disp
    if min_disp:
        right, right_content = shift_right(right, right_content, min_disp)

    fn = matchers.get_matcher(method, **options)
    from stereonet.tiling import match_with_budget

    tiling: dict = {}
    try:
        with torch.no_grad(), Stopwatch() as clock:
            out = match_with_budget(fn, left, right, int(max_disp - min_disp), budget_mib=st.memory_budget,
                                    info=tiling, output_scale=st.output_scale)
    except (MemoryError, RuntimeError) as e:
        if isinstance(e, RuntimeError) and "not enough memory" not in str(e) and "out of memory" not in str(e):
            raise
        raise MemoryError(f"out of memory matching {width}x{left.shape[-2]} px over {max_disp - min_disp + 1} "
                          "disparities: pass --scale 0.5 (or smaller) or a smaller --max-disp") from None
    info["seconds"] = clock.seconds
    info["memory"] = {"budget_mib": st.memory_budget, "strips": tiling.get("strips", 1),
                      "rows_per_strip": tiling.get("rows_per_strip")}
    grid = out.disparity.shape[-2:]
    sx = grid[-1] / left.shape[-1]
    if tuple(grid) != tuple(left.shape[-2:]):  # --output-scale: the head answered on a finer (or coarser) grid
        import torch.nn.functional as F

        def nearest(mask):
            return F.interpolate(mask[None, None].float(), size=tuple(grid), mode="nearest")[0, 0] > 0.5

        left_content, right_content = nearest(left_content), nearest(right_content)
        colours = F.interpolate(colours, size=tuple(grid), mode="bilinear", align_corners=False)
        depth_calib = resize_calibration(depth_calib, (left.shape[-1], left.shape[-2]), (grid[-1], grid[-2]))
        info["output_scale"] = st.output_scale
        info["output_size"] = [int(grid[-1]), int(grid[-2])]
        info["units"]["disparity"] = "px of the output grid (--output-scale x the images processed)"
    min_disp_out = min_disp * sx
    # padding (no source content) is never an answer, before or after filling
    content = content_valid(out.disparity, left_content, right_content)
    padded = not bool(content.all())
    if padded or min_disp:
        out.valid = out.valid & content
    if st.fill:
        from stereonet.evaluation import apply_fill

        info["density_before_fill"] = 100.0 * float(out.valid.float().mean())
        out = apply_fill(out)
        if padded or min_disp:
            out.valid = out.valid & content
    if mirror:
        out = mirror_output(out)
    confidence = out.confidence  # after the mirror, on the first image's grid like the disparity
    if confidence is None and out.uncertainty is not None:
        confidence = torch.exp(-out.uncertainty.float())
    disparity = out.disparity + min_disp_out if min_disp else out.disparity
    disp, valid = disparity[0, 0].float().cpu(), out.valid[0, 0].cpu()
    info["density"] = 100.0 * float(valid.float().mean())
    if min_disp < 0:  # negative disparities are answers here: plain PFM, inf where invalid
        write_pfm(out_dir / "disparity.pfm", torch.where(valid, disp, torch.full_like(disp, math.inf)).numpy())
    else:
        write_disparity_pfm(out_dir / "disparity.pfm", disp, valid)
    viz.save_png(out_dir / "disparity.png", viz.colorize_disparity(disp.numpy() - min_disp_out,
                                                                   (max_disp - min_disp) * sx, valid.numpy()))
    info["disparity_png_scale_px"] = [min_disp_out, max_disp * sx]
    if confidence is not None:
        conf = torch.where(out.valid, confidence.float(), torch.zeros_like(confidence.float()))[0, 0].cpu()
        write_disparity_pfm(out_dir / "confidence.pfm", conf.clamp(0, 1))
        write_image(out_dir / "confidence.png", conf.clamp(0, 1)[None])
    if depth_calib is not None:
        from stereonet.geometry import disparity_to_depth, disparity_to_points

        depth = disparity_to_depth(disparity.double(), depth_calib, valid=out.valid)  # 0 = no depth
        has_depth = depth[0, 0] > 0
        write_disparity_pfm(out_dir / "depth.pfm", depth[0, 0], has_depth)
        unit = st.unit or "unit of the calibration's baseline (unknown: pass --unit)"
        info["units"]["depth"] = unit
        if st.unit is not None:
            mm = (depth[0, 0] * MM_PER_UNIT[st.unit]).round()
            far = int((mm > 65535).sum())
            if far:  # 65535 would read as a real 65.5 m: beyond the format's range is "no depth" there
                info["warnings"].append(f"depth_mm.png: {far} pixels lie beyond 65.535 m, the uint16 format's range, "
                                        "and are written as 0 = no depth (depth.pfm has them)")
            mm = torch.where(mm > 65535, torch.zeros_like(mm), mm).clamp(min=0)
            from stereonet.io.atomic import atomic_write_bytes
            from stereonet.io.image import encode_image

            depth_mm = mm.to(torch.int64).numpy().astype(np.uint16)
            atomic_write_bytes(out_dir / "depth_mm.png", encode_image(out_dir / "depth_mm.png", depth_mm))
            info["units"]["depth_mm.png"] = "uint16 millimetres, 0 = no depth (KITTI/RealSense convention)"
        viz.save_png(out_dir / "depth.png", viz.colorize_depth(depth[0, 0].numpy(), st.unit or "?",
                                                               has_depth.numpy()))
        keep = out.valid
        if st.cloud_min_confidence > 0:
            if confidence is None:
                info["warnings"].append(f"--cloud-min-confidence: {method} returns no confidence; the cloud keeps "
                                        "every valid pixel")
            else:
                keep = keep & (confidence >= st.cloud_min_confidence)
                info["cloud_min_confidence"] = st.cloud_min_confidence
        points, colors = disparity_to_points(disparity, keep, depth_calib, colours)
        info["cloud_frame"] = "rectified left camera"
        if rect is not None and rect.R1 is not None and st.cloud_frame == "original":
            points = points @ rect.R1.to(points.dtype).to(points.device)  # X_orig = R1^T X_rect (rows)
            info["cloud_frame"] = "original left camera"
        write_ply(out_dir / "cloud.ply", points, colors)
        info["points"] = int(len(points))
        info["units"]["cloud.ply"] = unit
        info["depth_unit"] = unit
    for message in info["warnings"]:
        print(f"{PROG}: warning: {pair.left.name}: {message}", file=sys.stderr)
    from stereonet.io import atomic_write_text

    atomic_write_text(out_dir / "info.json", json.dumps(info, indent=2) + "\n")
    return info


# ------------------------------------------------------------------------------------------------ main

def build_parser() -> OneLineParser:
    p = OneLineParser(prog=PROG, description="Disparity, depth and a point cloud from a stereo pair (or a batch).")
    p.add_argument("left", help="left image, folder of left images, a quoted glob, or a video file")
    p.add_argument("right", help="right image, folder of right images, a quoted glob, or a video file")
    p.add_argument("-o", "--out", type=Path, required=True, help="output folder (must not exist without --overwrite)")
    p.add_argument("--method", default=None, help="registered matcher (default: sgm)")
    p.add_argument("--max-disp", type=int, default=None, help="disparity range (default: automatic)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--calib", type=Path, default=None,
                   help="Middlebury calib.txt, KITTI calib or OpenCV YAML/JSON stereo calibration")
    g.add_argument("--uncalibrated", action="store_true", help="rectify from SIFT matches (no metric depth)")
    p.add_argument("--checkpoint", type=Path, default=None, help="weights for a learned method")
    p.add_argument("--backend", choices=("torch", "onnx"), default="torch",
                   help="where a learned method's network runs: torch (default) or onnxruntime (CPU)")
    p.add_argument("--onnx-model", type=Path, default=None,
                   help="with --backend onnx: the file `python -m stereonet.export onnx` wrote (default: export "
                        "the weights in memory)")
    p.add_argument("--overwrite", action="store_true", help="replace OUT if it exists")
    p.add_argument("--device", default="cpu", help="torch device (default cpu)")
    p.add_argument("--fill", action="store_true",
                   help="fill invalid pixels (occlusions, LR failures) along scanlines for a dense map")
    p.add_argument("--no-progress", action="store_true", help="no progress bar in batch mode")
    p.add_argument("--scale", type=float, default=1.0,
                   help="downscale both images by S (0 < S <= 1) first; outputs are for the scaled images")
    p.add_argument("--output-scale", type=float, default=1.0,
                   help="answer on a grid S times the processed images (0.25 <= S <= 4), for methods with a "
                        "continuous output head (smd); disparity then in pixels of that grid")
    p.add_argument("--memory-budget", type=float, default=float(DEFAULT_BUDGET_MIB), metavar="MIB",
                   help=f"extra memory one matcher call may use (default {DEFAULT_BUDGET_MIB} MiB, for an 8 GB "
                        "laptop); larger "
                        "pairs are matched in overlapping strips of rows")
    p.add_argument("--min-disp", type=int, default=0,
                   help="smallest disparity searched (negative for rigs with converging cameras; default 0)")
    p.add_argument("--alpha", type=float, default=1.0,
                   help="rectification crop as OpenCV's alpha: 0 = only pixels both views cover, 1 = keep all")
    p.add_argument("--unit", choices=sorted(MM_PER_UNIT), default=None,
                   help="unit of the calibration's baseline (default: mm for Middlebury calib.txt, m for KITTI, "
                        "else unknown and no depth_mm.png)")
    p.add_argument("--prefilter", choices=("vertical", "binomial"), default=None,
                   help="smooth the images the census cost reads (sgm, siamese-census-sgm, sgm-refine): for noisy "
                        "photos (low light, small sensors); a little worse on clean ones, so off by default")
    p.add_argument("--wmf-radius", type=int, default=None, metavar="PX",
                   help="radius of the image-guided weighted median that dispnet, smd and sgm-refine end with (default "
                        "9; 0 = off: dispnet and smd then leave their left-right rejections to --fill); sgm applies it "
                        "only when given (off by default)")
    p.add_argument("--no-align", action="store_true",
                   help="keep the right view as it is (by default a residual vertical offset of the rectified pair, "
                        "fitted to SIFT matches, is corrected when it reaches 0.25 px)")
    p.add_argument("--cloud-frame", choices=("rectified", "original"), default="rectified",
                   help="frame of cloud.ply when the pair is rectified first (default: rectified left camera)")
    p.add_argument("--cloud-min-confidence", type=float, default=0.0, metavar="C",
                   help="cloud.ply keeps only pixels whose confidence (confidence.pfm, 0..1) is at least C: drops "
                        "unsure and filled pixels (default 0: every valid pixel, filled ones too)")
    return p


def backend_options(args, method: str, spec) -> dict:
    """The matcher options of ``--backend``/``--onnx-model`` (none for the torch default), checked."""
    if args.onnx_model is not None and args.backend != "onnx":
        raise StereoInputError("--onnx-model: only used with --backend onnx")
    if args.backend == "torch":
        return {}
    if spec.kind != "learned":
        raise StereoInputError(f"--backend onnx: method {method!r} is {spec.kind} and has no network to run in "
                               "onnxruntime; use a learned method (dispnet, smd, siamese, siamese-sgm, ...)")
    try:
        import onnx  # noqa: F401
        import onnxruntime  # noqa: F401
    except ImportError as e:
        raise StereoInputError(f"--backend onnx: {e.name} is not installed (pip install 'stereonet[onnx]')") from None
    if args.onnx_model is None:
        return {"backend": "onnx"}
    if args.checkpoint is not None:
        raise StereoInputError("--checkpoint: the ONNX model carries its own weights; pass --checkpoint or "
                               "--onnx-model, not both")
    if not args.onnx_model.is_file():
        raise FileNotFoundError(f"--onnx-model: no such file: {args.onnx_model}")
    from stereonet.matchers.learned import NETWORK_OF, network_graph

    try:  # opens it once: not an export of this method's network is an argument error
        network_graph(NETWORK_OF[method], backend="onnx", onnx_model=args.onnx_model)
    except StereoInputError as e:
        raise StereoInputError(f"--onnx-model: {str(e).removeprefix('onnx_model: ')}") from None
    return {"backend": "onnx", "onnx_model": str(args.onnx_model)}


def _prepare(args) -> tuple[list[Pair], str, dict, object, torch.device]:
    """Check every argument before anything is computed or written."""
    from stereonet import matchers

    if args.out.exists() and not args.overwrite:
        raise FileExistsError(f"-o: {args.out} already exists (pass --overwrite to replace it)")
    if args.max_disp is not None and args.max_disp <= 0:
        raise StereoInputError(f"--max-disp: expected a positive integer, got {args.max_disp}")
    if not 0 < args.scale <= 1:
        raise StereoInputError(f"--scale: expected 0 < S <= 1, got {args.scale}")
    if not args.memory_budget > 0:
        raise StereoInputError(f"--memory-budget: expected a positive number of MiB, got {args.memory_budget}")
    if not 0.25 <= args.output_scale <= 4:
        raise StereoInputError(f"--output-scale: expected 0.25 <= S <= 4, got {args.output_scale}")
    if not 0 <= args.alpha <= 1:
        raise StereoInputError(f"--alpha: expected 0 <= A <= 1, got {args.alpha}")
    if not 0 <= args.cloud_min_confidence <= 1:
        raise StereoInputError(f"--cloud-min-confidence: expected 0 <= C <= 1, got {args.cloud_min_confidence}")
    if args.max_disp is not None and args.min_disp >= args.max_disp:
        raise StereoInputError(f"--min-disp: expected less than --max-disp {args.max_disp}, got {args.min_disp}")
    try:
        device = torch.device(args.device)
        torch.empty(0, device=device)
    except (RuntimeError, AssertionError) as e:
        raise StereoInputError(f"--device: {args.device!r} is not usable here ({str(e).splitlines()[0]})") from None
    pairs = find_pairs(args.left, args.right)
    out = args.out.resolve()
    inputs = [p for pair in pairs for p in (pair.left, pair.right)] + [
        p for p in (args.calib, args.checkpoint) if p is not None]
    for p in inputs:  # --overwrite replaces OUT as a whole: never a folder that holds an input
        if p.resolve() == out or out in p.resolve().parents:
            raise StereoInputError(f"-o: {args.out} holds the input {p}; replacing it would delete the input "
                                   "(choose another output folder)")
    for pair in pairs:
        if pair.frame is None and pair.left.resolve() == pair.right.resolve():
            raise StereoInputError(f"RIGHT: expected a second view, got the same file as LEFT ({pair.left})")
    method = args.method or default_method()
    spec = matchers.spec(method)
    options: dict = backend_options(args, method, spec)
    if args.checkpoint is not None:
        if not spec.needs_weights:
            raise StereoInputError(f"--checkpoint: method {method!r} takes no weights")
        if not args.checkpoint.is_file():
            raise FileNotFoundError(f"--checkpoint: no such file: {args.checkpoint}")
        options["checkpoint"] = str(args.checkpoint)
    elif spec.needs_weights and "onnx_model" not in options and not weights_available(method):
        raise FileNotFoundError(f"--method {method}: its weights are missing (pass --checkpoint CKPT)")
    if args.output_scale != 1.0:
        if "upsample" not in inspect.signature(spec.fn).parameters:
            raise StereoInputError(f"--output-scale: method {method!r} answers on the input grid only; use a method "
                                   "with a continuous output head (smd)")
        options["upsample"] = float(args.output_scale)
    if args.prefilter is not None:
        if method not in PREFILTER_METHODS:
            raise StereoInputError(f"--prefilter: method {method!r} has no census pre-filter; use one of "
                                   f"{', '.join(PREFILTER_METHODS)}")
        options["prefilter"] = args.prefilter
    if args.wmf_radius is not None:
        if args.wmf_radius < 0:
            raise StereoInputError(f"--wmf-radius: expected an integer >= 0 (0 = no weighted median), "
                                   f"got {args.wmf_radius}")
        if "wmf_radius" not in inspect.signature(spec.fn).parameters:
            raise StereoInputError(f"--wmf-radius: method {method!r} has no weighted median; use one of "
                                   f"{', '.join(WMF_METHODS)}")
        options["wmf_radius"] = args.wmf_radius
    calib = None
    if args.calib is not None:
        from stereonet.calibration import read_calibration

        if not args.calib.is_file():
            raise FileNotFoundError(f"--calib: no such file: {args.calib}")
        calib = read_calibration(args.calib)
        if args.unit is None:
            args.unit = calibration_unit(args.calib)
    return pairs, method, options, calib, device


def calibration_unit(path: Path) -> str | None:
    """The baseline unit a calibration format implies: Middlebury ``calib.txt`` is in mm, KITTI in m;
    an OpenCV FileStorage file may carry ``unit`` (as ``stereonet-calibrate`` writes it); else None."""
    try:
        text = path.read_text(errors="replace")
    except OSError:
        return None
    if "baseline=" in text and "cam0=" in text:
        return "mm"
    if "P_rect_0" in text or text.lstrip().startswith("P0:"):
        return "m"
    import re

    m = re.search(r'^\s*"?unit"?\s*:\s*"?(mm|cm|m)"?\s*,?\s*$', text, re.MULTILINE)  # YAML, JSON
    m = m or re.search(r"<unit>\s*\"?(mm|cm|m)\"?\s*</unit>", text)  # OpenCV XML (stereonet-calibrate --out x.xml)
    return m.group(1) if m else None


def _umask() -> int:
    import os

    mask = os.umask(0)
    os.umask(mask)
    return mask


def _make_parents(out: Path) -> list[Path]:
    """Create the missing parent folders of ``-o`` and return them deepest first (so that a failed run can remove
    them again); a one-line error when ``-o`` or one of its parents is an existing file."""
    check_output_path(out, "-o", folder=True)
    missing = []
    parent = out.parent
    while not parent.exists():
        missing.append(parent)
        parent = parent.parent
    out.parent.mkdir(parents=True, exist_ok=True)
    return missing


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
    reuse_freed_memory()  # large buffers from the heap, reused instead of mapped afresh (stereonet.measure)
    try:
        pairs, method, options, calib, device = _prepare(args)
    except USER_ERRORS as e:
        return fail(PROG, e)
    except ImportError as e:
        return fail(PROG, f"{e} (this part of stereonet is not installed)")
    out = args.out.resolve()
    try:
        created = _make_parents(out)
    except USER_ERRORS as e:
        return fail(PROG, e)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.tmp-", dir=out.parent))
    tmp.chmod(0o777 & ~_umask())  # mkdtemp's folder is private (0700); OUT gets a folder's usual mode
    failures: list[str] = []
    settings = Settings(fill=args.fill, scale=args.scale, min_disp=args.min_disp, alpha=args.alpha, unit=args.unit,
                        cloud_frame=args.cloud_frame, cloud_min_confidence=args.cloud_min_confidence,
                        output_scale=args.output_scale,
                        memory_budget=args.memory_budget, align=not args.no_align)
    try:
        from tqdm import tqdm

        batch = len(pairs) > 1 or pairs[0].name != ""
        for pair in tqdm(pairs, desc="infer", unit="pair", disable=not batch or args.no_progress, file=sys.stderr):
            pair_dir = tmp / pair.name if pair.name else tmp
            pair_dir.mkdir(exist_ok=True)
            try:
                process_pair(pair, pair_dir, method, options, args.max_disp, calib, args.calib,
                             args.uncalibrated, device, settings=settings)
            except (*USER_ERRORS, ImportError, RuntimeError, MemoryError) as e:
                if not batch:
                    raise
                fail(PROG, f"{pair.left.name if pair.frame is None else pair.name}: {e}", 1)
                failures.append(pair.name)
                shutil.rmtree(pair_dir, ignore_errors=True)
        if len(failures) == len(pairs):
            raise StereoInputError("every pair failed; nothing written")
        _publish(tmp, out)
    except BaseException as e:  # nothing half-written: the temporary folder goes, OUT is untouched
        shutil.rmtree(tmp, ignore_errors=True)
        for folder in created:  # the parents this call made, deepest first, if still empty
            try:
                folder.rmdir()
            except OSError:
                break
        if isinstance(e, USER_ERRORS):
            return fail(PROG, e)
        if isinstance(e, ImportError):
            return fail(PROG, f"{e} (this part of stereonet is not installed)")
        if isinstance(e, MemoryError):
            return fail(PROG, e, 1)
        if isinstance(e, RuntimeError):  # the method itself failed (e.g. out of memory)
            return fail(PROG, f"--method {method}: {e}", 1)
        raise
    finally:
        VIDEO_FRAMES.close()
    if failures:
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
