"""Random unrectified rigs and exact correspondences, for tests, benchmarks and teaching.

A pure function of the seed: ``random_rig(seed)`` draws two pinhole cameras with different intrinsics, a
relative rotation of a few degrees and a mostly horizontal baseline; ``random_correspondences`` draws 3D
points in front of the left camera that both cameras see and returns their exact projections.
"""

from __future__ import annotations

import math

import torch

from stereonet.checks import StereoInputError
from stereonet.geometry.camera import back_project, project_points
from stereonet.types import Calibration

__all__ = ["random_correspondences", "random_rig", "random_rotation"]


def random_rotation(max_angle_deg: float, generator: torch.Generator) -> torch.Tensor:
    """Rotation :math:`(3, 3)` float64 about a random axis by an angle uniform in [0, max_angle_deg]."""
    axis = torch.randn(3, generator=generator, dtype=torch.float64)
    axis = axis / torch.linalg.vector_norm(axis)
    angle = math.radians(max_angle_deg) * float(torch.rand(1, generator=generator, dtype=torch.float64))
    Kx = torch.tensor(
        [[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]], dtype=torch.float64
    )
    return torch.eye(3, dtype=torch.float64) + math.sin(angle) * Kx + (1 - math.cos(angle)) * Kx @ Kx


def random_rig(
    seed: int,
    image_size: tuple[int, int] = (640, 480),
    max_rotation_deg: float = 8.0,
    off_axis: float = 0.15,
    distortion: bool = False,
) -> Calibration:
    """A random unrectified rig (``X_r = R X_l + t``), right camera roughly to the right of the left one.

    Args:
        seed: the rig is a pure function of it.
        image_size: ``(width, height)``.
        max_rotation_deg: largest relative rotation.
        off_axis: std of the baseline direction's y and z components (relative to its x component).
        distortion: add OpenCV radial/tangential coefficients ``(k1, k2, p1, p2, k3)``.
    """
    g = torch.Generator().manual_seed(seed)
    w, h = image_size

    def u(lo: float, hi: float) -> float:
        return lo + (hi - lo) * float(torch.rand(1, generator=g, dtype=torch.float64))

    def intrinsics(f: float) -> torch.Tensor:
        return torch.tensor(
            [[f * u(0.98, 1.02), 0.0, w / 2 + u(-20, 20)], [0.0, f, h / 2 + u(-15, 15)], [0.0, 0.0, 1.0]],
            dtype=torch.float64,
        )

    f = u(0.8, 1.4) * w
    K1 = intrinsics(f)
    K2 = intrinsics(f * u(0.95, 1.05))
    R = random_rotation(max_rotation_deg, g)
    centre = torch.tensor(
        [1.0, off_axis * float(torch.randn(1, generator=g)), off_axis * float(torch.randn(1, generator=g))],
        dtype=torch.float64,
    )
    centre = centre / torch.linalg.vector_norm(centre) * u(0.1, 0.4)  # right camera centre, left frame
    t = -(R @ centre)
    dist1 = dist2 = None
    if distortion:
        dist1 = torch.tensor(
            [u(-0.25, 0.1), u(-0.05, 0.05), u(-1e-3, 1e-3), u(-1e-3, 1e-3), 0.0], dtype=torch.float64
        )
        dist2 = torch.tensor(
            [u(-0.25, 0.1), u(-0.05, 0.05), u(-1e-3, 1e-3), u(-1e-3, 1e-3), 0.0], dtype=torch.float64
        )
    return Calibration(K1, K2, R, t, image_size=(w, h), dist1=dist1, dist2=dist2)


def random_correspondences(
    calib: Calibration,
    count: int,
    seed: int,
    depth_range: tuple[float, float] = (1.5, 8.0),
    margin: float = 1.0,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Exact correspondences of random 3D points seen by both cameras (pixels as the lenses record them).

    Returns:
        (points :math:`(N, 3)` in the left camera frame, pts1 :math:`(N, 2)`, pts2 :math:`(N, 2)`), float64,
        ``N = count`` (points are drawn until enough land inside both images, ``margin`` px from the border).
    """
    if calib.image_size is None:
        raise StereoInputError("calib.image_size: needed to draw visible points, got None")
    g = torch.Generator().manual_seed(seed + 7919)
    w, h = calib.image_size
    kept_X, kept_1, kept_2, total = [], [], [], 0
    while total < count:
        n = 4 * count
        uv = torch.rand(n, 2, generator=g, dtype=torch.float64) * torch.tensor(
            [w - 1.0, h - 1.0], dtype=torch.float64
        )
        z = depth_range[0] + (depth_range[1] - depth_range[0]) * torch.rand(
            n, generator=g, dtype=torch.float64
        )
        X = back_project(uv, calib.K1, z, dist=calib.dist1)
        p1 = project_points(X, calib.K1, dist=calib.dist1)
        p2, z2 = project_points(X, calib.K2, calib.R, calib.t, dist=calib.dist2, return_depth=True)
        ok = z2 > 0
        for p in (p1, p2):
            ok &= (
                (p[:, 0] >= margin)
                & (p[:, 0] <= w - 1 - margin)
                & (p[:, 1] >= margin)
                & (p[:, 1] <= h - 1 - margin)
            )
        kept_X.append(X[ok])
        kept_1.append(p1[ok])
        kept_2.append(p2[ok])
        total += int(ok.sum())
    return torch.cat(kept_X)[:count], torch.cat(kept_1)[:count], torch.cat(kept_2)[:count]
