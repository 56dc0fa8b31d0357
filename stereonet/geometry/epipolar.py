"""Two-view epipolar geometry: the normalized eight-point F, robust F, epipolar lines, epipoles, E and pose.

Convention: ``x2^T F x1 = 0`` for a point ``x1`` of the first (left) image and its match ``x2`` in the second
(right) image, pixels in ``(u, v)`` order. ``E = K2^T F K1`` and, with the pose ``X_2 = R X_1 + t``,
``E = [t]_x R``. F has 7 degrees of freedom (scale fixed to ``||F||_F = 1``, ``det F = 0``), E has 5 (its two
non-zero singular values are equal; we scale them to 1).

All solvers run in float64 internally and return the input's dtype. The numerical cores are kornia's
(:mod:`kornia.geometry.epipolar`); this module adds the input checks, the degeneracy tests, the canonical
scale/sign of F and E, and arbitrary leading batch dimensions. Robust F (RANSAC/LMedS) and the epipoles are ours.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
from kornia.geometry import epipolar as kge

from stereonet.checks import StereoInputError, check_finite, check_shape, check_tensor
from stereonet.geometry.camera import (
    DegenerateGeometryError,
    check_intrinsics,
    check_point_pairs,
    check_points,
)

__all__ = [
    "FundamentalEstimate",
    "PoseEstimate",
    "cross_product_matrix",
    "decompose_essential",
    "epipolar_lines",
    "epipoles",
    "essential_from_fundamental",
    "essential_from_pose",
    "fundamental_8point",
    "fundamental_from_essential",
    "fundamental_from_pose",
    "fundamental_robust",
    "homography_explains_matches",
    "normalize_points_hartley",
    "pose_from_essential",
    "project_to_essential",
    "sampson_distance",
]

# Relative size of the 8th singular value of the eight-point system below which the correspondences do not
# determine F (duplicate, collinear or exactly coplanar configurations): a few ulps of float64 work.
_RANK_TOL = {torch.float64: 1e-11, torch.float32: 1e-5, torch.float16: 1e-2, torch.bfloat16: 1e-2}


def cross_product_matrix(v: torch.Tensor) -> torch.Tensor:
    """``[v]_x`` :math:`(*, 3, 3)` for ``v`` :math:`(*, 3)`, so that ``[v]_x w = v x w`` (kornia)."""
    return kge.cross_product_matrix(v)


def _flat(points: torch.Tensor) -> torch.Tensor:
    """:math:`(*, N, D)` -> :math:`(B, N, D)`, the one batch dimension kornia's solvers take."""
    return points.reshape((-1,) + points.shape[-2:])


def _fix_scale_and_sign(M: torch.Tensor) -> torch.Tensor:
    """Scale to unit Frobenius norm and make the largest-magnitude entry positive (a canonical F)."""
    M = M / torch.linalg.matrix_norm(M).clamp_min(1e-300)[..., None, None]
    flat = M.flatten(-2)  # *x9
    sign = torch.gather(flat, -1, flat.abs().argmax(-1, keepdim=True)).sign()
    return M * sign.unsqueeze(-1)


def normalize_points_hartley(points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Hartley normalisation: centroid at the origin, mean distance to it :math:`\\sqrt 2`
    (:func:`kornia.geometry.epipolar.normalize_points`, any leading dimensions).

    Args:
        points: :math:`(*, N, 2)`.

    Returns:
        (normalized points :math:`(*, N, 2)`, ``T`` :math:`(*, 3, 3)` with ``x_norm = T x``).

    Raises:
        DegenerateGeometryError: when all points coincide (no scale can be defined).
    """
    check_points(points, "points", 2)
    # kornia's Hartley normalisation with eps = 0 (exact sqrt 2): coincident points are refused below instead
    x, T = kge.normalize_points(_flat(points), eps=0.0)  # BxNx2, Bx3x3
    mean_dist = math.sqrt(2.0) / T[:, 0, 0].detach()  # B, 0 when all points coincide
    centroid = points.detach().mean(dim=-2)
    if bool((mean_dist <= 1e-12 * (1.0 + centroid.abs().amax())).any()):
        raise DegenerateGeometryError(
            "points: all points coincide; Hartley normalisation needs spread points"
        )
    return x.reshape(points.shape), T.reshape(points.shape[:-2] + (3, 3))


def _eight_point_system(x1: torch.Tensor, x2: torch.Tensor) -> torch.Tensor:
    """Rows of the M x 9 system ``A f = 0`` for ``x2^T F x1 = 0`` with ``f`` = F in row-major order (for the
    rank test of :func:`_eight_point_core`; kornia solves the same system)."""
    u1, v1 = x1.unbind(-1)
    u2, v2 = x2.unbind(-1)
    one = torch.ones_like(u1)
    return torch.stack([u2 * u1, u2 * v1, u2, v2 * u1, v2 * v1, v2, u1, v1, one], dim=-1)  # *xMx9


def _eight_point_core(pts1: torch.Tensor, pts2: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The normalized eight-point F by :func:`kornia.geometry.epipolar.find_fundamental`, no input checks.

    Returns (F :math:`(*, 3, 3)` canonical scale/sign, rank margin :math:`(*)` = sigma_8 / sigma_1 of the
    Hartley-normalised system A).
    """
    x1, _ = normalize_points_hartley(pts1)  # raises on coincident points
    x2, _ = normalize_points_hartley(pts2)
    with torch.no_grad():
        s = torch.linalg.svdvals(_eight_point_system(x1, x2))  # *xmin(M,9)
    F = kge.find_fundamental(_flat(pts1), _flat(pts2), method="8POINT")  # Bx3x3, F[2, 2] = 1
    F = F.reshape(pts1.shape[:-2] + (3, 3))
    return _fix_scale_and_sign(F), s[..., 7] / s[..., 0].clamp_min(1e-300)


def fundamental_8point(pts1: torch.Tensor, pts2: torch.Tensor) -> torch.Tensor:
    """Normalized eight-point algorithm (Hartley & Zisserman, Alg. 11.1).

    Steps: Hartley normalisation of each image's points, the M x 9 linear system, its SVD, rank-2
    enforcement by zeroing F's smallest singular value, de-normalisation ``F = T2^T F_n T1``; F is returned
    with ``||F||_F = 1`` and its largest-magnitude entry positive. Differentiable for M >= 8 points in
    general position. The solve is :func:`kornia.geometry.epipolar.find_fundamental` (``"8POINT"``) in float64;
    kornia's ``F[2, 2] = 1`` scale is replaced by the canonical one.

    Args:
        pts1, pts2: matching pixels :math:`(*, M, 2)`, M >= 8.

    Returns:
        F :math:`(*, 3, 3)` with ``x2^T F x1 = 0``, dtype of ``pts1``.

    Raises:
        DegenerateGeometryError: fewer than 8 matches, or a configuration that leaves F undetermined
            (coincident/collinear points, an exactly planar scene, pure rotation).
    """
    check_points(pts1, "pts1", 2, min_count=8)
    check_points(pts2, "pts2", 2, min_count=8)
    if pts1.shape != pts2.shape:
        raise StereoInputError(
            f"pts2: expected the same shape as pts1 {tuple(pts1.shape)}, got {tuple(pts2.shape)}"
        )
    F, margin = _eight_point_core(pts1.double(), pts2.double())
    if bool((margin < _RANK_TOL.get(pts1.dtype, 1e-5)).any()):
        raise DegenerateGeometryError(
            "pts1, pts2: the eight-point system has rank < 8, so F is not determined (coincident, collinear "
            "or coplanar points, or a pure rotation); smallest relative singular value "
            f"{float(margin.min()):.1e}"
        )
    return F.to(pts1.dtype)


def sampson_distance(
    pts1: torch.Tensor, pts2: torch.Tensor, F: torch.Tensor, squared: bool = True
) -> torch.Tensor:
    """First-order geometric error of ``x2^T F x1 = 0``:
    ``(x2^T F x1)^2 / ((F x1)_1^2 + (F x1)_2^2 + (F^T x2)_1^2 + (F^T x2)_2^2)`` in px² (px if not squared).

    Args:
        pts1, pts2: :math:`(*, N, 2)`; F :math:`(*, 3, 3)` (broadcast over leading dims).

    Returns:
        :math:`(*, N)` (:func:`kornia.geometry.epipolar.sampson_epipolar_distance`; one point set against
        ``(H, 3, 3)`` models gives :math:`(H, N)`). A correspondence whose two epipolar lines are both
        degenerate (zero denominator, e.g. at both epipoles) is at distance ``inf``, never NaN.
    """
    check_point_pairs(pts1, pts2)
    _check_fundamental(F)
    return kge.sampson_epipolar_distance(pts1, pts2, F, squared=squared)


def _check_fundamental(F: object, name: str = "F") -> None:
    """A tensor :math:`(*, 3, 3)` of finite values; a one-line error naming ``name`` otherwise."""
    check_shape(check_tensor(F, name), ["*", "3", "3"], name)
    check_finite(F, name)


def epipolar_lines(points: torch.Tensor, F: torch.Tensor, in_image: int = 2) -> torch.Tensor:
    """Epipolar lines ``(a, b, c)`` with ``a^2 + b^2 = 1`` (so ``a u + b v + c`` is a distance in px).

    Args:
        points: :math:`(*, N, 2)` in image 1 when ``in_image == 2`` (lines ``F x1`` in image 2), in image 2
            when ``in_image == 1`` (lines ``F^T x2`` in image 1).
        F: :math:`(*, 3, 3)`.

    Returns:
        lines :math:`(*, N, 3)` (:func:`kornia.geometry.epipolar.compute_correspond_epilines`; a line with
        ``a = b = 0`` is left unscaled).
    """
    if in_image not in (1, 2):
        raise StereoInputError(f"in_image: expected 1 or 2, got {in_image!r}")
    M = F if in_image == 2 else F.transpose(-1, -2)
    return kge.compute_correspond_epilines(points, M)


def epipoles(F: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Epipoles as unit homogeneous vectors: ``e1`` with ``F e1 = 0`` (image 1), ``e2`` with ``F^T e2 = 0``.

    Returns:
        (e1, e2) each :math:`(*, 3)`, sign chosen so that the last coordinate is >= 0. Divide by the last
        coordinate for pixels; a last coordinate ~0 means the epipole is at infinity (e.g. a rectified pair).
    """
    _check_fundamental(F)
    U, _, Vh = torch.linalg.svd(F)
    e1, e2 = Vh[..., 2, :], U[..., :, 2]
    e1 = e1 * torch.where(e1[..., 2:] < 0, -1.0, 1.0)
    e2 = e2 * torch.where(e2[..., 2:] < 0, -1.0, 1.0)
    return e1, e2


def essential_from_fundamental(F: torch.Tensor, K1: torch.Tensor, K2: torch.Tensor) -> torch.Tensor:
    """``E = K2^T F K1`` projected to the essential manifold (equal singular values, see
    :func:`project_to_essential`). F :math:`(*, 3, 3)`, K1, K2 :math:`(*, 3, 3)`; the product is kornia's."""
    _check_fundamental(F)
    check_intrinsics(K1, "K1")
    check_intrinsics(K2, "K2")
    return project_to_essential(kge.essential_from_fundamental(F, K1, K2))


def fundamental_from_essential(E: torch.Tensor, K1: torch.Tensor, K2: torch.Tensor) -> torch.Tensor:
    """``F = K2^{-T} E K1^{-1}`` (kornia), canonical scale/sign as :func:`fundamental_8point`.
    E, K1, K2 :math:`(*, 3, 3)`, leading dimensions broadcast."""
    check_intrinsics(K1, "K1")
    check_intrinsics(K2, "K2")
    shape = torch.broadcast_shapes(E.shape[:-2], K1.shape[:-2], K2.shape[:-2]) + (3, 3)
    F = kge.fundamental_from_essential(E.expand(shape), K1.expand(shape), K2.expand(shape))
    return _fix_scale_and_sign(F)


def essential_from_pose(R: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """``E = [t]_x R`` for ``X_2 = R X_1 + t`` (R :math:`(*, 3, 3)`, t :math:`(*, 3)`)."""
    return cross_product_matrix(t) @ R


def fundamental_from_pose(
    K1: torch.Tensor, K2: torch.Tensor, R: torch.Tensor, t: torch.Tensor
) -> torch.Tensor:
    """F of a calibrated rig (``X_2 = R X_1 + t``), canonical scale/sign."""
    return fundamental_from_essential(essential_from_pose(R, t), K1, K2)


def project_to_essential(E: torch.Tensor) -> torch.Tensor:
    """Closest essential matrix (Frobenius): ``U diag(1, 1, 0) V^T`` from the SVD of ``E`` (kornia's
    projection, rescaled to unit singular values).

    Raises:
        DegenerateGeometryError: when E is (numerically) zero, i.e. a pure rotation with t = 0.
    """
    E_k = kge.project_to_essential(E)  # U diag(s, s, 0) V^T, s the mean of E's two largest singular values
    s = torch.linalg.matrix_norm(E_k) / math.sqrt(2.0)  # *
    if bool((s.detach() <= 1e-12 * E.detach().abs().amax().clamp_min(1e-300)).any()) or bool((s == 0).any()):
        raise DegenerateGeometryError("E: the essential matrix is zero (pure rotation without translation)")
    return E_k / s[..., None, None]


def decompose_essential(E: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The four ``(R, t)`` of an essential matrix (H&Z Result 9.19), ``|t| = 1``.

    Returns:
        (R :math:`(*, 4, 3, 3)`, t :math:`(*, 4, 3)`) in the order (R_a, t), (R_a, -t), (R_b, t), (R_b, -t)
        with ``R_a = U W V^T``, ``R_b = U W^T V^T``, ``t = u_3``
        (:func:`kornia.geometry.epipolar.motion_from_essential`).
    """
    R4, t4 = kge.motion_from_essential(E)  # *x4x3x3, *x4x3x1
    return R4, t4.squeeze(-1)


class PoseEstimate(NamedTuple):
    """Relative pose from E: ``X_2 = R X_1 + t`` with ``|t| = 1``; ``in_front`` counts the matches in front
    of both cameras for each of the four candidates :math:`(4,)` (order of :func:`decompose_essential`)."""

    R: torch.Tensor
    t: torch.Tensor
    in_front: torch.Tensor


def pose_from_essential(
    E: torch.Tensor, pts1: torch.Tensor, pts2: torch.Tensor, K1: torch.Tensor, K2: torch.Tensor
) -> PoseEstimate:
    """Pick the one of the four decompositions of E that puts the matches in front of both cameras.

    Args:
        E: :math:`(3, 3)`; pts1, pts2: matching (undistorted) pixels :math:`(N, 2)`; K1, K2: :math:`(3, 3)`.

    Returns:
        :class:`PoseEstimate` (R :math:`(3, 3)`, t :math:`(3,)`, in_front counts :math:`(4,)` per candidate).

    Raises:
        DegenerateGeometryError: E is zero (pure rotation), or no candidate has a majority of the matches in
            front of both cameras (wrong E or mismatched points).
    """
    from stereonet.geometry.triangulate import triangulate_dlt

    check_points(pts1, "pts1", 2)
    check_points(pts2, "pts2", 2)
    E = project_to_essential(E)
    R4, t4 = decompose_essential(E)
    P1 = torch.cat([K1, K1.new_zeros(3, 1)], dim=-1)  # 3x4
    P2 = K2 @ torch.cat([R4, t4.unsqueeze(-1)], dim=-1)  # 4x3x4
    X = triangulate_dlt(P1.expand(4, 3, 4), P2, pts1.expand(4, -1, -1), pts2.expand(4, -1, -1))  # 4xNx3
    z1 = X[..., 2]
    z2 = (X @ R4.transpose(-1, -2) + t4.unsqueeze(-2))[..., 2]
    counts = ((z1 > 0) & (z2 > 0)).sum(-1)
    best = int(counts.argmax())
    if int(counts[best]) * 2 <= pts1.shape[-2]:
        raise DegenerateGeometryError(
            "E, pts1, pts2: no decomposition puts most matches in front of both cameras "
            f"(best {int(counts[best])} of {pts1.shape[-2]}); E does not fit these matches"
        )
    return PoseEstimate(R4[best], t4[best], counts)


def homography_explains_matches(
    pts1: torch.Tensor, pts2: torch.Tensor, threshold: float = 3.0, min_off_plane: float = 0.05
) -> bool:
    """True when one homography (kornia's RANSAC, transfer error <= ``threshold`` px) explains the matches
    :math:`(N, 2)` except fewer than 8 of them or fewer than a fraction ``min_off_plane``: a planar scene or a
    pure rotation, where F is not determined. A dominant plane with enough parallax off it is not
    degenerate."""
    from kornia.geometry.ransac import RANSAC

    n = pts1.shape[0]
    H, mask = RANSAC("homography", inl_th=threshold, max_iter=5, seed=0)(pts1.double(), pts2.double())
    if not bool(torch.isfinite(H).all()) or not bool(H.abs().sum() > 0):
        return False
    off_plane = n - int(mask.sum())
    return off_plane < 8 or off_plane < min_off_plane * n


class FundamentalEstimate(NamedTuple):
    """Robust F: the matrix :math:`(3, 3)`, the inlier mask :math:`(N,)` bool, and ``planar``: True when one
    homography explains nearly all inliers (planar scene, pure rotation, or a dominant plane with too little
    parallax off it), so F is weakly or not at all determined away from that plane."""

    F: torch.Tensor
    inliers: torch.Tensor
    planar: bool = False


def _sample_minimal_sets(num_points: int, count: int, generator: torch.Generator) -> torch.Tensor:
    weights = torch.ones(count, num_points, dtype=torch.float64)
    return torch.multinomial(weights, 8, replacement=False, generator=generator)  # countx8


def fundamental_robust(
    pts1: torch.Tensor,
    pts2: torch.Tensor,
    method: str = "ransac",
    threshold: float = 1.0,
    confidence: float = 0.999,
    max_iterations: int = 5000,
    batch_size: int = 64,
    seed: int = 0,
    on_planar: str = "flag",
) -> FundamentalEstimate:
    """Robust F by RANSAC or LMedS over eight-point hypotheses, scored with the Sampson distance.

    Hypotheses are drawn ``batch_size`` at a time and solved and scored as one batched tensor computation.
    RANSAC keeps the hypothesis with most matches within ``threshold`` px (Sampson, not squared) and stops
    when ``confidence`` is reached (adaptive count); LMedS keeps the one with the least median Sampson error
    and sets the threshold to ``2.5 * 1.4826 * (1 + 5 / (N - 8)) * sqrt(median)``. The winner is refined by
    the eight-point solve on its inliers until the inlier set stops changing (at most 5 times).

    Args:
        pts1, pts2: matching pixels :math:`(N, 2)`, N >= 8.
        method: ``"ransac"`` or ``"lmeds"``.
        threshold: RANSAC inlier threshold in px (Sampson distance).
        seed: the random sampling is a pure function of it.
        on_planar: what to do when one homography explains nearly all inliers (planar scene, pure rotation;
            see :func:`homography_explains_matches`): ``"flag"`` sets ``planar=True`` in the result,
            ``"raise"`` raises DegenerateGeometryError, ``"ignore"`` skips the test.

    Returns:
        :class:`FundamentalEstimate` (F :math:`(3, 3)` in the input dtype, inliers :math:`(N,)` bool).
    """
    check_points(pts1, "pts1", 2, min_count=8)
    check_points(pts2, "pts2", 2, min_count=8)
    if pts1.dim() != 2 or pts1.shape != pts2.shape:
        raise StereoInputError(
            f"pts1, pts2: expected two (N, 2) tensors of equal shape, got "
            f"{tuple(pts1.shape)} and {tuple(pts2.shape)}"
        )
    if method not in ("ransac", "lmeds"):
        raise StereoInputError(f"method: expected 'ransac' or 'lmeds', got {method!r}")
    if on_planar not in ("flag", "raise", "ignore"):
        raise StereoInputError(f"on_planar: expected 'flag', 'raise' or 'ignore', got {on_planar!r}")
    if not threshold > 0:
        raise StereoInputError(f"threshold: expected a positive number of pixels, got {threshold!r}")
    if isinstance(batch_size, bool) or not isinstance(batch_size, int) or batch_size < 1:
        raise StereoInputError(f"batch_size: expected a positive integer, got {batch_size!r}")
    p1, p2 = pts1.detach().double(), pts2.detach().double()
    n = p1.shape[0]
    gen = torch.Generator().manual_seed(seed)
    best_score, best_F = math.inf, None
    needed, done = (max_iterations if method == "ransac" else min(max_iterations, 1000)), 0
    while done < needed:
        count = min(batch_size, needed - done)
        idx = _sample_minimal_sets(n, count, gen)  # Hx8
        try:
            F_h, margin = _eight_point_core(p1[idx], p2[idx])  # Hx3x3
        except DegenerateGeometryError:  # a sample of coincident points: redraw
            done += count
            continue
        ok = (margin > 1e-12) & torch.isfinite(F_h).all(-1).all(-1)  # H, determined samples
        d2 = kge.sampson_epipolar_distance(p1, p2, F_h, squared=True)  # HxN (hypotheses may be degenerate: unchecked)
        if method == "ransac":
            score = -((d2 < threshold**2) & ok[:, None]).sum(-1).double()
        else:
            score = torch.where(ok, d2.median(-1).values, torch.full_like(margin, math.inf))
        k = int(score.argmin())
        if float(score[k]) < best_score:
            best_score, best_F = float(score[k]), F_h[k]
            if method == "ransac":
                w = -best_score / n
                needed = min(max_iterations, _ransac_iterations(w, confidence))
        done += count
    if best_F is None:
        raise DegenerateGeometryError(
            "pts1, pts2: every sample was degenerate; the matches do not determine F"
        )
    if method == "lmeds":
        sigma = 1.4826 * (1 + 5 / max(n - 8, 1)) * math.sqrt(max(best_score, 0.0))
        threshold = max(2.5 * sigma, 1e-6)
    inliers = kge.sampson_epipolar_distance(p1, p2, best_F, squared=True) < threshold**2
    for _ in range(5):
        if int(inliers.sum()) < 8:
            break
        F_ref, _ = _eight_point_core(p1[inliers], p2[inliers])
        new_inliers = kge.sampson_epipolar_distance(p1, p2, F_ref, squared=True) < threshold**2
        if int(new_inliers.sum()) < int(inliers.sum()):
            break
        best_F, changed, inliers = F_ref, bool((new_inliers != inliers).any()), new_inliers
        if not changed:
            break
    if int(inliers.sum()) < 8:
        raise DegenerateGeometryError(
            f"pts1, pts2: only {int(inliers.sum())} of {n} matches fit one F "
            f"(need 8); too many outliers or threshold {threshold:.3g} px too small"
        )
    planar = on_planar != "ignore" and homography_explains_matches(
        p1[inliers], p2[inliers], threshold=3 * max(threshold, 1.0)
    )
    if planar and on_planar == "raise":
        raise DegenerateGeometryError(
            "pts1, pts2: a single homography explains the matches (planar scene or pure rotation without "
            "translation), so F is not determined; pass on_planar='flag' to get an arbitrary F anyway"
        )
    return FundamentalEstimate(best_F.to(pts1.dtype), inliers, planar)


def _ransac_iterations(inlier_ratio: float, confidence: float, sample_size: int = 8) -> int:
    if inlier_ratio <= 0:
        return 10**9
    p_good = inlier_ratio**sample_size
    if p_good >= 1.0:
        return 1
    return int(math.ceil(math.log(1 - confidence) / math.log1p(-p_good)))
