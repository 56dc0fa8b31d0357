"""Triangulation by intersecting camera rays with known light planes (a laser sheet, a projector column).

Both active sensors of this package reduce to one formula. In the camera frame a pixel ``(u, v)`` sees the
ray ``X = z * r`` with ``r = K^-1 (u, v, 1)`` (so ``z`` is the depth), and the light plane is ``n . X = c``;
hence ``z = c / (n . r)``. The answer is undetermined when the ray lies in the plane (``n . r -> 0``: the plane
seen edge-on, i.e. parallel to the camera rays) and when the plane passes through the camera centre
(``c -> 0``: every ray lies in it). The first is flagged per pixel, the second raises.
"""

from __future__ import annotations

import torch

from data_gen import Camera
from stereonet.checks import StereoInputError, check_finite, check_shape
from stereonet.geometry.camera import back_project


def plane_to_camera(normal_world: torch.Tensor, offset_world: torch.Tensor,
                    camera: Camera) -> tuple[torch.Tensor, torch.Tensor]:
    """World planes ``n . X_w = c`` (normals :math:`(*, 3)`, offsets :math:`(*)`) -> the same planes in
    ``camera``'s frame (``X_c = R X_w + t``): ``n_c = R n``, ``c_c = c + n_c . t``."""
    n_c = normal_world.to(torch.float64) @ torch.as_tensor(camera.R).T
    return n_c, offset_world.to(torch.float64) + n_c @ torch.as_tensor(camera.t)


def projector_column_planes(u_proj: torch.Tensor, camera: Camera,
                            projector: Camera) -> tuple[torch.Tensor, torch.Tensor]:
    """Light planes (camera frame) of projector columns ``u_proj`` :math:`(*)` (sub-pixel allowed).

    Column ``u`` of the projector image is the image line ``l = (1, 0, -u)``; its back-projection is the plane
    ``(K_p^T l) . X_p = 0`` through the projector centre. With ``X_p = R X_c + t`` (projector pose relative to the
    camera) the plane in camera coordinates is ``(R^T n_p) . X_c = -n_p . t``.
    Returns normals :math:`(*, 3)` and offsets :math:`(*)`.
    """
    R, t = (torch.as_tensor(a) for a in projector.relative_to(camera))
    u = u_proj.to(torch.float64)
    line = torch.stack([torch.ones_like(u), torch.zeros_like(u), -u], dim=-1)  # *x3
    n_p = line @ torch.as_tensor(projector.K)  # (K^T l)^T = l^T K
    return n_p @ R, -(n_p @ t)


def ray_plane_depth(K: torch.Tensor, uv: torch.Tensor, normals: torch.Tensor, offsets: torch.Tensor,
                    min_angle_deg: float = 0.5, degenerate: str = "raise") -> tuple[torch.Tensor, torch.Tensor]:
    """Depth where the camera rays through pixels ``uv`` meet the planes ``normals . X = offsets`` (camera frame).

    Args:
        K: camera intrinsics :math:`(3, 3)` (a tensor or array, e.g. ``camera.K``).
        uv: pixel coordinates :math:`(*, 2)` (column, row), sub-pixel allowed.
        normals: plane normals :math:`(*, 3)` (any length, broadcast against ``uv``).
        offsets: plane offsets :math:`(*)`.
        min_angle_deg: rays meeting their plane at a grazing angle below this are invalid (depth is then
            ill-conditioned: a small plane error moves the point far along the ray).
        degenerate: what to do with a plane through the camera centre: ``"raise"`` or ``"invalid"`` (mark
            its pixels invalid, for sweeps where one plane of many may be degenerate).

    Returns:
        depth :math:`(*)` (0 where invalid) and valid :math:`(*)` bool (finite, in front of the camera, not grazing).
        Differentiable in ``uv``, ``normals`` and ``offsets`` where valid.

    Raises:
        StereoInputError: when a plane passes through the camera centre (every ray lies in it: no depth).
    """
    K = torch.as_tensor(K)
    check_shape(K, ["3", "3"], "K")
    check_shape(uv, ["*", "2"], "uv")
    check_shape(normals, ["*", "3"], "normals")
    for name, x in (("uv", uv), ("normals", normals), ("offsets", offsets)):
        check_finite(x, name)
    n_norm = normals.norm(dim=-1)
    if bool((n_norm < 1e-12).any()):
        raise StereoInputError("normals: expected non-zero plane normals, got a zero vector")
    if degenerate not in ("raise", "invalid"):
        raise StereoInputError(f"degenerate: expected 'raise' or 'invalid', got {degenerate!r}")
    through_centre = offsets.abs() / n_norm < 1e-9
    if degenerate == "raise" and bool(through_centre.any()):
        raise StereoInputError("offsets: a light plane passes through the camera centre, so every camera ray "
                               "lies in it (plane parallel to the camera rays); depth is undetermined")
    uv1 = torch.cat([uv, torch.ones_like(uv[..., :1])], dim=-1)
    rays = uv1 @ torch.linalg.inv(K).to(uv1.dtype).T  # *x3, z-component 1
    dot = (rays * normals).sum(-1)
    sin_angle = dot.abs() / (rays.norm(dim=-1) * n_norm)
    ok = sin_angle >= torch.sin(torch.deg2rad(torch.tensor(float(min_angle_deg), dtype=torch.float64)))
    safe = torch.where(ok, dot, torch.ones_like(dot))
    depth = offsets / safe
    valid = ok & (depth > 0) & torch.isfinite(depth) & ~through_centre
    return torch.where(valid, depth, torch.zeros_like(depth)), valid


def depth_to_points(depth: torch.Tensor, valid: torch.Tensor, K: torch.Tensor,
                    uv: torch.Tensor | None = None) -> torch.Tensor:
    """Back-project a depth map :math:`(H, W)` (or depths at ``uv`` :math:`(*, 2)`) to camera-frame points
    :math:`(N, 3)`, keeping the ``valid`` entries in row-major order; ``K`` :math:`(3, 3)` tensor or array."""
    if uv is None:
        h, w = depth.shape
        v, u = torch.meshgrid(torch.arange(h, dtype=torch.float64), torch.arange(w, dtype=torch.float64),
                              indexing="ij")
        uv = torch.stack([u, v], dim=-1)
    if not bool(valid.any()):  # (back_project wants at least one point)
        return torch.zeros((0, 3), dtype=torch.float64)
    return back_project(uv.to(torch.float64)[valid], torch.as_tensor(K, dtype=torch.float64),
                        depth.to(torch.float64)[valid])


def reject_depth_edges(depth: torch.Tensor, valid: torch.Tensor, max_relative_jump: float = 0.03
                       ) -> torch.Tensor:
    """Flying-pixel filter: invalidate pixels at a depth jump.

    A pixel that straddles a depth discontinuity mixes the light of two surfaces and decodes to either of
    them (or to neither). Inverse depth is affine in ``(u, v)`` on any plane, so its second difference along
    a line of three valid pixels is ~0 on smooth surfaces however slanted, and as large as the jump at both
    pixels beside a step. A pixel is dropped when, along the row, the column or a diagonal,
    ``|1/z(p-s) - 2/z(p) + 1/z(p+s)| > max_relative_jump / z(p)``.
    ``depth``/``valid``: :math:`(B, 1, H, W)`. Returns the new valid mask.
    """
    check_shape(depth, ["B", "1", "H", "W"], "depth")
    inv = torch.where(valid, 1.0 / torch.where(valid, depth, torch.ones_like(depth)), torch.zeros_like(depth))
    pad_inv = torch.nn.functional.pad(inv, (1, 1, 1, 1))
    pad_ok = torch.nn.functional.pad(valid, (1, 1, 1, 1))
    h, w = depth.shape[-2:]
    shifted = lambda x, dy, dx: x[..., 1 + dy:1 + dy + h, 1 + dx:1 + dx + w]
    keep = valid.clone()
    for dy, dx in ((0, 1), (1, 0), (1, 1), (1, -1)):
        both = shifted(pad_ok, dy, dx) & shifted(pad_ok, -dy, -dx) & valid
        second = (shifted(pad_inv, dy, dx) - 2 * inv + shifted(pad_inv, -dy, -dx)).abs()
        keep &= ~(both & (second > max_relative_jump * inv))
    return keep
