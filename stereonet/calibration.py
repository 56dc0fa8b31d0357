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
  ``stereoCalibrate`` follow our convention ``X_r = R X_l + t``.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import cv2
import numpy as np
import torch

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
            return kind(float(text))
        except ValueError:
            raise fail(p, f"malformed {key!r}: expected a number, got {text!r}") from None

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
        except ValueError:
            raise fail(p, f"malformed {s_key!r}: expected 'width height', got {values[s_key]!r}") from None
    return _build(p, K1, K2, np.eye(3), t_r - t_l, size, doffs=float(K2[0, 2] - K1[0, 2]))


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
        return np.asarray(vals, dtype=np.float64)
    if node.isReal() or node.isInt():
        return np.asarray([node.real()], dtype=np.float64)
    raise fail(path, f"malformed {key!r}: expected a matrix or a list of numbers")


def read_opencv_calibration(path: str | os.PathLike) -> Calibration:
    """Read an OpenCV ``FileStorage`` stereo calibration (YAML, JSON or XML; see the module docstring)."""
    p = existing_file(path)
    try:
        fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)
        opened = fs.isOpened()
    except (cv2.error, SystemError) as e:
        raise fail(p, f"cannot parse as OpenCV FileStorage YAML/JSON/XML ({str(e).splitlines()[0][:120]})") from None
    if not opened:
        raise fail(p, "cannot open as OpenCV FileStorage YAML/JSON/XML")
    try:
        def find(name: str, required: bool = True):
            for key in _KEY_ALIASES[name]:
                node = fs.getNode(key)
                if not node.empty() and not node.isNone():
                    return _node_array(node, p, key), key
            if required:
                raise fail(p, f"missing key {name!r} (also accepted: {', '.join(_KEY_ALIASES[name][1:])})")
            return None, None

        def matrix(name: str, shape: tuple[int, ...], required: bool = True):
            arr, key = find(name, required)
            if arr is None:
                return None
            if arr.size != int(np.prod(shape)):
                raise fail(p, f"malformed {key!r}: expected {'x'.join(map(str, shape))} values, got shape {arr.shape}")
            return arr.reshape(shape)

        K1, K2 = matrix("K1", (3, 3)), matrix("K2", (3, 3))
        R, T = matrix("R", (3, 3)), matrix("T", (3,))
        D1, _ = find("D1", required=False)
        D2, _ = find("D2", required=False)
        size = None
        w_node, h_node = fs.getNode("image_width"), fs.getNode("image_height")
        if not w_node.empty() and not h_node.empty():
            size = (int(w_node.real()), int(h_node.real()))
        else:
            for key in ("size", "imageSize", "image_size"):
                node = fs.getNode(key)
                if not node.empty() and not node.isNone():
                    wh = _node_array(node, p, key).reshape(-1)
                    if wh.size != 2:
                        raise fail(p, f"malformed {key!r}: expected [width, height], got {wh.size} values")
                    size = (int(wh[0]), int(wh[1]))
                    break
        doffs_node, ndisp_node = fs.getNode("doffs"), fs.getNode("ndisp")
        doffs = doffs_node.real() if not doffs_node.empty() else 0.0
        ndisp = int(ndisp_node.real()) if not ndisp_node.empty() else None
    finally:
        fs.release()
    return _build(p, K1, K2, R, T, size, D1, D2, doffs=doffs, ndisp=ndisp)


def write_opencv_calibration(path: str | os.PathLike, calib: Calibration) -> None:
    """Write ``calib`` as OpenCV FileStorage (.yml/.yaml/.json/.xml by extension), atomically.

    Keys: K1, D1, K2, D2, R, T, image_width, image_height, doffs, ndisp (those that are set); readable by
    :func:`read_opencv_calibration` and by ``cv2.FileStorage``.
    """
    if not isinstance(calib, Calibration):
        raise TypeError(f"calib: expected a Calibration, got {type(calib).__name__}")
    if Path(path).suffix.lower() not in _OPENCV_EXTENSIONS:
        raise ValueError(f"path: expected one of {', '.join(_OPENCV_EXTENSIONS)}, got {str(path)!r}")

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
