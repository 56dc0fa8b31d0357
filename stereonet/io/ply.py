"""PLY point clouds: binary little-endian writer (x, y, z float32; red, green, blue uchar), as Open3D,
MeshLab and CloudCompare read them, and a reader for the vertex element of binary or ASCII PLY files.
"""

from __future__ import annotations

import os

import numpy as np

from stereonet.checks import StereoInputError
from stereonet.io.atomic import atomic_write_bytes
from stereonet.io.errors import existing_file, fail

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}


def write_ply(path: str | os.PathLike, points, colors=None) -> None:
    """Write a binary little-endian PLY point cloud, atomically.

    Args:
        points: :math:`(N, 3)` float (numpy or torch), finite; stored as float32.
        colors: optional :math:`(N, 3)` uint8 RGB (a float array in [0, 1] is scaled by 255).
    """
    pts = np.asarray(points.detach().cpu().numpy() if hasattr(points, "detach") else points)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise StereoInputError(f"points: expected shape (N, 3), got {pts.shape}")
    if not np.isfinite(pts).all():
        raise StereoInputError("points: expected finite coordinates, got NaN or inf")
    n = pts.shape[0]
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    props = "property float x\nproperty float y\nproperty float z\n"
    if colors is not None:
        col = np.asarray(colors.detach().cpu().numpy() if hasattr(colors, "detach") else colors)
        if col.shape != (n, 3):
            raise StereoInputError(f"colors: expected shape ({n}, 3) like points, got {col.shape}")
        if col.dtype != np.uint8:
            if not np.issubdtype(col.dtype, np.floating):
                raise TypeError(f"colors: expected uint8 or float in [0, 1], got {col.dtype}")
            col = (np.clip(col, 0, 1) * 255 + 0.5).astype(np.uint8)
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
        props += "property uchar red\nproperty uchar green\nproperty uchar blue\n"
    rec = np.empty(n, dtype=np.dtype(fields))
    rec["x"], rec["y"], rec["z"] = pts[:, 0], pts[:, 1], pts[:, 2]
    if colors is not None:
        rec["red"], rec["green"], rec["blue"] = col[:, 0], col[:, 1], col[:, 2]
    header = (f"ply\nformat binary_little_endian 1.0\ncomment written by stereonet\nelement vertex {n}\n"
              f"{props}end_header\n").encode("ascii")
    atomic_write_bytes(path, header + rec.tobytes())


def _parse_header(data: bytes, path) -> tuple[str, list[tuple[str, int, list]], int]:
    """-> (format, [(element name, count, [(prop name, dtype or None for lists)])], data offset)."""
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise fail(path, "not a PLY file (expected 'ply' ... 'end_header')")
    nl = data.find(b"\n", end)
    if nl < 0:
        raise fail(path, "truncated PLY header (no newline after end_header)")
    fmt = None
    elements: list[tuple[str, int, list]] = []
    for line in data[:end].decode("ascii", errors="replace").splitlines()[1:]:
        parts = line.split()
        if not parts or parts[0] in ("comment", "obj_info"):
            continue
        if parts[0] == "format" and len(parts) >= 2:
            fmt = parts[1]
        elif parts[0] == "element" and len(parts) == 3:
            try:
                elements.append((parts[1], int(parts[2]), []))
            except ValueError:
                raise fail(path, f"corrupt PLY header line {line!r}") from None
        elif parts[0] == "property" and elements:
            if parts[1] == "list":
                elements[-1][2].append((parts[-1], None))
            elif len(parts) == 3 and parts[1] in _PLY_TYPES:
                elements[-1][2].append((parts[2], _PLY_TYPES[parts[1]]))
            else:
                raise fail(path, f"unsupported PLY property line {line!r}")
        else:
            raise fail(path, f"corrupt PLY header line {line!r}")
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise fail(path, f"unsupported PLY format {fmt!r}")
    return fmt, elements, nl + 1


def read_ply(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray | None]:
    """Read the vertices of a PLY file.

    Returns:
        ``(points, colors)``: float32 :math:`(N, 3)` and uint8 :math:`(N, 3)` RGB, or None when the file has
        no red/green/blue properties. Elements after ``vertex`` (faces...) are ignored; elements before it
        must have fixed-size properties.
    """
    p = existing_file(path)
    data = p.read_bytes()
    fmt, elements, offset = _parse_header(data, p)
    names = [e[0] for e in elements]
    if "vertex" not in names:
        raise fail(p, "PLY file has no 'vertex' element")
    order = "<" if fmt == "binary_little_endian" else ">"
    vertex = None
    if fmt == "ascii":
        lines = data[offset:].decode("ascii", errors="replace").splitlines()
        row = 0
        for name, count, props in elements:
            if name == "vertex":
                if any(t is None for _, t in props):
                    raise fail(p, "list properties in the vertex element are not supported")
                chunk = lines[row:row + count]
                if len(chunk) < count:
                    raise fail(p, f"truncated, expected {count} vertex lines, got {len(chunk)}")
                try:
                    table = np.array([[float(v) for v in ln.split()[:len(props)]] for ln in chunk], dtype=np.float64)
                except ValueError:
                    raise fail(p, "corrupt ASCII vertex data") from None
                if table.shape != (count, len(props)):
                    raise fail(p, f"corrupt ASCII vertex data: expected {len(props)} values per line")
                vertex = {pn: table[:, i].astype(t) for i, (pn, t) in enumerate(props)}
                break
            row += count
    else:
        for name, count, props in elements:
            if any(t is None for _, t in props):
                raise fail(p, f"list properties before the vertex element ({name!r}) are not supported")
            dt = np.dtype([(pn, order + t) for pn, t in props])
            nbytes = dt.itemsize * count
            if name == "vertex":
                got = len(data) - offset
                if got < nbytes:
                    raise fail(p, f"truncated, expected {nbytes} bytes of vertex data, got {got}")
                vertex = np.frombuffer(data, dtype=dt, count=count, offset=offset)
                break
            offset += nbytes
    assert vertex is not None
    for axis in ("x", "y", "z"):
        if axis not in (vertex.dtype.names if isinstance(vertex, np.ndarray) else vertex):
            raise fail(p, f"PLY vertex element has no {axis!r} property")
    points = np.stack([np.asarray(vertex[a], dtype=np.float32) for a in ("x", "y", "z")], axis=1)
    keys = vertex.dtype.names if isinstance(vertex, np.ndarray) else tuple(vertex)
    colors = None
    if all(c in keys for c in ("red", "green", "blue")):
        colors = np.stack([np.asarray(vertex[c]) for c in ("red", "green", "blue")], axis=1)
        if colors.dtype != np.uint8:
            colors = np.clip(colors, 0, 255).astype(np.uint8)
    return points, colors
