"""Stereo rig calibration from chessboard (or ChArUco) views, on OpenCV, to a :class:`Calibration`.

    stereonet-calibrate LEFT RIGHT --board COLSxROWS --square SIZE -o CALIB.yaml
    python -m stereonet.calibrate LEFT RIGHT --board COLSxROWS --square SIZE -o CALIB.yaml

writes the OpenCV FileStorage YAML that ``infer.py --calib`` reads (:func:`stereonet.calibration.
read_calibration`) and a rectified preview with epipolar lines (the command line is
:mod:`stereonet.cli.calibrate`). The library:

- :mod:`~stereonet.calibrate.board`: :class:`Board` (inner corners, square size, optional ChArUco
  dictionary), :func:`detect_board` -> :class:`Detection` (corner ids and sub-pixel points);
- :mod:`~stereonet.calibrate.solve`: :func:`calibrate_rig` (each camera, then the pair; outlier views
  dropped) -> :class:`RigCalibration` with a :class:`ViewReport` per view;
- :mod:`~stereonet.calibrate.preview`: :func:`rectified_preview`.
"""

from stereonet.calibrate.board import Board, Detection, align_detection, detect_board, parse_board_size
from stereonet.calibrate.preview import Preview, rectified_preview
from stereonet.calibrate.solve import (
    CalibrationError,
    RigCalibration,
    ViewReport,
    calibrate_rig,
    outlier_views,
)

__all__ = [
    "Board", "CalibrationError", "Detection", "Preview", "RigCalibration", "ViewReport", "align_detection",
    "calibrate_rig", "detect_board", "outlier_views", "parse_board_size", "rectified_preview",
]
