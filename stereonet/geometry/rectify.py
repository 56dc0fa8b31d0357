"""Stereo rectification: calibrated (rotation from the baseline), OpenCV-compatible, uncalibrated (Hartley).

After rectification corresponding points share a row, and the disparity follows the project convention
(left reference, ``x_right = x_left - d``). Images are warped by inverse mapping: every rectified pixel
looks up its source position (kornia ``warp_perspective`` for a pure homography, kornia ``remap`` when the
source lenses are distorted). Pixel centres are at integer coordinates (OpenCV convention,
``align_corners=True``).
"""

from __future__ import annotations

import logging
import math
import os
from dataclasses import dataclass, field, replace

import torch
from kornia.geometry.transform import remap, warp_perspective

from stereonet.checks import StereoInputError, check_image_pair
from stereonet.geometry.camera import DegenerateGeometryError, distort_pixels, undistort_pixels
from stereonet.geometry.epipolar import epipoles, fundamental_robust, sampson_distance
from stereonet.types import Calibration

__all__ = [
    "Rectification",
    "apply_homography",
    "hartley_homographies",
    "rectification_maps",
    "rectify_calibrated",
    "rectify_from_file",
    "rectify_points",
    "rectify_uncalibrated",
    "is_reversed_rig",
    "rectifying_rotation",
    "stereo_rectify",
    "stereo_rectify_uncalibrated",
    "warp_image",
]


@dataclass
class Rectification:
    """A rectified pair and everything needed to map between the original and rectified frames.

    Attributes:
        left, right: rectified images :math:`(B, C, H', W')` (None from :func:`stereo_rectify`, which computes
            the geometry only).
        H1, H2: float64 :math:`(3, 3)` homographies from the original *ideal* (undistorted) pixels of the
            left/right image to the rectified pixels (``K R_rect K1^-1`` and ``K R_rect R^T K2^-1`` when
            calibrated).
        P1, P2: rectified projection matrices :math:`(3, 4)` (left camera frame of the rectified rig, OpenCV
            layout: ``P2[0, 3] = -f B``); None when uncalibrated.
        Q: :math:`(4, 4)` disparity-to-depth matrix, ``[X Y Z W]^T = Q [u v d 1]^T`` (OpenCV layout); None
            when uncalibrated.
        calib: the rectified rig as a :class:`Calibration` (usable by ``disparity_to_depth``); None when
            uncalibrated.
        maps: ``(map_left, map_right)``, each :math:`(H', W', 2)`: the source pixel ``(x, y)`` each rectified
            pixel samples (lens distortion included); None from :func:`stereo_rectify`.
        R1, R2: rectifying rotations of the left/right camera (calibrated only, else None).
        original: the calibration the pair came with (for :func:`rectify_points`), None when uncalibrated.
        F: fundamental matrix of the original pair (uncalibrated only); matches / inliers: the matches
            :math:`(N, 2)` x 2 in original pixels and their inlier mask (uncalibrated only).
        disparity_range: (1st, 99th percentile) of the inlier matches' disparity after rectification
            (uncalibrated), a hint for ``max_disp``.
        notes: warnings about the result, e.g. that one homography explains nearly all matches (dominant
            plane, pure rotation: F, hence the rectification, is weakly determined away from that plane).
        reversed: the "right" camera sits to the left of the "left" one (its centre at negative x in the left
            camera frame). The rectified frame is then kept upright (its x axis points against the baseline,
            instead of turning both images by 180 degrees as a baseline-aligned frame would), so the second
            camera lies at ``-B`` along x: matches in the second image are at ``x + d`` (``P2[0, 3] = +f B``,
            OpenCV's signed disparity ``x_first - x_second`` is negative); ``calib`` keeps ``B > 0`` for the
            mirrored, positive disparity ``x_second - x_first`` (see :func:`is_reversed_rig`).
    """

    left: torch.Tensor | None
    right: torch.Tensor | None
    H1: torch.Tensor
    H2: torch.Tensor
    P1: torch.Tensor | None
    P2: torch.Tensor | None
    Q: torch.Tensor | None
    calib: Calibration | None
    maps: tuple[torch.Tensor, torch.Tensor] | None
    R1: torch.Tensor | None = None
    R2: torch.Tensor | None = None
    original: Calibration | None = None
    F: torch.Tensor | None = None
    matches: tuple[torch.Tensor, torch.Tensor] | None = None
    inliers: torch.Tensor | None = None
    disparity_range: tuple[float, float] | None = None
    notes: list[str] = field(default_factory=list)
    reversed: bool = False


def is_reversed_rig(calib: Calibration) -> bool:
    """Whether the second camera's centre ``-R^T t`` lies at negative x in the first camera's frame (a rig
    whose "right" camera sits on the left, e.g. the two files given in the other order)."""
    return float(-(calib.R.T @ calib.t)[0]) < 0


def apply_homography(H: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """``H x`` dehomogenised for points :math:`(*, N, 2)`, H :math:`(*, 3, 3)` (points mapped to infinity
    get a huge finite value, never NaN)."""
    p = torch.cat([points, torch.ones_like(points[..., :1])], -1) @ H.transpose(-1, -2)  # *xNx3
    w = p[..., 2:]
    w = torch.where(w.abs() < 1e-12, torch.where(w < 0, -1e-12, 1e-12).to(w.dtype), w)
    return p[..., :2] / w


def rectifying_rotation(R: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """Rotation taking the left camera frame to the rectified frame: rows ``r1, r2, r3`` with
    ``r1`` = direction of the baseline (the right camera centre ``-R^T t`` seen from the left camera, i.e. the
    epipole of the left image), ``r2 = z x r1`` normalised, ``r3 = r1 x r2``.

    Raises:
        DegenerateGeometryError: ``t = 0`` (pure rotation) or a baseline along the optical axis (forward
            motion: the epipole is the image centre, no rectifying rotation keeps the image).
    """
    c2 = -(R.T @ t)
    norm = float(torch.linalg.vector_norm(c2))
    if norm == 0 or not math.isfinite(norm):
        raise DegenerateGeometryError("calib.t: the baseline is zero (pure rotation); cannot rectify")
    r1 = c2 / norm
    z = torch.tensor([0.0, 0.0, 1.0], dtype=R.dtype, device=R.device)
    r2 = torch.linalg.cross(z, r1)
    if float(torch.linalg.vector_norm(r2)) < 0.1:  # baseline within ~6 degrees of the optical axis
        raise DegenerateGeometryError(
            "calib.t: the baseline points along the optical axis (forward motion); the epipole lies inside "
            "the image and no rectifying rotation can keep it"
        )
    r2 = r2 / torch.linalg.vector_norm(r2)
    r3 = torch.linalg.cross(r1, r2)
    return torch.stack([r1, r2, r3])


_PER_EDGE = 32


def _border_edges(width: int, height: int, per_edge: int = _PER_EDGE) -> list[torch.Tensor]:
    """Pixel-centre samples of the four image edges (top, bottom, left, right), each (per_edge, 2) float64."""
    xs = torch.linspace(0, width - 1, per_edge, dtype=torch.float64)
    ys = torch.linspace(0, height - 1, per_edge, dtype=torch.float64)
    return [
        torch.stack([xs, torch.zeros_like(xs)], -1),
        torch.stack([xs, torch.full_like(xs, height - 1.0)], -1),
        torch.stack([torch.zeros_like(ys), ys], -1),
        torch.stack([torch.full_like(ys, width - 1.0), ys], -1),
    ]


def _content_boxes(mapped_edges: list[torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
    """Outer bounding box and an inner (all-valid) box ``(x0, y0, x1, y1)`` of one warped image outline."""
    allp = torch.cat(mapped_edges)
    outer = torch.stack([allp[:, 0].min(), allp[:, 1].min(), allp[:, 0].max(), allp[:, 1].max()])
    mean = torch.stack([e.mean(0) for e in mapped_edges])  # 4x2
    left, right = int(mean[:, 0].argmin()), int(mean[:, 0].argmax())
    top, bottom = int(mean[:, 1].argmin()), int(mean[:, 1].argmax())
    inner = torch.stack(
        [
            mapped_edges[left][:, 0].max(),
            mapped_edges[top][:, 1].max(),
            mapped_edges[right][:, 0].min(),
            mapped_edges[bottom][:, 1].min(),
        ]
    )
    return outer, inner


def _fit_to_frame(
    boxes: list[tuple[torch.Tensor, torch.Tensor]], out_w: int, out_h: int, alpha: float
) -> tuple[float, float, float]:
    """(scale, x offset, y offset) so that the chosen box (alpha = 1: union of everything, 0: the common
    all-valid region) fills the ``out_w`` x ``out_h`` frame, centred."""
    outer = torch.stack([torch.stack([b[0][0], b[0][1]]) for b in boxes]).amin(0)
    outer = torch.cat([outer, torch.stack([torch.stack([b[0][2], b[0][3]]) for b in boxes]).amax(0)])
    inner = torch.stack([torch.stack([b[1][0], b[1][1]]) for b in boxes]).amax(0)
    inner = torch.cat([inner, torch.stack([torch.stack([b[1][2], b[1][3]]) for b in boxes]).amin(0)])
    if not bool((inner[2:] > inner[:2]).all()):
        inner = outer
    box = alpha * outer + (1 - alpha) * inner
    bw, bh = float(box[2] - box[0]), float(box[3] - box[1])
    if not (bw > 0 and bh > 0 and math.isfinite(bw) and math.isfinite(bh)):
        raise DegenerateGeometryError(
            "the rectified images collapse to a line; the geometry cannot be rectified"
        )
    s = min((out_w - 1) / bw, (out_h - 1) / bh)
    return (
        s,
        (out_w - 1) / 2 - s * float(box[0] + box[2]) / 2,
        (out_h - 1) / 2 - s * float(box[1] + box[3]) / 2,
    )


def _check_image_size(image_size: object) -> tuple[int, int]:
    """``(width, height)``: two positive integers; a one-line error naming ``image_size`` otherwise."""
    try:
        w, h = image_size  # type: ignore[misc]
        ok = all(not isinstance(v, bool) and int(v) == v and v > 0 for v in (w, h))
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise StereoInputError(f"image_size: expected (width, height), two positive integers, got {image_size!r}")
    return int(w), int(h)


def _check_alpha(alpha: float) -> float:
    if not (isinstance(alpha, int | float) and 0.0 <= float(alpha) <= 1.0):
        raise StereoInputError(f"alpha: expected a number in [0, 1], got {alpha!r}")
    return float(alpha)


def _output_size(size: tuple[int, int] | None, h: int, w: int) -> tuple[int, int]:
    if size is None:
        return h, w
    if len(size) != 2 or any(int(s) != s or s < 2 for s in size):
        raise StereoInputError(f"output_size: expected (height, width) integers >= 2, got {size!r}")
    return int(size[0]), int(size[1])


def rectification_maps(
    H: torch.Tensor,
    out_h: int,
    out_w: int,
    K: torch.Tensor | None = None,
    dist: torch.Tensor | None = None,
    dtype: torch.dtype = torch.float32,
) -> torch.Tensor:
    """Inverse map of a rectifying homography: for every rectified pixel the source pixel it samples.

    ``H`` maps ideal source pixels to rectified ones; with ``dist`` the ideal pixels are re-distorted through
    ``K`` (kornia ``distort_points``) so that the map reads the recorded image. Returns :math:`(H', W', 2)`.
    """
    v, u = torch.meshgrid(
        torch.arange(out_h, dtype=torch.float64), torch.arange(out_w, dtype=torch.float64), indexing="ij"
    )
    grid = torch.stack([u, v], -1).reshape(-1, 2)  # (H'W')x2
    src = apply_homography(torch.linalg.inv(H.double()), grid)
    if dist is not None:
        src = distort_pixels(src, K.double(), dist.double())
    return src.reshape(out_h, out_w, 2).to(dtype)


def content_mask(source_map: torch.Tensor, width: int, height: int) -> torch.Tensor:
    """Which rectified pixels have source content: the pixel a :func:`rectification_maps` map samples lies
    inside the ``width`` x ``height`` source image (pixel centres, ``0 <= x <= W - 1``, ``0 <= y <= H - 1``).

    Returns a bool :math:`(H', W')` mask; pixels outside it are black padding in the warped image and must
    be invalid in every downstream output (disparity, depth, cloud, filling)."""
    x, y = source_map[..., 0], source_map[..., 1]
    return (x >= -1e-3) & (x <= width - 1 + 1e-3) & (y >= -1e-3) & (y <= height - 1 + 1e-3)


def warp_image(
    image: torch.Tensor,
    H: torch.Tensor | None = None,
    out_size: tuple[int, int] | None = None,
    source_map: torch.Tensor | None = None,
) -> torch.Tensor:
    """Warp ``image`` :math:`(B, C, H, W)` by inverse mapping: through the homography ``H`` (source ideal
    pixels -> output pixels, kornia ``warp_perspective``; differentiable in the image and in ``H``) or
    through a ``source_map`` :math:`(H', W', 2)` (kornia ``remap``). Outside the source: 0."""
    b = image.shape[0]
    if source_map is not None:
        m = source_map.to(image.dtype).to(image.device).expand(b, -1, -1, -1)
        return remap(image, m[..., 0], m[..., 1], mode="bilinear", padding_mode="zeros", align_corners=True)
    if H is None or out_size is None:
        raise StereoInputError("warp_image: give H and out_size, or source_map")
    M = H.to(image.dtype).to(image.device).expand(b, 3, 3)
    return warp_perspective(image, M, out_size, mode="bilinear", padding_mode="zeros", align_corners=True)


def _has_distortion(d: torch.Tensor | None) -> bool:
    return d is not None and bool((d.abs() > 0).any())


def _check_calib_for(calib: object, w: int, h: int) -> Calibration:
    if not isinstance(calib, Calibration):
        raise TypeError(f"calib: expected a stereonet.types.Calibration, got {type(calib).__name__}")
    if calib.image_size is not None and tuple(calib.image_size) != (w, h):
        raise StereoInputError(
            f"calib.image_size: expected the images' (width, height) = {(w, h)}, "
            f"got {tuple(calib.image_size)}"
        )
    return calib


def _rectified_outputs(
    K_new: torch.Tensor, baseline: float, out_w: int, out_h: int, doffs: float = 0.0
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, Calibration]:
    f, cx, cy = float(K_new[0, 0]), float(K_new[0, 2]), float(K_new[1, 2])
    P1 = torch.cat([K_new, torch.zeros(3, 1, dtype=torch.float64)], 1)
    K2 = K_new.clone()
    K2[0, 2] += doffs
    P2 = torch.cat([K2, torch.tensor([[-f * baseline], [0.0], [0.0]], dtype=torch.float64)], 1)
    Q = torch.tensor(
        [[1.0, 0, 0, -cx], [0, 1.0, 0, -cy], [0, 0, 0, f], [0, 0, 1.0 / baseline, doffs / baseline]],
        dtype=torch.float64,
    )
    calib = Calibration.rectified(f, cx, cy, baseline, image_size=(out_w, out_h), doffs=doffs)
    return P1, P2, Q, calib


def _warp_pair(left, right, H1, H2, maps, distorted: tuple[bool, bool], out_size):
    l_img = warp_image(left, source_map=maps[0]) if distorted[0] else warp_image(left, H1, out_size)
    r_img = warp_image(right, source_map=maps[1]) if distorted[1] else warp_image(right, H2, out_size)
    return l_img, r_img


def stereo_rectify(
    calib: Calibration, alpha: float = 1.0, output_size: tuple[int, int] | None = None, method: str = "kornia"
) -> Rectification:
    """The rectifying geometry of a calibrated rig, without touching images (OpenCV's ``stereoRectify``).

    ``method="kornia"`` (ours): the rectifying rotation ``R_rect`` of :func:`rectifying_rotation` is given to
    the left camera and ``R_rect R^T`` to the right one, so both look along the same axis with the baseline as
    their x axis; one shared intrinsic matrix ``K = [[f, 0, cx], [0, f, cy], [0, 0, 1]]`` (f from the mean
    focal length, scaled and centred so that the warped content fits, see ``alpha``); the homographies are
    ``H1 = K R_rect K1^-1`` and ``H2 = K R_rect R^T K2^-1``.
    ``method="opencv"``: ``cv2.stereoRectify`` with ``CALIB_ZERO_DISPARITY``, returned in the same layout.

    Args:
        calib: the rig (``X_r = R X_l + t``, optional OpenCV distortion); ``calib.image_size`` is required.
        alpha: 1 keeps every source pixel in view, 0 shows only the region both images cover (OpenCV's alpha).
        output_size: ``(H', W')`` of the rectified images (default: the calibration's image size).

    Returns:
        :class:`Rectification` with ``left``, ``right`` and ``maps`` set to None (see
        :func:`rectify_calibrated`).
    """
    if not isinstance(calib, Calibration):
        raise TypeError(f"calib: expected a stereonet.types.Calibration, got {type(calib).__name__}")
    if calib.image_size is None:
        raise StereoInputError("calib.image_size: expected (width, height) of the images, got None")
    w, h = calib.image_size
    alpha = _check_alpha(alpha)
    out_h, out_w = _output_size(output_size, h, w)
    if method == "opencv":
        return _stereo_rectify_opencv(calib, alpha, out_h, out_w)
    if method != "kornia":
        raise StereoInputError(f"method: expected 'kornia' or 'opencv', got {method!r}")
    K1, K2, R = calib.K1, calib.K2, calib.R
    reversed_rig = is_reversed_rig(calib)
    R1 = rectifying_rotation(R, -calib.t if reversed_rig else calib.t)  # upright: x against the baseline
    R2 = R1 @ R.T
    f0 = float(torch.stack([K1[0, 0], K1[1, 1], K2[0, 0], K2[1, 1]]).mean())
    K0 = torch.diag(torch.tensor([f0, f0, 1.0], dtype=torch.float64))
    boxes = []
    for K, Rr, dist in ((K1, R1, calib.dist1), (K2, R2, calib.dist2)):
        G = K0 @ Rr @ torch.linalg.inv(K)
        edges = list(undistort_pixels(torch.cat(_border_edges(w, h)), K, dist).split(_PER_EDGE))
        rays = [torch.cat([e, torch.ones_like(e[:, :1])], -1) @ G.T for e in edges]
        if any(bool((r[:, 2] <= 1e-9).any()) for r in rays):
            raise DegenerateGeometryError(
                "calib: the rectifying rotation turns part of an image behind the camera "
                "(field of view too wide for this baseline direction)"
            )
        boxes.append(_content_boxes([r[:, :2] / r[:, 2:] for r in rays]))
    s, ox, oy = _fit_to_frame(boxes, out_w, out_h, alpha)
    K_new = torch.tensor([[s * f0, 0.0, ox], [0.0, s * f0, oy], [0.0, 0.0, 1.0]], dtype=torch.float64)
    H1 = K_new @ R1 @ torch.linalg.inv(K1)
    H2 = K_new @ R2 @ torch.linalg.inv(K2)
    P1, P2, Q, rect_calib = _rectified_outputs(K_new, calib.baseline, out_w, out_h)
    if reversed_rig:  # the second camera at -B: OpenCV's P2 and Q for the signed (negative) disparity
        P2, Q = _rectified_outputs(K_new, -calib.baseline, out_w, out_h)[1:3]
    return Rectification(None, None, H1, H2, P1, P2, Q, rect_calib, None, R1=R1, R2=R2, original=calib,
                         reversed=reversed_rig)


def _stereo_rectify_opencv(calib: Calibration, alpha: float, out_h: int, out_w: int) -> Rectification:
    import cv2
    import numpy as np

    w, h = calib.image_size
    d1 = np.zeros(5) if calib.dist1 is None else calib.dist1.numpy()
    d2 = np.zeros(5) if calib.dist2 is None else calib.dist2.numpy()
    R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(
        calib.K1.numpy(),
        d1,
        calib.K2.numpy(),
        d2,
        (w, h),
        calib.R.numpy(),
        calib.t.numpy().reshape(3, 1),
        flags=cv2.CALIB_ZERO_DISPARITY,
        alpha=alpha,
        newImageSize=(out_w, out_h),
    )
    R1, R2, P1, P2, Q = (torch.from_numpy(np.asarray(m, dtype=np.float64)) for m in (R1, R2, P1, P2, Q))
    H1 = P1[:, :3] @ R1 @ calib.K1.inverse()
    H2 = P2[:, :3] @ R2 @ calib.K2.inverse()
    f = float(P1[0, 0])
    baseline = -float(P2[0, 3]) / f
    if abs(baseline) < 1e-9 * max(calib.baseline, 1e-300):  # OpenCV put the baseline along y (P2[1, 3])
        raise StereoInputError("calib: the rig's baseline is vertical; OpenCV rectifies it along the columns, which "
                               "the matchers here do not search (rotate both images by 90 degrees first)")
    doffs = float(P2[0, 2] - P1[0, 2])
    # a reversed rig (the second camera on the left): OpenCV's P2[0, 3] = +f B, negative disparities; the
    # rectified rig is described with its positive baseline and matched mirrored, as the kornia method does
    reversed_rig = baseline < 0
    rect_calib = Calibration.rectified(
        f, float(P1[0, 2]), float(P1[1, 2]), abs(baseline), image_size=(out_w, out_h),
        doffs=doffs,
    )
    return Rectification(None, None, H1, H2, P1, P2, Q, rect_calib, None, R1=R1, R2=R2, original=calib,
                         reversed=reversed_rig)


def rectify_calibrated(
    left: torch.Tensor,
    right: torch.Tensor,
    calib: Calibration,
    alpha: float = 1.0,
    output_size: tuple[int, int] | None = None,
    method: str = "kornia",
    prepared: Rectification | None = None,
) -> Rectification:
    """Rectify a calibrated pair: :func:`stereo_rectify` (``method`` "kornia" = ours, "opencv" =
    ``cv2.stereoRectify``), then inverse-map both images: kornia ``warp_perspective`` by ``H1``/``H2`` when
    the lens is undistorted (differentiable in the images and the homography), kornia ``remap`` through
    :func:`rectification_maps` (undistortion in the same lookup) when it is distorted.

    Args:
        left, right: :math:`(B, C, H, W)` float in [0, 1], the original (unrectified) images.
        calib: their :class:`Calibration` (``X_r = R X_l + t``, optional OpenCV distortion); when its
            ``image_size`` is None the images' size is used.
        alpha: 1 keeps every source pixel in view, 0 shows only the region both images cover (OpenCV's alpha).
        output_size: ``(H', W')`` of the rectified images (default: the input size).
        prepared: the result of an earlier call for the same rig and image size: its geometry and maps are
            reused and only the images are warped (a fixed rig's frames; ``calib``, ``alpha`` and ``method``
            are then ignored).

    Returns:
        :class:`Rectification`; ``.calib`` is the rectified rig (R = I, t = (-B, 0, 0), shared K).
    """
    left, right = check_image_pair(left, right)
    _, _, h, w = left.shape
    out_h, out_w = _output_size(output_size, h, w)
    if prepared is not None:  # a fixed rig: the geometry and maps of an earlier pair, only the warp is new
        if prepared.maps is None or prepared.original is None:
            raise StereoInputError("prepared: expected the Rectification of an earlier rectify_calibrated call")
        if tuple(prepared.maps[0].shape[:2]) != (out_h, out_w) or prepared.original.image_size != (w, h):
            raise StereoInputError(f"prepared: made for {prepared.original.image_size} -> "
                                   f"{tuple(prepared.maps[0].shape[:2])}, got {w}x{h} -> {(out_h, out_w)}")
        rect, calib, maps = replace(prepared, left=None, right=None), prepared.original, prepared.maps
    else:
        calib = _check_calib_for(calib, w, h)
        if calib.image_size is None:
            calib = replace(calib, image_size=(w, h))
        rect = stereo_rectify(calib, alpha=alpha, output_size=output_size, method=method)
        maps = (
            rectification_maps(rect.H1, out_h, out_w, calib.K1, calib.dist1, left.dtype),
            rectification_maps(rect.H2, out_h, out_w, calib.K2, calib.dist2, left.dtype),
        )
    distorted = (_has_distortion(calib.dist1), _has_distortion(calib.dist2))
    rect.left, rect.right = _warp_pair(left, right, rect.H1, rect.H2, maps, distorted, (out_h, out_w))
    rect.maps = maps
    return rect


def rectify_from_file(
    left: torch.Tensor,
    right: torch.Tensor,
    path: str | os.PathLike,
    alpha: float = 1.0,
    method: str = "kornia",
) -> Rectification:
    """:func:`rectify_calibrated` with the calibration read by ``stereonet.calibration.read_calibration`` (an
    OpenCV FileStorage YAML/JSON as written by ``cv2.stereoCalibrate`` users, Middlebury or KITTI files)."""
    from stereonet.calibration import read_calibration

    return rectify_calibrated(left, right, read_calibration(path), alpha=alpha, method=method)


def rectify_points(points: torch.Tensor, rect: Rectification, view: str = "left") -> torch.Tensor:
    """Map recorded pixels :math:`(*, N, 2)` of the original ``view`` ("left"/"right") to rectified pixels
    (lens distortion removed first when the original calibration has it)."""
    if view not in ("left", "right"):
        raise StereoInputError(f"view: expected 'left' or 'right', got {view!r}")
    H = (rect.H1 if view == "left" else rect.H2).to(points.dtype).to(points.device)
    if rect.original is not None:
        K = rect.original.K1 if view == "left" else rect.original.K2
        dist = rect.original.dist1 if view == "left" else rect.original.dist2
        points = undistort_pixels(points, K.to(points.dtype), dist)
    return apply_homography(H, points)


def hartley_homographies(
    F: torch.Tensor, pts1: torch.Tensor, pts2: torch.Tensor, image_size: tuple[int, int], match: str = "shape"
) -> tuple[torch.Tensor, torch.Tensor]:
    """Rectifying homographies from F alone (Hartley & Zisserman, Alg. 11.12).

    ``H2 = G R T`` sends the right epipole to infinity along x (T: image centre to the origin, R: epipole onto
    the x axis by the smaller rotation, G: ``[[1,0,0],[0,1,0],[-1/f,0,1]]``); ``H1 = H_A H2 M`` with
    ``M = [e2]_x F + e2 (1,1,1)`` (so ``F ~ H2^T [i]_x H1``) and a row-preserving
    ``H_A = [[a, b, c], [0, 1, 0], [0, 0, 1]]``: with ``match="disparity"`` Hartley's least-squares choice
    minimising the x-distance of the matches (which shears the left image wherever the disparity varies
    with y, e.g. a road); with ``match="shape"`` (default) ``a, b`` give the left warp the right warp's
    x-derivatives (Jacobian row) at the image centre and ``c`` centres the matches' disparities. ``H_A`` never changes rows, so row alignment
    is the same either way. Both homographies are then flipped together if needed so that rows point down and
    images are not mirrored.

    Args:
        F: :math:`(3, 3)`; pts1, pts2: inlier matches :math:`(N, 2)`; image_size: ``(width, height)``.
        match: ``"shape"`` or ``"disparity"``, the choice of ``H_A`` above.

    Returns:
        (H1, H2) float64 :math:`(3, 3)` (before fitting to an output frame).
    """
    F = F.double()
    p1, p2 = pts1.double(), pts2.double()
    w, h = image_size
    e1, e2 = epipoles(F)
    for name, e in (("left", e1), ("right", e2)):
        if (
            float(e[2]) > 1e-12
            and -0.5 <= float(e[0] / e[2]) <= w - 0.5
            and -0.5 <= float(e[1] / e[2]) <= h - 0.5
        ):
            raise DegenerateGeometryError(
                f"F: the epipole lies inside the {name} image (camera moving along its optical axis); no "
                "pair of homographies can rectify it (polar rectification would be needed)"
            )
    T = torch.tensor([[1.0, 0, -(w - 1) / 2], [0, 1.0, -(h - 1) / 2], [0, 0, 1.0]], dtype=torch.float64)
    e = T @ e2
    if float(e[2].abs()) > 1e-9 * float(torch.linalg.vector_norm(e[:2])):
        ex, ey = float(e[0] / e[2]), float(e[1] / e[2])
        finite = True
    else:
        ex, ey = float(e[0]), float(e[1])
        finite = False
    angle = math.atan2(ey, ex)
    if angle > math.pi / 2:  # rotate by the smaller angle (epipole may land on the negative x axis)
        angle -= math.pi
    elif angle < -math.pi / 2:
        angle += math.pi
    c, s = math.cos(-angle), math.sin(-angle)
    Rot = torch.tensor([[c, -s, 0], [s, c, 0], [0, 0, 1.0]], dtype=torch.float64)
    G = torch.eye(3, dtype=torch.float64)
    if finite:
        fx = c * ex - s * ey
        if abs(fx) < 1e-9:
            raise DegenerateGeometryError(
                "F: the epipole is at the image centre (forward motion); cannot rectify"
            )
        G[2, 0] = -1.0 / fx
    H2 = G @ Rot @ T
    e2n = e2 / torch.linalg.vector_norm(e2)
    M = _cross(e2n) @ F + torch.outer(e2n, torch.ones(3, dtype=torch.float64))
    H0 = H2 @ M
    x1, x2 = apply_homography(H0, p1), apply_homography(H2, p2)
    centre = torch.tensor([(w - 1) / 2, (h - 1) / 2], dtype=torch.float64)
    J0, J2 = _jacobian(H0, centre), _jacobian(H2, centre)
    if match == "shape" and abs(float(torch.linalg.det(J0))) > 1e-12 * float(J0.abs().max()) ** 2:
        # first row of H_A's linear part so that H1 = H_A H0 has H2's local shape at the image centre
        ab = torch.linalg.solve(J0.T, J2[0])
        c = float((x2[:, 0] - ab[0] * x1[:, 0] - ab[1] * x1[:, 1]).median())
        abc = torch.stack([ab[0], ab[1], torch.tensor(c, dtype=torch.float64)])
    elif match in ("shape", "disparity"):  # Hartley's least-squares: minimise sum (a x1 + b y1 + c - x2)^2
        A = torch.cat([x1, torch.ones_like(x1[:, :1])], 1)  # Nx3
        abc = torch.linalg.lstsq(A, x2[:, :1]).solution[:, 0]
    else:
        raise StereoInputError(f"match: expected 'shape' or 'disparity', got {match!r}")
    HA = torch.tensor(
        [[float(abc[0]), float(abc[1]), float(abc[2])], [0, 1.0, 0], [0, 0, 1.0]], dtype=torch.float64
    )
    H1 = HA @ H0
    # Orientation: rows down (y axis not inverted) and no mirror, judged at the right image centre.
    J = _jacobian(H2, torch.tensor([(w - 1) / 2, (h - 1) / 2], dtype=torch.float64))
    flip = torch.diag(torch.tensor([1.0, -1.0 if float(J[1, 1]) < 0 else 1.0, 1.0], dtype=torch.float64))
    H1, H2 = flip @ H1, flip @ H2
    if (
        float(torch.linalg.det(_jacobian(H2, torch.tensor([(w - 1) / 2, (h - 1) / 2], dtype=torch.float64))))
        < 0
    ):
        mirror = torch.diag(torch.tensor([-1.0, 1.0, 1.0], dtype=torch.float64))
        H1, H2 = mirror @ H1, mirror @ H2
    return H1, H2


def _cross(v: torch.Tensor) -> torch.Tensor:
    return torch.tensor(
        [
            [0.0, -float(v[2]), float(v[1])],
            [float(v[2]), 0.0, -float(v[0])],
            [-float(v[1]), float(v[0]), 0.0],
        ],
        dtype=torch.float64,
    )


def _jacobian(H: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
    return torch.autograd.functional.jacobian(lambda q: apply_homography(H, q[None])[0], p)


def stereo_rectify_uncalibrated(
    pts1: torch.Tensor,
    pts2: torch.Tensor,
    image_size: tuple[int, int],
    F: torch.Tensor | None = None,
    alpha: float = 1.0,
    output_size: tuple[int, int] | None = None,
    threshold: float = 1.0,
    min_matches: int = 16,
    seed: int = 0,
) -> Rectification:
    """Rectifying homographies from matches alone (no images are touched): robust F (RANSAC on the Sampson
    distance, unless ``F`` is given), Hartley's homographies (:func:`hartley_homographies`), the right image
    shifted along x so that the inlier matches have disparities >= 0, both scaled/centred together to fit the
    frame (``alpha`` as in :func:`stereo_rectify`).

    Args:
        pts1, pts2: matches :math:`(N, 2)` in pixels; image_size: ``(width, height)``;
            F: optional :math:`(3, 3)`.
        threshold: RANSAC Sampson threshold in px; min_matches: refuse below this many matches or inliers.
        output_size: ``(H', W')`` (default: the image size).

    Returns:
        :class:`Rectification` with ``left``, ``right``, ``maps``, ``P1``, ``P2``, ``Q``, ``calib`` = None.

    Raises:
        DegenerateGeometryError: fewer than ``min_matches`` matches/inliers, or a degenerate F.
    """
    alpha = _check_alpha(alpha)
    w, h = _check_image_size(image_size)
    out_h, out_w = _output_size(output_size, h, w)
    if (pts1 is None) != (pts2 is None):
        raise StereoInputError("pts1, pts2: give both or neither")
    if pts1.shape[0] < min_matches:
        raise DegenerateGeometryError(
            f"pts1, pts2: {pts1.shape[0]} matches, need at least {min_matches} to "
            "estimate F robustly (try a larger ratio or more textured images)"
        )
    p1, p2 = pts1.double(), pts2.double()
    notes = []
    if F is None:
        F, inliers, planar = fundamental_robust(p1, p2, threshold=threshold, seed=seed)
        if planar:
            notes.append(
                "one homography explains nearly all matches (dominant plane or pure rotation): F and the "
                "rectification are weakly determined away from that plane"
            )
            logging.getLogger(__name__).warning("rectify_uncalibrated: %s", notes[-1])
    else:
        inliers = sampson_distance(p1, p2, F.double()) < max(threshold, 1e-9) ** 2
    if int(inliers.sum()) < min_matches:
        raise DegenerateGeometryError(
            f"pts1, pts2: only {int(inliers.sum())} inlier matches, need {min_matches}"
        )
    F = F.double()
    H1, H2 = hartley_homographies(F, p1[inliers], p2[inliers], (w, h))
    border = torch.cat(_border_edges(w, h))
    for H in (H1, H2):
        wgt = (torch.cat([border, torch.ones_like(border[:, :1])], -1) @ H.T)[:, 2]
        if not bool((wgt > 0).all() or (wgt < 0).all()):
            raise DegenerateGeometryError(
                "F: the rectifying homography sends part of the image to infinity (the "
                "epipole is too close to the image); cannot rectify with homographies"
            )
    disp = apply_homography(H1, p1[inliers])[:, 0] - apply_homography(H2, p2[inliers])[:, 0]
    shift = -float(
        torch.quantile(disp, 0.01)
    )  # move the right image so that ~all inlier disparities are >= 0
    H2 = torch.tensor([[1.0, 0, -shift], [0, 1.0, 0], [0, 0, 1.0]], dtype=torch.float64) @ H2
    boxes = [_content_boxes([apply_homography(H, e) for e in _border_edges(w, h)]) for H in (H1, H2)]
    s, ox, oy = _fit_to_frame(boxes, out_w, out_h, alpha)
    S = torch.tensor([[s, 0, ox], [0, s, oy], [0, 0, 1.0]], dtype=torch.float64)
    H1, H2 = S @ H1, S @ H2
    disp = apply_homography(H1, p1[inliers])[:, 0] - apply_homography(H2, p2[inliers])[:, 0]
    return Rectification(
        None,
        None,
        H1,
        H2,
        None,
        None,
        None,
        None,
        None,
        F=F,
        matches=(pts1, pts2),
        inliers=inliers,
        disparity_range=(float(torch.quantile(disp, 0.01)), float(torch.quantile(disp, 0.99))),
        notes=notes,
    )


def rectify_uncalibrated(
    left: torch.Tensor,
    right: torch.Tensor,
    pts1: torch.Tensor | None = None,
    pts2: torch.Tensor | None = None,
    F: torch.Tensor | None = None,
    alpha: float = 1.0,
    output_size: tuple[int, int] | None = None,
    ratio: float = 0.75,
    threshold: float = 1.0,
    min_matches: int = 16,
    seed: int = 0,
) -> Rectification:
    """Rectify a pair with no calibration: SIFT matches + ratio test (:func:`stereonet.features.match_sift`,
    unless ``pts1``/``pts2`` are given), then :func:`stereo_rectify_uncalibrated` (robust F, Hartley's
    homographies, disparities shifted to be >= 0) and a kornia ``warp_perspective`` of both images.

    Args:
        left, right: :math:`(B, C, H, W)`; the matching uses the first batch element.
        pts1, pts2: optional matches :math:`(N, 2)` in pixels; F: optional :math:`(3, 3)`.
        ratio: Lowe's ratio; threshold: RANSAC Sampson threshold in px; min_matches: refuse below this.

    Returns:
        :class:`Rectification` with P1, P2, Q, calib = None (no metric information), F, matches, inliers and
        the inlier ``disparity_range``.

    Raises:
        DegenerateGeometryError: fewer than ``min_matches`` matches/inliers, or a degenerate F.
    """
    left, right = check_image_pair(left, right)
    _, _, h, w = left.shape
    if (pts1 is None) != (pts2 is None):
        raise StereoInputError("pts1, pts2: give both or neither")
    if pts1 is None:
        from stereonet.features import match_sift

        pts1, pts2 = match_sift(left[:1], right[:1], ratio=ratio, min_matches=min_matches)
    rect = stereo_rectify_uncalibrated(
        pts1,
        pts2,
        (w, h),
        F=F,
        alpha=alpha,
        output_size=output_size,
        threshold=threshold,
        min_matches=min_matches,
        seed=seed,
    )
    out_h, out_w = _output_size(output_size, h, w)
    rect.maps = (
        rectification_maps(rect.H1, out_h, out_w, dtype=left.dtype),
        rectification_maps(rect.H2, out_h, out_w, dtype=left.dtype),
    )
    rect.left, rect.right = _warp_pair(
        left, right, rect.H1, rect.H2, rect.maps, (False, False), (out_h, out_w)
    )
    return rect
