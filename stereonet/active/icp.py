"""Aligning range scans: ICP (point-to-point and point-to-plane), pose errors, and merging into one cloud.

All maths is vectorized in torch (float64); nearest neighbours come from ``scipy.spatial.cKDTree``.

* :func:`best_rigid_transform` — the closed-form least-squares rotation + translation between matched points
  (Kabsch/Umeyama via SVD, reflection-corrected).
* :func:`point_to_plane_step` — one linearised Gauss-Newton step minimising ``sum (n_i . (R p_i + t - q_i))^2``
  for small rotations (Chen & Medioni / Low 2004).
* :func:`icp` — alternates nearest-neighbour matching (with a distance gate) and one of the two solvers,
  from an initial guess. Raises :class:`~stereonet.checks.StereoInputError` when the scans do not overlap
  (too few source points have a target neighbour within the gate) instead of returning a meaningless pose.
* :func:`merge_scans` — transform every scan into the reference frame, concatenate, voxel-downsample.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from scipy.spatial import cKDTree

from stereonet.checks import StereoInputError, check_finite, check_shape

_F64 = torch.float64


def _check_points(x: object, name: str) -> torch.Tensor:
    if not isinstance(x, torch.Tensor):
        raise TypeError(f"{name}: expected a torch.Tensor of shape (N, 3), got {type(x).__name__}")
    check_shape(x, ["N", "3"], name)
    check_finite(x, name)
    return x.to(_F64)


def rotation_matrix(axis_angle: Sequence[float] | torch.Tensor) -> torch.Tensor:
    """Rodrigues: rotation :math:`(3, 3)` of an axis-angle vector :math:`(3,)` (radians)."""
    w = torch.as_tensor(axis_angle, dtype=_F64).reshape(3)
    theta = w.norm()
    if float(theta) < 1e-15:
        return torch.eye(3, dtype=_F64)
    k = w / theta
    Kx = torch.zeros(3, 3, dtype=_F64)
    Kx[0, 1], Kx[0, 2], Kx[1, 2] = -k[2], k[1], -k[0]
    Kx = Kx - Kx.T
    return torch.eye(3, dtype=_F64) + torch.sin(theta) * Kx + (1 - torch.cos(theta)) * Kx @ Kx


def rotation_error_deg(R_est: torch.Tensor, R_gt: torch.Tensor) -> float:
    """Angle (degrees) of the rotation ``R_est^T R_gt``."""
    c = (torch.trace(R_est.to(_F64).T @ R_gt.to(_F64)) - 1) / 2
    return math.degrees(math.acos(float(c.clamp(-1, 1))))


def best_rigid_transform(src: torch.Tensor, dst: torch.Tensor,
                         weights: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Least-squares ``R, t`` with ``dst ~ R src + t`` for matched points :math:`(N, 3)` (N >= 3, not collinear).

    Kabsch: SVD of the weighted cross-covariance, with the sign fix that keeps ``det R = +1``.
    """
    w = torch.ones(src.shape[0], dtype=src.dtype) if weights is None else weights.to(src.dtype)
    w = w / w.sum()
    mu_s, mu_d = w @ src, w @ dst
    H = (src - mu_s).T @ ((dst - mu_d) * w[:, None])  # 3x3
    U, _, Vt = torch.linalg.svd(H)
    d = torch.sign(torch.linalg.det(Vt.T @ U.T))
    D = torch.diag(torch.stack([torch.ones_like(d), torch.ones_like(d), d]))
    R = Vt.T @ D @ U.T
    return R, mu_d - R @ mu_s


def point_to_plane_step(src: torch.Tensor, dst: torch.Tensor, dst_normals: torch.Tensor,
                        weights: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """One linearised point-to-plane step: ``R, t`` minimising ``sum w (n . (R p + t - q))^2`` for small angles.

    With ``R ~ I + [w]x`` the residual is ``(p x n) . w + n . t + n . (p - q)``: a 6x6 normal-equation solve.
    The small-angle solution is re-orthonormalised through Rodrigues.
    """
    w = torch.ones(src.shape[0], dtype=src.dtype) if weights is None else weights.to(src.dtype)
    A = torch.cat([torch.linalg.cross(src, dst_normals), dst_normals], dim=1)  # Nx6
    b = -((src - dst) * dst_normals).sum(-1)  # N
    AtA = A.T @ (A * w[:, None])
    Atb = A.T @ (b * w)
    x = torch.linalg.solve(AtA + 1e-12 * torch.eye(6, dtype=src.dtype), Atb)
    return rotation_matrix(x[:3]), x[3:]


def estimate_normals(points: torch.Tensor, k: int = 12, viewpoint: Sequence[float] | None = (0.0, 0.0, 0.0),
                     tree: cKDTree | None = None) -> torch.Tensor:
    """Unit normals :math:`(N, 3)` by PCA of each point's ``k`` nearest neighbours (smallest-eigenvalue axis),
    oriented toward ``viewpoint`` (the scanner centre in the points' frame) when given."""
    points = _check_points(points, "points")
    n = points.shape[0]
    if n < 3:
        raise StereoInputError(f"points: expected at least 3 points to estimate normals, got {n}")
    k = min(k, n)
    tree = cKDTree(points.numpy()) if tree is None else tree
    _, idx = tree.query(points.numpy(), k=k)
    nb = points[torch.from_numpy(np.asarray(idx)).long()]  # NxKx3
    c = nb - nb.mean(dim=1, keepdim=True)
    cov = c.transpose(1, 2) @ c  # Nx3x3
    _, vecs = torch.linalg.eigh(cov)
    normals = vecs[:, :, 0]
    if viewpoint is not None:
        vp = torch.as_tensor(viewpoint, dtype=_F64)
        flip = ((vp - points) * normals).sum(-1) < 0
        normals = torch.where(flip[:, None], -normals, normals)
    return normals


@dataclass
class ICPResult:
    """``R`` :math:`(3, 3)`, ``t`` :math:`(3,)` mapping source into target (``target ~ R source + t``);
    ``rmse`` of the final inlier correspondences (point-to-point distance, or point-to-plane distance for that
    method), ``overlap`` = fraction of source points with a target neighbour within the gate, ``iterations``,
    ``converged``."""

    R: torch.Tensor
    t: torch.Tensor
    rmse: float
    overlap: float
    iterations: int
    converged: bool

    def transform(self, points: torch.Tensor) -> torch.Tensor:
        return points.to(_F64) @ self.R.T + self.t


def icp(source: torch.Tensor, target: torch.Tensor, init_R: torch.Tensor | None = None,
        init_t: torch.Tensor | None = None, method: str = "point_to_plane", max_iterations: int = 60,
        max_distance: float = 0.1, tolerance: float = 1e-7, min_overlap: float = 0.1,
        target_normals: torch.Tensor | None = None, trim: float = 0.9, normal_k: int = 12) -> ICPResult:
    """Iterative closest point: find ``R, t`` with ``target ~ R source + t``.

    Args:
        source: :math:`(N, 3)` points to move; target: :math:`(M, 3)` fixed points.
        init_R, init_t: initial guess (identity / zero when omitted), e.g. from odometry or feature matches.
        method: ``"point_to_point"`` (Besl & McKay, closed-form Kabsch each step) or ``"point_to_plane"``
            (Chen & Medioni, linearised; converges in fewer steps on smooth surfaces).
        max_distance: correspondence gate (scene units) — pairs farther apart are ignored.
        tolerance: stop when the pose update moves points by less than this (RMS, scene units).
        min_overlap: fewer gated matches than this fraction of source points (at the start or the end)
            means the scans do not overlap under the guess: raises instead of returning a meaningless pose.
        target_normals: :math:`(M, 3)` normals for point-to-plane (estimated by PCA when omitted).
        trim: keep this fraction of the gated pairs with the smallest distances (robust to partial overlap).

    Raises:
        StereoInputError: bad shapes, unknown method, or no overlap.
    """
    src = _check_points(source, "source")
    dst = _check_points(target, "target")
    methods = ("point_to_point", "point_to_plane")
    if method not in methods:
        raise StereoInputError(f"method: expected one of {methods}, got {method!r}")
    if src.shape[0] < 3 or dst.shape[0] < 3:
        raise StereoInputError(f"source/target: expected at least 3 points each, got {src.shape[0]} and {dst.shape[0]}")
    if not 0 < trim <= 1:
        raise StereoInputError(f"trim: expected 0 < trim <= 1, got {trim}")
    R = torch.eye(3, dtype=_F64) if init_R is None else init_R.to(_F64).clone()
    t = torch.zeros(3, dtype=_F64) if init_t is None else init_t.to(_F64).reshape(3).clone()
    check_shape(R, ["3", "3"], "init_R")
    tree = cKDTree(dst.numpy())
    if method == "point_to_plane":
        if target_normals is None:
            target_normals = estimate_normals(dst, k=normal_k, viewpoint=None, tree=tree)
        nrm = _check_points(target_normals, "target_normals")
        if nrm.shape != dst.shape:
            raise StereoInputError(f"target_normals: expected shape {tuple(dst.shape)}, got {tuple(nrm.shape)}")

    def match(moved: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        dist, idx = tree.query(moved.numpy(), k=1, distance_upper_bound=max_distance)
        dist, idx = torch.from_numpy(dist), torch.from_numpy(idx).long()
        keep = torch.isfinite(dist)
        sel = keep.nonzero().flatten()
        if trim < 1 and sel.numel() > 3:
            n_keep = max(3, int(math.ceil(trim * sel.numel())))
            sel = sel[torch.argsort(dist[sel])[:n_keep]]
        return sel, idx[sel], keep.to(_F64).mean()

    def no_overlap(overlap: float, when: str) -> StereoInputError:
        return StereoInputError(
            f"source/target: the scans do not overlap {when}: only {100 * overlap:.1f}% of source points have "
            f"a target point within max_distance={max_distance} (min_overlap={100 * min_overlap:.0f}%); "
            f"give a better initial pose or a larger max_distance")

    converged = False
    it = 0
    for it in range(1, max_iterations + 1):  # noqa: B007 - the count is reported
        moved = src @ R.T + t
        sel, j, overlap = match(moved)
        if float(overlap) < min_overlap or sel.numel() < 6:
            raise no_overlap(float(overlap), "under the initial pose" if it == 1 else f"at iteration {it}")
        if method == "point_to_point":
            dR, dt = best_rigid_transform(moved[sel], dst[j])
        else:
            dR, dt = point_to_plane_step(moved[sel], dst[j], nrm[j])
        R, t = dR @ R, dR @ t + dt
        step = (moved[sel] @ dR.T + dt - moved[sel]).norm(dim=-1).pow(2).mean().sqrt()
        if float(step) < tolerance:
            converged = True
            break
    moved = src @ R.T + t
    sel, j, overlap = match(moved)
    if float(overlap) < min_overlap or sel.numel() < 3:
        raise no_overlap(float(overlap), "after alignment")
    diff = moved[sel] - dst[j]
    res = (diff * nrm[j]).sum(-1) if method == "point_to_plane" else diff.norm(dim=-1)
    return ICPResult(R, t, float(res.pow(2).mean().sqrt()), float(overlap), it, converged)


def voxel_downsample(points: torch.Tensor, colors: torch.Tensor | None, voxel: float
                     ) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Average points (and colours) falling in the same cubic voxel of side ``voxel``."""
    points = _check_points(points, "points")
    if voxel <= 0:
        raise StereoInputError(f"voxel: expected > 0, got {voxel}")
    keys = torch.floor(points / voxel).to(torch.int64)
    _, inv = torch.unique(keys, dim=0, return_inverse=True)
    n = int(inv.max()) + 1 if inv.numel() else 0
    count = torch.zeros(n, dtype=_F64).index_add_(0, inv, torch.ones_like(inv, dtype=_F64))
    out = torch.zeros(n, 3, dtype=_F64).index_add_(0, inv, points) / count[:, None]
    if colors is None:
        return out, None
    col = torch.zeros(n, 3, dtype=_F64).index_add_(0, inv, colors.to(_F64)) / count[:, None]
    return out, col.round().clamp(0, 255).to(torch.uint8) if colors.dtype == torch.uint8 else col


def merge_scans(points: Sequence[torch.Tensor], colors: Sequence[torch.Tensor] | None,
                rotations: Sequence[torch.Tensor], translations: Sequence[torch.Tensor],
                voxel: float | None = None) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Map scan ``i`` by ``X -> R_i X + t_i`` into the common frame, concatenate, optionally voxel-downsample.

    Returns points :math:`(N, 3)` float64 and colours :math:`(N, 3)` (uint8 if given as uint8) or None.
    """
    if not (len(points) == len(rotations) == len(translations)) or (colors is not None and len(colors) != len(points)):
        raise StereoInputError("points/colors/rotations/translations: expected one entry per scan each")
    pts = torch.cat([_check_points(p, f"points[{i}]") @ R.to(_F64).T + t.to(_F64).reshape(3)
                     for i, (p, R, t) in enumerate(zip(points, rotations, translations))])
    col = None if colors is None else torch.cat(list(colors))
    if voxel is not None:
        return voxel_downsample(pts, col, voxel)
    return pts, col


def ransac_rigid(src: torch.Tensor, dst: torch.Tensor, threshold: float = 0.03, iterations: int = 1000,
                 min_inliers: int = 6, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Robust ``R, t`` with ``dst ~ R src + t`` from putative 3-D matches :math:`(N, 3)` (e.g. back-projected
    feature matches), some wrong: RANSAC over minimal 3-point Kabsch fits (all hypotheses solved at once by a
    batched SVD), then a least-squares refit on the inliers (distance < ``threshold``).

    Returns ``R`` :math:`(3, 3)`, ``t`` :math:`(3,)`, inlier mask :math:`(N,)`.
    Raises :class:`StereoInputError` when fewer than ``min_inliers`` matches agree on one motion.
    """
    src, dst = _check_points(src, "src"), _check_points(dst, "dst")
    if src.shape != dst.shape:
        raise StereoInputError(f"dst: expected shape {tuple(src.shape)} like src, got {tuple(dst.shape)}")
    n = src.shape[0]
    if n < max(3, min_inliers):
        raise StereoInputError(f"src: expected at least {max(3, min_inliers)} matches, got {n}")
    g = torch.Generator().manual_seed(int(seed))
    idx = torch.randint(0, n, (iterations, 3), generator=g)
    S, D = src[idx], dst[idx]  # Ix3x3
    mu_s, mu_d = S.mean(1, keepdim=True), D.mean(1, keepdim=True)
    H = (S - mu_s).transpose(1, 2) @ (D - mu_d)  # Ix3x3
    U, _, Vt = torch.linalg.svd(H)
    V, Ut = Vt.transpose(1, 2), U.transpose(1, 2)
    fix = torch.ones(iterations, 3, dtype=_F64)
    fix[:, 2] = torch.sign(torch.linalg.det(V @ Ut))
    R = V @ torch.diag_embed(fix) @ Ut  # Ix3x3
    t = mu_d[:, 0] - (R @ mu_s[:, 0, :, None])[..., 0]  # Ix3
    resid = (src[None] @ R.transpose(1, 2) + t[:, None] - dst[None]).norm(dim=-1)  # IxN
    count = (resid < threshold).sum(1)
    best = int(count.argmax())
    inliers = resid[best] < threshold
    if int(inliers.sum()) < min_inliers:
        raise StereoInputError(f"src/dst: no rigid motion explains more than {int(inliers.sum())} of {n} matches "
                               f"within {threshold} (need {min_inliers}); the scans may not overlap")
    R_fit, t_fit = best_rigid_transform(src[inliers], dst[inliers])
    inliers = (src @ R_fit.T + t_fit - dst).norm(dim=-1) < threshold
    return R_fit, t_fit, inliers


@dataclass
class RangeScan:
    """One range scan: camera-frame ``points`` :math:`(N, 3)`, ``colors`` :math:`(N, 3)` uint8, and the scanner's
    true world-to-camera pose ``R`` :math:`(3, 3)`, ``t`` :math:`(3,)` (for evaluation and for making guesses).
    Optionally the scanner's colour ``image`` :math:`(1, 3, H, W)`, its noisy ``depth`` map :math:`(H, W)`
    (0 = no return) and intrinsics ``K``, for feature-based initial guesses (:func:`feature_guess`)."""

    points: torch.Tensor
    colors: torch.Tensor
    R: torch.Tensor
    t: torch.Tensor
    image: torch.Tensor | None = None
    depth: torch.Tensor | None = None
    K: torch.Tensor | None = None


def feature_guess(scan_to: RangeScan, scan_from: RangeScan, threshold: float = 0.03,
                  seed: int = 0) -> tuple[torch.Tensor, torch.Tensor, int]:
    """Coarse pose of ``scan_from`` in ``scan_to``'s frame from SIFT matches between their images, lifted to
    3-D through their depth maps and fitted by :func:`ransac_rigid`. Returns ``R``, ``t``, inlier count.

    Raises :class:`StereoInputError` when the images share too few consistent features (no overlap).
    """
    from stereonet.checks import DegenerateGeometryError
    from stereonet.features.matching import match_sift

    for name, sc in (("scan_to", scan_to), ("scan_from", scan_from)):
        if sc.image is None or sc.depth is None or sc.K is None:
            raise StereoInputError(f"{name}: expected a scan with image, depth and K for feature matching")
    try:
        xy_to, xy_from = match_sift(scan_to.image, scan_from.image, min_matches=6)
    except DegenerateGeometryError as e:
        raise StereoInputError(f"scan_to/scan_from: too few feature matches to guess a pose ({e})") from e

    def lift(sc: RangeScan, xy: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        h, w = sc.depth.shape
        px = xy.round().long()
        px[:, 0].clamp_(0, w - 1)
        px[:, 1].clamp_(0, h - 1)
        z = sc.depth[px[:, 1], px[:, 0]].to(_F64)
        uv1 = torch.cat([xy, torch.ones_like(xy[:, :1])], 1).to(_F64)
        return (uv1 @ torch.linalg.inv(sc.K.to(_F64)).T) * z[:, None], z > 0

    p_to, ok_to = lift(scan_to, xy_to)
    p_from, ok_from = lift(scan_from, xy_from)
    ok = ok_to & ok_from
    R, t, inl = ransac_rigid(p_from[ok], p_to[ok], threshold=threshold, seed=seed)
    return R, t, int(inl.sum())


def relative_pose(R_to: torch.Tensor, t_to: torch.Tensor, R_from: torch.Tensor,
                  t_from: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Pose mapping points of camera ``from`` into camera ``to`` (both world-to-camera poses):
    ``R = R_to R_from^T``, ``t = t_to - R t_from``."""
    R = R_to.to(_F64) @ R_from.to(_F64).T
    return R, t_to.to(_F64) - R @ t_from.to(_F64)


@dataclass
class Alignment:
    """:func:`align_scans` output: per scan the pose into scan 0's frame (``R[i]``, ``t[i]``; scan 0 is the
    identity) and the :class:`ICPResult` of scans 1..n-1 (``results[i - 1]``)."""

    R: list
    t: list
    results: list


def align_scans(points: Sequence[torch.Tensor], init_R: Sequence[torch.Tensor], init_t: Sequence[torch.Tensor],
                method: str = "point_to_plane", voxel: float | None = 0.01, max_distance: float = 0.1,
                **icp_options) -> Alignment:
    """Register scans 1..n-1 one after another onto the growing model of the scans already placed (frame of
    scan 0), each from its initial guess ``init_R[i], init_t[i]`` (into scan 0's frame; entry 0 is ignored).

    Aligning to the growing model rather than to scan 0 alone lets a scan that barely overlaps scan 0 lock
    onto the scans between them. Raises like :func:`icp` when a scan overlaps none of the placed ones.
    """
    if not (len(points) == len(init_R) == len(init_t)) or len(points) < 2:
        raise StereoInputError("points/init_R/init_t: expected one entry per scan each, at least 2 scans")
    eye, zero = torch.eye(3, dtype=_F64), torch.zeros(3, dtype=_F64)
    Rs, ts, results = [eye], [zero], []
    model = _check_points(points[0], "points[0]")
    for i in range(1, len(points)):
        tgt = voxel_downsample(model, None, voxel)[0] if voxel else model
        src = _check_points(points[i], f"points[{i}]")
        src_ds = voxel_downsample(src, None, voxel)[0] if voxel else src
        try:
            res = icp(src_ds, tgt, init_R[i], init_t[i], method=method, max_distance=max_distance, **icp_options)
        except StereoInputError as e:
            raise StereoInputError(f"points[{i}]: {e}") from e
        Rs.append(res.R)
        ts.append(res.t)
        results.append(res)
        model = torch.cat([model, res.transform(src)])
    return Alignment(Rs, ts, results)
