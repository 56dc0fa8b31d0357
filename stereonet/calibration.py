"""Reading and writing two-camera calibrations as :class:`stereonet.types.Calibration`.

Formats (``read_calibration`` detects them from the extension and content):

- Middlebury 2014 ``calib.txt``: ``cam0=[f 0 cx; 0 f cy; 0 0 1]``, ``cam1=[...]``, ``doffs``, ``baseline``
  (mm), ``width``, ``height``, ``ndisp`` (plus ``isint``, ``vmin``, ``vmax``... which are ignored). The rig is
  rectified: ``R = I``, ``t = (-baseline, 0, 0)`` mm, depth ``z = f * baseline / (d + doffs)``.
- KITTI: the raw-data / scene-flow ``calib_cam_to_cam.txt`` (``P_rect_02``, ``P_rect_03``, optional
  ``S_rect_02``) and the stereo/odometry ``calib.txt`` (``P0:`` ... ``P3:``). ``K`` is the left 3x3 block of
  each rectified projection matrix ``P = K [I | t_i]`` (``t_i = K^-1 P[:, 3]``, metres, in the rectified
  reference frame), so ``R = I`` and ``t = t_right - t_left``. Cameras 2/3 (colour) by default.
- OpenCV ``FileStorage`` YAML/JSON/XML as written by stereo calibration tools: ``K1``/``M1``/``cameraMatrix1``,
  ``D1``/``dist1``/``distCoeffs1``, the same for camera 2, ``R``, ``T``, and the image size as
  ``image_width``/``image_height`` or ``size``/``imageSize`` (``[width, height]``). OpenCV's ``R, T`` from
  ``stereoCalibrate`` follow our convention ``X_r = R X_l + t``. OpenCV's stereo sample writes two files,
  ``intrinsics.yml`` (M1, D1, M2, D2) and ``extrinsics.yml`` (R, T, R1, R2, P1, P2, Q): given either, the
  other is read from the same folder and merged; they hold no image size (the images' size is used).
  ``stereonet-calibrate`` (:mod:`stereonet.calibrate`) writes this format.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Mapping
from pathlib import Path

import cv2
import numpy as np
import torch

from stereonet.checks import StereoInputError
from stereonet.io.atomic import atomic_path
from stereonet.io.errors import existing_file, fail
from stereonet.types import Calibration

__all__ = ["read_calibration", "read_kitti_calibration", "read_middlebury_calibration",
           "read_opencv_calibration", "write_opencv_calibration"]

_OPENCV_EXTENSIONS = (".yml", ".yaml", ".json", ".xml")
_KEY_ALIASES = {
    "K1": ("K1", "M1", "cameraMatrix1", "camera_matrix_1"),
    "K2": ("K2", "M2", "cameraMatrix2", "camera_matrix_2"),
    "D1": ("D1", "dist1", "distCoeffs1", "dist_coeffs_1"),
    "D2": ("D2", "dist2", "distCoeffs2", "dist_coeffs_2"),
    "R": ("R",),
    "T": ("T", "t"),
}


def read_calibration(path: str | os.PathLike, kitti_cameras: tuple[int, int] = (2, 3)) -> Calibration:
    """Read a calibration file in any supported format (see the module docstring).

    Raises:
        FileNotFoundError: the file does not exist.
        FileFormatError: unknown format, or a malformed/missing key (the message names file and key).
    """
    p = existing_file(path)
    if p.suffix.lower() in _OPENCV_EXTENSIONS:
        return read_opencv_calibration(p)
    text = p.read_text(encoding="utf-8", errors="replace")
    if re.search(r"^\s*cam0\s*=", text, re.M):
        return read_middlebury_calibration(p)
    if re.search(r"^\s*(P_rect_0\d|P\d)\s*:", text, re.M):
        return read_kitti_calibration(p, kitti_cameras)
    if text.lstrip().startswith(("%YAML", "{", "<?xml")):
        return read_opencv_calibration(p)
    raise fail(p, "unknown calibration format: expected Middlebury 2014 calib.txt (cam0=...), KITTI "
                  "(P_rect_02: / P2:) or OpenCV FileStorage (.yml/.yaml/.json/.xml)")


# ------------------------------------------------------------------------------------------ Middlebury
def _key_values(path: Path, sep: str) -> dict[str, str]:
    """``key<sep>value`` lines of a text file as a dict of stripped strings (other lines ignored)."""
    values: dict[str, str] = {}
    for line in path.read_text(encoding="utf-8", errors="replace").splitlines():
        if sep in line:
            k, v = line.split(sep, 1)
            values[k.strip()] = v.strip()
    return values


def _parse_matrix(text: str, path: Path, key: str) -> np.ndarray:
    rows = [r.split() for r in text.strip().strip("[]").split(";")]
    try:
        m = np.array([[float(v) for v in r] for r in rows], dtype=np.float64)
    except ValueError:
        raise fail(path, f"malformed {key!r}: expected numbers like [f 0 cx; 0 f cy; 0 0 1], got {text!r}") from None
    if m.shape != (3, 3):
        raise fail(path, f"malformed {key!r}: expected a 3x3 matrix, got shape {m.shape}")
    return m


def read_middlebury_calibration(path: str | os.PathLike) -> Calibration:
    """Read a Middlebury 2014 ``calib.txt`` (``key=value`` lines; ``baseline`` in mm)."""
    p = existing_file(path)
    values = _key_values(p, "=")

    def get(key: str) -> str:
        if key not in values:
            raise fail(p, f"missing key {key!r} (Middlebury calib.txt needs cam0, cam1, baseline; "
                          f"doffs, width, height, ndisp are optional)")
        return values[key]

    def number(key: str, default=None, kind=float):
        if key not in values and default is not None:
            return default
        text = get(key)
        try:
            value = float(text)
            if not math.isfinite(value):
                raise ValueError(text)
            return kind(value)
        except ValueError:
            raise fail(p, f"malformed {key!r}: expected a finite number, got {text!r}") from None

    K1 = _parse_matrix(get("cam0"), p, "cam0")
    K2 = _parse_matrix(get("cam1"), p, "cam1")
    baseline = number("baseline")
    doffs = number("doffs", default=float(K2[0, 2] - K1[0, 2]))
    size = None
    if "width" in values and "height" in values:
        size = (number("width", kind=int), number("height", kind=int))
    ndisp = number("ndisp", kind=int) if "ndisp" in values else None
    return _build(p, K1, K2, np.eye(3), np.array([-baseline, 0.0, 0.0]), size, doffs=doffs, ndisp=ndisp)


# ------------------------------------------------------------------------------------------ KITTI
def read_kitti_calibration(path: str | os.PathLike, cameras: tuple[int, int] = (2, 3)) -> Calibration:
    """Read KITTI ``calib_cam_to_cam.txt`` (``P_rect_0i``) or stereo/odometry ``calib.txt`` (``Pi``).

    ``cameras``: (left, right) camera indices; (2, 3) is the colour pair (KITTI 2015 image_2/image_3,
    KITTI 2012 colored_0/colored_1), (0, 1) the grey pair. Translations are in metres.

    The images these matrices describe are rectified (one rotation, rows aligned), so the rig is returned as
    rectified: R = I and the baseline along x only, ``t = ((K2^-1 P_r - K1^-1 P_l)_x, 0, 0)``, as KITTI's own
    depth ``f B / d`` uses it. The y and z parts of that difference (a few mm: the cameras' centres in the
    common rectified frame) are dropped; kept, they made the rig look unrectified (beyond
    :meth:`~stereonet.types.Calibration.is_rectified`'s tolerance) and infer.py re-rectified the already
    rectified images (a 0.3 degree rotation and new padding).
    """
    p = existing_file(path)
    values = _key_values(p, ":")
    projections = []
    for cam in cameras:
        key = next((k for k in (f"P_rect_{cam:02d}", f"P{cam}") if k in values), None)
        if key is None:
            raise fail(p, f"missing key 'P_rect_{cam:02d}' or 'P{cam}' (KITTI rectified projection of camera {cam})")
        try:
            P = np.array([float(v) for v in values[key].split()], dtype=np.float64)
        except ValueError:
            raise fail(p, f"malformed {key!r}: expected 12 numbers, got {values[key]!r}") from None
        if P.size != 12:
            raise fail(p, f"malformed {key!r}: expected 12 numbers (3x4 matrix), got {P.size}")
        projections.append(P.reshape(3, 4))
    (P_l, P_r) = projections
    K1, K2 = P_l[:, :3], P_r[:, :3]
    for name, K in (("left", K1), ("right", K2)):
        if abs(np.linalg.det(K)) < 1e-12:
            raise fail(p, f"malformed projection matrix of the {name} camera: singular 3x3 block")
    t_l = np.linalg.solve(K1, P_l[:, 3])
    t_r = np.linalg.solve(K2, P_r[:, 3])
    size = None
    s_key = f"S_rect_{cameras[0]:02d}"
    if s_key in values:
        try:
            w, h = (int(round(float(v))) for v in values[s_key].split())
            size = (w, h)
        except (ValueError, OverflowError):
            raise fail(p, f"malformed {s_key!r}: expected 'width height', got {values[s_key]!r}") from None
    t = np.array([t_r[0] - t_l[0], 0.0, 0.0])
    return _build(p, K1, K2, np.eye(3), t, size, doffs=float(K2[0, 2] - K1[0, 2]))


# ------------------------------------------------------------------------------------------ OpenCV
def _node_array(node, path: Path, key: str) -> np.ndarray:
    if node.isMap():
        m = node.mat()
        if m is None:
            raise fail(path, f"malformed {key!r}: expected an opencv-matrix")
        return np.asarray(m, dtype=np.float64)
    if node.isSeq():
        vals = []
        for i in range(node.size()):
            item = node.at(i)
            if item.isSeq():
                vals.append([item.at(j).real() for j in range(item.size())])
            elif item.isReal() or item.isInt():
                vals.append(item.real())
            else:
                raise fail(path, f"malformed {key!r}: expected numbers")
        if len({len(v) if isinstance(v, list) else -1 for v in vals}) > 1:
            raise fail(path, f"malformed {key!r}: expected rows of equal length (a matrix)")
        return np.asarray(vals, dtype=np.float64)
    if node.isReal() or node.isInt():
        return np.asarray([node.real()], dtype=np.float64)
    raise fail(path, f"malformed {key!r}: expected a matrix or a list of numbers")


def read_opencv_calibration(path: str | os.PathLike) -> Calibration:
    """Read an OpenCV ``FileStorage`` stereo calibration (YAML, JSON or XML; see the module docstring).

    OpenCV's stereo sample (``stereo_calib.cpp``) splits its result in two files beside each other:
    ``intrinsics.yml`` (M1, D1, M2, D2) and ``extrinsics.yml`` (R, T, R1, R2, P1, P2, Q). Given either, the
    other is looked up in the same folder (the name with "intrinsics" and "extrinsics" swapped, the same
    extension first) and the two are merged; R1, R2, P1, P2, Q are not read (the rig is rectified again
    from R, T). Those files hold no image size, so ``image_size`` is None (the images' size is used).
    """
    p = existing_file(path)
    values = _opencv_values(p)
    sibling = None
    if any(name not in values for name in _REQUIRED):
        sibling = _two_file_sibling(p)
        if sibling is not None:
            values = {**_opencv_values(sibling), **values}  # the file given wins where both have a key
    for name in _REQUIRED:
        if name not in values:
            raise fail(p, _missing_key_message(p, name, sibling))
    matrices = {}
    for name, shape in _REQUIRED.items():
        arr, key, source = values[name]
        if arr.size != int(np.prod(shape)):
            raise fail(source, f"malformed {key!r}: expected {'x'.join(map(str, shape))} values, got shape {arr.shape}")
        matrices[name] = arr.reshape(shape)
    D1 = values["D1"][0] if "D1" in values else None
    D2 = values["D2"][0] if "D2" in values else None
    size = values["size"][0] if "size" in values else None
    # without one, doffs is the principal points' difference, as the Middlebury and KITTI readers take it
    doffs = values["doffs"][0] if "doffs" in values else float(matrices["K2"][0, 2] - matrices["K1"][0, 2])
    ndisp = values["ndisp"][0] if "ndisp" in values else None
    return _build(p, matrices["K1"], matrices["K2"], matrices["R"], matrices["T"], size, D1, D2, doffs=doffs,
                  ndisp=ndisp)


_REQUIRED = {"K1": (3, 3), "K2": (3, 3), "R": (3, 3), "T": (3,)}


def _opencv_values(p: Path) -> dict[str, tuple[object, str, Path]]:
    """The calibration entries a FileStorage file holds: our name -> (value, key in the file, file)."""
    try:
        fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)
        opened = fs.isOpened()
    except (cv2.error, SystemError) as e:
        raise fail(p, f"cannot parse as OpenCV FileStorage YAML/JSON/XML ({str(e).splitlines()[0][:120]})") from None
    if not opened:
        raise fail(p, "cannot open as OpenCV FileStorage YAML/JSON/XML")
    values: dict[str, tuple[object, str, Path]] = {}
    try:
        def present(key: str):
            node = fs.getNode(key)
            return None if node.empty() or node.isNone() else node

        for name, aliases in _KEY_ALIASES.items():
            for key in aliases:
                node = present(key)
                if node is not None:
                    values[name] = (_node_array(node, p, key), key, p)
                    break
        w_node, h_node = present("image_width"), present("image_height")
        if w_node is not None and h_node is not None:
            values["size"] = ((int(w_node.real()), int(h_node.real())), "image_width", p)
        else:
            for key in ("size", "imageSize", "image_size"):
                node = present(key)
                if node is not None:
                    wh = _node_array(node, p, key).reshape(-1)
                    if wh.size != 2:
                        raise fail(p, f"malformed {key!r}: expected [width, height], got {wh.size} values")
                    values["size"] = ((int(wh[0]), int(wh[1])), key, p)
                    break
        doffs_node, ndisp_node = present("doffs"), present("ndisp")
        if doffs_node is not None:
            values["doffs"] = (doffs_node.real(), "doffs", p)
        if ndisp_node is not None:
            values["ndisp"] = (int(ndisp_node.real()), "ndisp", p)
    finally:
        fs.release()
    return values


_TWO_FILE_WORDS = {"intrinsics": "extrinsics", "extrinsics": "intrinsics"}


def _two_file_sibling(p: Path) -> Path | None:
    """The other file of OpenCV's two-file stereo output beside ``p`` (intrinsics <-> extrinsics), if any."""
    match = re.search("intrinsics|extrinsics", p.stem, re.I)
    if match is None:
        return None
    word = match.group(0)
    other = _TWO_FILE_WORDS[word.lower()]
    other = other.upper() if word.isupper() else other.capitalize() if word[0].isupper() else other
    stem = p.stem[:match.start()] + other + p.stem[match.end():]
    suffixes = [p.suffix] + [e for e in _OPENCV_EXTENSIONS if e != p.suffix.lower()]
    return next((c for c in (p.with_name(stem + s) for s in suffixes) if c.is_file()), None)


def _missing_key_message(p: Path, name: str, sibling: Path | None) -> str:
    aliases = _KEY_ALIASES[name][1:]
    message = f"missing key {name!r}" + (f" (also accepted: {', '.join(aliases)})" if aliases else "")
    if sibling is not None:
        return message + f" in it or in {sibling.name} beside it"
    match = re.search("intrinsics|extrinsics", p.stem, re.I)
    if match is not None:
        other = p.stem[:match.start()] + _TWO_FILE_WORDS[match.group(0).lower()] + p.stem[match.end():]
        return message + f"; OpenCV's two-file output needs {other}{p.suffix} beside it, not found"
    return message


def write_opencv_calibration(path: str | os.PathLike, calib: Calibration,
                             extra: Mapping[str, object] | None = None) -> None:
    """Write ``calib`` as OpenCV FileStorage (.yml/.yaml/.json/.xml by extension), atomically.

    Keys: K1, D1, K2, D2, R, T, image_width, image_height, doffs, ndisp (those that are set); readable by
    :func:`read_opencv_calibration` and by ``cv2.FileStorage``. ``extra``: more entries written after them
    (str, int, float or numpy array values; names must not be one the reader takes for a calibration key).
    """
    if not isinstance(calib, Calibration):
        raise TypeError(f"calib: expected a Calibration, got {type(calib).__name__}")
    if Path(path).suffix.lower() not in _OPENCV_EXTENSIONS:
        raise StereoInputError(f"path: expected one of {', '.join(_OPENCV_EXTENSIONS)}, got {str(path)!r}")
    reserved = {k for aliases in _KEY_ALIASES.values() for k in aliases} | {
        "image_width", "image_height", "size", "imageSize", "image_size", "doffs", "ndisp"}
    extra = dict(extra or {})
    for key, value in extra.items():
        if key in reserved:
            raise StereoInputError(f"extra: {key!r} is a calibration key, expected another name")
        if not isinstance(value, (str, int, float, np.ndarray)) or isinstance(value, bool):
            raise TypeError(f"extra[{key!r}]: expected str, int, float or numpy array, got {type(value).__name__}")

    def arr(t: torch.Tensor) -> np.ndarray:
        return t.detach().cpu().numpy().astype(np.float64)

    with atomic_path(path) as tmp:
        fs = cv2.FileStorage(str(tmp), cv2.FILE_STORAGE_WRITE)
        fs.write("K1", arr(calib.K1))
        if calib.dist1 is not None:
            fs.write("D1", arr(calib.dist1).reshape(1, -1))
        fs.write("K2", arr(calib.K2))
        if calib.dist2 is not None:
            fs.write("D2", arr(calib.dist2).reshape(1, -1))
        fs.write("R", arr(calib.R))
        fs.write("T", arr(calib.t).reshape(3, 1))
        if calib.image_size is not None:
            fs.write("image_width", int(calib.image_size[0]))
            fs.write("image_height", int(calib.image_size[1]))
        fs.write("doffs", float(calib.doffs))
        if calib.ndisp is not None:
            fs.write("ndisp", int(calib.ndisp))
        for key, value in extra.items():
            fs.write(key, value.astype(np.float64) if isinstance(value, np.ndarray) else value)
        fs.release()


def _build(path: Path, K1, K2, R, t, size, dist1=None, dist2=None, doffs: float = 0.0,
           ndisp: int | None = None) -> Calibration:
    """Construct the Calibration, turning its validation errors into errors that name the file."""
    try:
        return Calibration(torch.as_tensor(K1), torch.as_tensor(K2), torch.as_tensor(R), torch.as_tensor(t),
                           image_size=size,
                           dist1=None if dist1 is None else torch.as_tensor(dist1),
                           dist2=None if dist2 is None else torch.as_tensor(dist2),
                           doffs=float(doffs), ndisp=ndisp)
    except (ValueError, TypeError) as e:
        raise fail(path, f"invalid calibration: {e}") from None
