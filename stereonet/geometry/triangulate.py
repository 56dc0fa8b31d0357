"""Two-view triangulation: linear (DLT, H&Z 12.2) and midpoint, with the reprojection error.

Points come out in the first (left) camera's frame; the rig follows :class:`stereonet.types.Calibration`
(``X_r = R X_l + t``). Both methods are differentiable; neither returns NaN: matches whose rays are
parallel (a point at infinity) get ``valid = False`` and a finite placeholder. The DLT is kornia's
(:func:`kornia.geometry.epipolar.triangulate_points`, SVD solver); the midpoint method is ours (kornia has none).
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from kornia.geometry.epipolar import triangulate_points

from stereonet.checks import StereoInputError, check_finite, check_shape, check_tensor
from stereonet.geometry.camera import (
    _check_rt,
    camera_centre,
    check_intrinsics,
    check_point_pairs,
    check_points,
    projection_matrix,
    undistort_pixels,
)
from stereonet.types import Calibration

__all__ = ["Triangulation", "reprojection_error", "triangulate", "triangulate_dlt", "triangulate_midpoint"]

# |w| of the homogeneous DLT solution (unit norm) below which the point is at infinity; for the Euclidean point
# X = v / w of a unit 4-vector (v, w) that is |X| > sqrt(1 - tol^2) / tol, i.e. |X| > 1 / tol.
_INFINITY_TOL = 1e-12


def _dlt(
    P1: torch.Tensor, P2: torch.Tensor, pts1: torch.Tensor, pts2: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    X = triangulate_points(P1, P2, pts1, pts2, solver="svd")  # *xNx3, NaN at infinity
    finite = torch.linalg.vector_norm(X, dim=-1) < 1.0 / _INFINITY_TOL  # NaN compares False
    # placeholder for points at infinity: the unit direction of the ray of pts1, M1^+ x1 (P1 = [M1 | p1])
    M1_pinv = torch.linalg.pinv(P1[..., :3])  # *x3x3
    ray = torch.cat([pts1, torch.ones_like(pts1[..., :1])], -1) @ M1_pinv.transpose(-1, -2)  # *xNx3
    ray = ray / torch.linalg.vector_norm(ray, dim=-1, keepdim=True).clamp_min(1e-300)
    X = torch.where(finite.unsqueeze(-1), X, ray)
    return X, finite


def triangulate_dlt(
    P1: torch.Tensor, P2: torch.Tensor, pts1: torch.Tensor, pts2: torch.Tensor
) -> torch.Tensor:
    """Linear triangulation: the null vector (SVD) of the 4 x 4 system ``x P^3 - P^1, y P^3 - P^2`` per match.

    Args:
        P1, P2: projection matrices :math:`(*, 3, 4)`; pts1, pts2: matching ideal pixels :math:`(*, N, 2)`.

    Returns:
        points :math:`(*, N, 3)` in the frame the projection matrices act on. Points at infinity are returned
        as their direction (finite, the unit ray of ``pts1``); use :func:`triangulate` to get the ``valid`` flag.
    """
    check_point_pairs(pts1, pts2)
    for name, P in (("P1", P1), ("P2", P2)):
        check_shape(check_tensor(P, name), ["*", "3", "4"], name)
        check_finite(P, name)
    return _dlt(P1, P2, pts1, pts2)[0]


def _midpoint(pts1, pts2, K1, K2, R, t) -> tuple[torch.Tensor, torch.Tensor]:
    ones = torch.ones_like(pts1[..., :1])
    d1 = torch.cat([pts1, ones], -1) @ torch.linalg.inv(K1).transpose(-1, -2)  # *xNx3, left frame
    d2 = torch.cat([pts2, ones], -1) @ torch.linalg.inv(K2).transpose(-1, -2) @ R  # R^T K2^-1 x2, left frame
    c2 = camera_centre(R, t).unsqueeze(-2)  # *x1x3
    # minimise |s d1 - (c2 + u d2)|^2 over (s, u): 2x2 normal equations
    a, b, c = (d1 * d1).sum(-1), (d1 * d2).sum(-1), (d2 * d2).sum(-1)
    p, q = (d1 * c2).sum(-1), (d2 * c2).sum(-1)
    det = a * c - b * b
    ok = det > 1e-12 * a * c
    det_safe = torch.where(ok, det, torch.ones_like(det))
    s = (c * p - b * q) / det_safe
    u = (b * p - a * q) / det_safe
    X = 0.5 * (s.unsqueeze(-1) * d1 + c2 + u.unsqueeze(-1) * d2)
    return X, ok


def triangulate_midpoint(
    pts1: torch.Tensor,
    pts2: torch.Tensor,
    K1: torch.Tensor,
    K2: torch.Tensor,
    R: torch.Tensor,
    t: torch.Tensor,
) -> torch.Tensor:
    """Midpoint of the shortest segment between the two viewing rays (left camera frame).

    Args:
        pts1, pts2: ideal pixels :math:`(*, N, 2)`; K1, K2, R :math:`(*, 3, 3)`; t :math:`(*, 3)`.

    Returns:
        points :math:`(*, N, 3)`; parallel rays give a finite placeholder (see :func:`triangulate`).
    """
    check_point_pairs(pts1, pts2)
    check_intrinsics(K1, "K1")
    check_intrinsics(K2, "K2")
    _check_rt(R, t)
    return _midpoint(pts1, pts2, K1, K2, R, t)[0]


def reprojection_error(points: torch.Tensor, P: torch.Tensor, pixels: torch.Tensor) -> torch.Tensor:
    """Distance in px between ``P X`` and the observed ``pixels``.

    Args:
        points :math:`(*, N, 3)`, P :math:`(*, 3, 4)`, pixels :math:`(*, N, 2)`.

    Returns:
        :math:`(*, N)`; points on the camera plane (|depth| < 1e-12) get a very large finite error.
    """
    proj = torch.cat([points, torch.ones_like(points[..., :1])], -1) @ P.transpose(-1, -2)  # *xNx3
    w = proj[..., 2:]
    w = torch.where(w.abs() < 1e-12, torch.where(w < 0, -1e-12, 1e-12).to(w.dtype), w)
    return torch.linalg.vector_norm(proj[..., :2] / w - pixels, dim=-1)


class Triangulation(NamedTuple):
    """Result of :func:`triangulate`.

    Attributes:
        points: :math:`(*, N, 3)` in the left camera frame.
        reprojection_error: :math:`(*, N)` RMS over the two views, in px (of the ideal, undistorted pixels).
        in_front: :math:`(*, N)` bool, positive depth in both cameras.
        valid: :math:`(*, N)` bool, finite intersection (rays not parallel) and in front of both cameras.
    """

    points: torch.Tensor
    reprojection_error: torch.Tensor
    in_front: torch.Tensor
    valid: torch.Tensor


def triangulate(
    pts1: torch.Tensor, pts2: torch.Tensor, calib: Calibration, method: str = "dlt"
) -> Triangulation:
    """Triangulate matches of a calibrated rig (lens distortion removed first when ``calib`` has it).

    Args:
        pts1, pts2: recorded pixels :math:`(*, N, 2)` in the left/right image.
        calib: the rig (``X_r = R X_l + t``).
        method: ``"dlt"`` (linear, algebraic) or ``"midpoint"`` (geometric, rays in 3D).

    Returns:
        :class:`Triangulation` with points in the left camera frame and the unit of ``t``.
    """
    if not isinstance(calib, Calibration):
        raise TypeError(f"calib: expected a stereonet.types.Calibration, got {type(calib).__name__}")
    check_points(pts1, "pts1", 2)
    check_points(pts2, "pts2", 2)
    if pts1.shape != pts2.shape:
        raise StereoInputError(
            f"pts2: expected the same shape as pts1 {tuple(pts1.shape)}, got {tuple(pts2.shape)}"
        )
    if calib.baseline == 0:
        raise StereoInputError("calib: the baseline |t| is zero (pure rotation); nothing can be triangulated")
    dt, dev = pts1.dtype, pts1.device
    K1, K2, R, t = (x.to(dt).to(dev) for x in (calib.K1, calib.K2, calib.R, calib.t))
    x1 = undistort_pixels(pts1, K1, calib.dist1)
    x2 = undistort_pixels(pts2, K2, calib.dist2)
    P1, P2 = projection_matrix(K1), projection_matrix(K2, R, t)
    if method == "dlt":
        X, finite = _dlt(P1, P2, x1, x2)
    elif method == "midpoint":
        X, finite = _midpoint(x1, x2, K1, K2, R, t)
    else:
        raise StereoInputError(f"method: expected 'dlt' or 'midpoint', got {method!r}")
    err = ((reprojection_error(X, P1, x1) ** 2 + reprojection_error(X, P2, x2) ** 2) / 2).sqrt()
    in_front = (X[..., 2] > 0) & ((X @ R.T + t)[..., 2] > 0)
    return Triangulation(X, err, in_front, in_front & finite)
