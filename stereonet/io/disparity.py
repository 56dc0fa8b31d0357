"""Disparity maps on disk: PFM (float, inf = unknown), KITTI 16-bit PNG (value / 256, 0 = invalid),
Middlebury 2001/2003 8-bit PNG/PGM (value / scale, 0 = unknown).

All readers return ``(disparity float32 (H, W), valid bool (H, W))`` with invalid pixels set to 0.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from stereonet.checks import StereoInputError, check_number
from stereonet.io.atomic import atomic_write_bytes
from stereonet.io.errors import existing_file, fail
from stereonet.io.image import encode_image, read_array
from stereonet.io.pfm import read_pfm, write_pfm

KITTI_SCALE = 256.0


def read_disparity(path: str | os.PathLike, scale: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Read a disparity map, format by extension.

    - ``.pfm``: float values; non-finite (Middlebury 2014 uses ``inf``) = invalid. ``scale`` must be None.
    - 16-bit ``.png``/``.pgm``: disparity = value / ``scale`` (default 256, KITTI), 0 = invalid.
    - 8-bit ``.png``/``.pgm``: disparity = value / ``scale``, 0 = unknown; ``scale`` is required because it
      differs per dataset (Middlebury 2001: Tsukuba 16, Venus 8; Middlebury 2003 quarter size: 4).

    Returns:
        ``(disp, valid)``: float32 :math:`(H, W)` (0 where invalid) and bool :math:`(H, W)`.
    """
    p = existing_file(path)
    if p.suffix.lower() == ".pfm":
        if scale is not None:
            raise StereoInputError(f"scale: PFM disparities are stored in pixels, expected scale=None, got {scale}")
        d = read_pfm(p)
        if d.ndim != 2:
            raise fail(p, f"expected a single-channel ('Pf') disparity PFM, got shape {d.shape}")
        valid = np.isfinite(d)
        return np.where(valid, d, 0).astype(np.float32), valid
    raw = read_array(p)
    if raw.ndim != 2:
        raise fail(p, f"expected a single-channel disparity image, got {raw.shape[2]} channels")
    if raw.dtype == np.uint16:
        scale = KITTI_SCALE if scale is None else scale
    elif raw.dtype == np.uint8:
        if scale is None:
            raise StereoInputError(f"scale: {p} is an 8-bit disparity map; pass its scale (Middlebury 2001: "
                             f"Tsukuba 16, Venus 8; Middlebury 2003 quarter size: 4)")
    else:
        raise fail(p, f"expected an 8- or 16-bit disparity image, got {raw.dtype}")
    check_number(scale, "scale", strict=True)
    valid = raw > 0
    return (raw.astype(np.float32) / np.float32(scale)), valid


def _disp_and_valid(disp, valid) -> tuple[np.ndarray, np.ndarray]:
    d = np.asarray(disp.detach().cpu().numpy() if hasattr(disp, "detach") else disp, dtype=np.float64)
    d = d.reshape(d.shape[-2:]) if d.ndim > 2 and int(np.prod(d.shape[:-2])) == 1 else d
    if d.ndim != 2:
        raise StereoInputError(f"disp: expected shape (H, W) (or with leading 1s), got {np.shape(disp)}")
    if valid is None:
        v = np.isfinite(d)
    else:
        v = np.asarray(valid.detach().cpu().numpy() if hasattr(valid, "detach") else valid)
        if v.dtype != np.bool_:
            raise TypeError(f"valid: expected a bool mask, got {v.dtype}")
        if v.size != d.size:
            raise StereoInputError(f"valid: expected {d.shape} like disp, got {v.shape}")
        v = v.reshape(d.shape)
    if not np.isfinite(d[v]).all():
        raise StereoInputError("disp: expected finite values where valid, got NaN or inf")
    if (d[v] < 0).any():
        raise StereoInputError(f"disp: expected disparities >= 0 where valid, got min {d[v].min():.3f}")
    return d, v


def _write_scaled(path, disp, valid, scale: float, dtype) -> None:
    d, v = _disp_and_valid(disp, valid)
    top = np.iinfo(dtype).max
    q = np.rint(d * scale)
    if v.any() and q[v].max() > top:
        raise StereoInputError(f"disp: max {d[v].max():.3f} does not fit in {dtype.__name__} at scale {scale} "
                         f"(limit {top / scale:.3f})")
    q = np.where(v, np.clip(q, 1, top), 0).astype(dtype)  # a valid 0 would read back as invalid: store 1
    atomic_write_bytes(path, encode_image(path, q))


def write_disparity_png16(path: str | os.PathLike, disp, valid=None) -> None:
    """Write a KITTI-style 16-bit PNG (value = round(d * 256), 0 = invalid), atomically.

    Args:
        disp: :math:`(H, W)` (or with leading singleton dims), numpy or torch, >= 0 where valid, < 256.
        valid: bool mask like ``disp`` (default: finite pixels). Valid disparities below 1/512 are stored as
            1/256 so that they stay valid.
    """
    if Path(path).suffix.lower() != ".png":
        raise StereoInputError(f"path: expected a .png file for a 16-bit disparity map, got {str(path)!r}")
    _write_scaled(path, disp, valid, KITTI_SCALE, np.uint16)


def write_disparity_png8(path: str | os.PathLike, disp, valid=None, scale: float = 4.0) -> None:
    """Write a Middlebury-2001/2003-style 8-bit PNG/PGM (value = round(d * scale), 0 = unknown), atomically."""
    if Path(path).suffix.lower() not in (".png", ".pgm"):
        raise StereoInputError(f"path: expected a .png or .pgm file, got {str(path)!r}")
    _write_scaled(path, disp, valid, float(scale), np.uint8)


def write_disparity_pfm(path: str | os.PathLike, disp, valid=None) -> None:
    """Write a float PFM with ``inf`` where invalid (the Middlebury 2014 convention), atomically."""
    d, v = _disp_and_valid(disp, valid)
    write_pfm(path, np.where(v, d, np.inf).astype(np.float32))
