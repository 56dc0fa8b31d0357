"""Portable Float Map (PFM) read/write.

Format: a text header ``PF`` (3 channels) or ``Pf`` (1 channel), then ``width height``, then a scale whose
sign gives the byte order (negative = little-endian, positive = big-endian), each followed by whitespace
(a single whitespace byte after the scale), then ``height`` rows of float32 stored **bottom row first**.
Arrays returned here are top row first, as images are everywhere else in stereonet.
"""

from __future__ import annotations

import os

import numpy as np

from stereonet.checks import StereoInputError
from stereonet.io.atomic import atomic_write_bytes
from stereonet.io.errors import existing_file, fail

_WHITESPACE = b" \t\r\n"
_MAX_HEADER = 256


def _header_tokens(data: bytes, path) -> tuple[list[bytes], int]:
    """The four header fields (magic, width, height, scale) and the offset of the first data byte."""
    tokens: list[bytes] = []
    i = 0
    n = min(len(data), _MAX_HEADER)
    while len(tokens) < 4:
        while i < n and data[i] in _WHITESPACE:
            i += 1
        start = i
        while i < n and data[i] not in _WHITESPACE:
            i += 1
        if i >= n:
            raise fail(path, f"truncated or corrupt PFM header (read {len(tokens)} of 4 header fields)")
        tokens.append(data[start:i])
    return tokens, i + 1  # exactly one whitespace byte ends the header


def read_pfm(path: str | os.PathLike) -> np.ndarray:
    """Read a PFM file.

    Returns:
        float32 array :math:`(H, W)` for ``Pf`` or :math:`(H, W, 3)` for ``PF``, top row first, native byte
        order. Infinite values (Middlebury's "unknown") are kept as they are.

    Raises:
        FileNotFoundError: ``path`` does not exist.
        FileFormatError: bad magic, malformed size/scale, or truncated data (the message names the file).
    """
    p = existing_file(path)
    data = p.read_bytes()
    if data[:2] not in (b"PF", b"Pf") or (len(data) > 2 and data[2] not in _WHITESPACE):
        raise fail(p, f"not a PFM file: expected magic 'PF' or 'Pf', got {data[:3]!r}")
    (magic, w_tok, h_tok, s_tok), start = _header_tokens(data, p)
    try:
        width, height = int(w_tok), int(h_tok)
    except ValueError:
        raise fail(p, f"corrupt PFM header: expected integer width and height, got {w_tok!r} {h_tok!r}") from None
    try:
        scale = float(s_tok)
    except ValueError:
        raise fail(p, f"corrupt PFM header: expected a float scale, got {s_tok!r}") from None
    if width <= 0 or height <= 0:
        raise fail(p, f"corrupt PFM header: expected positive width and height, got {width}x{height}")
    if scale == 0 or not np.isfinite(scale):
        raise fail(p, f"corrupt PFM header: expected a non-zero finite scale (its sign is the byte order), got {scale}")
    channels = 3 if magic == b"PF" else 1
    expected = width * height * channels * 4
    if data[start - 1:start + 1] == b"\r\n" and len(data) - start - 1 == expected:
        start += 1  # a header written with Windows line ends
    got = len(data) - start
    if got < expected:
        raise fail(p, f"truncated, expected {expected} bytes of data, got {got}")
    dtype = np.dtype("<f4") if scale < 0 else np.dtype(">f4")
    arr = np.frombuffer(data, dtype=dtype, count=width * height * channels, offset=start)
    arr = arr.reshape(height, width, channels)[::-1]  # file rows are bottom to top
    arr = arr.astype(np.float32)  # native byte order, own memory, writable
    return arr[:, :, 0] if channels == 1 else arr


def write_pfm(path: str | os.PathLike, arr, little_endian: bool = True) -> None:
    """Write ``arr`` as PFM, atomically.

    Args:
        arr: array-like (numpy or torch) :math:`(H, W)`, :math:`(H, W, 1)`, :math:`(H, W, 3)`, or with leading
            singleton dimensions such as :math:`(1, 1, H, W)` / :math:`(1, H, W)`; stored as float32, top row
            first in ``arr`` (the file holds it bottom row first, as the format demands).
        little_endian: byte order; written as the sign of the scale (-1 little, +1 big).
    """
    a = _as_numpy(arr)
    if a.ndim == 3 and a.shape[2] in (1, 3):
        pass
    else:
        while a.ndim > 2 and a.shape[0] == 1:
            a = a[0]
        if a.ndim == 3 and a.shape[0] in (1, 3) and a.shape[2] not in (1, 3):
            a = np.moveaxis(a, 0, -1)  # CxHxW -> HxWxC
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[:, :, 0]
    if a.ndim not in (2, 3) or (a.ndim == 3 and a.shape[2] != 3) or a.size == 0:
        raise StereoInputError(f"arr: expected shape (H, W) or (H, W, 3), got {tuple(np.shape(arr))}")
    channels = 1 if a.ndim == 2 else 3
    h, w = a.shape[:2]
    header = f"{'Pf' if channels == 1 else 'PF'}\n{w} {h}\n{-1.0 if little_endian else 1.0}\n".encode("ascii")
    body = np.ascontiguousarray(a[::-1], dtype="<f4" if little_endian else ">f4").tobytes()
    atomic_write_bytes(path, header + body)


def _as_numpy(arr) -> np.ndarray:
    if hasattr(arr, "detach"):
        arr = arr.detach().cpu().numpy()
    return np.asarray(arr)
