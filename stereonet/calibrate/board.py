"""Calibration targets and their detection: a chessboard or a ChArUco board, corners in pixels.

A board has ``cols x rows`` *inner* corners (the points where four squares meet), ``square`` apart in the
unit wanted for depth. Corner ``id = j * cols + i`` (column ``i < cols``, row ``j < rows``) sits at
``board.object_points()[id]`` on the plane ``Z = 0`` of the board. A ChArUco board with the same inner
corners has ``(cols + 1) x (rows + 1)`` squares, ArUco markers of side ``marker`` in its white squares and
OpenCV's corner ids and positions (``cv2.aruco.CharucoBoard.getChessboardCorners``); it can be seen in part.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np

from stereonet.checks import StereoInputError

__all__ = ["Board", "Detection", "align_detection", "detect_board", "parse_board_size"]

# Fewest ChArUco corners that make a view (OpenCV's planar calibration needs 4 non-collinear points; 8 keep
# a partial view from being a near-degenerate line of corners).
MIN_CHARUCO_CORNERS = 8


def parse_board_size(text: str) -> tuple[int, int]:
    """``"9x6"`` -> ``(9, 6)``: inner corners ``COLSxROWS``, each at least 2."""
    m = re.fullmatch(r"\s*(\d+)\s*[xX*,]\s*(\d+)\s*", str(text))
    if m is None:
        raise StereoInputError(f"--board: expected inner corners as COLSxROWS (e.g. 9x6), got {text!r}")
    cols, rows = int(m.group(1)), int(m.group(2))
    if cols < 2 or rows < 2:
        raise StereoInputError(f"--board: expected at least 2x2 inner corners, got {cols}x{rows}")
    return cols, rows


@dataclass(frozen=True)
class Board:
    """A planar target: ``cols x rows`` inner corners ``square`` apart.

    ``dictionary`` (an OpenCV ArUco dictionary name such as ``"DICT_4X4_50"``) makes it a ChArUco board with
    markers of side ``marker`` (default ``0.75 * square``); None is a plain chessboard.
    """

    cols: int
    rows: int
    square: float
    dictionary: str | None = None
    marker: float | None = None

    def __post_init__(self) -> None:
        if int(self.cols) < 2 or int(self.rows) < 2:
            raise StereoInputError(f"board: expected at least 2x2 inner corners, got {self.cols}x{self.rows}")
        if not float(self.square) > 0:
            raise StereoInputError(f"square: expected a positive size, got {self.square}")
        if self.dictionary is not None:
            if not hasattr(cv2.aruco, self.dictionary) or not self.dictionary.startswith("DICT_"):
                names = ", ".join(n for n in dir(cv2.aruco) if n.startswith("DICT_") and n == n.upper())
                raise StereoInputError(f"charuco dictionary: expected one of {names}, got {self.dictionary!r}")
            marker = 0.75 * self.square if self.marker is None else float(self.marker)
            if not 0 < marker < self.square:
                raise StereoInputError(f"marker: expected a size between 0 and the square ({self.square}), got {marker}")
            object.__setattr__(self, "marker", marker)

    @property
    def kind(self) -> str:
        return "chessboard" if self.dictionary is None else "charuco"

    @property
    def corners(self) -> int:
        return self.cols * self.rows

    def describe(self) -> str:
        what = "chessboard" if self.dictionary is None else f"ChArUco board ({self.dictionary})"
        return f"{what} of {self.cols}x{self.rows} inner corners"

    def object_points(self) -> np.ndarray:
        """Corner positions on the board, :math:`(cols \\cdot rows, 3)` float32, row-major (``id = j*cols + i``)."""
        if self.dictionary is not None:
            return np.asarray(self.charuco().getChessboardCorners(), dtype=np.float32).reshape(-1, 3)
        j, i = np.mgrid[0:self.rows, 0:self.cols]
        pts = np.stack([i.ravel(), j.ravel(), np.zeros(i.size)], axis=1) * float(self.square)
        return pts.astype(np.float32)

    def charuco(self):
        """The ``cv2.aruco.CharucoBoard`` of a ChArUco board (``(cols + 1) x (rows + 1)`` squares)."""
        if self.dictionary is None:
            raise StereoInputError("board: a chessboard has no ChArUco board (give a dictionary)")
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((self.cols + 1, self.rows + 1), float(self.square), float(self.marker),
                                      dictionary)


MIN_DETECT_SIDE = 16
"""px: a smaller image cannot show a board (three pixels per square at least); :func:`detect_board` finds none."""


class Detection(NamedTuple):
    """Corners of a board found in one image: ``ids`` :math:`(N,)` int into ``Board.object_points()`` and
    their sub-pixel positions ``points`` :math:`(N, 2)` float32 (pixel centres at integer coordinates)."""

    ids: np.ndarray
    points: np.ndarray


def detect_board(board: Board, gray: np.ndarray) -> Detection | None:
    """Find ``board`` in a greyscale uint8 image :math:`(H, W)`; None when it is not found (in full, for a
    chessboard; with at least ``MIN_CHARUCO_CORNERS`` corners, for ChArUco).

    Chessboard: ``cv2.findChessboardCorners``, falling back to the sector-based ``cv2.findChessboardCornersSB``
    (more robust, ~20x slower), then ``cv2.cornerSubPix`` with a window sized to the corner spacing (on
    rendered boards with known corners: 0.04 px mean error, against 0.066 px for ``findChessboardCornersSB``
    alone).
    ChArUco: ``cv2.aruco.CharucoDetector.detectBoard`` (markers, then interpolated sub-pixel corners).
    """
    gray = np.asarray(gray)
    if gray.ndim != 2 or gray.dtype != np.uint8:
        raise StereoInputError(f"gray: expected a uint8 (H, W) image, got {gray.dtype} {gray.shape}")
    if min(gray.shape) < MIN_DETECT_SIDE or min(gray.shape) < 3 * (min(board.rows, board.cols) + 1):
        return None  # too small to show the board (and below what OpenCV's adaptive threshold accepts)
    if board.dictionary is not None:
        corners, ids, _, _ = cv2.aruco.CharucoDetector(board.charuco()).detectBoard(gray)
        if ids is None or len(ids) < MIN_CHARUCO_CORNERS:
            return None
        return Detection(ids.reshape(-1).astype(np.int64), corners.reshape(-1, 2).astype(np.float32))
    size = (board.cols, board.rows)
    found, corners = cv2.findChessboardCorners(
        gray, size, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
    if not found:  # the sector-based detector copes better with blur, noise and uneven light (and is slower)
        found, corners = cv2.findChessboardCornersSB(gray, size, flags=cv2.CALIB_CB_NORMALIZE_IMAGE)
        if not found:
            return None
    grid = corners.reshape(board.rows, board.cols, 2)
    spacing = min(np.linalg.norm(np.diff(grid, axis=0), axis=-1).min(),
                  np.linalg.norm(np.diff(grid, axis=1), axis=-1).min())
    half = int(np.clip(spacing * 0.4, 2, 11))  # the window must not reach the next corner
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 1e-3)
    corners = cv2.cornerSubPix(gray, corners.astype(np.float32), (half, half), (-1, -1), criteria)
    return Detection(np.arange(board.corners, dtype=np.int64), corners.reshape(-1, 2).astype(np.float32))


def align_detection(board: Board, reference: Detection, other: Detection) -> Detection:
    """``other`` with its chessboard corner ids renumbered by the board symmetry that best agrees with
    ``reference`` (the same view seen by the other camera).

    A chessboard's corner order is only defined up to a half turn (a quarter turn too when cols == rows), and
    OpenCV may pick a different one in each camera; the stereo calibration needs the same corner to carry
    the same id in both. The symmetry kept is the one whose row and column directions in the image point
    the same way as the reference's (cameras of a rig differ by much less than a quarter turn of roll).
    ChArUco ids are unique, so ChArUco detections are returned as they are.
    """
    if board.dictionary is not None or len(other.ids) != board.corners or len(reference.ids) != board.corners:
        return other
    order = np.argsort(reference.ids)
    ref = reference.points[order].reshape(board.rows, board.cols, 2)
    grid = other.points[np.argsort(other.ids)].reshape(board.rows, board.cols, 2)
    candidates = [grid, grid[::-1, ::-1]]
    if board.cols == board.rows:
        candidates += [np.rot90(grid, 1), np.rot90(grid, 3)]

    def directions(g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        along_row, along_col = g[0, -1] - g[0, 0], g[-1, 0] - g[0, 0]
        return along_row / np.linalg.norm(along_row), along_col / np.linalg.norm(along_col)

    u_ref, v_ref = directions(ref)
    scores = [float(u @ u_ref + v @ v_ref) for u, v in map(directions, candidates)]
    best = candidates[int(np.argmax(scores))]
    return Detection(np.arange(board.corners, dtype=np.int64), np.ascontiguousarray(best.reshape(-1, 2)))
