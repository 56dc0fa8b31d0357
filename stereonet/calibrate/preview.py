"""The check picture of a calibration: one view rectified with it, epipolar lines and the board corners.

The pair is rectified by :func:`stereonet.geometry.rectify_calibrated`, the same call ``infer.py --calib``
makes, so the picture shows what inference will see. In a rectified pair every corner lies on the same row
in both images; the row error of the board corners (mapped by :func:`stereonet.geometry.rectify_points`)
measures how well the calibration rectifies.
"""

from __future__ import annotations

from typing import NamedTuple

import cv2
import numpy as np
import torch

from stereonet.calibrate.board import Detection
from stereonet.types import Calibration

__all__ = ["Preview", "rectified_preview"]


class Preview(NamedTuple):
    """``image``: uint8 RGB :math:`(H', 2 W', 3)`, rectified left | right with lines and corners;
    ``row_error_px``: median ``|y_left - y_right|`` of the corners both images hold, after rectification."""

    image: np.ndarray
    row_error_px: float


def rectified_preview(left: torch.Tensor, right: torch.Tensor, calib: Calibration, left_corners: Detection,
                      right_corners: Detection, lines: int = 16) -> Preview:
    """Rectify one calibration view and draw it (see the module docstring).

    Args:
        left, right: the view's images :math:`(1, C, H, W)` float in [0, 1] (C = 1 or 3).
        calib: the rig; left_corners, right_corners: the board corners found in each image.
        lines: number of bands the horizontal epipolar lines cut the image into.
    """
    from stereonet.geometry import rectify_calibrated, rectify_points
    from stereonet.io import to_uint8_rgb

    rect = rectify_calibrated(left, right, calib)
    ids, il, ir = np.intersect1d(left_corners.ids, right_corners.ids, return_indices=True)
    pl = rectify_points(torch.from_numpy(left_corners.points[il].astype(np.float64)), rect, "left").numpy()
    pr = rectify_points(torch.from_numpy(right_corners.points[ir].astype(np.float64)), rect, "right").numpy()
    dy = np.abs(pl[:, 1] - pr[:, 1])
    row_error = float(np.median(dy)) if len(dy) else float("nan")

    def rgb(img: torch.Tensor) -> np.ndarray:
        a = to_uint8_rgb(img[:1])
        return np.repeat(a[:, :, None], 3, axis=2) if a.ndim == 2 else a

    a, b = rgb(rect.left), rgb(rect.right)
    h, w = a.shape[:2]
    canvas = np.ascontiguousarray(np.concatenate([a, b], axis=1))
    for k in range(1, lines):
        y = int(round(k * h / lines))
        cv2.line(canvas, (0, y), (2 * w - 1, y), (0, 255, 255) if k % 2 else (255, 0, 255), 1, cv2.LINE_AA)
    cv2.line(canvas, (w, 0), (w, h - 1), (255, 255, 255), 1)
    for (xl, yl), (xr, yr), e in zip(pl, pr, dy):
        colour = (0, 200, 0) if e <= 0.5 else (255, 128, 0) if e <= 2 else (255, 0, 0)
        cv2.circle(canvas, (int(round(xl)), int(round(yl))), 3, colour, 1, cv2.LINE_AA)
        cv2.circle(canvas, (int(round(xr)) + w, int(round(yr))), 3, colour, 1, cv2.LINE_AA)
    text = (f"{len(dy)} corners, median row error {row_error:.2f} px" if len(dy) else "no common corners")
    for colour, thickness in (((0, 0, 0), 3), ((255, 255, 255), 1)):
        cv2.putText(canvas, text, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, colour, thickness, cv2.LINE_AA)
    return Preview(canvas, row_error)
