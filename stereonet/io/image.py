"""Image files in and out (PNG, PPM/PGM, JPEG, BMP, TIFF through OpenCV), RGB order in every array.

Files are read as bytes and checked for truncation before decoding (PNG chunk walk with CRCs, Netpbm header
size, JPEG end marker), so a damaged file gives one clear error naming it instead of a silent partial image.
"""

from __future__ import annotations

import os
import re
import zlib
from pathlib import Path

import cv2
import numpy as np
import torch

from stereonet.checks import StereoInputError
from stereonet.io.atomic import atomic_write_bytes
from stereonet.io.errors import existing_file, fail

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_NETPBM_CHANNELS = {b"P5": 1, b"P6": 3}


def _check_png(data: bytes, path: Path) -> None:
    """Walk the PNG chunks: every chunk complete, CRCs correct, IEND present."""
    pos = len(_PNG_SIGNATURE)
    while True:
        if pos + 8 > len(data):
            raise fail(path, f"truncated PNG: file ends at byte {len(data)} before the IEND chunk")
        length = int.from_bytes(data[pos:pos + 4], "big")
        ctype = data[pos + 4:pos + 8]
        end = pos + 12 + length
        if end > len(data):
            raise fail(path, f"truncated PNG: chunk {ctype.decode('latin-1')!r} needs {length + 12} bytes, "
                             f"only {len(data) - pos} left")
        crc = int.from_bytes(data[end - 4:end], "big")
        if zlib.crc32(data[pos + 4:end - 4]) != crc:
            raise fail(path, f"corrupt PNG: CRC mismatch in chunk {ctype.decode('latin-1')!r} at byte {pos}")
        if ctype == b"IEND":
            return
        pos = end


def _netpbm_header(data: bytes, path: Path) -> tuple[int, int, int, int, int]:
    """Parse a binary P5/P6 header -> (width, height, maxval, channels, data offset)."""
    tokens: list[bytes] = []
    pos = 2
    n = len(data)
    while len(tokens) < 3:
        m = re.compile(rb"(?:\s|#[^\n]*\n?)*").match(data, pos)
        pos = m.end()
        m = re.compile(rb"[^\s#]+").match(data, pos)
        if m is None or m.end() >= n:
            raise fail(path, f"truncated or corrupt Netpbm header (read {len(tokens)} of 3 fields)")
        tokens.append(m.group())
        pos = m.end()
    try:
        width, height, maxval = (int(t) for t in tokens)
    except ValueError:
        raise fail(path, f"corrupt Netpbm header: expected integers, got {tokens}") from None
    if width <= 0 or height <= 0 or not 0 < maxval < 65536:
        raise fail(path, f"corrupt Netpbm header: width {width}, height {height}, maxval {maxval}")
    return width, height, maxval, _NETPBM_CHANNELS[data[:2]], pos + 1


def _check_netpbm(data: bytes, path: Path) -> None:
    width, height, maxval, channels, offset = _netpbm_header(data, path)
    expected = width * height * channels * (1 if maxval < 256 else 2)
    got = len(data) - offset
    if got < expected:
        raise fail(path, f"truncated, expected {expected} bytes of data, got {got}")


_JPEG_SOF = set(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}  # start-of-frame markers (not DHT, JPG, DAC)


def _check_jpeg(data: bytes, path: Path) -> int:
    """Walk the JPEG segments up to the first scan, then require an end-of-image marker after it.

    Data after the end marker (phones append vendor blocks, MPF previews) is allowed; a thumbnail's own
    end marker inside an APP segment is skipped with its segment. Returns the number of colour components
    of the frame (1 = grey, 3 = colour)."""
    pos, n, components = 2, len(data), 0
    while True:
        while pos < n and data[pos] == 0xFF and pos + 1 < n and data[pos + 1] == 0xFF:
            pos += 1  # fill bytes
        if pos + 4 > n or data[pos] != 0xFF:
            raise fail(path, f"truncated or corrupt JPEG: no segment marker at byte {pos} of {n}")
        marker, length = data[pos + 1], int.from_bytes(data[pos + 2:pos + 4], "big")
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:  # stand-alone markers
            pos += 2
            continue
        if length < 2 or pos + 2 + length > n:
            raise fail(path, f"truncated JPEG: segment FF{marker:02X} at byte {pos} needs {length} bytes, "
                             f"{n - pos - 2} left")
        if marker in _JPEG_SOF and length >= 8:
            components = data[pos + 9]
        pos += 2 + length
        if marker == 0xDA:  # start of scan: entropy-coded data follows, up to EOI (FFD9)
            break
    if data.find(b"\xff\xd9", pos) < 0:
        raise fail(path, "truncated JPEG: no end-of-image marker (FFD9) after the image data")
    return components


def read_array(path: str | os.PathLike) -> np.ndarray:
    """Decode an image file as stored: uint8/uint16 :math:`(H, W)` or :math:`(H, W, 3|4)` in **BGR(A)** order.

    The lowest-level reader (used for disparity PNG/PGM); most callers want :func:`read_image`.
    """
    p = existing_file(path)
    data = p.read_bytes()
    if not data:
        raise fail(p, "empty file")
    if data.startswith(_PNG_SIGNATURE):
        _check_png(data, p)
    elif data[:2] in _NETPBM_CHANNELS:
        _check_netpbm(data, p)
    flags = cv2.IMREAD_UNCHANGED
    if data[:2] == b"\xff\xd8":
        # decoded with the EXIF orientation applied (IMREAD_UNCHANGED would ignore it); JPEG is 8-bit
        flags = cv2.IMREAD_GRAYSCALE if _check_jpeg(data, p) == 1 else cv2.IMREAD_COLOR
    try:
        arr = cv2.imdecode(np.frombuffer(data, np.uint8), flags)
    except cv2.error as e:  # e.g. a header that claims more pixels than OpenCV decodes
        raise fail(p, f"cannot decode as an image ({str(e).strip().splitlines()[-1]})") from None
    if arr is None:
        raise fail(p, f"cannot decode as an image (starts with {data[:8]!r}; expected PNG, PPM/PGM, JPEG, BMP or TIFF)")
    return arr


def read_image(path: str | os.PathLike) -> torch.Tensor:
    """Read an image as a float32 tensor :math:`(1, C, H, W)` in [0, 1].

    C = 3 (RGB order) for colour files (an alpha channel is dropped), C = 1 for greyscale files.
    8-bit values are divided by 255, 16-bit by 65535.
    """
    arr = read_array(path)
    if arr.dtype == np.uint8:
        scale = 255.0
    elif arr.dtype == np.uint16:
        scale = 65535.0
    elif arr.dtype in (np.float32, np.float64):
        scale = 1.0
    else:
        raise fail(path, f"unsupported pixel type {arr.dtype} (expected 8-bit, 16-bit or float)")
    if arr.ndim == 3:
        if arr.shape[2] == 4:
            arr = cv2.cvtColor(arr, cv2.COLOR_BGRA2RGB)
        elif arr.shape[2] == 3:
            arr = cv2.cvtColor(arr, cv2.COLOR_BGR2RGB)
        elif arr.shape[2] == 1:
            arr = arr[:, :, 0]
        else:
            raise fail(path, f"unsupported channel count {arr.shape[2]} (expected 1, 3 or 4)")
    img = torch.from_numpy(np.ascontiguousarray(arr).astype(np.float32) / np.float32(scale))
    img = img[None, None] if img.dim() == 2 else img.permute(2, 0, 1)[None]  # 1xCxHxW
    return img


def to_uint8_rgb(img, name: str = "img") -> np.ndarray:
    """Convert an image to a uint8 numpy array :math:`(H, W)` or :math:`(H, W, 3)`, RGB order.

    Accepts a float tensor :math:`(1, C, H, W)` / :math:`(C, H, W)` / :math:`(H, W)` in [0, 1] (C = 1 or 3;
    values are clamped and rounded), or a numpy array :math:`(H, W)` / :math:`(H, W, 3)`: uint8 as is, float
    in [0, 1] scaled by 255.
    """
    if isinstance(img, torch.Tensor):
        t = img.detach().cpu()
        if t.dim() == 4:
            if t.shape[0] != 1:
                raise StereoInputError(f"{name}: expected a single image (1, C, H, W), got {tuple(t.shape)}")
            t = t[0]
        if t.dim() == 3:
            if t.shape[0] not in (1, 3):
                raise StereoInputError(f"{name}: expected 1 or 3 channels in (C, H, W), got {tuple(t.shape)}")
            t = t.permute(1, 2, 0)  # HxWxC
        elif t.dim() != 2:
            raise StereoInputError(f"{name}: expected shape (1, C, H, W), (C, H, W) or (H, W), got {tuple(img.shape)}")
        if not t.is_floating_point():
            if t.dtype != torch.uint8:
                raise TypeError(f"{name}: expected a float tensor in [0, 1] or uint8, got {t.dtype}")
            arr = t.numpy()
        else:
            if not bool(torch.isfinite(t).all()):
                raise StereoInputError(f"{name}: expected finite values, got NaN or inf")
            arr = (t.float().clamp(0, 1) * 255.0 + 0.5).to(torch.uint8).numpy()
    else:
        arr = np.asarray(img)
        if arr.dtype != np.uint8:
            if not np.issubdtype(arr.dtype, np.floating):
                raise TypeError(f"{name}: expected a uint8 or float array, got {arr.dtype}")
            if not np.isfinite(arr).all():
                raise StereoInputError(f"{name}: expected finite values, got NaN or inf")
            arr = (np.clip(arr, 0, 1) * 255.0 + 0.5).astype(np.uint8)
    if arr.ndim == 3 and arr.shape[2] == 1:
        arr = arr[:, :, 0]
    if not (arr.ndim == 2 or (arr.ndim == 3 and arr.shape[2] == 3)) or arr.size == 0:
        raise StereoInputError(f"{name}: expected shape (H, W) or (H, W, 3), got {arr.shape}")
    return np.ascontiguousarray(arr)


def encode_image(path: str | os.PathLike, arr: np.ndarray) -> bytes:
    """Encode a uint8/uint16 array (RGB order for colour) in the format named by ``path``'s extension."""
    ext = Path(path).suffix.lower()
    if not ext:
        raise StereoInputError(f"path: expected a file extension (.png, .ppm, .pgm, .jpg...), got {str(path)!r}")
    if arr.ndim == 3:
        arr = cv2.cvtColor(arr, cv2.COLOR_RGB2BGR)
    if ext == ".pgm" and arr.ndim == 3:
        raise StereoInputError(f"{path}: a .pgm file holds a greyscale image, got a colour one")
    try:
        ok, buf = cv2.imencode(ext, arr)
    except cv2.error as e:
        raise StereoInputError(f"{path}: OpenCV cannot write extension {ext!r} ({e.msg.strip() if hasattr(e, 'msg') else e})") from None
    if not ok:
        raise StereoInputError(f"{path}: OpenCV failed to encode the image as {ext}")
    return buf.tobytes()


def write_image(path: str | os.PathLike, img) -> None:
    """Write an image atomically; the format follows the extension (.png, .ppm, .pgm, .jpg, .bmp, .tif).

    Args:
        img: float tensor :math:`(1, C, H, W)` or :math:`(C, H, W)` in [0, 1] (C = 1 or 3, RGB), or a numpy
            uint8 array :math:`(H, W)` / :math:`(H, W, 3)` in RGB order (see :func:`to_uint8_rgb`).
    """
    atomic_write_bytes(path, encode_image(path, to_uint8_rgb(img)))
