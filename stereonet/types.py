"""Core data types shared by every module: :class:`StereoOutput` and :class:`Calibration`."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace

import torch


@dataclass
class StereoOutput:
    """What every matcher returns (one signature: ``matcher(left, right, max_disp) -> StereoOutput``).

    Attributes:
        disparity: left-referenced disparity :math:`(B, 1, H, W)`, float, ``x_right = x_left - d``.
        valid: bool mask :math:`(B, 1, H, W)`; False where the method gives no answer (LR failure, border...).
        confidence: optional :math:`(B, 1, H, W)` in [0, 1], higher = more confident.
        uncertainty: optional :math:`(B, 1, H, W)`, higher = less sure (a scale in pixels of disparity, or a
            probability of error such as ``smd``'s).
        cost_volume: optional :math:`(B, D, H, W)`, lower = better.
        extras: free-form named tensors (e.g. occlusion labels, mixture parameters).
    """

    disparity: torch.Tensor
    valid: torch.Tensor
    confidence: torch.Tensor | None = None
    uncertainty: torch.Tensor | None = None
    cost_volume: torch.Tensor | None = None
    extras: dict[str, torch.Tensor] = field(default_factory=dict)

    def __post_init__(self) -> None:
        from stereonet.checks import check_shape

        check_shape(self.disparity, ["B", "1", "H", "W"], "disparity")
        if self.valid.shape != self.disparity.shape:
            raise ValueError(
                f"valid: expected shape {tuple(self.disparity.shape)} (same as disparity), "
                f"got {tuple(self.valid.shape)}"
            )
        if self.valid.dtype != torch.bool:
            raise TypeError(f"valid: expected dtype torch.bool, got {self.valid.dtype}")

    def to(self, device: torch.device | str) -> StereoOutput:
        """Move every tensor to ``device`` (dtypes unchanged)."""
        changes = {f.name: getattr(self, f.name).to(device) for f in fields(self)
                   if isinstance(getattr(self, f.name), torch.Tensor)}
        changes["extras"] = {k: v.to(device) for k, v in self.extras.items()}
        return replace(self, **changes)

    def filled(self) -> torch.Tensor:
        """Disparity with invalid pixels set to 0 (useful for display)."""
        return torch.where(self.valid, self.disparity, torch.zeros_like(self.disparity))


@dataclass
class Calibration:
    """Two-camera calibration.

    Convention: right camera pose ``X_r = R @ X_l + t`` (points in left camera coordinates map to right
    camera coordinates); the baseline is ``|t|`` in the unit of ``t``.

    Attributes:
        K1, K2: intrinsics :math:`(3, 3)` float64.
        R: rotation :math:`(3, 3)`; t: translation :math:`(3,)`.
        image_size: ``(width, height)`` of the images the calibration belongs to, or None if unknown.
        dist1, dist2: optional OpenCV distortion coefficients ``(k1, k2, p1, p2[, k3...])``.
        doffs: x-difference of principal points (Middlebury 2014), so that ``z = f*B/(d + doffs)``.
        ndisp: optional disparity range hint (Middlebury ``ndisp``).
    """

    K1: torch.Tensor
    K2: torch.Tensor
    R: torch.Tensor
    t: torch.Tensor
    image_size: tuple[int, int] | None = None
    dist1: torch.Tensor | None = None
    dist2: torch.Tensor | None = None
    doffs: float = 0.0
    ndisp: int | None = None

    def __post_init__(self) -> None:
        from stereonet.checks import StereoInputError, check_shape

        self.K1 = torch.as_tensor(self.K1, dtype=torch.float64)
        self.K2 = torch.as_tensor(self.K2, dtype=torch.float64)
        self.R = torch.as_tensor(self.R, dtype=torch.float64)
        self.t = torch.as_tensor(self.t, dtype=torch.float64).reshape(-1)
        check_shape(self.K1, ["3", "3"], "K1")
        check_shape(self.K2, ["3", "3"], "K2")
        check_shape(self.R, ["3", "3"], "R")
        check_shape(self.t, ["3"], "t")
        for name in ("K1", "K2", "R", "t"):
            v = getattr(self, name)
            if not torch.isfinite(v).all():
                raise StereoInputError(f"{name}: expected finite values, got NaN or inf")
        for name in ("K1", "K2"):
            if abs(float(torch.linalg.det(getattr(self, name)))) < 1e-12:
                raise StereoInputError(f"{name}: expected an invertible intrinsic matrix, got a singular one")
        for name in ("dist1", "dist2"):
            v = getattr(self, name)
            if v is not None:
                setattr(self, name, torch.as_tensor(v, dtype=torch.float64).reshape(-1))
        if not math.isfinite(float(self.doffs)):
            raise StereoInputError(f"doffs: expected a finite number of pixels, got {self.doffs}")
        self.doffs = float(self.doffs)
        if self.ndisp is not None:
            if not float(self.ndisp) == int(self.ndisp) or int(self.ndisp) < 0:
                raise StereoInputError(f"ndisp: expected a whole number of disparities >= 0 (0 = unknown), "
                                       f"got {self.ndisp}")
            self.ndisp = int(self.ndisp) or None
        if self.image_size is not None:
            try:
                w, h = (int(x) for x in self.image_size)
            except (TypeError, ValueError):
                raise StereoInputError(f"image_size: expected (width, height), got {self.image_size!r}") from None
            if w <= 0 or h <= 0:
                raise StereoInputError(f"image_size: expected positive (width, height), got {self.image_size}")
            self.image_size = (w, h)

    @property
    def baseline(self) -> float:
        return float(torch.linalg.norm(self.t))

    @property
    def focal(self) -> float:
        """Horizontal focal length of the left camera in pixels."""
        return float(self.K1[0, 0])

    def is_rectified(self, tol: float = 1e-6) -> bool:
        """True when the rig is already rectified: R = I, t along x, K1 and K2 equal up to cx."""
        eye = torch.eye(3, dtype=torch.float64)
        t = self.t / max(self.baseline, 1e-300)
        same_k = torch.allclose(self.K1[[0, 0, 1, 1], [0, 1, 1, 2]], self.K2[[0, 0, 1, 1], [0, 1, 1, 2]],
                                atol=tol * max(1.0, float(self.K1[0, 0])))
        undistorted = all(d is None or bool(torch.all(d.abs() < tol)) for d in (self.dist1, self.dist2))
        return (torch.allclose(self.R, eye, atol=tol) and abs(float(t[1])) < tol and abs(float(t[2])) < tol
                and same_k and undistorted)

    @staticmethod
    def rectified(focal: float, cx: float, cy: float, baseline: float,
                  image_size: tuple[int, int] | None = None, doffs: float = 0.0) -> Calibration:
        """A rectified rig: R = I, the right camera ``baseline`` units to the right (t = (-B, 0, 0))."""
        K1 = torch.tensor([[focal, 0.0, cx], [0.0, focal, cy], [0.0, 0.0, 1.0]], dtype=torch.float64)
        K2 = K1.clone()
        K2[0, 2] += doffs
        return Calibration(K1, K2, torch.eye(3, dtype=torch.float64),
                           torch.tensor([-baseline, 0.0, 0.0], dtype=torch.float64),
                           image_size=image_size, doffs=doffs)
