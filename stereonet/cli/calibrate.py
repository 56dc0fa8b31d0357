"""stereonet-calibrate: chessboard (or ChArUco) views of a stereo rig in; the calibration ``--calib`` reads out.

    stereonet-calibrate LEFT RIGHT --board COLSxROWS --square SIZE -o CALIB.yaml [--unit mm|cm|m]
                        [--preview PATH] [--charuco DICT [--marker SIZE]] [--min-views N]
                        [--fix-intrinsics] [--k3] [--overwrite] [--no-progress]
    python -m stereonet.calibrate ...   (the same)

LEFT/RIGHT are two folders or two quoted globs of images, paired in sorted order (the i-th left image and
the i-th right image are one view, taken at the same moment). COLSxROWS counts the board's *inner* corners;
SIZE is the side of one square in the unit wanted for depth (the baseline, depth and clouds of ``infer.py``
come out in it; ``--unit`` names it in the YAML). Corners are detected in every image, each camera is
calibrated, then the pair (see :mod:`stereonet.calibrate.solve`); views with an outlying reprojection error
are dropped and the calibration made again. A table of the per-view RMS reprojection error goes to stdout.

Writes ``CALIB.yaml`` (OpenCV FileStorage: K1, D1, K2, D2, R, T, image_width, image_height, and what the
calibration was made from: board, square, unit (with ``--unit``), rms_px, views_used, views_given,
per_view_rms_px (one row ``[view, left px, right px]`` per used view), rectified_row_error_px) and ``CALIB_preview.png`` beside it (or ``--preview PATH``): the best view
rectified with the new calibration, with epipolar lines and the board corners, which should lie on them.
Both are written atomically and only once everything has succeeded. Bad input (no board found, too few
views, images of different sizes, LEFT and RIGHT of different lengths...) ends in one line on stderr and
exit code 2, with nothing written.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from stereonet.checks import StereoInputError
from stereonet.cli.common import USER_ERRORS, OneLineParser, fail

PROG = "stereonet-calibrate"
CALIB_EXTENSIONS = (".yaml", ".yml", ".json", ".xml")
UNITS = ("mm", "cm", "m")


def build_parser() -> OneLineParser:
    p = OneLineParser(prog=PROG, description="Calibrate a stereo rig from chessboard (or ChArUco) image pairs.")
    p.add_argument("left", help="folder of left images, or a quoted glob")
    p.add_argument("right", help="folder of right images, or a quoted glob (paired with LEFT in sorted order)")
    p.add_argument("--board", required=True, help="inner corners of the board as COLSxROWS, e.g. 9x6")
    p.add_argument("--square", type=float, required=True,
                   help="side of one square, in the unit wanted for depth (e.g. 25 for 25 mm squares)")
    p.add_argument("-o", "--out", type=Path, required=True, help="calibration file to write (.yaml/.yml/.json/.xml)")
    p.add_argument("--unit", choices=UNITS, default=None, help="unit of --square, written into the calibration")
    p.add_argument("--preview", type=Path, default=None,
                   help="rectified preview image (default: OUT's name + _preview.png beside it)")
    p.add_argument("--charuco", metavar="DICT", default=None,
                   help="the board is ChArUco with this OpenCV ArUco dictionary (e.g. DICT_4X4_50); "
                        "COLSxROWS still counts inner corners ((COLS+1)x(ROWS+1) squares)")
    p.add_argument("--marker", type=float, default=None, help="ChArUco marker side (default 0.75 x --square)")
    p.add_argument("--min-views", type=int, default=6,
                   help="fewest views with the board found in both images (default 6)")
    p.add_argument("--fix-intrinsics", action="store_true",
                   help="keep each camera's own calibration in the stereo step (default: refine it jointly)")
    p.add_argument("--k3", action="store_true", help="also estimate the k3 radial term (wide-angle lenses)")
    p.add_argument("--overwrite", action="store_true", help="replace OUT and the preview if they exist")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p


def preview_path(out: Path) -> Path:
    """``CALIB.yaml`` -> ``CALIB_preview.png`` beside it."""
    return out.with_name(f"{out.stem}_preview.png")


def _check_arguments(args):
    """Every argument, before anything is read or written. Returns (board, out, preview)."""
    from stereonet.calibrate import Board, parse_board_size

    cols, rows = parse_board_size(args.board)
    if not math.isfinite(args.square) or args.square <= 0:
        raise StereoInputError(f"--square: expected a positive size, got {args.square}")
    if args.marker is not None and args.charuco is None:
        raise StereoInputError("--marker: only for a ChArUco board (pass --charuco DICT)")
    if args.min_views < 3:
        raise StereoInputError(f"--min-views: expected at least 3, got {args.min_views}")
    try:
        board = Board(cols, rows, args.square, dictionary=args.charuco, marker=args.marker)
    except ValueError as e:
        which = "--marker" if str(e).startswith("marker") else "--charuco"
        raise StereoInputError(f"{which}: {str(e).split(': ', 1)[1]}") from None
    out = args.out
    if out.suffix.lower() not in CALIB_EXTENSIONS:
        raise StereoInputError(f"-o: expected a {', '.join(CALIB_EXTENSIONS)} file, got {str(out)!r}")
    preview = args.preview if args.preview is not None else preview_path(out)
    if preview.suffix.lower() != ".png":
        raise StereoInputError(f"--preview: expected a .png file, got {str(preview)!r}")
    if preview.resolve() == out.resolve():
        raise StereoInputError(f"--preview: must differ from -o ({out})")
    for flag, path in (("-o", out), ("--preview", preview)):
        if path.is_dir():
            raise IsADirectoryError(f"{flag}: {path} is a folder, expected a file name")
        if path.exists() and not args.overwrite:
            raise FileExistsError(f"{flag}: {path} already exists (pass --overwrite to replace it)")
    return board, out, preview


def _gray(img) -> np.ndarray:
    import cv2

    from stereonet.io import to_uint8_rgb

    a = to_uint8_rgb(img)
    return cv2.cvtColor(a, cv2.COLOR_RGB2GRAY) if a.ndim == 3 else a


def detect_views(board, pairs, progress: bool):
    """Read every image (one size for all) and find the board in it. Returns (left, right, (width, height))."""
    from tqdm import tqdm

    from stereonet.calibrate import detect_board
    from stereonet.checks import StereoInputError
    from stereonet.io import read_image

    left, right, size, first = [], [], None, None
    for pair in tqdm(pairs, desc="corners", unit="view", disable=not progress, file=sys.stderr):
        for which, path, dets in (("LEFT", pair.left, left), ("RIGHT", pair.right, right)):
            gray = _gray(read_image(path))
            h, w = gray.shape
            if size is None:
                size, first = (w, h), path
            elif (w, h) != size:
                raise StereoInputError(f"{which}: {path} is {w}x{h}, expected {size[0]}x{size[1]} like {first} "
                                       "(every image of both cameras must have one size)")
            dets.append(detect_board(board, gray))
    return left, right, size


def print_table(result, file=None) -> None:
    """The per-view RMS reprojection errors and what became of each view (to ``file``, default stdout)."""
    file = sys.stdout if file is None else file
    views = result.views
    wl = max([4] + [len(v.left) for v in views])
    wr = max([5] + [len(v.right) for v in views])

    def px(x: float) -> str:
        return "-" if math.isnan(x) else f"{x:.3f}"

    print(f"{'view':>4}  {'left':<{wl}}  {'right':<{wr}}  {'left px':>8}  {'right px':>8}  status", file=file)
    for v in views:
        print(f"{v.index:>4}  {v.left:<{wl}}  {v.right:<{wr}}  {px(v.rms_left):>8}  {px(v.rms_right):>8}  {v.status}",
              file=file)


def essential_and_fundamental(calib) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's ``E = [T]x R`` and ``F = K2^-T E K1^-1`` (scaled to ``F[2, 2] = 1`` when it is not ~0) of a rig
    ``X2 = R X1 + T``: ``x2^T F x1 = 0`` for undistorted pixel coordinates of one point."""
    R, t = calib.R.numpy(), calib.t.numpy()
    tx = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
    E = tx @ R
    F = np.linalg.inv(calib.K2.numpy()).T @ E @ np.linalg.inv(calib.K1.numpy())
    if abs(F[2, 2]) > 1e-12 * np.abs(F).max():
        F = F / F[2, 2]
    return E, F


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return _run(args)
    except USER_ERRORS as e:
        return fail(PROG, e)
    except ImportError as e:
        return fail(PROG, f"{e} (this part of stereonet is not installed)")


def _run(args) -> int:
    import cv2

    from stereonet.calibrate import CalibrationError, calibrate_rig, rectified_preview
    from stereonet.calibration import write_opencv_calibration
    from stereonet.checks import StereoInputError
    from stereonet.cli.infer import find_pairs
    from stereonet.io import read_image
    from stereonet.io.atomic import atomic_path
    from stereonet.io.image import encode_image

    board, out, preview = _check_arguments(args)
    pairs = find_pairs(args.left, args.right)
    if any(p.frame is not None for p in pairs):
        raise StereoInputError("LEFT: expected two folders or globs of board images, got videos (extract the "
                               "frames that show the board, e.g. with ffmpeg, and pass their folders)")
    progress = not args.no_progress and sys.stderr.isatty()
    left, right, size = detect_views(board, pairs, progress)
    names = [(p.left.name, p.right.name) for p in pairs]
    try:
        result = calibrate_rig(board, left, right, size, names, min_views=args.min_views,
                               refine=not args.fix_intrinsics, k3=args.k3)
    except cv2.error as e:  # OpenCV gave up on the views (degenerate poses, e.g. all fronto-parallel)
        raise CalibrationError(f"OpenCV could not calibrate from these views ({str(e).strip().splitlines()[-1]})") \
            from None
    for message in result.warnings:
        print(f"{PROG}: warning: {message}", file=sys.stderr)
    print_table(result)

    used = [v for v in result.views if v.used]
    best = min(used, key=lambda v: max(v.rms_left, v.rms_right))
    pair = pairs[best.index]
    try:
        shown = rectified_preview(read_image(pair.left), read_image(pair.right), result.calib,
                                  result.left[best.index], result.right[best.index])
    except StereoInputError as e:  # e.g. a rectifying rotation that turns part of the image behind the camera
        raise CalibrationError(f"the calibration does not rectify view {best.index} ({pair.left.name}) for the "
                               f"preview: {e}") from None
    calib = result.calib
    per_view = np.array([[v.index, v.rms_left, v.rms_right] for v in used], dtype=np.float64)
    extra: dict = {"calibrated_with": PROG, "board": f"{board.cols}x{board.rows}", "board_kind": board.kind,
                   "square": float(board.square), "unit": args.unit or "unknown (the unit of --square)",
                   "rms_px": result.rms, "views_used": len(used), "views_given": len(result.views),
                   "per_view_rms_px": per_view, "rectified_row_error_px": shown.row_error_px}
    if args.unit is None:
        del extra["unit"]  # infer.py reads `unit` as mm/cm/m; an unknown unit is simply absent
    extra["E"], extra["F"] = essential_and_fundamental(calib)
    if board.dictionary is not None:
        extra["charuco_dictionary"] = board.dictionary
        extra["charuco_marker"] = float(board.marker)
    png = encode_image(preview, shown.image)
    # both files appear only when both are complete: the YAML is renamed into place inside the preview's
    # atomic block, whose own rename follows; any failure removes both temporary files
    with atomic_path(preview) as tmp_preview:
        tmp_preview.write_bytes(png)
        write_opencv_calibration(out, calib, extra=extra)

    unit = args.unit or "units of --square"
    print(f"stereo RMS {result.rms:.3f} px over {len(used)} of {len(result.views)} views; "
          f"f = {float(calib.K1[0, 0]):.2f} / {float(calib.K2[0, 0]):.2f} px (left / right); "
          f"baseline {calib.baseline:.4g} {unit}; rectified row error {shown.row_error_px:.3f} px (median)")
    print(f"wrote {out} and {preview}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
