"""Seeded test scenes and rigs for the active-stereo experiments, built from data_gen's primitives and materials.

* :func:`make_scene` — a room corner (back wall, floor, tilted side wall: infinite :class:`data_gen.Plane` s)
  with random boxes (six :class:`data_gen.PlanarPatch` faces each, :func:`data_gen.box_faces`) and spheres,
  all with one surface kind: ``"textureless"`` (flat greys: passive matching has nothing to match),
  ``"repetitive"`` (stripes varying along world x with a period of a few pixels: every disparity a period apart
  matches), or ``"textured"`` (data_gen's natural-statistics bank textures in colour: the easy case, and
  colourful merged clouds).
* :func:`make_rig` — a rectified stereo pair with a projector between the cameras (:class:`data_gen.Camera` s).

Units are metres (data_gen's geometry is unit-agnostic; a material's ``texel_mm`` is then metres per texel);
world = left camera frame (x right, y down, z forward). The scene's lighting is the one the active renderers
default to for plain views (:func:`~stereonet.active.render.render_captures`): ambient 0.35 and a directional
light of strength 0.45 travelling along (0.3, 0.6, 1.0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import torch

from data_gen import Camera, Material, Plane, Scene, Sphere, box_faces
from data_gen.textures import BANK_COUNT
from stereonet.checks import StereoInputError

SCENE_KINDS = ("textureless", "repetitive", "textured")
LIGHT_TRAVEL = (0.3, 0.6, 1.0)  # direction the directional light travels (world frame)
STRIPE_TEXELS = 16.0  # texels per stripe period (data_gen's analytic textures)
BANK_TEXELS_PER_CELL = 4.0  # a bank texel is a quarter of the sampled cell size: features of a few pixels


def _material(kind: str, g: torch.Generator, i: int) -> Material:
    r = lambda lo, hi: lo + (hi - lo) * float(torch.rand(1, generator=g, dtype=torch.float64))
    if kind == "textureless":
        v = r(0.45, 0.8)
        return Material.flat((v, v, v))
    if kind == "repetitive":
        hi, lo, period = r(0.75, 0.9), r(0.25, 0.4), r(0.03, 0.045)
        return Material(kind="stripes", colors=np.array([[lo] * 3, [hi] * 3, [0.0] * 3]),
                        texel_mm=period / STRIPE_TEXELS, period=STRIPE_TEXELS)
    bright = [r(0.35, 0.95) for _ in range(3)]
    dark = [r(0.05, 0.45) for _ in range(3)]
    cell = r(0.05, 0.15)
    bank = (int(1000 * r(0, 1)) + i) % BANK_COUNT
    return Material(kind="bank", colors=np.array([dark, bright, [0.0] * 3]), texel_mm=cell / BANK_TEXELS_PER_CELL,
                    bank=(bank, bank))


def _stripes_along_x(obj) -> None:
    """Give ``obj`` its own copy of its stripe material, turned so that the stripes vary along world x
    (vertical in the image).

    On a planar surface texture ``s`` runs along ``cos(angle) e1 - sin(angle) e2``; on a sphere with the default
    vertical axis it runs along the longitude, which angle 0 already gives.
    """
    if not isinstance(obj, Sphere):
        obj.material = replace(obj.material, angle=math.atan2(-float(obj.e2[0]), float(obj.e1[0])))


def make_scene(kind: str = "textureless", seed: int = 0, objects: int = 4) -> Scene:
    """A seeded room corner with ``objects`` random boxes/spheres between 1.4 and 2.6 m, walls at ~3.2 m."""
    if kind not in SCENE_KINDS:
        raise StereoInputError(f"kind: expected one of {SCENE_KINDS}, got {kind!r}")
    g = torch.Generator().manual_seed(int(seed))
    r = lambda lo, hi: lo + (hi - lo) * float(torch.rand(1, generator=g, dtype=torch.float64))
    back = r(3.0, 3.4)
    items: list = [Plane((0.0, 0.0, back), (0.0, 0.0, -1.0), material=_material(kind, g, 0))]  # back wall z = c
    floor_y = r(0.6, 0.8)
    items.append(Plane((0.0, floor_y, 0.0), (0.0, -1.0, 0.0), material=_material(kind, g, 1)))  # floor y = c (y down)
    side_n = np.array([1.0, 0.0, -0.25])
    side_k = -r(1.5, 1.8) / np.linalg.norm(side_n)  # tilted side wall on the left: n . X = k
    items.append(Plane(side_k * side_n / np.linalg.norm(side_n), side_n, material=_material(kind, g, 2)))
    for i in range(objects):
        z = r(1.4, 2.6)
        x = r(-0.55, 0.55) * z / 1.6
        if i % 2 == 0:
            s = r(0.15, 0.3)
            lo, hi = (x - s, floor_y - r(0.3, 0.9), z - s), (x + s, floor_y, z + s)
            items += box_faces(lo, hi, _material(kind, g, 3 + i))
        else:
            rad = r(0.15, 0.3)
            items.append(Sphere((x, r(-0.3, 0.3), z), rad, material=_material(kind, g, 3 + i)))
    if kind == "repetitive":
        for obj in items:
            _stripes_along_x(obj)
    light = -np.asarray(LIGHT_TRAVEL) / np.linalg.norm(LIGHT_TRAVEL)  # data_gen: from surfaces towards the light
    return Scene(items, light_dir=light, ambient=0.35, light_strength=0.45, num_background=3)


@dataclass
class Rig:
    """Rectified stereo pair (``left`` at the origin, ``right`` at ``(baseline, 0, 0)``) and a ``projector``."""

    left: Camera
    right: Camera
    projector: Camera
    baseline: float

    @property
    def focal(self) -> float:
        return float(self.left.K[0, 0])

    def max_disp(self, min_depth: float = 1.0) -> int:
        """Disparity range (multiple of 16) covering depths down to ``min_depth``."""
        return int(16 * math.ceil(self.focal * self.baseline / min_depth / 16))


def make_rig(width: int = 320, height: int = 240, focal: float = 300.0, baseline: float = 0.2,
             projector_scale: int = 2, projector_offset: tuple[float, float, float] | None = None) -> Rig:
    """A rectified rig (x_right = x_left - f B / z) with a projector of ``projector_scale`` times the camera
    resolution and the same field of view, halfway between the cameras unless ``projector_offset`` is given."""
    left = Camera.pinhole(focal, width, height)
    right = Camera.pinhole(focal, width, height, eye=(baseline, 0.0, 0.0))
    off = (baseline / 2, -0.03, 0.0) if projector_offset is None else projector_offset
    s = int(projector_scale)
    projector = Camera.pinhole(focal * s, width * s, height * s, eye=off)
    return Rig(left, right, projector, baseline)
