"""Mono and stereo calibration from board detections (OpenCV), with outlier views dropped.

The pipeline of :func:`calibrate_rig`:

1. views: a view is a (left, right) image pair; one whose board is found in one camera only is dropped
   (a warning names it) while enough views remain, else it is named in the error;
2. each camera alone: ``cv2.calibrateCamera`` on every image of that camera where the board was found;
3. the pair: ``cv2.stereoCalibrate`` on the views found in both, starting from (``refine``) or keeping
   (``CALIB_FIX_INTRINSIC``) the single-camera intrinsics;
4. after each of steps 2 and 3, views whose RMS reprojection error exceeds ``max(1 px, 3 x median)`` are
   dropped and the step is run again (until none is dropped, at most ``MAX_ROUNDS`` times).

Distortion: OpenCV's ``(k1, k2, p1, p2, k3)`` with ``k3`` fixed at 0 unless ``k3=True`` (wide-angle lenses);
ChArUco views may see the board in part, and a view's stereo points are the corners both cameras see.
OpenCV's ``R, T`` follow our convention ``X_r = R X_l + t``, ``t`` in the unit of the board's square.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from stereonet.calibrate.board import Board, Detection, align_detection
from stereonet.checks import StereoInputError
from stereonet.types import Calibration

__all__ = ["CalibrationError", "RigCalibration", "ViewReport", "calibrate_rig", "outlier_views"]

MAX_ROUNDS = 3
OUTLIER_FLOOR_PX = 1.0
OUTLIER_FACTOR = 3.0
_CRITERIA = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-10)


class CalibrationError(StereoInputError):
    """The views cannot give a calibration (too few boards found, too few left after outliers...)."""


@dataclass
class ViewReport:
    """What happened to one view: ``status`` is "used" or "dropped: <why>"; RMS in pixels (NaN = none)."""

    index: int
    left: str
    right: str
    found_left: bool
    found_right: bool
    rms_left: float = math.nan
    rms_right: float = math.nan
    status: str = "used"

    @property
    def used(self) -> bool:
        return self.status == "used"


@dataclass
class RigCalibration:
    """Result of :func:`calibrate_rig`: the rig, the stereo RMS (px) over the used views, one report per
    view, and the warnings (dropped views) in order."""

    calib: Calibration
    rms: float
    views: list[ViewReport]
    warnings: list[str] = field(default_factory=list)
    left: list[Detection | None] = field(default_factory=list, repr=False)
    right: list[Detection | None] = field(default_factory=list, repr=False)

    @property
    def used(self) -> list[int]:
        return [v.index for v in self.views if v.used]


def outlier_views(errors: np.ndarray, floor: float = OUTLIER_FLOOR_PX, factor: float = OUTLIER_FACTOR) -> np.ndarray:
    """Which views are outliers: RMS error :math:`(V,)` (px) above ``max(floor, factor * median)``."""
    errors = np.asarray(errors, dtype=np.float64).reshape(-1)
    if errors.size == 0:
        return np.zeros(0, dtype=bool)
    return errors > max(floor, factor * float(np.median(errors)))


def _names(views: Sequence[ViewReport], which: str = "left", limit: int = 8) -> str:
    names = [getattr(v, which) for v in views]
    shown = ", ".join(names[:limit])
    return shown + (f", ... ({len(names) - limit} more)" if len(names) > limit else "")


def _flags(k3: bool) -> int:
    return 0 if k3 else cv2.CALIB_FIX_K3


def _mono(board: Board, dets: list[Detection], size: tuple[int, int], k3: bool):
    obj = board.object_points()
    objects = [obj[d.ids] for d in dets]
    images = [d.points.reshape(-1, 1, 2) for d in dets]
    rms, K, D, _, _, _, _, per_view = cv2.calibrateCameraExtended(
        objects, images, size, None, None, flags=_flags(k3), criteria=_CRITERIA)
    return float(rms), K, D.reshape(-1), per_view.reshape(-1)


def _common(a: Detection, b: Detection) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Corner ids both detections hold, with their points in each: ids (N,), (N, 2), (N, 2)."""
    ids, ia, ib = np.intersect1d(a.ids, b.ids, return_indices=True)
    return ids, a.points[ia], b.points[ib]


def calibrate_rig(board: Board, left: Sequence[Detection | None], right: Sequence[Detection | None],
                  image_size: tuple[int, int], names: Sequence[tuple[str, str]] | None = None,
                  min_views: int = 6, refine: bool = True, k3: bool = False) -> RigCalibration:
    """Calibrate a two-camera rig from per-view board detections (see the module docstring).

    Args:
        board: the target; left, right: one detection (or None: not found) per view, in view order.
        image_size: ``(width, height)`` of every image; names: ``(left file, right file)`` per view, for
            the messages (default ``view <i>``).
        min_views: fewest views found in both cameras (after outliers) a calibration is made from.
        refine: refine the intrinsics in the stereo step (else ``CALIB_FIX_INTRINSIC``); k3: estimate k3.

    Raises:
        CalibrationError: the board is never found, or found in both images of fewer than ``min_views``
            views (before or after dropping outliers); the one-line message says how many and which.
    """
    if len(left) != len(right):
        raise CalibrationError(f"right: expected as many views as left ({len(left)}), got {len(right)}")
    if min_views < 3:
        raise StereoInputError(f"min_views: expected at least 3, got {min_views}")
    n = len(left)
    names = list(names) if names is not None else [(f"view {i} (left)", f"view {i} (right)") for i in range(n)]
    left, right = list(left), list(right)
    views = [ViewReport(i, names[i][0], names[i][1], left[i] is not None, right[i] is not None) for i in range(n)]
    warnings: list[str] = []
    if not any(v.found_left or v.found_right for v in views):
        raise CalibrationError(f"{board.describe()} not found in any of the {n} left and {n} right images "
                               f"(check --board: it counts inner corners, COLSxROWS)")

    # views whose board one camera sees and the other does not (or ChArUco views with too few common corners)
    for v in views:
        if v.found_left and v.found_right:
            right[v.index] = align_detection(board, left[v.index], right[v.index])
            if len(_common(left[v.index], right[v.index])[0]) < 6:
                v.status = "dropped: too few corners seen by both cameras"
        elif v.found_left or v.found_right:
            side = "left" if v.found_left else "right"
            v.status = f"dropped: board found in the {side} image only"
        else:
            v.status = "dropped: board not found"
    both = [v for v in views if v.used]
    if len(both) < min_views:
        one = [v for v in views if v.found_left != v.found_right]
        extra = ""
        if one:
            extra = "; found in one camera only: " + ", ".join(
                f"{v.left if v.found_left else v.right} ({'left' if v.found_left else 'right'} only)"
                for v in one[:8]) + (f", ... ({len(one) - 8} more)" if len(one) > 8 else "")
        found = f": {_names(both)}" if both else ""
        raise CalibrationError(f"{board.describe()} found in both images of {len(both)} of {n} views{found} "
                               f"(need at least {min_views}){extra}")
    for v in views:
        if not v.used and (v.found_left or v.found_right):
            warnings.append(f"view {v.index} ({v.left} | {v.right}): {v.status[len('dropped: '):]}; view dropped")

    # 1) each camera alone, on every image of it where the board was found
    mono = {}
    for side, dets, attr in (("left", left, "rms_left"), ("right", right, "rms_right")):
        keep = [v for v in views if dets[v.index] is not None]
        for round_ in range(MAX_ROUNDS + 1):
            _, K, D, per_view = _mono(board, [dets[v.index] for v in keep], image_size, k3)
            for v, e in zip(keep, per_view):
                setattr(v, attr, float(e))
            bad = outlier_views(per_view)
            # the last round drops nothing: the intrinsics kept are always those of a fit without dropped views
            if not bad.any() or len(keep) - int(bad.sum()) < 3 or round_ == MAX_ROUNDS:
                break
            for v, b in zip(keep, bad):
                if b and v.used:
                    v.status = f"dropped: outlier ({side} camera alone: {getattr(v, attr):.2f} px RMS)"
                    warnings.append(f"view {v.index} ({v.left} | {v.right}): {v.status[len('dropped: '):]}; "
                                    "view dropped")
            keep = [v for v, b in zip(keep, bad) if not b]
        mono[side] = (K, D)

    # 2) the pair
    flags = _flags(k3) | (cv2.CALIB_USE_INTRINSIC_GUESS if refine else cv2.CALIB_FIX_INTRINSIC)
    obj = board.object_points()
    for round_ in range(MAX_ROUNDS + 1):
        used = [v for v in views if v.used]
        if len(used) < min_views:
            dropped = [v for v in views if v.status.startswith("dropped: outlier")]
            raise CalibrationError(f"only {len(used)} views left after dropping {len(dropped)} outlier views "
                                   f"({_names(dropped)}); need at least {min_views}")
        objects, pts_l, pts_r = [], [], []
        for v in used:
            ids, pl, pr = _common(left[v.index], right[v.index])
            objects.append(obj[ids])
            pts_l.append(pl.reshape(-1, 1, 2))
            pts_r.append(pr.reshape(-1, 1, 2))
        (K1, D1), (K2, D2) = mono["left"], mono["right"]
        rms, K1, D1, K2, D2, R, T, _, _, _, _, per_view = cv2.stereoCalibrateExtended(
            objects, pts_l, pts_r, K1.copy(), D1.copy(), K2.copy(), D2.copy(), image_size, None, None,
            flags=flags, criteria=_CRITERIA)
        per_view = np.asarray(per_view, dtype=np.float64).reshape(-1, 2)
        for v, (el, er) in zip(used, per_view):
            v.rms_left, v.rms_right = float(el), float(er)
        bad = outlier_views(per_view.max(axis=1))
        if not bad.any() or round_ == MAX_ROUNDS:
            break
        for v, b in zip(used, bad):
            if b:
                v.status = f"dropped: outlier (stereo: {max(v.rms_left, v.rms_right):.2f} px RMS)"
                warnings.append(f"view {v.index} ({v.left} | {v.right}): {v.status[len('dropped: '):]}; "
                                "view dropped")
    calib = Calibration(K1, K2, R, np.asarray(T).reshape(3), image_size=tuple(image_size),
                        dist1=np.asarray(D1).reshape(-1), dist2=np.asarray(D2).reshape(-1))
    return RigCalibration(calib, float(rms), views, warnings, left, right)
