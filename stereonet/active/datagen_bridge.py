"""A pattern projector added to data_gen's rigs and scenes (data_gen's renderer, its ``extra_light_fn`` hook).

:func:`datagen_active_pair` samples data_gen's rig and scene for ``(seed, index, difficulty)`` exactly as
``data_gen.render_pair`` does, optionally repaints every surface flat grey (``surface="textureless"``) or with
fine stripes (``"repetitive"``), puts a projector halfway between the cameras, and renders both views with
the projector showing ``pattern`` (or off). The projector's light at a surface point is
``power * pattern(projector.project(X)) * max(0, n . l) * visible_from(projector)``, added to data_gen's
diffuse irradiance. Units are data_gen's (millimetres).
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from stereonet.active.structured_light import ActivePair
from stereonet.checks import StereoInputError

SURFACES = ("original", "textureless", "repetitive")


def _repaint(scene, surface: str, rng: np.random.Generator) -> None:
    from data_gen import Material

    for obj in scene.objects:
        m = obj.material
        if surface == "textureless":
            g = rng.uniform(0.4, 0.8)
            obj.material = Material(kind="flat", colors=np.array([[g] * 3, [g] * 3, [0.0] * 3]), texel_mm=m.texel_mm)
        elif surface == "repetitive":
            lo, hi = rng.uniform(0.2, 0.35), rng.uniform(0.7, 0.9)
            obj.material = Material(kind="stripes", colors=np.array([[lo] * 3, [hi] * 3, [0.0] * 3]),
                                    texel_mm=m.texel_mm, period=float(rng.uniform(5.0, 9.0)),
                                    angle=float(rng.uniform(-0.3, 0.3)))


def projector_light(scene, projector, pattern: torch.Tensor, power: float):
    """data_gen ``extra_light_fn`` of a projector (a data_gen ``Camera``) showing ``pattern`` :math:`(H_p, W_p)`."""
    from data_gen import visible_from

    w, h = projector.size
    if tuple(pattern.shape) != (h, w):
        raise StereoInputError(f"pattern: expected ({h}, {w}) for this projector, got {tuple(pattern.shape)}")
    centre = torch.as_tensor(projector.center)

    def light(points: torch.Tensor, normals: torch.Tensor, ids: torch.Tensor) -> torch.Tensor:
        pix, z = projector.project(points)
        grid = torch.stack([2 * pix[:, 0] / max(w - 1, 1) - 1, 2 * pix[:, 1] / max(h - 1, 1) - 1], -1)
        val = F.grid_sample(pattern[None, None].float(), grid.view(1, 1, -1, 2).float(), mode="bilinear",
                            padding_mode="zeros", align_corners=True).view(-1).to(points.dtype)
        to_p = centre.to(points.dtype) - points
        lam = ((normals * to_p).sum(-1) / to_p.norm(dim=-1).clamp_min(1e-12)).clamp_min(0)
        vis = visible_from(scene, projector, points, projected=(pix, z))
        return power * val * lam * vis * (ids >= 0)

    return light


def datagen_active_pair(seed: int, index: int, pattern: torch.Tensor | None, difficulty: int = 1,
                        surface: str = "textureless", height: int = 192, width: int = 256,
                        projector_scale: int = 1, power: float = 0.8, noise_std: float = 0.005) -> tuple[ActivePair, int]:
    """A data_gen rectified pair with a projector between the cameras (``pattern`` None = projector off).

    ``pattern`` must be :math:`(H s, W s)` for ``s = projector_scale``. Returns the pair (GT disparity
    ``f B / z``, valid where a surface is hit, occlusion where the right camera cannot see the left pixel's
    point) and data_gen's disparity bound for the scene.
    """
    import data_gen
    from data_gen import Camera, render_view, sample_rig, sample_scene, visible_from

    if surface not in SURFACES:
        raise StereoInputError(f"surface: expected one of {SURFACES}, got {surface!r}")
    rng = np.random.default_rng(np.random.SeedSequence([seed, index]))  # as data_gen.render_pair
    rig = sample_rig(rng, height, width, rectified=True)
    max_disp = data_gen.default_max_disp(difficulty, width)
    scene = sample_scene(rng, difficulty, rig, max_disp)
    _repaint(scene, surface, np.random.default_rng(np.random.SeedSequence([seed, index, 1])))
    s = int(projector_scale)
    K = rig.left.K.copy()
    K[:2] *= s
    K[:2, 2] = (rig.left.K[:2, 2] + 0.5) * s - 0.5  # same field of view, pixel centres at integers
    eye = np.array([rig.baseline / 2, -0.02 * rig.baseline, 0.0])
    projector = Camera(K, np.eye(3), -eye, size=(width * s, height * s))
    light = None if pattern is None else projector_light(scene, projector, pattern, power)
    g = torch.Generator().manual_seed(int(seed) * 1000 + int(index))
    views = []
    for cam in (rig.left, rig.right):
        v = render_view(scene, cam, supersample=2, specular=False, extra_light_fn=light)
        img = v["image"] + noise_std * torch.randn(v["image"].shape, generator=g)
        views.append((img.clamp(0, 1)[None].float(), v))
    vl = views[0][1]
    depth = vl["depth"].to(torch.float64)
    valid = torch.isfinite(depth) & (depth > 0)
    disp = torch.where(valid, rig.focal * rig.baseline / torch.where(valid, depth, torch.ones_like(depth)),
                       torch.zeros_like(depth))
    seen = visible_from(scene, rig.right, vl["points"]).view(height, width)
    pair = ActivePair(views[0][0], views[1][0], disp[None, None].float(), valid[None, None],
                      (~seen | ~valid)[None, None], torch.where(valid, depth, torch.zeros_like(depth)))
    return pair, max_disp
