"""What the active sensors' cameras record, rendered through data_gen.

A camera (a :class:`data_gen.Camera`) sees a data_gen :class:`~data_gen.Scene` lit by the scene's ambient and
directional light (irradiance ``ambient + light_strength * max(0, n . l)``) plus an optional *emitter*: a
pattern projector (:func:`~stereonet.active.structured_light.projector_light`) or a laser sheet
(:func:`~stereonet.active.laser.laser_light`). An emitter is a data_gen light function
``lights(points (N, 3), normals (N, 3), ids (N,)) -> (N, P)``: the irradiance it adds at world surface points
in each of its P states (the patterns of a sequence, the angles of a sweep), its own shadow test included
(:func:`data_gen.visible_from`, :func:`data_gen.visible_from_point`). :func:`data_gen.render_sequence` casts
the camera rays once and shades every state: the camera records ``albedo * irradiance`` (Lambertian, no
highlights) clipped to [0, 1] per channel — bright emitters on bright surfaces saturate, as real sensors do —
and :func:`render_captures` adds Gaussian sensor noise.

Geometry is rendered in float64; images are float32 in [0, 1].
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch

from data_gen import Camera, Scene, render_sequence
from data_gen.render import LightsFn
from stereonet.active.icp import RangeScan
from stereonet.active.triangulate import depth_to_points


@dataclass
class View:
    """Pixel-centre geometry of a rendered view: ``image`` :math:`(1, C, H, W)` float32 (the first capture),
    ``depth`` :math:`(H, W)` float64 camera z (0 where nothing is hit), ``hit`` :math:`(H, W)` bool,
    ``points`` / ``normals`` :math:`(H, W, 3)` in world coordinates."""

    image: torch.Tensor
    depth: torch.Tensor
    hit: torch.Tensor
    points: torch.Tensor
    normals: torch.Tensor


@dataclass
class Capture:
    """Camera images of every emitter state, ``images`` :math:`(P, C, H, W)` float32, and the ``view``."""

    images: torch.Tensor
    view: View


def render_captures(scene: Scene, camera: Camera, lights: LightsFn | None = None, ambient: float | None = None,
                    light: float | None = None, samples: int = 1, noise_std: float = 0.0, seed: int = 0,
                    grey: bool = False) -> Capture:
    """``camera``'s images of ``scene`` in each state of the emitter ``lights`` (one image without an emitter).

    Args:
        ambient, light: the scene's ambient level and directional light strength for these captures (None keeps
            the scene's own).
        samples: data_gen's adaptive anti-aliasing: ``samples x samples`` rays on object edges and normal
            creases; the geometry comes from the pixel-centre rays.
        noise_std: standard deviation of additive Gaussian sensor noise (seeded by ``seed``), after clipping
            the radiance to [0, 1]; the images are clipped again.
        grey: a monochrome sensor: ``C = 1``, the mean of the colour channels (noise added to it).
    """
    lit = replace(scene, ambient=scene.ambient if ambient is None else float(ambient),
                  light_strength=scene.light_strength if light is None else float(light))
    out = render_sequence(lit, camera, lights, supersample=samples, specular=False, dtype=torch.float64)
    images = out["images"].mean(1, keepdim=True) if grey else out["images"]
    if noise_std > 0:
        g = torch.Generator().manual_seed(int(seed))
        images = images + noise_std * torch.randn(images.shape, generator=g, dtype=images.dtype)
    images = images.clamp(0, 1).float()
    w, h = camera.size
    hit = (out["ids"] >= 0) & torch.isfinite(out["depth"])
    depth = torch.where(hit, out["depth"], torch.zeros_like(out["depth"]))
    view = View(images[:1], depth, hit, out["points"].view(h, w, 3), out["normals"].view(h, w, 3))
    return Capture(images, view)


def render_range_scan(scene: Scene, camera: Camera, noise_std: float = 0.002, stride: int = 1,
                      max_range: float | None = None, seed: int = 0) -> RangeScan:
    """A range scanner's output at ``camera``: camera-frame points :math:`(N, 3)` of every ``stride``-th pixel
    hit (depth noise ``noise_std`` along the ray, seeded; beyond ``max_range`` dropped) with uint8 colours
    (the scene's shaded albedo), as a :class:`~stereonet.active.icp.RangeScan` carrying the true pose."""
    view = render_captures(scene, camera).view
    sl = (slice(None, None, stride), slice(None, None, stride))
    depth, hit = view.depth[sl], view.hit[sl]
    if max_range is not None:
        hit = hit & (depth <= max_range)
    g = torch.Generator().manual_seed(int(seed))
    noisy = depth + noise_std * torch.randn(depth.shape, generator=g, dtype=depth.dtype)
    K = torch.as_tensor(camera.K).clone()
    K[:2] /= stride  # pixel (u, v) of the strided grid is pixel (s u, s v) of the camera
    colors = (view.image[0].permute(1, 2, 0)[sl] * 255 + 0.5).to(torch.uint8)
    depth_map = torch.where(hit, noisy, torch.zeros_like(noisy))
    return RangeScan(depth_to_points(noisy, hit, K), colors[hit], torch.as_tensor(camera.R).clone(),
                     torch.as_tensor(camera.t).clone(), view.image[..., ::stride, ::stride], depth_map, K)
