"""A pattern projector added to data_gen's own rigs and scenes.

:func:`datagen_active_pair` samples data_gen's rig and scene for ``(seed, index, difficulty)`` exactly as
``data_gen.render_pair`` does, optionally repaints every surface flat grey (``surface="textureless"``) or with
fine stripes (``"repetitive"``), puts a projector halfway between the cameras, and renders both views with
the projector showing ``pattern`` (or off) by :func:`~stereonet.active.structured_light.render_active_pair`:
the same projector model (:func:`~stereonet.active.structured_light.projector_light`) and renderer as the
active room scenes, under the scene's own sampled lighting. Units are data_gen's (millimetres).
"""

from __future__ import annotations

import numpy as np
import torch

from stereonet.active.structured_light import ActivePair, render_active_pair
from stereonet.checks import StereoInputError

SURFACES = ("original", "textureless", "repetitive")


def _repaint(scene, surface: str, rng: np.random.Generator) -> None:
    from data_gen import Material

    for obj in scene.objects:
        m = obj.material
        if surface == "textureless":
            obj.material = Material.flat([rng.uniform(0.4, 0.8)] * 3, texel_mm=m.texel_mm)
        elif surface == "repetitive":
            lo, hi = rng.uniform(0.2, 0.35), rng.uniform(0.7, 0.9)
            obj.material = Material(kind="stripes", colors=np.array([[lo] * 3, [hi] * 3, [0.0] * 3]),
                                    texel_mm=m.texel_mm, period=float(rng.uniform(5.0, 9.0)),
                                    angle=float(rng.uniform(-0.3, 0.3)))


def datagen_active_pair(seed: int, index: int, pattern: torch.Tensor | None, difficulty: int = 1,
                        surface: str = "textureless", height: int = 192, width: int = 256,
                        projector_scale: int = 1, power: float = 0.8, noise_std: float = 0.005) -> tuple[ActivePair, int]:
    """A data_gen rectified pair with a projector between the cameras (``pattern`` None = projector off).

    ``pattern`` must be :math:`(H s, W s)` for ``s = projector_scale``. Returns the pair (GT disparity
    ``f B / z``, valid where a surface is hit, occlusion where the right camera cannot see the left pixel's
    point) and data_gen's disparity bound for the scene.
    """
    import data_gen
    from data_gen import Camera, sample_rig, sample_scene
    from stereonet.active.scenes import Rig

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
    pair = render_active_pair(scene, Rig(rig.left, rig.right, projector, rig.baseline), pattern,
                              seed=int(seed) * 1000 + int(index), power=power, noise_std=noise_std,
                              ambient=None, light=None)
    return pair, max_disp
