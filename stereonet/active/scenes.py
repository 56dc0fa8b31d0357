"""Seeded test scenes and rigs for the active-stereo experiments.

* :func:`make_scene` — a room corner (back wall, floor, side wall) with random boxes and spheres, all with
  one surface kind: ``"textureless"`` (flat greys: passive matching has nothing to match),
  ``"repetitive"`` (vertical stripes with a period of a few pixels: every disparity a period apart matches),
  or ``"textured"`` (smooth value noise in colour: the easy case, and colourful merged clouds).
* :func:`make_rig` — a rectified stereo pair with a projector between the cameras.

Units are metres; world = left camera frame (x right, y down, z forward).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from stereonet.active.scene import Box, PinholeCamera, Plane, Scene, Sphere, Texture
from stereonet.checks import StereoInputError

SCENE_KINDS = ("textureless", "repetitive", "textured")


def _texture(kind: str, g: torch.Generator, i: int) -> Texture:
    r = lambda lo, hi: lo + (hi - lo) * float(torch.rand(1, generator=g, dtype=torch.float64))
    if kind == "textureless":
        v = r(0.45, 0.8)
        return Texture("constant", (v, v, v))
    if kind == "repetitive":
        return Texture("stripes", (r(0.75, 0.9),) * 3, (r(0.25, 0.4),) * 3, period=r(0.03, 0.045), axis=0)
    c1 = tuple(r(0.35, 0.95) for _ in range(3))
    c2 = tuple(r(0.05, 0.45) for _ in range(3))
    return Texture("noise", c1, c2, period=r(0.05, 0.15), seed=int(1000 * r(0, 1)) + i)


def make_scene(kind: str = "textureless", seed: int = 0, objects: int = 4) -> Scene:
    """A seeded room corner with ``objects`` random boxes/spheres between 1.4 and 2.6 m, walls at ~3.2 m."""
    if kind not in SCENE_KINDS:
        raise StereoInputError(f"kind: expected one of {SCENE_KINDS}, got {kind!r}")
    g = torch.Generator().manual_seed(int(seed))
    r = lambda lo, hi: lo + (hi - lo) * float(torch.rand(1, generator=g, dtype=torch.float64))
    items: list = [
        Plane((0.0, 0.0, -1.0), -r(3.0, 3.4), _texture(kind, g, 0)),          # back wall z = c
        Plane((0.0, -1.0, 0.0), -r(0.6, 0.8), _texture(kind, g, 1)),          # floor y = c (y down)
        Plane((1.0, 0.0, -0.25), -r(1.5, 1.8), _texture(kind, g, 2)),         # tilted side wall on the left
    ]
    floor_y = -items[1].offset
    for i in range(objects):
        z = r(1.4, 2.6)
        x = r(-0.55, 0.55) * z / 1.6
        if i % 2 == 0:
            s = r(0.15, 0.3)
            items.append(Box((x - s, floor_y - r(0.3, 0.9), z - s), (x + s, floor_y, z + s), _texture(kind, g, 3 + i)))
        else:
            rad = r(0.15, 0.3)
            items.append(Sphere((x, r(-0.3, 0.3), z), rad, _texture(kind, g, 3 + i)))
    return Scene(items)


@dataclass
class Rig:
    """Rectified stereo pair (``left`` at the origin, ``right`` at ``(baseline, 0, 0)``) and a ``projector``."""

    left: PinholeCamera
    right: PinholeCamera
    projector: PinholeCamera
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
    left = PinholeCamera.create(focal, width, height)
    right = PinholeCamera.create(focal, width, height, eye=(baseline, 0.0, 0.0))
    off = (baseline / 2, -0.03, 0.0) if projector_offset is None else projector_offset
    s = int(projector_scale)
    projector = PinholeCamera.create(focal * s, width * s, height * s, eye=off,
                                     cx=(width * s - 1) / 2.0, cy=(height * s - 1) / 2.0)
    return Rig(left, right, projector, baseline)
