"""Disparity <-> depth <-> 3D points for a rectified rig.

``z = f * B / (d + doffs)`` with ``f`` the rectified focal length in px, ``B = |t|`` the baseline and
``doffs`` the x-difference of the principal points (``cx_right - cx_left``, Middlebury 2014); ``d`` is the
left-referenced disparity (``x_right = x_left - d``). Everything is differentiable in the disparity/depth
(and in ``focal``/``baseline`` when they are tensors) and never produces NaN or inf: pixels without a
depth (``d + doffs <= 0``, ``valid`` False, ``z <= 0``) get 0.
"""

from __future__ import annotations

import numpy as np
import torch

from stereonet.checks import StereoInputError, check_finite, check_image, check_shape, check_tensor
from stereonet.types import Calibration

__all__ = ["depth_to_disparity", "disparity_to_depth", "disparity_to_points", "reproject_disparity"]

# Rectified means R = I and t = (-B, 0, 0) up to this tolerance (relative for t, absolute for R).
_RECTIFIED_TOL = 1e-4


def _rig_parameters(calib: Calibration | None, focal, baseline, doffs) -> tuple[object, object, object]:
    """(focal, baseline, doffs) from a rectified calibration or from the explicit numbers."""
    if calib is not None:
        if focal is not None or baseline is not None or doffs is not None:
            raise StereoInputError("calib: give either calib or focal/baseline/doffs, not both")
        if not isinstance(calib, Calibration):
            raise TypeError(f"calib: expected a stereonet.types.Calibration, got {type(calib).__name__}")
        if not calib.is_rectified(_RECTIFIED_TOL):
            raise StereoInputError(
                "calib: expected a rectified rig (R = I, t along x, equal K up to cx, no distortion); "
                "rectify first with stereonet.geometry.rectify_calibrated and use its .calib"
            )
        if float(calib.t[0]) >= 0:
            raise StereoInputError(
                f"calib: expected the right camera to the right of the left one (t[0] < 0), "
                f"got t[0] = {float(calib.t[0]):.4g}"
            )
        return calib.focal, calib.baseline, float(calib.doffs)
    if focal is None or baseline is None:
        raise StereoInputError("calib: expected a Calibration, or focal and baseline (and optionally doffs)")
    for name, v in (("focal", focal), ("baseline", baseline)):
        v_t = torch.as_tensor(v)
        if not bool(torch.isfinite(v_t).all()) or not bool((v_t > 0).all()):
            raise StereoInputError(f"{name}: expected a positive finite number, got {v!r}")
    doffs = 0.0 if doffs is None else doffs
    if not bool(torch.isfinite(torch.as_tensor(doffs)).all()):
        raise StereoInputError(f"doffs: expected a finite number, got {doffs!r}")
    return focal, baseline, doffs


def _check_map(x: object, name: str, valid: torch.Tensor | None) -> torch.Tensor:
    check_shape(x, ["B", "1", "H", "W"], name)
    assert isinstance(x, torch.Tensor)
    if not x.is_floating_point():
        raise TypeError(f"{name}: expected a floating-point tensor, got dtype {x.dtype}")
    if valid is not None:
        check_tensor(valid, "valid")
        if valid.shape != x.shape or valid.dtype != torch.bool:
            raise StereoInputError(
                f"valid: expected a bool tensor of shape {tuple(x.shape)}, "
                f"got {valid.dtype} {tuple(valid.shape)}"
            )
    # Non-finite values are allowed only where valid is False (they are ignored there).
    check_finite(x if valid is None else torch.where(valid, x, torch.zeros_like(x)), name)
    return x


def _reciprocal(x: torch.Tensor, numerator, valid: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor]:
    """(``numerator / x`` where ``x > 0`` and valid, else 0; that mask), with no inf/NaN in value or gradient."""
    has = x > 0 if valid is None else (x > 0) & valid
    safe = torch.where(has, x, torch.ones_like(x))
    return torch.where(has, numerator / safe, torch.zeros_like(x)), has


def disparity_to_depth(
    disparity: torch.Tensor,
    calib: Calibration | None = None,
    *,
    focal=None,
    baseline=None,
    doffs=None,
    valid: torch.Tensor | None = None,
) -> torch.Tensor:
    """``z = f * B / (d + doffs)``.

    Args:
        disparity: left-referenced disparity :math:`(B, 1, H, W)` in px.
        calib: a rectified :class:`Calibration` (e.g. ``Rectification.calib`` or Middlebury's calib.txt);
            or give ``focal`` (px), ``baseline`` (unit of the result) and optionally ``doffs`` (px).
        valid: optional bool mask :math:`(B, 1, H, W)`.

    Returns:
        depth :math:`(B, 1, H, W)` in the unit of the baseline, 0 where there is no depth
        (``d + doffs <= 0`` or not ``valid``).
    """
    _check_map(disparity, "disparity", valid)
    f, b, off = _rig_parameters(calib, focal, baseline, doffs)
    depth, _ = _reciprocal(disparity + off, f * b, valid)
    return depth


def depth_to_disparity(
    depth: torch.Tensor,
    calib: Calibration | None = None,
    *,
    focal=None,
    baseline=None,
    doffs=None,
    valid: torch.Tensor | None = None,
) -> torch.Tensor:
    """``d = f * B / z - doffs`` (inverse of :func:`disparity_to_depth`).

    Args:
        depth: :math:`(B, 1, H, W)`; calib / focal, baseline, doffs / valid as in :func:`disparity_to_depth`.

    Returns:
        disparity :math:`(B, 1, H, W)`, 0 where ``z <= 0`` or not ``valid``.
    """
    _check_map(depth, "depth", valid)
    f, b, off = _rig_parameters(calib, focal, baseline, doffs)
    inverse, has = _reciprocal(depth, f * b, valid)
    return torch.where(has, inverse - off, torch.zeros_like(depth))


def disparity_to_points(
    disparity: torch.Tensor, valid: torch.Tensor | None, calib: Calibration, image: torch.Tensor | None = None
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Coloured point cloud in the (rectified) left camera frame, ready for ``stereonet.io.write_ply``.

    Args:
        disparity: :math:`(1, 1, H, W)`; valid: bool :math:`(1, 1, H, W)` or None (all pixels).
        calib: rectified :class:`Calibration` (K1 gives fx, fy, cx, cy).
        image: optional left image :math:`(1, C, H, W)` in [0, 1], C = 1 or 3, for the colours.

    Returns:
        (points :math:`(N, 3)` in the disparity's dtype (differentiable), colours :math:`(N, 3)` uint8 or
        None), one row per valid pixel with a positive depth, in row-major pixel order.
    """
    _check_map(disparity, "disparity", valid)
    if disparity.shape[0] != 1:
        raise StereoInputError(f"disparity: expected a single map (1, 1, H, W), got {tuple(disparity.shape)}")
    depth = disparity_to_depth(disparity, calib, valid=valid)[0, 0]  # HxW
    keep = depth > 0
    _, _, h, w = disparity.shape
    K = calib.K1.to(disparity.dtype).to(disparity.device)
    v, u = torch.meshgrid(
        torch.arange(h, dtype=disparity.dtype, device=disparity.device),
        torch.arange(w, dtype=disparity.dtype, device=disparity.device),
        indexing="ij",
    )
    z = depth[keep]
    y = (v[keep] - K[1, 2]) / K[1, 1] * z
    x = (u[keep] - K[0, 2] - K[0, 1] * (v[keep] - K[1, 2]) / K[1, 1]) / K[0, 0] * z
    points = torch.stack([x, y, z], dim=-1)  # Nx3
    colors = None
    if image is not None:
        check_image(image, "image")
        if image.shape[0] != 1 or image.shape[-2:] != disparity.shape[-2:]:
            raise StereoInputError(f"image: expected shape (1, C, {h}, {w}), got {tuple(image.shape)}")
        rgb = image[0].detach().expand(3, h, w) if image.shape[1] == 1 else image[0].detach()
        colors = (rgb[:, keep].T.clamp(0, 1) * 255).round().to(torch.uint8)  # Nx3
    return points, colors


def reproject_disparity(disparity: torch.Tensor, Q: torch.Tensor | np.ndarray) -> torch.Tensor:
    """Per-pixel 3D points through a 4x4 ``Q`` (``[X Y Z W]^T = Q [u v d 1]^T``), like
    ``cv2.reprojectImageTo3D``. disparity :math:`(B, 1, H, W)` -> points :math:`(B, 3, H, W)`; pixels with
    ``W <= 0`` (no depth) get 0."""
    _check_map(disparity, "disparity", None)
    Q = torch.as_tensor(Q, dtype=disparity.dtype, device=disparity.device)
    check_shape(Q, ["4", "4"], "Q")
    b, _, h, w = disparity.shape
    v, u = torch.meshgrid(
        torch.arange(h, dtype=disparity.dtype, device=disparity.device),
        torch.arange(w, dtype=disparity.dtype, device=disparity.device),
        indexing="ij",
    )
    uvd1 = torch.stack(
        [u.expand(b, h, w), v.expand(b, h, w), disparity[:, 0], torch.ones_like(disparity[:, 0])], dim=1
    )  # Bx4xHxW
    xyzw = torch.einsum("ij,bjhw->bihw", Q, uvd1)
    wgt = xyzw[:, 3:]
    ok = wgt > 0
    return torch.where(
        ok, xyzw[:, :3] / torch.where(ok, wgt, torch.ones_like(wgt)), torch.zeros_like(xyzw[:, :3])
    )
