"""Pinhole camera model with OpenCV-style lens distortion.

Convention: a world point ``X_w`` maps to camera coordinates ``X_c = R @ X_w + t``, then to the normalized
plane ``(X_c / Z_c, Y_c / Z_c)``, then (optionally) through the radial/tangential distortion
``(k1, k2, p1, p2[, k3, ...])``, then to pixels by ``K``. Pixel centres sit at integer coordinates (OpenCV).
Distortion is delegated to kornia (:func:`kornia.geometry.calibration.distort_points` /
:func:`~kornia.geometry.calibration.undistort_points`).

Every function works on ``(*, N, 3)`` points / ``(*, N, 2)`` pixels with ``(*, 3, 3)`` matrices and is
differentiable in all its tensor arguments.

This is the project's one camera model: :class:`data_gen.Camera` (the renderer's cameras, and the cameras and
projectors of :mod:`stereonet.active`) projects and back-projects exactly like these functions
(``tests/geometry/test_camera_models.py``); it holds ``K, R, t, dist`` as numpy arrays for the renderer.
"""

from __future__ import annotations

import torch
from kornia.geometry.calibration import distort_points, undistort_points

from stereonet.checks import DegenerateGeometryError, StereoInputError, check_finite, check_shape  # noqa: F401 (re-exported)

__all__ = [
    "DegenerateGeometryError",
    "back_project",
    "camera_centre",
    "check_intrinsics",
    "check_points",
    "distort_pixels",
    "project_points",
    "projection_matrix",
    "undistort_pixels",
    "world_to_camera",
    "camera_to_world",
]

# Points closer than this to the camera plane (in the unit of the scene) are "not in front".
DEPTH_EPS = 1e-12




def check_points(points: object, name: str, dim: int, min_count: int = 1) -> torch.Tensor:
    """Check a floating-point point set :math:`(*, N, dim)` with ``N >= min_count`` and finite values."""
    check_shape(points, ["*", "N", str(dim)], name)
    assert isinstance(points, torch.Tensor)
    if not points.is_floating_point():
        raise TypeError(f"{name}: expected a floating-point tensor, got dtype {points.dtype}")
    if points.shape[-2] < min_count:
        raise DegenerateGeometryError(
            f"{name}: expected at least {min_count} points, got {points.shape[-2]} "
            f"(shape {tuple(points.shape)})"
        )
    check_finite(points, name)
    return points


def check_point_pairs(pts1: object, pts2: object, dim: int = 2) -> None:
    """Two point sets :math:`(*, N, dim)` (:func:`check_points`) of corresponding points: the same N."""
    check_points(pts1, "pts1", dim)
    check_points(pts2, "pts2", dim)
    if pts1.shape[-2] != pts2.shape[-2]:
        raise StereoInputError(f"pts2: expected as many points as pts1 ({pts1.shape[-2]}), got {pts2.shape[-2]}")


def check_intrinsics(K: object, name: str = "K") -> torch.Tensor:
    """Check an intrinsic matrix :math:`(*, 3, 3)`: finite, last row ``(0, 0, 1)``-like, invertible."""
    check_shape(K, ["*", "3", "3"], name)
    assert isinstance(K, torch.Tensor)
    if not K.is_floating_point():
        raise TypeError(f"{name}: expected a floating-point tensor, got dtype {K.dtype}")
    check_finite(K, name)
    det = torch.linalg.det(K.detach().double())
    scale = K.detach().double().abs().amax(dim=(-2, -1)).clamp_min(1e-300) ** 3
    if bool((det.abs() <= 1e-12 * scale).any()):
        raise StereoInputError(
            f"{name}: expected an invertible intrinsic matrix, got a singular one (shape {tuple(K.shape)})"
        )
    return K


def _check_rt(R: torch.Tensor | None, t: torch.Tensor | None) -> None:
    if (R is None) != (t is None):
        raise StereoInputError("R, t: give both or neither (got only one)")
    if R is not None and t is not None:
        check_shape(R, ["*", "3", "3"], "R")
        check_shape(t, ["*", "3"], "t")
        check_finite(R, "R")
        check_finite(t, "t")


def world_to_camera(points: torch.Tensor, R: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """``X_c = R X_w + t`` for points :math:`(*, N, 3)`, ``R`` :math:`(*, 3, 3)`, ``t`` :math:`(*, 3)`."""
    return points @ R.transpose(-1, -2) + t.unsqueeze(-2)


def camera_to_world(points: torch.Tensor, R: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`world_to_camera`: ``X_w = R^T (X_c - t)``."""
    return (points - t.unsqueeze(-2)) @ R


def camera_centre(R: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """Camera centre in world coordinates ``C = -R^T t`` :math:`(*, 3)`."""
    return -(R.transpose(-1, -2) @ t.unsqueeze(-1)).squeeze(-1)


def projection_matrix(
    K: torch.Tensor, R: torch.Tensor | None = None, t: torch.Tensor | None = None
) -> torch.Tensor:
    """``P = K [R | t]`` :math:`(*, 3, 4)` (``R = I, t = 0`` when omitted)."""
    if R is None:
        R = torch.eye(3, dtype=K.dtype, device=K.device).expand_as(K)
    if t is None:
        t = K.new_zeros(K.shape[:-2] + (3,))
    return K @ torch.cat([R, t.unsqueeze(-1)], dim=-1)


def _dist_like(dist: torch.Tensor, ref: torch.Tensor) -> torch.Tensor:
    dist = torch.as_tensor(dist, dtype=ref.dtype, device=ref.device)
    if dist.shape[-1] not in (4, 5, 8, 12, 14):
        raise StereoInputError(
            f"dist: expected 4, 5, 8, 12 or 14 OpenCV coefficients, got shape {tuple(dist.shape)}"
        )
    return dist


def distort_pixels(pixels: torch.Tensor, K: torch.Tensor, dist: torch.Tensor | None) -> torch.Tensor:
    """Ideal (undistorted) pixels :math:`(*, N, 2)` -> pixels as the real lens records them (kornia)."""
    if dist is None:
        return pixels
    return distort_points(pixels, K, _dist_like(dist, pixels))


def undistort_pixels(
    pixels: torch.Tensor, K: torch.Tensor, dist: torch.Tensor | None, num_iters: int = 20
) -> torch.Tensor:
    """Recorded pixels :math:`(*, N, 2)` -> ideal pixels of the same ``K`` (kornia's fixed-point inverse)."""
    if dist is None:
        return pixels
    return undistort_points(pixels, K, _dist_like(dist, pixels), num_iters=num_iters)


def project_points(
    points: torch.Tensor,
    K: torch.Tensor,
    R: torch.Tensor | None = None,
    t: torch.Tensor | None = None,
    dist: torch.Tensor | None = None,
    return_depth: bool = False,
) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
    """World -> camera -> image.

    Args:
        points: world points :math:`(*, N, 3)`.
        K: intrinsics :math:`(*, 3, 3)`; R :math:`(*, 3, 3)` and t :math:`(*, 3)` the world-to-camera pose
            (identity when omitted); dist: OpenCV distortion coefficients :math:`(*, n)` or None.
        return_depth: also return the camera-frame depth :math:`(*, N)`.

    Returns:
        pixels :math:`(*, N, 2)` (and depth). Points with ``|Z_c| < 1e-12`` are projected as if at
        ``Z_c = 1e-12`` (finite, never NaN); ``depth > 0`` tells which points are in front of the camera.
    """
    check_points(points, "points", 3)
    check_intrinsics(K, "K")
    _check_rt(R, t)
    cam = points if R is None else world_to_camera(points, R, t)  # *xNx3
    z = cam[..., 2]
    z_safe = torch.where(z.abs() < DEPTH_EPS, torch.full_like(z, DEPTH_EPS), z)
    normalized = cam[..., :2] / z_safe.unsqueeze(-1)  # *xNx2
    pixels = normalized @ K[..., :2, :2].transpose(-1, -2) + K[..., :2, 2].unsqueeze(-2)
    pixels = distort_pixels(pixels, K, dist)
    return (pixels, z) if return_depth else pixels


def back_project(
    pixels: torch.Tensor,
    K: torch.Tensor,
    depth: torch.Tensor | None = None,
    R: torch.Tensor | None = None,
    t: torch.Tensor | None = None,
    dist: torch.Tensor | None = None,
) -> torch.Tensor:
    """Image -> camera -> world (inverse of :func:`project_points`).

    Args:
        pixels: recorded pixels :math:`(*, N, 2)`; K :math:`(*, 3, 3)`; dist as in :func:`project_points`.
        depth: camera-frame depth ``Z_c`` :math:`(*, N)`; None gives the ray points at ``Z_c = 1``.
        R, t: world-to-camera pose; when given the result is in world coordinates.

    Returns:
        points :math:`(*, N, 3)`.
    """
    check_points(pixels, "pixels", 2)
    check_intrinsics(K, "K")
    _check_rt(R, t)
    ideal = undistort_pixels(pixels, K, dist)
    fx, fy = K[..., 0, 0].unsqueeze(-1), K[..., 1, 1].unsqueeze(-1)
    cx, cy, skew = K[..., 0, 2].unsqueeze(-1), K[..., 1, 2].unsqueeze(-1), K[..., 0, 1].unsqueeze(-1)
    y = (ideal[..., 1] - cy) / fy
    x = (ideal[..., 0] - cx - skew * y) / fx
    rays = torch.stack([x, y, torch.ones_like(x)], dim=-1)  # *xNx3
    if depth is not None:
        check_finite(depth, "depth")
        rays = rays * depth.unsqueeze(-1)
    return rays if R is None else camera_to_world(rays, R, t)
