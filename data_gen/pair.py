"""Stereo pairs with exact ground truth: :func:`render_pair` is a pure function of ``(seed, index)``."""

from __future__ import annotations

import contextlib
import math

import cv2
import numpy as np
import torch

from data_gen import render as render_module
from data_gen.render import SPECULAR_MASK_THRESHOLD, render_view, render_view_arrays
from data_gen.scene import (
    DIFFICULTY,
    Rig,
    Scene,
    add_thin_structures,
    check_difficulty,
    check_probability,
    check_textures,
    default_max_disp,
    sample_rig,
    sample_scene,
    share_materials,
    weaken_background,
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
        return _camera_response_hwc(np.ascontiguousarray(img.permute(1, 2, 0).numpy()), params, photometric, blur,
                                    noise)
    return _camera_response_torch(img, params, photometric, blur, noise)


def _camera_response_hwc(hwc: np.ndarray, params: dict, photometric: bool = True, blur: bool = True,
                         noise: bool = True) -> torch.Tensor:
    """:func:`apply_camera_response` of a float32 :math:`(H, W, 3)` image; returns :math:`(3, H, W)`."""
    from data_gen._kernels import NOISE_TABLE_SIZE, camera_response, noise_table

    sigma = params["blur"] if blur else 0.0
    if sigma >= 0.05:
        r = max(1, int(math.ceil(2.5 * sigma)))
        hwc = cv2.GaussianBlur(hwc, (2 * r + 1, 2 * r + 1), sigmaX=sigma, sigmaY=sigma,
                               borderType=cv2.BORDER_REFLECT_101)
    amp = params["noise"] if noise else 0.0
    out = np.empty((3, hwc.shape[0], hwc.shape[1]), dtype=np.float32)
    camera_response(hwc, out, np.asarray(params["gain"], dtype=np.float64).reshape(3), float(params["bias"]),
                    float(params["gamma"]), float(params.get("vignetting", 0.0)), bool(photometric), float(amp),
                    noise_table(), int(params["noise_seed"] % NOISE_TABLE_SIZE))
    return torch.from_numpy(out)


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


def _view_arrays(view: dict) -> dict[str, np.ndarray]:
    """float64 ``points`` :math:`(N, 3)`, int64 ``ids``, float64 ``t`` (depth), ``spec``, ``spec2`` :math:`(N,)`
    of a view: the arrays of :func:`render_view_arrays` as they are, or the tensors of :func:`render_view`."""
    if "image" not in view:
        return view

    def f64(x: torch.Tensor) -> np.ndarray:
        return np.ascontiguousarray(x.reshape(-1).double().numpy())

    out = dict(points=np.ascontiguousarray(view["points"].double().numpy()), t=f64(view["depth"]),
               ids=np.ascontiguousarray(view["ids"].reshape(-1).numpy().astype(np.int64)), spec=f64(view["specular"]))
    out["spec2"] = f64(view["specular_second"]) if "specular_second" in view else np.zeros_like(out["spec"])
    return out


def _ground_truth(scene: Scene, rig: Rig, left: dict, right: dict, occlusion_right: bool = False
                  ) -> dict[str, torch.Tensor]:
    """Disparities, correspondences, occlusion and specular masks from the centre-ray geometry (float64
    inside; :func:`data_gen._kernels.ground_truth_maps`). ``left``, ``right``: :func:`render_view` dicts or
    :func:`render_view_arrays` arrays (the left one rendered with ``second_eye`` = the right camera centre)."""
    from data_gen._kernels import ground_truth_maps, hidden_points, pack_scene
    from data_gen.render import project_points, visible_np

    cam_l, cam_r = rig.left, rig.right
    w, h = cam_l.size
    n = h * w
    left, right = _view_arrays(left), _view_arrays(right)
    pts_l, ids_l, depth_l = left["points"], left["ids"], left["t"]
    pts_r, ids_r, depth_r, packed_r = right["points"], right["ids"], right["t"], right.get("packed")
    corr, z_r = project_points(cam_r, pts_l)  # HWx2 right pixel of each left pixel's surface point
    corr_l, z_l = project_points(cam_l, pts_r)
    packed_r = pack_scene(scene, cam_r) if packed_r is None else packed_r
    hidden = np.empty(n, dtype=np.bool_)
    hidden_points(pts_l, corr, np.asarray(cam_r.center, dtype=np.float64), packed_r["objs"], packed_r["edges"],
                  packed_r["blobs"], packed_r["boxes"], 1e-4, hidden)
    # representable: in front of both cameras, depth disparity f B / z within the range in both (the scene
    # sampler guarantees it; this only guards hand-built scenes and float round-off at the bound)
    limit = scene.max_disp * (1 + DISP_TOLERANCE) if scene.max_disp > 0 else math.inf
    maps = dict(disparity=np.empty(n, np.float32), valid=np.empty(n, np.bool_),
                disparity_right=np.empty(n, np.float32), valid_right=np.empty(n, np.bool_),
                occlusion=np.empty(n, np.bool_), depth=np.empty(n, np.float32), specular=np.empty(n, np.bool_))
    correspondence = np.empty((2, n), np.float32)
    ground_truth_maps(w, h, ids_l, depth_l, corr, z_r, hidden, ids_r, depth_r, corr_l, z_l, left["spec"], left["spec2"],
                      cam_l.K[0, 0] * rig.baseline, cam_r.K[0, 0] * rig.baseline, float(limit), bool(rig.rectified),
                      SPECULAR_MASK_THRESHOLD, *maps.values(), correspondence)
    out = {k: torch.from_numpy(v.reshape(1, h, w)) for k, v in maps.items()}
    out["correspondence"] = torch.from_numpy(correspondence.reshape(2, h, w))
    if occlusion_right:  # right pixels whose surface point the left camera does not see
        seen_l = visible_np(scene, cam_l, pts_r, corr_l, z_l)
        out["occlusion_right"] = torch.from_numpy((~seen_l & maps["valid_right"]).reshape(1, h, w))
    return out


def pair_name(seed: int, index: int, difficulty: int, rectified: bool, shared_material: float = 0.0,
              textures: dict[str, float] | None = None, weak_background: float = 0.0,
              thin_structures: float = 0.0) -> str:
    """The name of a rendered pair (``name`` of :func:`render_pair`; the CLI's folder names)."""
    kind = "rect" if rectified else "unrect"
    name = f"synth_{kind}_d{difficulty}_s{seed}_{index:06d}" + (f"_m{shared_material:g}" if shared_material else "")
    if textures:
        name += "_t" + "-".join(f"{k}{w:g}" for k, w in sorted(textures.items()) if w > 0)
    if weak_background:
        name += f"_w{weak_background:g}"
    if thin_structures:
        name += f"_r{thin_structures:g}"
    return name


def render_pair(seed: int, index: int, difficulty: int = 2, height: int = 256, width: int = 512,
                rectified: bool = True, supersample: int = 2, *, num_objects: int | None = None,
                max_disp: int | None = None, baseline: float | None = None, distortion: bool | None = None,
                noise: bool = True, photometric: bool = True, blur: bool = True, specular: bool = True,
                occlusion_right: bool = False, shared_material: float = 0.0,
                textures: dict[str, float] | None = None, weak_background: float = 0.0,
                thin_structures: float = 0.0) -> dict:
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
        shared_material: probability that an object takes the look of the surface behind it
            (:func:`data_gen.scene.share_materials`: depth edges without a colour edge, as in photos). Drawn from a
            stream of its own, so the geometry, lights and camera responses are those of the same pair at 0
            (the default, which draws nothing).
        textures: ``{kind: weight}`` over :data:`data_gen.textures.TEXTURE_KINDS` instead of the difficulty's
            texture mix (e.g. without ``weak`` and ``flat``: every surface textured); None = the difficulty's.
        weak_background: probability that the scene's background walls get a weaker texture
            (:func:`data_gen.scene.weaken_background`: objects in front of weakly textured walls, as often in
            photos). A stream of its own, like ``shared_material``; 0 (the default) draws nothing.
        thin_structures: probability that the scene gets a few thin rods (poles, branches, cables:
            :func:`data_gen.scene.add_thin_structures`), appended after its objects. A stream of its own, like
            ``shared_material``; 0 (the default) draws nothing.

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
    shared_material = check_probability(shared_material, "shared_material")
    weak_background = check_probability(weak_background, "weak_background")
    thin_structures = check_probability(thin_structures, "thin_structures")
    textures = check_textures(textures)
    with single_thread():
        return _render_pair(seed, index, difficulty, height, width, rectified, supersample, num_objects, max_disp,
                            baseline, distortion, noise, photometric, blur, specular, occlusion_right,
                            shared_material, textures, weak_background, thin_structures)


def _render_pair(seed, index, difficulty, height, width, rectified, supersample, num_objects, max_disp, baseline,
                 distortion, noise, photometric, blur, specular, occlusion_right, shared_material,
                 textures=None, weak_background=0.0, thin_structures=0.0) -> dict:
    rng = np.random.default_rng(np.random.SeedSequence([seed, index]))
    rig = sample_rig(rng, height, width, rectified=rectified, baseline=baseline, distortion=distortion)
    scene = sample_scene(rng, difficulty, rig, max_disp, num_objects, textures)
    level = DIFFICULTY[difficulty]
    response = [_photometric(rng, level), _photometric(rng, level)]
    if shared_material > 0:  # a stream of its own: everything above is the same pair as without it
        share_materials(scene, np.random.default_rng(np.random.SeedSequence([seed, index, 1])), shared_material)
    if weak_background > 0:  # another stream of its own
        weaken_background(scene, np.random.default_rng(np.random.SeedSequence([seed, index, 2])), weak_background)
    if thin_structures > 0:  # a third stream of its own; rods use the scene's texture mix
        add_thin_structures(scene, np.random.default_rng(np.random.SeedSequence([seed, index, 3])), rig,
                            level if textures is None else {**level, "textures": textures}, max_disp, thin_structures)
    if render_module.USE_KERNELS:
        views = [render_view_arrays(scene, rig.left, supersample, specular, second_eye=rig.right.center),
                 render_view_arrays(scene, rig.right, supersample, specular)]
        images = [_camera_response_hwc(v["rgb"], r, photometric, blur, noise) for v, r in zip(views, response)]
    else:
        views = [render_view(scene, rig.left, supersample, specular=specular, second_eye=rig.right.center),
                 render_view(scene, rig.right, supersample, specular=specular)]
        images = [apply_camera_response(v["image"], r, photometric, blur, noise) for v, r in zip(views, response)]
    gt = _ground_truth(scene, rig, views[0], views[1], occlusion_right)
    if not specular:
        gt["specular"].zero_()
    out = dict(left=images[0], right=images[1], calib=calibration_of(rig, max_disp), max_disp=max_disp,
               name=pair_name(seed, index, difficulty, rectified, shared_material, textures, weak_background,
                              thin_structures),
               difficulty=difficulty, scene=scene,
               rig=rig)
    out.update(gt)
    return out

