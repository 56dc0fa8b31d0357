"""File I/O: images, disparity maps (PFM, KITTI 16-bit PNG, Middlebury 8-bit PNG/PGM), PLY point clouds.

Every writer is atomic (through :mod:`stereonet.io.atomic`); every reader raises ``FileNotFoundError`` naming
a missing file and :class:`FileFormatError` (a ``StereoInputError``) naming a truncated or corrupt one.
"""

from stereonet.io.atomic import atomic_path, atomic_write_bytes, atomic_write_text
from stereonet.io.disparity import (
    read_disparity,
    write_disparity_pfm,
    write_disparity_png8,
    write_disparity_png16,
)
from stereonet.io.errors import FileFormatError
from stereonet.io.image import read_array, read_image, to_uint8_rgb, write_image
from stereonet.io.pfm import read_pfm, write_pfm
from stereonet.io.ply import read_ply, write_ply

__all__ = [
    "FileFormatError", "atomic_path", "atomic_write_bytes", "atomic_write_text", "read_array",
    "read_disparity", "read_image", "read_pfm", "read_ply", "to_uint8_rgb", "write_disparity_pfm",
    "write_disparity_png8", "write_disparity_png16", "write_image", "write_pfm", "write_ply",
]
