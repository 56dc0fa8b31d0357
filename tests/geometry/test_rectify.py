"""Rectification: calibrated (ours and OpenCV's stereoRectify in the same run), OpenCV-file path, image maps,
uncalibrated (ours and OpenCV's stereoRectifyUncalibrated), gradients and bad input."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from stereonet.checks import StereoInputError
from stereonet.geometry import (
    DegenerateGeometryError,
    apply_homography,
    disparity_to_depth,
    fundamental_from_pose,
    hartley_homographies,
    rectify_calibrated,
    rectify_from_file,
    rectify_points,
    rectify_uncalibrated,
    reproject_disparity,
    stereo_rectify,
    stereo_rectify_uncalibrated,
    warp_image,
)
from stereonet.geometry.random_scene import random_correspondences, random_rig
from stereonet.types import Calibration

SIZE = (320, 240)  # (width, height) of the random rigs: keeps the image warps cheap
SMALL = (160, 120)  # for the tests that warp images


def _blank(calib: Calibration, channels: int = 1) -> torch.Tensor:
    w, h = calib.image_size
    return torch.zeros(1, channels, h, w)


def _row_errors(rect, p1, p2) -> tuple[torch.Tensor, torch.Tensor]:
    a, b = rectify_points(p1, rect, "left"), rectify_points(p2, rect, "right")
    return (a[:, 1] - b[:, 1]).abs(), a[:, 0] - b[:, 0]


def test_calibrated_rectification_aligns_rows_on_random_rigs(one_thread):
    """|dy| of exact correspondences after rectification, ours vs cv2.stereoRectify on the same 16 rigs
    (rotations up to 8 degrees, half with lens distortion); the 50-rig data_gen run: test_data_gen_rigs.py."""
    stats = {"kornia": [], "opencv": []}
    for seed in range(16):
        calib = random_rig(seed, image_size=SIZE, distortion=seed % 2 == 1)
        X, p1, p2 = random_correspondences(calib, 100, seed)
        for method in stats:
            # method="opencv" runs
            # cv2.stereoRectify(K1, D1, K2, D2, size, R, T, flags=CALIB_ZERO_DISPARITY, alpha=alpha)
            rect = stereo_rectify(calib, method=method)
            dy, d = _row_errors(rect, p1, p2)
            stats[method].append(dy)
            assert bool((d > 0).all()), "disparity must be positive for points in front of the rig"
            # the rectified calibration gives the depth of the point in the rectified left camera frame
            z = disparity_to_depth(d.reshape(1, 1, 1, -1), rect.calib).flatten()
            z_true = (X @ rect.R1.T)[:, 2]
            assert float(((z - z_true) / z_true).abs().max()) < 1e-6
    for method, dys in stats.items():
        dy = torch.cat(dys)
        assert float(dy.median()) < 0.1 and float(dy.max()) < 0.5, (
            method,
            float(dy.median()),
            float(dy.max()),
        )
    # ours is exact up to the undistortion iteration
    assert float(torch.cat(stats["kornia"]).max()) < 1e-6


def test_rectifying_rotation_layout():
    calib = random_rig(3, image_size=SIZE)
    rect = rectify_calibrated(_blank(calib), _blank(calib), calib)
    R1, R2 = rect.R1, rect.R2
    assert torch.allclose(R1 @ R1.T, torch.eye(3, dtype=torch.float64), atol=1e-12)
    c2 = -(calib.R.T @ calib.t)
    assert torch.allclose(R1[0], c2 / c2.norm())  # r1 = baseline direction
    assert abs(float(R1[1, 2])) < 1e-12  # r2 = z x r1 is orthogonal to the old optical axis
    assert torch.allclose(R2, R1 @ calib.R.T)
    assert torch.allclose(R2 @ calib.t, torch.tensor([-calib.baseline, 0.0, 0.0], dtype=torch.float64))
    K = rect.P1[:, :3]
    assert torch.allclose(rect.H1, K @ R1 @ torch.linalg.inv(calib.K1))
    assert torch.allclose(rect.H2, K @ R1 @ calib.R.T @ torch.linalg.inv(calib.K2))
    assert rect.calib.is_rectified() and rect.calib.image_size == SIZE


@pytest.mark.parametrize("distortion", [False, True])
def test_rectified_images_sample_their_maps(distortion):
    """The warped image of a linear ramp reads, at every rectified pixel, the source position the map names;
    and the map is the inverse of rectify_points."""
    calib = random_rig(7, image_size=SMALL, distortion=distortion)
    w, h = SMALL
    ys, xs = torch.meshgrid(
        torch.arange(h, dtype=torch.float64), torch.arange(w, dtype=torch.float64), indexing="ij"
    )
    ramp = torch.stack([xs / w, ys / h, torch.zeros_like(xs)])[None]  # 1x3xHxW, linear => bilinear is exact
    rect = rectify_calibrated(ramp, ramp, calib)
    for img, src, view in ((rect.left, rect.maps[0], "left"), (rect.right, rect.maps[1], "right")):
        inside = (src[..., 0] >= 0) & (src[..., 0] <= w - 1) & (src[..., 1] >= 0) & (src[..., 1] <= h - 1)
        assert float(inside.double().mean()) > 0.5
        assert torch.allclose(img[0, 0][inside], src[..., 0][inside] / w, atol=1e-9)
        assert torch.allclose(img[0, 1][inside], src[..., 1][inside] / h, atol=1e-9)
        hh, ww = src.shape[:2]
        grid = torch.stack(
            torch.meshgrid(
                torch.arange(hh, dtype=torch.float64), torch.arange(ww, dtype=torch.float64), indexing="ij"
            )[::-1],
            -1,
        )
        back = rectify_points(src[inside], rect, view)
        assert float((back - grid[inside]).abs().max()) < 1e-6


def test_maps_match_opencv_init_undistort_rectify_map():
    calib = random_rig(5, image_size=SIZE, distortion=True)
    img = _blank(calib)
    rect = rectify_calibrated(img, img, calib, method="opencv")
    for K, dist, R_r, P, ours in (
        (calib.K1, calib.dist1, rect.R1, rect.P1, rect.maps[0]),
        (calib.K2, calib.dist2, rect.R2, rect.P2, rect.maps[1]),
    ):
        mx, my = cv2.initUndistortRectifyMap(
            K.numpy(), dist.numpy(), R_r.numpy(), P.numpy(), SIZE, cv2.CV_32FC1
        )
        inside = (mx >= 0) & (mx <= SIZE[0] - 1) & (my >= 0) & (my <= SIZE[1] - 1)
        err = np.abs(ours.numpy() - np.stack([mx, my], -1))[inside]
        assert err.max() < 1e-2  # float32 maps


def test_warp_perspective_and_remap_agree():
    calib = random_rig(9, image_size=SIZE)
    img = torch.rand(2, 3, SIZE[1], SIZE[0], dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    rect = rectify_calibrated(img, img, calib)
    via_remap = warp_image(img, source_map=rect.maps[0])
    assert torch.allclose(rect.left, via_remap, atol=1e-9)
    assert rect.left.shape == img.shape and rect.left.dtype == img.dtype


@pytest.mark.parametrize("method", ["kornia", "opencv"])
def test_alpha_keeps_content_or_crops_to_valid(method):
    calib = random_rig(12, image_size=SMALL, distortion=True)
    w, h = SMALL
    img = _blank(calib)
    corners = torch.tensor([[0.0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1]], dtype=torch.float64)
    full = rectify_calibrated(img, img, calib, alpha=1.0, method=method)
    for view in ("left", "right"):
        q = rectify_points(corners, full, view)
        assert bool((q >= -1.0).all()) and bool((q[:, 0] <= w).all()) and bool((q[:, 1] <= h).all())
    crop = rectify_calibrated(img, img, calib, alpha=0.0, method=method)
    for m in crop.maps:
        inside = (m[..., 0] >= -1) & (m[..., 0] <= w) & (m[..., 1] >= -1) & (m[..., 1] <= h)
        assert float(inside.double().mean()) > 0.97


def test_opencv_calibration_file_and_q(tmp_path):
    from stereonet.calibration import write_opencv_calibration

    calib = random_rig(21, image_size=SIZE, distortion=True)
    path = tmp_path / "stereo.yml"
    write_opencv_calibration(path, calib)
    img = _blank(calib)
    X, p1, p2 = random_correspondences(calib, 50, 21)
    for method in ("kornia", "opencv"):
        rect = rectify_from_file(img, img, path, method=method)
        dy, d = _row_errors(rect, p1, p2)
        assert float(dy.max()) < 1e-3
        # Q (OpenCV layout) reprojects disparities to the rectified-frame 3D points, like
        # cv2.reprojectImageTo3D(disparity, Q)
        q1 = rectify_points(p1, rect, "left")
        disp = torch.zeros(1, 1, SIZE[1], SIZE[0], dtype=torch.float64)
        u, v = q1[:, 0].round().long().clamp(0, SIZE[0] - 1), q1[:, 1].round().long().clamp(0, SIZE[1] - 1)
        disp[0, 0, v, u] = d
        ours = reproject_disparity(disp, rect.Q)[0, :, v, u].T
        ref = cv2.reprojectImageTo3D(disp[0, 0].float().numpy(), rect.Q.numpy())[v.numpy(), u.numpy()]
        assert np.allclose(ours.numpy(), ref, rtol=1e-4)
        assert torch.allclose(ours[:, 2], (X @ rect.R1.T)[:, 2], rtol=1e-6)


def test_gradcheck_rectifying_warp():
    g = torch.Generator().manual_seed(0)
    img = torch.rand(1, 1, 6, 7, dtype=torch.float64, generator=g, requires_grad=True)
    H = torch.tensor(
        [[1.02, 0.03, 0.4], [-0.02, 0.98, 0.3], [1e-3, -2e-3, 1.0]], dtype=torch.float64, requires_grad=True
    )
    assert torch.autograd.gradcheck(lambda i, m: warp_image(i, m, (6, 7)), (img, H), eps=1e-6, atol=1e-5)
    # and through the whole calibrated rectification with respect to the images
    K = torch.tensor([[8.0, 0, 3.5], [0, 8.0, 2.5], [0, 0, 1]], dtype=torch.float64)
    from stereonet.geometry.random_scene import random_rotation

    calib = Calibration(K, K, random_rotation(3, g), torch.tensor([-1.0, 0.05, 0.02]), image_size=(7, 6))
    right = torch.rand(1, 1, 6, 7, dtype=torch.float64, generator=g, requires_grad=True)

    def both(a, b):
        rect = rectify_calibrated(a, b, calib)
        return rect.left, rect.right

    assert torch.autograd.gradcheck(both, (img, right), eps=1e-6, atol=1e-5)


def test_calibrated_bad_input():
    calib = random_rig(1, image_size=SIZE)
    img = _blank(calib)
    K1, K2 = calib.K1, calib.K2
    eye = torch.eye(3, dtype=torch.float64)
    with pytest.raises(DegenerateGeometryError, match="pure rotation"):
        rectify_calibrated(img, img, Calibration(K1, K2, calib.R, torch.zeros(3), image_size=SIZE))
    with pytest.raises(DegenerateGeometryError, match="optical axis"):
        rectify_calibrated(
            img, img, Calibration(K1, K2, eye, torch.tensor([0.0, 0.0, -1.0]), image_size=SIZE)
        )
    with pytest.raises(StereoInputError, match="calib.image_size"):
        rectify_calibrated(torch.zeros(1, 1, 100, 100), torch.zeros(1, 1, 100, 100), calib)
    with pytest.raises(StereoInputError, match="alpha"):
        rectify_calibrated(img, img, calib, alpha=1.5)
    with pytest.raises(TypeError, match="calib"):
        rectify_calibrated(img, img, {"K1": K1})
    with pytest.raises(StereoInputError, match="right"):
        rectify_calibrated(img, torch.zeros(1, 1, 10, 10), calib)
    with pytest.raises(ValueError, match="K1"):  # singular K is refused by the Calibration itself
        Calibration(torch.zeros(3, 3), K2, eye, torch.tensor([-1.0, 0, 0]))


def _noisy_matches(
    calib: Calibration, seed: int, count: int = 200, sigma: float = 0.5, outliers: float = 0.2
):
    X, p1, p2 = random_correspondences(calib, count, seed)
    g = torch.Generator().manual_seed(seed)
    n1 = p1 + sigma * torch.randn(p1.shape, generator=g, dtype=torch.float64)
    n2 = p2 + sigma * torch.randn(p2.shape, generator=g, dtype=torch.float64)
    k = int(outliers * count)
    w, h = calib.image_size
    n2[:k] = torch.rand(k, 2, generator=g, dtype=torch.float64) * torch.tensor([w - 1.0, h - 1.0])
    return p1[k:], p2[k:], n1, n2


def test_uncalibrated_rectification_from_noisy_matches_on_random_rigs(one_thread):
    """Hartley rectification from F estimated on noisy matches (sigma 0.5 px, 20 % outliers); OpenCV's
    stereoRectifyUncalibrated with the same F and inliers in the same run (16 rigs here, 50 data_gen rigs in
    test_data_gen_rigs.py)."""
    ours, theirs = [], []
    for seed in range(16):
        calib = random_rig(seed, image_size=SIZE)
        gt1, gt2, n1, n2 = _noisy_matches(calib, seed)
        rect = stereo_rectify_uncalibrated(n1, n2, SIZE, seed=seed)
        dy, d = _row_errors(rect, gt1, gt2)
        ours.append(float(dy.median()))
        assert float((d >= -2).double().mean()) > 0.97  # disparities shifted to be >= 0
        lo, hi = rect.disparity_range
        assert lo >= -3 and hi > lo
        # reference: cv2.stereoRectifyUncalibrated(n1[inliers], n2[inliers], F, (w, h))
        inl = rect.inliers.numpy()
        ok, H1, H2 = cv2.stereoRectifyUncalibrated(n1.numpy()[inl], n2.numpy()[inl], rect.F.numpy(), SIZE)
        assert ok
        a = apply_homography(torch.from_numpy(H1), gt1)
        b = apply_homography(torch.from_numpy(H2), gt2)
        theirs.append(float((a[:, 1] - b[:, 1]).abs().median()))
    assert float(np.median(ours)) < 0.5 and max(ours) < 0.5, ours
    assert float(np.median(theirs)) < 0.5  # the same F through OpenCV's homographies


def test_uncalibrated_bad_input():
    calib = random_rig(2, image_size=SIZE)
    img = _blank(calib)
    _, _, n1, n2 = _noisy_matches(calib, 2, count=30)
    with pytest.raises(DegenerateGeometryError, match="need at least 16"):
        rectify_uncalibrated(img, img, n1[:10], n2[:10])
    with pytest.raises(StereoInputError, match="both or neither"):
        rectify_uncalibrated(img, img, n1)
    with pytest.raises(DegenerateGeometryError, match="SIFT"):  # textureless images: no matches at all
        rectify_uncalibrated(img, img)
    # forward motion: the epipole is inside the image
    eye = torch.eye(3, dtype=torch.float64)
    forward = Calibration(calib.K1, calib.K2, eye, torch.tensor([0.01, 0.0, -0.3]), image_size=SIZE)
    _, q1, q2 = random_correspondences(forward, 40, 2)
    with pytest.raises(DegenerateGeometryError, match="epipole lies inside"):
        stereo_rectify_uncalibrated(
            q1, q2, SIZE, F=fundamental_from_pose(forward.K1, forward.K2, eye, forward.t)
        )


def test_hartley_shape_matching_keeps_rows_and_local_shape():
    """H_A never changes rows, so both choices align rows equally; "shape" gives the left warp the right
    warp's x-derivatives at the image centre (no added shear); "disparity" is Hartley's least squares."""
    calib = random_rig(13, image_size=SIZE)
    _, p1, p2 = random_correspondences(calib, 150, 13)
    F = fundamental_from_pose(calib.K1, calib.K2, calib.R, calib.t)
    H1s, H2s = hartley_homographies(F, p1, p2, SIZE, match="shape")
    H1d, H2d = hartley_homographies(F, p1, p2, SIZE, match="disparity")
    assert torch.allclose(H2s, H2d)
    for H1 in (H1s, H1d):
        assert float((apply_homography(H1, p1)[:, 1] - apply_homography(H2s, p2)[:, 1]).abs().max()) < 1e-6
    centre = torch.tensor([[(SIZE[0] - 1) / 2, (SIZE[1] - 1) / 2]], dtype=torch.float64)
    J1 = torch.autograd.functional.jacobian(lambda q: apply_homography(H1s, q), centre)[0, :, 0]
    J2 = torch.autograd.functional.jacobian(lambda q: apply_homography(H2s, q), centre)[0, :, 0]
    assert torch.allclose(J1[0], J2[0], atol=1e-9)  # the x row; the y row is fixed by F
    with pytest.raises(ValueError, match="match"):
        hartley_homographies(F, p1, p2, SIZE, match="bogus")


def test_opencv_method_on_a_reversed_rig_and_a_vertical_one():
    """method="opencv" on a rig whose second camera sits on the left: marked reversed with a positive rectified
    baseline (depth works), as the kornia method does; a vertical rig (OpenCV rectifies along columns) is one line."""
    from stereonet.geometry import is_reversed_rig, stereo_rectify

    K = np.array([[300.0, 0, 159.5], [0, 300.0, 119.5], [0, 0, 1]])
    rev = Calibration(K, K, np.eye(3), np.array([0.1, 0.0, 0.002]), image_size=SIZE)
    assert is_reversed_rig(rev)
    for method in ("kornia", "opencv"):
        rect = stereo_rectify(rev, method=method)
        assert rect.reversed and rect.calib.baseline > 0 and float(rect.calib.t[0]) < 0, method
    up = Calibration(K, K, np.eye(3), np.array([0.0, -0.1, 0.0]), image_size=SIZE)
    with pytest.raises(StereoInputError, match="baseline is vertical") as e:
        stereo_rectify(up, method="opencv")
    assert "\n" not in str(e.value)
