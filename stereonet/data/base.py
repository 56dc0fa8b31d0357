"""The generic pair dataset behind every reader: a list of :class:`PairRecord` (file paths) loaded lazily
into the item dict of DESIGN.md.

Item dict (all tensors float32 / bool on CPU)::

    {"left": (C, H, W), "right": (C, H, W), "disparity": (1, H, W), "valid": (1, H, W) bool,
     "occlusion"?: (1, H, W) bool (True = occluded in the right view), "calib"?: Calibration,
     "name": str, "max_disp": int}

Without ground truth, ``disparity`` is zeros and ``valid`` all False.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import torch
from torch.utils.data import Dataset

from stereonet.calibration import read_calibration
from stereonet.checks import StereoInputError
from stereonet.io import read_array, read_disparity, read_image

DISPARITY_MULTIPLE = 16


@dataclass(frozen=True)
class PairRecord:
    """Where one pair's files are. ``disparity_scale`` applies to 8-bit/16-bit PNG/PGM ground truth.

    Occlusion comes from, in order: ``occlusion_mask`` (read as ``occlusion_mask_kind`` says: Middlebury 2014
    ``mask0nocc.png``, 128 = occluded; ETH3D ``mask0nocc.png``, 255 = visible and any other value on a pixel
    with ground truth = occluded), ``noc_disparity`` (KITTI ``disp_noc``: valid in ``disp_occ`` but not in ``disp_noc`` = occluded), or a
    left-right check of ``disparity`` against the right-view ground truth ``right_disparity``.
    """

    name: str
    left: Path
    right: Path
    disparity: Path | None = None
    disparity_scale: float | None = None
    right_disparity: Path | None = None
    noc_disparity: Path | None = None
    occlusion_mask: Path | None = None
    occlusion_mask_kind: Literal["middlebury2014", "eth3d"] = "middlebury2014"
    calib: Path | None = None


def round_up_max_disp(max_gt: float, width: int) -> int:
    """Disparity range for a ground-truth maximum: rounded up to a multiple of 16 (at least 16),
    capped at ``width - 1`` (every matcher needs ``0 < max_disp < width``)."""
    md = max(DISPARITY_MULTIPLE, DISPARITY_MULTIPLE * math.ceil(max(max_gt, 0.0) / DISPARITY_MULTIPLE))
    return int(max(1, min(md, width - 1)))


def default_max_disp(width: int) -> int:
    """Range when neither calibration nor ground truth says: a quarter of the width, rounded up to 16."""
    return round_up_max_disp(width / 4.0, width)


def occlusion_from_lr_check(disp_left: np.ndarray, valid_left: np.ndarray, disp_right: np.ndarray,
                            valid_right: np.ndarray, tol: float = 1.0) -> np.ndarray:
    """Pixels of the left view that are occluded in the right view, from left and right ground truth.

    A valid left pixel ``(y, x)`` with disparity ``d`` is visible when ``x' = round(x - d)`` is inside the
    image, the right ground truth is known there and ``|d_right(y, x') - d| <= tol``; otherwise occluded.

    Args:
        disp_left, valid_left: left-referenced disparity and mask :math:`(H, W)`.
        disp_right, valid_right: right-referenced disparity (``x_left = x_right + d``) and mask :math:`(H, W)`.
    Returns:
        bool :math:`(H, W)`, True = occluded (always False where ``valid_left`` is False).
    """
    import torch

    from stereonet.select.lr_check import left_right_check  # the one LR rule

    def t(a: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.ascontiguousarray(a))[None, None]

    consistent = left_right_check(t(disp_left.astype(np.float64)), t(disp_right.astype(np.float64)), tol,
                                  valid_right=t(valid_right.astype(bool)))  # float64: x - d as numpy did
    return valid_left & ~consistent[0, 0].numpy()


def same_size(a: Path, a_shape: Sequence[int], b: Path, b_shape: Sequence[int]) -> None:
    """Raise the one-line error naming ``b`` when its ``(H, W)`` differs from that of ``a``."""
    if tuple(a_shape) != tuple(b_shape):
        raise StereoInputError(f"{b}: expected the size of {a.name} (H, W) = {tuple(a_shape)}, got {tuple(b_shape)}")


def load_pair(rec: PairRecord) -> dict:
    """Read one :class:`PairRecord` into the item dict (see the module docstring)."""
    left, right = read_image(rec.left)[0], read_image(rec.right)[0]
    if left.shape != right.shape:
        raise StereoInputError(f"{rec.right}: expected the same shape as {rec.left.name} {tuple(left.shape)} "
                               f"(C, H, W), got {tuple(right.shape)}")
    h, w = left.shape[-2:]
    item: dict = {"left": left, "right": right, "name": rec.name}
    if rec.disparity is not None:
        disp, valid = read_disparity(rec.disparity, rec.disparity_scale)
        same_size(rec.left, (h, w), rec.disparity, disp.shape)
        occ = None
        if rec.occlusion_mask is not None:
            mask = read_array(rec.occlusion_mask)
            mask = mask if mask.ndim == 2 else mask[..., 0]
            same_size(rec.left, (h, w), rec.occlusion_mask, mask.shape)
            occ = valid & (mask != 255 if rec.occlusion_mask_kind == "eth3d" else mask == 128)
        elif rec.noc_disparity is not None:
            _, valid_noc = read_disparity(rec.noc_disparity, rec.disparity_scale)
            same_size(rec.left, (h, w), rec.noc_disparity, valid_noc.shape)
            occ = valid & ~valid_noc
        elif rec.right_disparity is not None:
            disp_r, valid_r = read_disparity(rec.right_disparity, rec.disparity_scale)
            same_size(rec.left, (h, w), rec.right_disparity, disp_r.shape)
            occ = occlusion_from_lr_check(disp, valid, disp_r, valid_r)
        item["disparity"] = torch.from_numpy(disp)[None]
        item["valid"] = torch.from_numpy(valid)[None]
        if occ is not None:
            item["occlusion"] = torch.from_numpy(occ)[None]
    else:
        item["disparity"] = torch.zeros(1, h, w)
        item["valid"] = torch.zeros(1, h, w, dtype=torch.bool)
    if rec.calib is not None:
        item["calib"] = read_calibration(rec.calib)
    item["max_disp"] = item_max_disp(item)
    return item


def item_max_disp(item: dict) -> int:
    """``calib.ndisp`` when known, else the ground-truth maximum rounded up to 16, else a quarter of the
    width; always ``< width``."""
    w = int(item["left"].shape[-1])
    calib = item.get("calib")
    if calib is not None and calib.ndisp:
        return int(max(1, min(int(calib.ndisp), w - 1)))
    top = float(torch.where(item["valid"], item["disparity"], -math.inf).max())
    return round_up_max_disp(top, w) if math.isfinite(top) else default_max_disp(w)


class StereoPairDataset(Dataset):
    """A torch Dataset over :class:`PairRecord` s; files are read on access (``__getitem__``)."""

    def __init__(self, records: Sequence[PairRecord], description: str = ""):
        self.records = list(records)
        self.description = description

    def __len__(self) -> int:
        return len(self.records)

    def __getitem__(self, index: int) -> dict:
        if not -len(self) <= index < len(self):
            raise IndexError(f"index: expected 0 <= index < {len(self)}, got {index}")
        return load_pair(self.records[index])

    @property
    def names(self) -> list[str]:
        return [r.name for r in self.records]

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.description!r}, {len(self)} pairs)"


def collate_stereo(items: Sequence[dict]) -> dict:
    """DataLoader ``collate_fn``: stack tensors of equal shape into batches; keep ``name``, ``calib`` and
    ``max_disp`` as lists (a Calibration is not a tensor)."""
    out: dict = {}
    for key in items[0]:
        values = [it[key] for it in items]
        if isinstance(values[0], torch.Tensor):
            shapes = {tuple(v.shape) for v in values}
            if len(shapes) != 1:
                raise StereoInputError(f"{key}: cannot batch items of different shapes {sorted(shapes)}; "
                                       f"use batch_size=1 or crop")
            out[key] = torch.stack(values)
        else:
            out[key] = values
    return out
