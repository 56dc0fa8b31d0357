"""SIFT matching (ratio test, mutual check) and uncalibrated rectification of real photos from SIFT alone."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from stereonet.features import image_to_uint8, match_descriptors, match_sift
from stereonet.geometry import DegenerateGeometryError, apply_homography, rectify_points, rectify_uncalibrated


def _texture(h: int = 200, w: int = 260, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = np.zeros((h, w), np.float32)
    for scale in (3, 7, 15):
        noise = rng.random((h // scale + 2, w // scale + 2)).astype(np.float32)
        img += cv2.resize(noise, (w, h), interpolation=cv2.INTER_CUBIC)
    return np.clip((img - img.min()) / (img.max() - img.min()), 0, 1)


def test_match_descriptors_ratio_and_mutual():
    d1 = torch.tensor([[0.0, 0.0], [10.0, 0.0], [5.0, 5.0]])
    d2 = torch.tensor([[0.1, 0.0], [10.0, 0.2], [5.0, 4.0], [5.0, 6.0]])
    pairs = match_descriptors(d1, d2, ratio=0.8)
    # the third descriptor is equally close to two candidates: the ratio test drops it
    assert pairs.tolist() == [[0, 0], [1, 1]]
    assert match_descriptors(d1, d2[:1]).shape == (0, 2)
    with pytest.raises(ValueError, match="ratio"):
        match_descriptors(d1, d2, ratio=1.5)


def test_sift_matches_follow_a_known_homography():
    left = _texture()
    H = np.array([[0.97, 0.02, 6.0], [-0.03, 1.01, -4.0], [1e-5, 2e-5, 1.0]])
    right = cv2.warpPerspective(left, H, (left.shape[1], left.shape[0]), flags=cv2.INTER_LINEAR)
    lt, rt = (torch.from_numpy(a)[None, None] for a in (left, right))
    p1, p2 = match_sift(lt, rt)
    assert p1.shape == p2.shape and p1.shape[0] >= 50 and p1.dtype == torch.float64
    err = (apply_homography(torch.from_numpy(H), p1) - p2).norm(dim=-1)
    assert float((err < 1.0).double().mean()) > 0.9
    assert image_to_uint8(lt).dtype == np.uint8


def test_too_few_matches_is_a_clear_error():
    flat = torch.full((1, 1, 64, 64), 0.5)
    with pytest.raises(DegenerateGeometryError, match="SIFT matches"):
        match_sift(flat, flat)
    left = torch.from_numpy(_texture(seed=1))[None, None]
    with pytest.raises(DegenerateGeometryError, match="need at least 100000"):
        match_sift(left, left, min_matches=100000)


def test_uncalibrated_rectification_of_a_real_pair(shared_data):
    """Middlebury Cones is rectified; we turn the right view by a known homography (a few degrees of rotation
    and a vertical shift) and check that SIFT + robust F + Hartley rectification puts the ground-truth
    correspondences (x, y) <-> H (x - d, y) back on common rows."""
    scene = shared_data / "middlebury2003" / "cones"
    left = cv2.imread(str(scene / "im2.png"), cv2.IMREAD_COLOR_RGB).astype(np.float32) / 255
    right = cv2.imread(str(scene / "im6.png"), cv2.IMREAD_COLOR_RGB).astype(np.float32) / 255
    disp = cv2.imread(str(scene / "disp2.png"), cv2.IMREAD_GRAYSCALE).astype(np.float64) / 4
    h, w = disp.shape
    a = np.deg2rad(3.0)
    c = np.array([w / 2, h / 2])
    Rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    T = np.array([[1, 0, -c[0]], [0, 1, -c[1]], [0, 0, 1]])
    H = np.linalg.inv(T) @ Rz @ T + np.array([[0, 0, 0], [0, 0, 6.0], [0, 0, 0]])
    right = cv2.warpPerspective(right, H, (w, h), flags=cv2.INTER_LINEAR)
    lt = torch.from_numpy(left).permute(2, 0, 1)[None]
    rt = torch.from_numpy(right).permute(2, 0, 1)[None]
    rect = rectify_uncalibrated(lt, rt)
    assert rect.left.shape == lt.shape and int(rect.inliers.sum()) >= 50
    ys, xs = np.nonzero(disp > 0)
    gt1 = torch.from_numpy(np.stack([xs, ys], -1).astype(np.float64))
    gt2 = apply_homography(torch.from_numpy(H), torch.from_numpy(np.stack([xs - disp[ys, xs], ys], -1)))
    dy = (rectify_points(gt1, rect, "left")[:, 1] - rectify_points(gt2, rect, "right")[:, 1]).abs()
    assert float(dy.median()) < 0.5, float(dy.median())
    # reference: cv2.stereoRectifyUncalibrated(inlier matches, F, (w, h)) on the same matches and F
    p1, p2 = (m.numpy()[rect.inliers.numpy()] for m in rect.matches)
    ok, H1, H2 = cv2.stereoRectifyUncalibrated(p1, p2, rect.F.numpy(), (w, h))
    dy_cv = (
        apply_homography(torch.from_numpy(H1), gt1)[:, 1] - apply_homography(torch.from_numpy(H2), gt2)[:, 1]
    )
    assert ok and float(dy_cv.abs().median()) < 1.0
