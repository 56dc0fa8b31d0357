"""Render what a camera sees of a :class:`~stereonet.active.scene.Scene` lit by ambient light, a soft
directional light and any number of *emitters* (a pattern projector, a laser sheet).

An emitter is any callable ``emitter(scene, points, normals) -> irradiance`` giving the light it adds at world
surface points :math:`(N, 3)` with normals :math:`(N, 3)` as :math:`(N,)` (grey) or :math:`(N, 3)` (coloured);
it is responsible for its own shadow test (:func:`~stereonet.active.scene.visible_from`).
The camera records ``albedo * (ambient + directional + sum of emitters)``, plus Gaussian noise, clipped to
[0, 1] — so bright emitters on bright surfaces saturate, as real sensors do.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch

from stereonet.active.scene import Hits, PinholeCamera, Scene, raycast

Emitter = Callable[[Scene, torch.Tensor, torch.Tensor], torch.Tensor]


@dataclass
class View:
    """A rendered view. ``image`` :math:`(1, 3, H, W)` float32 in [0, 1]; ``depth`` :math:`(H, W)` float64 camera z
    (0 where nothing is hit); ``hit`` :math:`(H, W)` bool; ``points``/``normals``/``albedo`` :math:`(H, W, 3)` of
    the pixel-centre rays in world coordinates."""

    image: torch.Tensor
    depth: torch.Tensor
    hit: torch.Tensor
    points: torch.Tensor
    normals: torch.Tensor
    albedo: torch.Tensor


def shade(scene: Scene, hits: Hits, ambient: float, light_dir: Sequence[float] | None, light: float,
          emitters: Sequence[Emitter]) -> torch.Tensor:
    """Radiance :math:`(*, 3)` of hits (float64, unclipped) under the lighting model of this module."""
    lead = hits.t.shape
    pts, nrm = hits.points.reshape(-1, 3), hits.normals.reshape(-1, 3)
    irr = torch.full((pts.shape[0], 3), float(ambient), dtype=torch.float64)
    if light_dir is not None and light > 0:
        ldir = torch.as_tensor(light_dir, dtype=torch.float64)
        ldir = ldir / ldir.norm()
        irr = irr + light * (nrm @ -ldir).clamp_min(0)[:, None]
    for emit in emitters:
        e = emit(scene, pts, nrm)
        irr = irr + (e[:, None] if e.dim() == 1 else e)
    rad = hits.albedo.reshape(-1, 3) * irr
    rad = torch.where(hits.hit.reshape(-1, 1), rad, torch.zeros_like(rad))
    return rad.reshape(*lead, 3)


def render_view(scene: Scene, camera: PinholeCamera, emitters: Sequence[Emitter] = (), ambient: float = 0.35,
                light_dir: Sequence[float] | None = (0.3, 0.6, 1.0), light: float = 0.45, noise_std: float = 0.0,
                seed: int = 0, samples: int = 1) -> View:
    """Render ``camera``'s view of ``scene``.

    Args:
        emitters: extra light sources (see module doc), e.g. a pattern projector or a laser sheet.
        ambient, light_dir, light: ambient level and a directional light (direction of travel, world frame).
        noise_std: standard deviation of additive Gaussian sensor noise (seeded by ``seed``).
        samples: ``samples x samples`` stratified rays per pixel, averaged (anti-aliasing); geometry outputs
            (``depth``, ``points``...) always come from the pixel-centre ray.
    """
    uv = camera.pixel_grid(samples)  # HxWxSx2
    o, d = camera.rays(uv)
    hits = raycast(scene, o, d)
    rad = shade(scene, hits, ambient, light_dir, light, emitters).mean(dim=2)  # HxWx3
    img = rad.permute(2, 0, 1)[None]  # 1x3xHxW
    if noise_std > 0:
        g = torch.Generator().manual_seed(int(seed))
        img = img + noise_std * torch.randn(img.shape, generator=g, dtype=img.dtype)
    img = img.clamp(0, 1).to(torch.float32)
    centre = hits if samples == 1 else raycast(scene, *camera.rays(camera.pixel_grid(1)))  # HxWx1
    c = lambda x: x[:, :, 0]
    depth = torch.where(c(centre.hit), c(centre.t), torch.zeros_like(c(centre.t)))  # ray dir has z = 1
    return View(img, depth, c(centre.hit), c(centre.points), c(centre.normals), c(centre.albedo))


def render_range_scan(scene: Scene, camera: PinholeCamera, noise_std: float = 0.002, stride: int = 1,
                      max_range: float | None = None, seed: int = 0):
    """A range scanner's output at ``camera``: camera-frame points :math:`(N, 3)` of every ``stride``-th pixel
    hit (depth noise ``noise_std`` along the ray, seeded; beyond ``max_range`` dropped) with uint8 colours
    (shaded albedo), as a :class:`~stereonet.active.icp.RangeScan` carrying the true pose."""
    from stereonet.active.icp import RangeScan

    view = render_view(scene, camera)
    sl = (slice(None, None, stride), slice(None, None, stride))
    depth, hit = view.depth[sl], view.hit[sl]
    if max_range is not None:
        hit = hit & (depth <= max_range)
    g = torch.Generator().manual_seed(int(seed))
    noisy = depth * (1 + noise_std * torch.randn(depth.shape, generator=g, dtype=depth.dtype) / depth.clamp_min(1e-9))
    v, u = torch.meshgrid(torch.arange(0, camera.height, stride, dtype=torch.float64),
                          torch.arange(0, camera.width, stride, dtype=torch.float64), indexing="ij")
    uv1 = torch.stack([u, v, torch.ones_like(u)], dim=-1)
    pts = (uv1 @ torch.linalg.inv(camera.K).T) * noisy[..., None]  # HxWx3, z = noisy depth
    colors = (view.image[0].permute(1, 2, 0)[sl] * 255 + 0.5).to(torch.uint8)
    depth_map = torch.where(hit, noisy, torch.zeros_like(noisy))
    K = camera.K.clone()
    K[:2] /= stride  # pixel (u, v) of the strided grid is pixel (s u, s v) of the camera
    return RangeScan(pts[hit], colors[hit], camera.R.clone(), camera.t.clone(), view.image[..., ::stride, ::stride],
                     depth_map, K)
