"""Stereo pairs with exact ground truth: :func:`render_pair` is a pure function of ``(seed, index)``."""

from __future__ import annotations

import contextlib
import math

import cv2
import numpy as np
import torch

from data_gen import render as render_module
from data_gen.render import SPECULAR_MASK_THRESHOLD, render_view
from data_gen.scene import (
    DIFFICULTY,
    Rig,
    Scene,
    check_difficulty,
    default_max_disp,
    sample_rig,
    sample_scene,
)


@contextlib.contextmanager
def single_thread():
    """Run torch single-threaded inside the block (restored after).

    The renderer's tensors are small and many: with several intra-op threads on a busy machine the thread
    synchronisation costs far more than it saves (measured 5-10x more CPU time at 2 threads).
    """
    before = torch.get_num_threads()
    if before == 1:
        yield
        return
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def _check_int(value: object, name: str, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or int(value) < minimum:
        raise ValueError(f"{name}: expected an integer >= {minimum}, got {value!r}")
    return int(value)


def check_render_args(seed, index, difficulty, height, width, supersample, max_disp, baseline,
                      num_objects) -> tuple[int, int, int, int, int, int, int]:
    """Validate :func:`render_pair` arguments; errors name the parameter. Returns the normalized ints
    ``(seed, index, difficulty, height, width, supersample, max_disp)``."""
    seed = _check_int(seed, "seed", 0)
    index = _check_int(index, "index", 0)
    difficulty = check_difficulty(difficulty)
    height = _check_int(height, "height", 8)
    width = _check_int(width, "width", 8)
    supersample = _check_int(supersample, "supersample", 1)
    if max_disp is None:
        max_disp = default_max_disp(difficulty, width)
    elif isinstance(max_disp, bool) or not isinstance(max_disp, int | np.integer) or max_disp < 1:
        raise ValueError(f"max_disp: expected a positive integer disparity range, got {max_disp!r}")
    elif max_disp >= width / 2:
        raise ValueError(f"max_disp: the disparity range must stay below half the image width "
                         f"(width={width}, so max_disp < {width / 2:g}), got {max_disp}")
    if baseline is not None and not (isinstance(baseline, int | float) and math.isfinite(baseline) and baseline > 0):
        raise ValueError(f"baseline: expected a positive baseline in mm, got {baseline!r}")
    if num_objects is not None:
        _check_int(num_objects, "num_objects", 1)
    return seed, index, difficulty, height, width, supersample, int(max_disp)


def _photometric(rng: np.random.Generator, level: dict) -> dict:
    """Per-camera response: gains (3,), bias, gamma, vignetting, blur sigma, noise sigma (all sampled, used
    or not, so that switching an effect off leaves the others unchanged)."""
    p = level["photometric"]
    params = dict(gain=(1 + rng.uniform(-p, p)) * (1 + rng.uniform(-p / 3, p / 3, 3)),
                  bias=rng.uniform(-p / 3, p / 3), gamma=1 + rng.uniform(-1.5 * p, 1.5 * p),
                  blur=rng.uniform(0.0, level["blur"]), noise=level["noise"] * rng.uniform(0.5, 1.0),
                  noise_seed=int(rng.integers(2 ** 62)))
    params["vignetting"] = rng.uniform(0.0, 2 * p)
    return params


def _gaussian_blur(img: torch.Tensor, sigma: float) -> torch.Tensor:
    """Gaussian blur of ``img`` :math:`(C, H, W)` (OpenCV, reflect-101 borders)."""
    if sigma < 0.05:
        return img
    r = max(1, int(math.ceil(2.5 * sigma)))
    arr = img.permute(1, 2, 0).contiguous().numpy()  # HxWxC
    out = cv2.GaussianBlur(arr, (2 * r + 1, 2 * r + 1), sigmaX=sigma, sigmaY=sigma, borderType=cv2.BORDER_REFLECT_101)
    return torch.from_numpy(out.reshape(arr.shape)).permute(2, 0, 1).to(img.dtype)


def apply_camera_response(img: torch.Tensor, params: dict, photometric: bool = True, blur: bool = True,
                          noise: bool = True) -> torch.Tensor:
    """Optics and sensor, :math:`(3, H, W)` in/out in [0, 1]: blur; vignetting ``1 - v r^2`` (r = 1 at the
    corners), gain/bias/gamma; signal-dependent Gaussian noise with std ``noise * sqrt(0.25 + I)``.

    float32 images run one fused numba pass (:func:`data_gen._kernels.camera_response`; its noise is a window
    of a fixed table of normal samples at an offset drawn from ``noise_seed``); other dtypes (or
    ``render.USE_KERNELS = False``) the torch reference, with fresh samples from ``noise_seed``.
    """
    if img.dtype == torch.float32 and render_module.USE_KERNELS:
        from data_gen._kernels import NOISE_TABLE_SIZE, camera_response, noise_table

        hwc = np.ascontiguousarray(img.permute(1, 2, 0).numpy())  # HxWx3
        sigma = params["blur"] if blur else 0.0
        if sigma >= 0.05:
            r = max(1, int(math.ceil(2.5 * sigma)))
            hwc = cv2.GaussianBlur(hwc, (2 * r + 1, 2 * r + 1), sigmaX=sigma, sigmaY=sigma,
                                   borderType=cv2.BORDER_REFLECT_101)
        amp = params["noise"] if noise else 0.0
        out = np.empty(tuple(img.shape), dtype=np.float32)
        camera_response(hwc, out, np.asarray(params["gain"], dtype=np.float64).reshape(3), float(params["bias"]),
                        float(params["gamma"]), float(params.get("vignetting", 0.0)), bool(photometric), float(amp),
                        noise_table(), int(params["noise_seed"] % NOISE_TABLE_SIZE))
        return torch.from_numpy(out)
    return _camera_response_torch(img, params, photometric, blur, noise)


def _camera_response_torch(img: torch.Tensor, params: dict, photometric: bool, blur: bool, noise: bool
                           ) -> torch.Tensor:
    """Reference of :func:`apply_camera_response` in torch."""
    if blur:
        img = _gaussian_blur(img, params["blur"])
    if photometric:
        gain = torch.as_tensor(params["gain"], dtype=img.dtype)[:, None, None]
        v = params.get("vignetting", 0.0)
        if v > 0:
            _, h, w = img.shape
            yy = torch.linspace(-1.0, 1.0, h, dtype=img.dtype)[:, None] ** 2
            xx = torch.linspace(-1.0, 1.0, w, dtype=img.dtype)[None, :] ** 2
            gain = gain * (1 - v * 0.5 * (xx + yy))  # 3xHxW
        img = (img * gain + params["bias"]).clamp(0.0, 1.0) ** params["gamma"]
    if noise and params["noise"] > 0:
        gauss = np.random.default_rng(params["noise_seed"]).standard_normal(tuple(img.shape), dtype=np.float32)
        sigma = params["noise"] * torch.sqrt(0.25 + img)
        img = img + sigma * torch.from_numpy(gauss).to(img.dtype)
    return img.clamp(0.0, 1.0)


def calibration_of(rig: Rig, max_disp: int):
    """The :class:`stereonet.types.Calibration` of a rig (units: mm)."""
    from stereonet.types import Calibration

    return Calibration(rig.left.K, rig.right.K, rig.right.R, rig.right.t, image_size=rig.left.size,
                       dist1=rig.left.dist, dist2=rig.right.dist, doffs=0.0, ndisp=int(max_disp))


DISP_TOLERANCE = 1e-3  # relative slack on max_disp before ground truth is marked invalid


def _geometry(view: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict | None]:
    """float64 points :math:`(N, 3)`, int64 ids, float64 depth :math:`(N,)` of a rendered view (the kernels'
    own arrays when present, else the tensors) and the view's packed scene (or None)."""
    raw = view.get("_raw")
    if raw is not None:
        return raw["points"], raw["ids"], raw["t"], raw["packed"]
    return (view["points"].double().numpy(), view["ids"].reshape(-1).numpy().astype(np.int64),
            view["depth"].reshape(-1).double().numpy(), None)


def _ground_truth(scene: Scene, rig: Rig, left: dict, right: dict, occlusion_right: bool = False
                  ) -> dict[str, torch.Tensor]:
    """Disparities, correspondences, occlusion and specular masks from the centre-ray geometry (float64)."""
    from data_gen.render import project_points, visible_np

    cam_l, cam_r = rig.left, rig.right
    w, h = cam_l.size
    xs = np.tile(np.arange(w, dtype=np.float64), h)
    pts_l, ids_l, depth_l, _ = _geometry(left)
    pts_r, ids_r, depth_r, packed_r = _geometry(right)
    hit_l = ids_l >= 0
    corr, z_r = project_points(cam_r, pts_l)  # HWx2 right pixel of each left pixel's surface point
    disp = xs - corr[:, 0]
    visible = visible_np(scene, cam_r, pts_l, corr, z_r, packed_r) & hit_l
    # representable: in front of both cameras, depth disparity f B / z within the range in both (the scene
    # sampler guarantees it; this only guards hand-built scenes and float round-off at the bound)
    limit = scene.max_disp * (1 + DISP_TOLERANCE) if scene.max_disp > 0 else math.inf
    fb_l, fb_r = cam_l.K[0, 0] * rig.baseline, cam_r.K[0, 0] * rig.baseline
    with np.errstate(invalid="ignore"):
        valid = hit_l & (z_r > 0) & (fb_l <= limit * depth_l) & (fb_r <= limit * z_r)
        if rig.rectified:
            valid &= disp > 0
        # disparity of the right view, right-referenced: x_left = x_right + d_right
        corr_l, z_l = project_points(cam_l, pts_r)
        disp_r = corr_l[:, 0] - xs
        valid_r = (ids_r >= 0) & (z_l > 0) & (fb_r <= limit * depth_r) & (fb_l <= limit * z_l)
        if rig.rectified:
            valid_r &= disp_r > 0
    # specular mask: shiny in the left view, or at the same surface point seen from the right camera
    specular = ((left["specular"].reshape(-1) > SPECULAR_MASK_THRESHOLD)
                | (left["specular_second"].reshape(-1) > SPECULAR_MASK_THRESHOLD)).numpy()

    def img(x: np.ndarray, dtype=np.float32) -> torch.Tensor:
        return torch.from_numpy(np.ascontiguousarray(x.reshape(1, h, w), dtype=dtype))

    extra = {}
    if occlusion_right:  # right pixels whose surface point the left camera does not see
        seen_l = visible_np(scene, cam_l, pts_r, corr_l, z_l)
        extra["occlusion_right"] = img(~seen_l & valid_r, np.bool_)
    return extra | dict(
        disparity=img(np.where(valid, disp, 0.0)), valid=img(valid, np.bool_),
        disparity_right=img(np.where(valid_r, disp_r, 0.0)), valid_right=img(valid_r, np.bool_),
        occlusion=img(~visible & valid, np.bool_), depth=img(np.where(hit_l, depth_l, 0.0)),
        specular=img(specular & hit_l, np.bool_),
        correspondence=torch.from_numpy(np.ascontiguousarray(
            np.where(valid[:, None], corr, 0.0).T.reshape(2, h, w), dtype=np.float32)),
    )


def render_pair(seed: int, index: int, difficulty: int = 2, height: int = 256, width: int = 512,
                rectified: bool = True, supersample: int = 2, *, num_objects: int | None = None,
                max_disp: int | None = None, baseline: float | None = None, distortion: bool | None = None,
                noise: bool = True, photometric: bool = True, blur: bool = True, specular: bool = True,
                occlusion_right: bool = False) -> dict:
    """Render one synthetic stereo pair with exact ground truth; a pure function of its arguments.

    Args:
        seed, index: non-negative ints; together they seed every random choice (same pair in any process).
        difficulty: 0..MAX_DIFFICULTY curriculum level; height, width: image size in pixels.
        rectified: rectified rig (R = I, t = (-B, 0, 0), K1 = K2) or a random unrectified one.
        supersample: rays per pixel side for anti-aliasing (ground truth uses the pixel-centre ray).
        num_objects: objects in front of the background (default from the difficulty), >= 1.
        max_disp: disparity range (default: the difficulty's, scaled with width); must be < width / 2.
        baseline: in mm (default random in [60, 300]); distortion: unrectified rigs only (None = random).
        noise, photometric, blur, specular: switch the corresponding effects off (the scene is unchanged).
        occlusion_right: also return ``occlusion_right`` :math:`(1, H, W)` bool (right pixels not seen by the
            left camera; one more visibility pass, ~10% of the time).

    Returns:
        dict with ``left``, ``right`` float32 :math:`(3, H, W)` in [0, 1]; ``disparity``, ``disparity_right``,
        ``depth`` float32 :math:`(1, H, W)` (left disparity ``x_l - x_r`` of each left pixel's surface point;
        for unrectified rigs the horizontal component of the correspondence); ``valid``, ``valid_right``,
        ``occlusion`` (True = left pixel not seen by the right camera), ``specular`` bool :math:`(1, H, W)`;
        ``correspondence`` float32 :math:`(2, H, W)` (right-image pixel (x, y) of each left pixel);
        ``calib`` (:class:`stereonet.types.Calibration`, mm); ``name``; ``max_disp``; ``difficulty``;
        ``scene`` and ``rig`` (the objects used).

    Runs torch single-threaded for its duration (see :func:`single_thread`); parallelize over pairs instead
    (DataLoader workers).
    """
    seed, index, difficulty, height, width, supersample, max_disp = check_render_args(
        seed, index, difficulty, height, width, supersample, max_disp, baseline, num_objects)
    with single_thread():
        return _render_pair(seed, index, difficulty, height, width, rectified, supersample, num_objects, max_disp,
                            baseline, distortion, noise, photometric, blur, specular, occlusion_right)


def _render_pair(seed, index, difficulty, height, width, rectified, supersample, num_objects, max_disp, baseline,
                 distortion, noise, photometric, blur, specular, occlusion_right) -> dict:
    rng = np.random.default_rng(np.random.SeedSequence([seed, index]))
    rig = sample_rig(rng, height, width, rectified=rectified, baseline=baseline, distortion=distortion)
    scene = sample_scene(rng, difficulty, rig, max_disp, num_objects)
    level = DIFFICULTY[difficulty]
    response = [_photometric(rng, level), _photometric(rng, level)]
    views = [render_view(scene, rig.left, supersample, specular=specular, second_eye=rig.right.center),
             render_view(scene, rig.right, supersample, specular=specular)]
    gt = _ground_truth(scene, rig, views[0], views[1], occlusion_right)
    if not specular:
        gt["specular"].zero_()
    images = [apply_camera_response(v["image"], r, photometric, blur, noise) for v, r in zip(views, response)]
    kind = "rect" if rectified else "unrect"
    out = dict(left=images[0], right=images[1], calib=calibration_of(rig, max_disp), max_disp=max_disp,
               name=f"synth_{kind}_d{difficulty}_s{seed}_{index:06d}", difficulty=difficulty, scene=scene, rig=rig)
    out.update(gt)
    return out

