"""Vectorized ray casting and shading of :class:`~data_gen.scene.Scene` objects from :class:`Camera` s.

* :func:`raycast_grid` — first hits of a camera's sample grid; each object is tested only on the block of
  samples inside its projected bounding box, all rays of the block at once.
* :func:`raycast` — first hits of arbitrary rays ``origins (N, 3) | (3,)``, ``dirs (N, 3)``.
* :func:`shade` — Lambertian + Blinn-Phong shading of hit points for one viewpoint, plus an optional extra
  light term (e.g. a projector pattern).
* :func:`render_view` — radiance image (adaptively supersampled) plus exact centre-ray geometry of one camera.
* :func:`render_sequence` — the same under a sequence of extra lights (a projector's patterns, a sweeping
  laser sheet), tracing the rays once.
* :func:`visible_from` — which world points a camera sees (not hidden by a nearer surface);
  :func:`visible_from_point` — which are lit by a point source (shadows of a laser or a projector).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np
import torch

from data_gen.camera import Camera, GridRays, PointRays
from data_gen.primitives import Plane
from data_gen.scene import Scene

SPECULAR_MASK_THRESHOLD = 0.02  # specular radiance above which a pixel counts as view-dependent
USE_KERNELS = True  # render_view / visible_from use the numba kernels of data_gen._kernels by default


class RayHits(NamedTuple):
    """First hits of N rays: ``t (N,)`` (inf = miss), ``ids (N,)`` long (-1 = miss), ``points (N, 3)``,
    ``normals (N, 3)`` (unit, facing the ray), ``uv (N, 2)`` (surface coordinates, scene units)."""

    t: torch.Tensor
    ids: torch.Tensor
    points: torch.Tensor
    normals: torch.Tensor
    uv: torch.Tensor


def _object_ranges(scene: Scene, grid: GridRays, camera: Camera) -> list[tuple[int, int, int, int] | None]:
    ranges = []
    for obj in scene.objects:
        bs = obj.bounding_sphere()
        if bs is None:
            ranges.append((0, grid.shape[0], 0, grid.shape[1]))
        else:
            ranges.append(grid.index_range(camera.pixel_bbox(bs[0], bs[1])))
    return ranges


def raycast_grid(scene: Scene, grid: GridRays) -> tuple[torch.Tensor, torch.Tensor, list]:
    """First hits of every ray of ``grid``.

    Returns:
        t :math:`(H', W')` ray parameter (= depth in the grid camera's frame; inf = miss), ids :math:`(H', W')`
        long object index (-1 = miss), and per object the sample block ``(r0, r1, c0, c1)`` it was tested on.
    """
    t_best = torch.full(grid.shape, math.inf, dtype=grid.dtype)
    ids = torch.full(grid.shape, -1, dtype=torch.long)
    ranges = _object_ranges(scene, grid, grid.camera)
    for k, (obj, rng) in enumerate(zip(scene.objects, ranges)):
        if rng is None:
            continue
        r0, r1, c0, c1 = rng
        t = obj.intersect(grid.block(r0, r1, c0, c1))
        tb = t_best[r0:r1, c0:c1]
        closer = t < tb
        tb.copy_(torch.where(closer, t, tb))
        ids[r0:r1, c0:c1].masked_fill_(closer, k)
    return t_best, ids, ranges


def _sorted_hit_surface(scene: Scene, ids: torch.Tensor, t: torch.Tensor, dirs_of, origin: np.ndarray,
                        spacing: float, with_albedo: bool) -> dict[str, torch.Tensor]:
    """Shared core of :func:`sorted_surface`: sort hits by object id, then one contiguous slice per object.

    ``dirs_of(order)`` returns the directions :math:`(N, 3)` of the hits in sorted order.
    """
    order = torch.argsort(ids)
    counts = torch.bincount(ids + 1, minlength=len(scene.objects) + 1).tolist()
    d = dirs_of(order)
    tt = t[order]
    miss = counts[0]
    tt[:miss] = 0.0
    p = torch.as_tensor(origin, dtype=d.dtype) + tt[:, None] * d
    normals = torch.zeros_like(p)
    uv = torch.zeros(p.shape[0], 2, dtype=p.dtype)
    albedo = torch.zeros_like(p) if with_albedo else None
    start = miss
    for k, obj in enumerate(scene.objects):
        stop = start + counts[k + 1]
        if stop > start:
            pk, dk = p[start:stop], d[start:stop]
            nk, uvk = obj.surface(pk, dk)
            normals[start:stop] = nk
            uv[start:stop] = uvk
            if albedo is not None:
                albedo[start:stop] = obj.material.albedo(uvk, _footprint(tt[start:stop], nk, dk, spacing))
        start = stop
    out = {"order": order, "ids": ids[order], "points": p, "normals": normals, "dirs": d, "uv": uv}
    if albedo is not None:
        out["albedo"] = albedo
    return out


def sorted_surface(scene: Scene, grid: GridRays, t: torch.Tensor, ids: torch.Tensor,
                   with_albedo: bool = True) -> dict[str, torch.Tensor]:
    """Surface data of the hits of :func:`raycast_grid`, with the samples sorted by object id.

    Sorting once makes every object's samples one contiguous slice (no per-object gathers or scatters).

    Returns a dict: ``order`` :math:`(N,)` (flat sample index of each sorted entry), ``ids`` :math:`(N,)`
    sorted, ``points``, ``normals``, ``dirs`` :math:`(N, 3)`, ``uv`` :math:`(N, 2)`, and ``albedo``
    :math:`(N, 3)` when ``with_albedo``. Misses (id -1) come first, with zeros.
    """
    w = grid.shape[1]

    def dirs_of(order):
        rows = torch.div(order, w, rounding_mode="floor")
        return grid.dirs_at(rows, order - rows * w)

    # angular spacing of neighbouring samples (radians, at the image centre) for texture footprints
    spacing = float(abs(grid.xs_np[1] - grid.xs_np[0]) if len(grid.xs_np) > 1 else 1.0) / float(grid.camera.K[0, 0])
    return _sorted_hit_surface(scene, ids.reshape(-1), t.reshape(-1), dirs_of, grid.origin, spacing, with_albedo)


def pixel_surface(scene: Scene, camera: Camera, x: torch.Tensor, y: torch.Tensor,
                  spacing: float) -> dict[str, torch.Tensor]:
    """:func:`sorted_surface` of the rays of ``camera`` through pixel coordinates ``x, y`` :math:`(N,)`;
    ``spacing``: radians between neighbouring rays (texture band limit)."""
    dirs = camera.ray_dirs(x, y)
    t, ids = _first_hits(scene, PointRays(camera.center, dirs), torch.stack([x, y], -1), camera)
    return _sorted_hit_surface(scene, ids, t, lambda order: dirs[order], camera.center, spacing, True)


LightsFn = Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor]


def shade_lights(scene: Scene, srt: dict[str, torch.Tensor], eye: np.ndarray, specular: bool,
                 lights_fn: LightsFn | None) -> tuple[list[torch.Tensor], torch.Tensor]:
    """:func:`shade` of sorted hits ``srt`` (from :func:`sorted_surface`) once per light of ``lights_fn``.

    ``lights_fn(points, normals, ids) -> (N, P)`` or :math:`(N, P, 3)` is evaluated once, on the sorted hits;
    None shades once without extra light. Returns the P radiances :math:`(N, 3)` and the specular radiance
    :math:`(N,)`, in the original (unsorted) order.
    """
    extra = None if lights_fn is None else lights_fn(srt["points"], srt["normals"], srt["ids"])
    base, spec = _unlit_terms(scene, srt["ids"], srt["points"], srt["normals"], eye, specular)  # once for all lights
    rgbs = [unsort(_radiance(base, None if extra is None else extra[:, k], srt["albedo"], spec if specular else None,
                             srt["ids"]),
                   srt["order"]) for k in range(1 if extra is None else extra.shape[1])]
    return rgbs, unsort(spec, srt["order"])


def unsort(values: torch.Tensor, order: torch.Tensor) -> torch.Tensor:
    """Inverse of ``values = x[order]``: returns x."""
    out = torch.empty_like(values)
    out[order] = values
    return out


def surface_fields(scene: Scene, grid: GridRays, t: torch.Tensor, ids: torch.Tensor,
                   with_albedo: bool = True) -> dict[str, torch.Tensor]:
    """Points, normals, uv (and albedo) of the hits found by :func:`raycast_grid`, flattened to :math:`(H' W', k)`.

    Misses get zeros (their ``ids`` are -1).
    """
    srt = sorted_surface(scene, grid, t, ids, with_albedo)
    keys = ("points", "normals", "uv") + (("albedo",) if with_albedo else ())
    return {k: unsort(srt[k], srt["order"]) for k in keys}


def _first_hits(scene: Scene, rays: PointRays, pixels: torch.Tensor | None = None,
                camera: Camera | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Nearest hit ``(t, ids)`` of explicit rays; with ``pixels`` :math:`(N, 2)` of the rays in ``camera``,
    each object is tested only on the rays inside its projected bounding box."""
    n = rays.dirs.shape[0]
    t_best = torch.full((n,), math.inf, dtype=rays.dirs.dtype)
    ids = torch.full((n,), -1, dtype=torch.long)
    for k, obj in enumerate(scene.objects):
        bs = obj.bounding_sphere()
        if pixels is not None and camera is not None and bs is not None:
            bbox = camera.pixel_bbox(bs[0], bs[1])
            if bbox is None:
                continue
            x0, x1, y0, y1 = bbox
            sel = ((pixels[:, 0] >= x0) & (pixels[:, 0] <= x1) & (pixels[:, 1] >= y0) & (pixels[:, 1] <= y1)).nonzero()[:, 0]
            if sel.numel() == 0:
                continue
            t = obj.intersect(rays.subset(sel))
            closer = t < t_best[sel]
            t_best[sel[closer]] = t[closer]
            ids[sel[closer]] = k
        else:
            t = obj.intersect(rays)
            closer = t < t_best
            t_best = torch.where(closer, t, t_best)
            ids.masked_fill_(closer, k)
    return t_best, ids


def raycast(scene: Scene, origins: torch.Tensor, dirs: torch.Tensor, pixels: torch.Tensor | None = None,
            camera: Camera | None = None) -> RayHits:
    """First hits of arbitrary rays.

    Args:
        origins: :math:`(N, 3)` or one shared origin :math:`(3,)`; dirs: :math:`(N, 3)` (any length; ``t`` is
            in units of ``|dirs|``).
        pixels, camera: optional pixel coordinates :math:`(N, 2)` of the rays in ``camera`` (rays through its
            centre); then each object is tested only on the rays inside its projected bounding box.
    """
    if dirs.dim() != 2 or dirs.shape[1] != 3:
        raise ValueError(f"dirs: expected shape (N, 3), got {tuple(dirs.shape)}")
    origins = torch.as_tensor(origins, dtype=dirs.dtype)
    if origins.shape not in ((3,), dirs.shape):
        raise ValueError(f"origins: expected shape (3,) or {tuple(dirs.shape)}, got {tuple(origins.shape)}")
    rays = PointRays(origins, dirs)
    t, ids = _first_hits(scene, rays, pixels, camera)
    n = dirs.shape[0]
    points = torch.zeros(n, 3, dtype=dirs.dtype)
    normals = torch.zeros(n, 3, dtype=dirs.dtype)
    uv = torch.zeros(n, 2, dtype=dirs.dtype)
    hit = ids >= 0
    o = origins.expand_as(dirs)
    points[hit] = o[hit] + t[hit][:, None] * dirs[hit]
    for k, obj in enumerate(scene.objects):
        sel = (ids == k).nonzero()[:, 0]
        if sel.numel():
            normals[sel], uv[sel] = obj.surface(points[sel], dirs[sel])
    return RayHits(t, ids, points, normals, uv)


def _footprint(t: torch.Tensor, normals: torch.Tensor, dirs: torch.Tensor, spacing: float) -> torch.Tensor:
    """Size on the surface (scene units) of one image sample, ``|t d| spacing / cos(incidence)``, cos >= 0.05.

    ``t``: ray parameters :math:`(N,)`; dirs :math:`(N, 3)` (any length); spacing: radians between samples.
    """
    dd = (dirs * dirs).sum(-1)
    nd = (normals * dirs).sum(-1).abs()
    return t * dd * spacing / torch.maximum(nd, 0.05 * dd.sqrt())


def albedo_of_hits(scene: Scene, hits: RayHits, dirs: torch.Tensor, spacing: float | None = None) -> torch.Tensor:
    """Albedo :math:`(N, 3)` of :class:`RayHits`; ``spacing`` (radians between neighbouring rays) band-limits
    the textures to the rays' footprint."""
    albedo = torch.zeros_like(hits.points)
    for k, obj in enumerate(scene.objects):
        sel = (hits.ids == k).nonzero()[:, 0]
        if sel.numel():
            fp = None
            if spacing is not None:
                d = dirs[sel]
                fp = _footprint(hits.t[sel], hits.normals[sel], d, spacing)
            albedo[sel] = obj.material.albedo(hits.uv[sel], fp)
    return albedo


def project_points(camera: Camera, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:meth:`Camera.project` of float64 world points :math:`(N, 3)` (numba): pixels :math:`(N, 2)`, depths :math:`(N,)`."""
    from data_gen._kernels import project

    n = points.shape[0]
    pix, z = np.empty((n, 2)), np.empty(n)
    dist = np.zeros(5) if camera.dist is None else np.asarray(camera.dist, dtype=np.float64)
    project(np.ascontiguousarray(points, dtype=np.float64), camera.R, camera.t, camera.K, dist, pix, z)
    return pix, z


def visible_np(scene: Scene, camera: Camera, points: np.ndarray, pix: np.ndarray, z: np.ndarray,
               packed: dict | None = None, rel_eps: float = 1e-4) -> np.ndarray:
    """:func:`visible_from` on float64 numpy points :math:`(N, 3)` with their projection ``pix`` :math:`(N, 2)`,
    ``z`` :math:`(N,)` into ``camera`` (compiled); ``packed``: ``pack_scene(scene, camera)`` if at hand."""
    from data_gen._kernels import hidden_points, pack_scene

    w, h = camera.size
    inside = (z > 0) & (pix[:, 0] >= -0.5) & (pix[:, 0] <= w - 0.5) & (pix[:, 1] >= -0.5) & (pix[:, 1] <= h - 0.5)
    packed = pack_scene(scene, camera) if packed is None else packed
    hidden = np.empty(points.shape[0], dtype=np.bool_)
    hidden_points(np.ascontiguousarray(points), np.ascontiguousarray(pix), np.asarray(camera.center, dtype=np.float64),
                  packed["objs"], packed["edges"], packed["blobs"], packed["boxes"], float(rel_eps), hidden)
    return inside & ~hidden


def visible_from(scene: Scene, camera: Camera, points: torch.Tensor, rel_eps: float = 1e-4,
                 projected: tuple[torch.Tensor, torch.Tensor] | None = None, compiled: bool | None = None
                 ) -> torch.Tensor:
    """Bool :math:`(N,)`: True where world ``points`` :math:`(N, 3)` are seen by ``camera``: in front of it,
    projecting inside its image, and not hidden by a nearer surface of ``scene``.

    Rays run from the camera centre to each point (t = 1 at the point); a hit with ``t < 1 - rel_eps``
    hides it. Infinite planes hide a point exactly when it lies on the other side from the camera.
    ``projected``: ``camera.project(points)`` if already computed; ``compiled``: numba kernel (default
    ``USE_KERNELS``) or torch reference.
    """
    if USE_KERNELS if compiled is None else compiled:
        if projected is None:
            pix_np, z_np = project_points(camera, points.double().numpy())
        else:
            pix_np, z_np = (np.ascontiguousarray(a.double().numpy()) for a in projected)
        return torch.from_numpy(visible_np(scene, camera, np.ascontiguousarray(points.double().numpy()), pix_np,
                                           z_np, rel_eps=rel_eps))
    pix, z = camera.project(points) if projected is None else projected
    w, h = camera.size
    inside = (z > 0) & (pix[:, 0] >= -0.5) & (pix[:, 0] <= w - 0.5) & (pix[:, 1] >= -0.5) & (pix[:, 1] <= h - 0.5)
    centre = camera.center
    hidden = torch.zeros(points.shape[0], dtype=torch.bool)
    ys_sorted, order = torch.sort(pix[:, 1].contiguous())  # objects are tested on the rows they cover
    xs_sorted = pix[order, 0]
    ys_np = ys_sorted.numpy()
    dirs_sorted = points[order] - torch.as_tensor(centre, dtype=points.dtype)
    hidden_sorted = torch.zeros_like(hidden)
    for obj in scene.objects:
        if isinstance(obj, Plane):
            hidden |= _plane_hides(obj, centre, points, rel_eps)
            continue
        bs = obj.bounding_sphere()
        bbox = camera.pixel_bbox(bs[0], bs[1]) if bs is not None else (-math.inf, math.inf, -math.inf, math.inf)
        if bbox is None:
            continue
        x0, x1, y0, y1 = bbox
        lo = int(np.searchsorted(ys_np, y0, side="left"))
        hi = int(np.searchsorted(ys_np, y1, side="right"))
        if hi <= lo:
            continue
        bx = xs_sorted[lo:hi]
        sel = ((bx >= x0) & (bx <= x1)).nonzero()[:, 0] + lo
        if sel.numel() == 0:
            continue
        t = obj.intersect(PointRays(centre, dirs_sorted[sel]))
        hidden_sorted[sel] |= t < 1 - rel_eps
    hidden[order] |= hidden_sorted
    return inside & ~hidden


def _plane_hides(plane: Plane, origin: np.ndarray, points: torch.Tensor, rel_eps: float) -> torch.Tensor:
    """Bool :math:`(N,)`: an infinite plane hides a point from ``origin`` when the point is on its other side."""
    side_cam = float(plane.n @ origin) - plane.k
    side_pts = points @ torch.as_tensor(plane.n, dtype=points.dtype) - plane.k
    return side_pts * math.copysign(1.0, side_cam) < -rel_eps * abs(side_cam)


def visible_from_point(scene: Scene, source, points: torch.Tensor, rel_eps: float = 1e-4,
                       compiled: bool | None = None) -> torch.Tensor:
    """Bool :math:`(N,)`: True where the straight segment from a point ``source`` :math:`(3,)` (a point light: a
    laser, a projector's centre) to each world point :math:`(N, 3)` crosses no surface of ``scene`` first.

    The hiding rule of :func:`visible_from` (a hit with ``t < 1 - rel_eps``; an infinite plane hides the
    points on its far side), with no image and no frustum: every object is tested on every segment.
    ``compiled``: numba kernel (default ``USE_KERNELS``) or torch reference.
    """
    src = np.asarray(source, dtype=np.float64).reshape(3)
    if USE_KERNELS if compiled is None else compiled:
        from data_gen._kernels import hidden_points, pack_scene

        packed = pack_scene(scene)  # no camera: unbounded pixel boxes, so the pixels below are never read
        pts = np.ascontiguousarray(points.double().numpy())
        hidden = np.empty(pts.shape[0], dtype=np.bool_)
        hidden_points(pts, np.zeros((pts.shape[0], 2)), src, packed["objs"], packed["edges"], packed["blobs"],
                      packed["boxes"], float(rel_eps), hidden)
        return torch.from_numpy(~hidden)
    hidden = torch.zeros(points.shape[0], dtype=torch.bool)
    rays = PointRays(src, points - torch.as_tensor(src, dtype=points.dtype))
    for obj in scene.objects:
        hidden |= _plane_hides(obj, src, points, rel_eps) if isinstance(obj, Plane) else obj.intersect(rays) < 1 - rel_eps
    return ~hidden


def specular_radiance(scene: Scene, ids: torch.Tensor, points: torch.Tensor, normals: torch.Tensor,
                      eye: np.ndarray) -> torch.Tensor:
    """Blinn-Phong ``ks max(0, n . h)^shininess`` :math:`(N,)` towards ``eye`` (zero on matte objects and
    where the light is behind the surface). Only the points of shiny objects are evaluated."""
    dtype = points.dtype
    spec = torch.zeros(points.shape[0], dtype=dtype)
    ks_table = np.array([o.material.specular for o in scene.objects] + [0.0])
    if not np.any(ks_table > 0):
        return spec
    ks = torch.as_tensor(ks_table, dtype=dtype)[ids]  # id -1 reads the trailing 0
    shiny = (ks > 0).nonzero()[:, 0]
    if shiny.numel() == 0:
        return spec
    shin = torch.as_tensor(np.array([o.material.shininess for o in scene.objects] + [1.0]), dtype=dtype)[ids[shiny]]
    light = torch.as_tensor(scene.light_dir, dtype=dtype)
    n = normals[shiny]
    view = torch.as_tensor(eye, dtype=dtype) - points[shiny]
    half = view / torch.linalg.norm(view, dim=-1, keepdim=True).clamp(min=1e-12) + light
    half = half / torch.linalg.norm(half, dim=-1, keepdim=True).clamp(min=1e-12)
    ndh = (n * half).sum(-1).clamp(min=0.0)
    spec[shiny] = ks[shiny] * ndh ** shin * ((n @ light) > 0)
    return spec


def shade(scene: Scene, ids: torch.Tensor, points: torch.Tensor, normals: torch.Tensor, albedo: torch.Tensor,
          eye: np.ndarray, specular: bool = True,
          extra_light_fn: Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor] | None = None
          ) -> tuple[torch.Tensor, torch.Tensor]:
    """Radiance towards the camera at ``eye`` :math:`(3,)` of N hit points.

    ``rgb = albedo * (ambient + (1 - ambient) max(0, n . l) + extra) + specular`` (``scene.light_strength`` in
    place of ``1 - ambient`` when set), with Blinn-Phong
    ``specular = ks max(0, n . h)^shininess`` (h = half vector of light and view directions: it depends on
    the viewpoint, so it differs between the two cameras).

    Args:
        ids :math:`(N,)` object ids (-1 = miss: black); points, normals, albedo :math:`(N, 3)`.
        extra_light_fn: ``fn(points (N, 3), normals (N, 3), ids (N,)) -> (N,) or (N, 3)`` extra irradiance
            added to the diffuse term (multiplied by the albedo), e.g. a projector's pattern.

    Returns:
        rgb :math:`(N, 3)` (not clipped), specular radiance :math:`(N,)`.
    """
    base, spec = _unlit_terms(scene, ids, points, normals, eye, specular)
    extra = None if extra_light_fn is None else extra_light_fn(points, normals, ids)
    return _radiance(base, extra, albedo, spec if specular else None, ids), spec


def _unlit_terms(scene: Scene, ids: torch.Tensor, points: torch.Tensor, normals: torch.Tensor, eye: np.ndarray,
                 specular: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """The parts of :func:`shade` that no extra light changes: the scene's irradiance :math:`(N, 1)` and the
    specular radiance :math:`(N,)` (zeros without ``specular``)."""
    dtype = points.dtype
    light = torch.as_tensor(scene.light_dir, dtype=dtype)
    strength = 1 - scene.ambient if scene.light_strength is None else scene.light_strength
    base = (normals @ (light * strength)).clamp_(min=0.0).add_(scene.ambient)[:, None]
    spec = specular_radiance(scene, ids, points, normals, eye) if specular else torch.zeros(points.shape[0], dtype=dtype)
    return base, spec


def _radiance(base: torch.Tensor, extra: torch.Tensor | None, albedo: torch.Tensor, spec: torch.Tensor | None,
              ids: torch.Tensor) -> torch.Tensor:
    """:func:`shade`'s ``rgb`` from its unlit terms and one extra irradiance (:math:`(N,)`, :math:`(N, 3)` or
    None); ``spec`` None: no specular term."""
    irradiance = base if extra is None else base + (extra if extra.dim() == 2 else extra[:, None])
    rgb = albedo * irradiance
    if spec is not None:
        rgb += spec[:, None]
    miss = ids < 0
    if bool(miss.any()):
        rgb[miss] = 0.0
    return rgb


EDGE_CREASE = 0.1  # 1 - cos of the normal turn between neighbours that marks a pixel for supersampling


def edge_pixels(ids: torch.Tensor, normals: torch.Tensor | None = None, crease: float = EDGE_CREASE) -> torch.Tensor:
    """Bool :math:`(H, W)`: pixels whose object id differs from one of their 8 neighbours, or (with
    ``normals`` :math:`(H, W, 3)`) whose normal turns by more than ``1 - cos = crease`` towards a 4-neighbour
    (cylinder rims, grazing sphere edges)."""
    pad = torch.nn.functional.pad(ids[None, None].double(), (1, 1, 1, 1), mode="replicate")[0, 0]
    h, w = ids.shape
    edge = torch.zeros_like(ids, dtype=torch.bool)
    centre = pad[1:h + 1, 1:w + 1]
    for dy in (0, 1, 2):
        for dx in (0, 1, 2):
            if dy != 1 or dx != 1:
                edge |= pad[dy:dy + h, dx:dx + w] != centre
    if normals is not None:
        bend_x = (normals[:, 1:] * normals[:, :-1]).sum(-1) < 1 - crease  # Hx(W-1)
        bend_y = (normals[1:] * normals[:-1]).sum(-1) < 1 - crease  # (H-1)xW
        edge[:, 1:] |= bend_x
        edge[:, :-1] |= bend_x
        edge[1:] |= bend_y
        edge[:-1] |= bend_y
    return edge


def _kernel_trace(scene: Scene, camera: Camera, packed: dict, dirs: np.ndarray, pix: np.ndarray | None,
                  spacing: float, specular: bool, second_eye: np.ndarray | None = None, grid_w: int = 0
                  ) -> dict[str, np.ndarray]:
    """Run :func:`data_gen._kernels.trace_shade` on rays ``dirs (N, 3)`` through pixels ``pix (N, 2)``, or
    (``grid_w > 0``, ``pix`` None) through a row-major pixel grid of that width."""
    from data_gen._kernels import trace_shade

    n = dirs.shape[0]
    out = dict(t=np.empty(n), ids=np.empty(n, dtype=np.int64), points=np.empty((n, 3)), normals=np.empty((n, 3)),
               rgb=np.empty((n, 3)), spec=np.empty(n), spec2=np.zeros(n))
    eye2 = np.zeros(0) if second_eye is None else np.asarray(second_eye, dtype=np.float64).reshape(3)
    trace_shade(np.ascontiguousarray(dirs, dtype=np.float64),
                np.zeros((0, 2)) if pix is None else np.ascontiguousarray(pix, dtype=np.float64),
                np.asarray(camera.center, dtype=np.float64), packed["objs"], packed["edges"], packed["blobs"],
                packed["mats"], packed["boxes"], packed["bank"], float(spacing),
                np.asarray(scene.light_dir, dtype=np.float64), float(scene.ambient), bool(specular), eye2,
                out["t"], out["ids"], out["points"], out["normals"], out["rgb"], out["spec"], out["spec2"], grid_w)
    return out


def _grid_dirs(camera: Camera) -> np.ndarray:
    """World directions :math:`(H W, 3)` float64 of the pixel-centre rays (camera-frame z = 1), row-major."""
    w, h = camera.size
    if camera.dist is not None:
        return camera.grid_rays(1, torch.float64).dirs().reshape(-1, 3).numpy()
    from data_gen._kernels import grid_dirs

    return grid_dirs(camera.R.T @ np.linalg.inv(camera.K), h, w)


def render_view_arrays(scene: Scene, camera: Camera, supersample: int = 2, specular: bool = True,
                       second_eye: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """The compiled :func:`render_view` as numpy arrays (no torch conversions): ``rgb`` :math:`(H, W, 3)`
    float32 in [0, 1]; float64 ``t`` (depth), ``points``, ``normals`` :math:`(H W, 3)`, ``spec``, ``spec2``;
    int64 ``ids`` :math:`(H W,)`; bool ``edges`` :math:`(H, W)`; ``packed`` (the scene packed for this camera).
    """
    from data_gen._kernels import edge_mask, edge_subsamples, finish_image, pack_scene, pixel_dirs

    s = int(supersample)
    w, h = camera.size
    packed = pack_scene(scene, camera)
    f = float(camera.K[0, 0])
    out = _kernel_trace(scene, camera, packed, _grid_dirs(camera), None, 1.0 / f, specular, second_eye, grid_w=w)
    rgb = out["rgb"]
    edges = np.zeros((h, w), dtype=np.bool_)
    if s > 1:
        edge_mask(out["ids"].reshape(h, w), out["normals"], EDGE_CREASE, edges)
    index, pix = edge_subsamples(edges, s) if s > 1 else (np.zeros(0, dtype=np.int64), np.zeros((0, 2)))
    sub_rgb = np.zeros((0, 3))
    if index.size:
        if camera.dist is None:
            dirs = pixel_dirs(camera.R.T @ np.linalg.inv(camera.K), pix)
        else:
            dirs = camera.ray_dirs(torch.from_numpy(pix[:, 0]), torch.from_numpy(pix[:, 1])).numpy()
        sub_rgb = _kernel_trace(scene, camera, packed, dirs, pix, 1.0 / (s * f), specular)["rgb"]
    out["rgb"] = np.empty((h, w, 3), dtype=np.float32)
    finish_image(rgb, index, sub_rgb, s * s, out["rgb"])
    out.update(edges=edges, packed=packed)
    return out


def _render_view_kernels(scene: Scene, camera: Camera, s: int, specular: bool, dtype: torch.dtype,
                         second_eye: np.ndarray | None = None) -> dict:
    """:func:`render_view` with the compiled kernels (same algorithm, float64 inside)."""
    a = render_view_arrays(scene, camera, s, specular, second_eye)
    w, h = camera.size
    img = torch.from_numpy(a["rgb"].transpose(2, 0, 1)).to(dtype)  # 3xHxW
    return {"image": img.contiguous(), "depth": torch.from_numpy(a["t"]).to(dtype).reshape(h, w),
            "ids": torch.from_numpy(a["ids"].reshape(h, w)), "points": torch.from_numpy(a["points"]).to(dtype),
            "normals": torch.from_numpy(a["normals"]).to(dtype),
            "specular": torch.from_numpy(a["spec"]).to(dtype).reshape(h, w), "edges": torch.from_numpy(a["edges"]),
            **({} if second_eye is None else {"specular_second": torch.from_numpy(a["spec2"]).to(dtype).reshape(h, w)})}


def render_view(scene: Scene, camera: Camera, supersample: int = 2, specular: bool = True,
                extra_light_fn: Callable | None = None, dtype: torch.dtype = torch.float32,
                compiled: bool | None = None, second_eye: np.ndarray | None = None) -> dict[str, torch.Tensor]:
    """Render one camera.

    One ray through each pixel centre gives the geometry (exact at pixel centres) and the shading of
    pixels inside a surface (textures are band-limited to the pixel footprint, mip-map style). Pixels on
    an object boundary (an 8-neighbour sees another object) are re-rendered with ``supersample x
    supersample`` rays and averaged (adaptive anti-aliasing).

    ``compiled``: use the numba kernels of :mod:`data_gen._kernels` (default: ``USE_KERNELS``, and only
    without ``extra_light_fn`` and with the default ``scene.light_strength``) or the torch reference (False).

    Returns a dict with ``image`` :math:`(3, H, W)` radiance clipped to [0, 1], ``depth`` :math:`(H, W)`
    (z in this camera's frame, inf = miss), ``ids`` :math:`(H, W)` long, ``points`` and ``normals``
    :math:`(H W, 3)` (world frame, centre rays), ``specular`` :math:`(H, W)` specular radiance at the centre
    rays, ``edges`` :math:`(H, W)` bool (the supersampled pixels: object boundaries and normal creases), and
    with ``second_eye`` :math:`(3,)` ``specular_second`` :math:`(H, W)`: the specular radiance of the same
    surface points towards that viewpoint (the other camera), for the view-dependence mask.
    (:func:`render_view_arrays` returns the compiled path's numpy arrays without torch conversions.)
    """
    s = _check_supersample(supersample)
    if compiled is None:
        compiled = USE_KERNELS
    if compiled and extra_light_fn is None and scene.light_strength is None:
        return _render_view_kernels(scene, camera, s, specular, dtype, second_eye)
    lights = None if extra_light_fn is None else (lambda p, n, i: extra_light_fn(p, n, i)[:, None])
    out = _render_torch(scene, camera, s, specular, lights, dtype, second_eye)
    return {"image": out.pop("images")[0], **out}


def render_sequence(scene: Scene, camera: Camera, lights_fn: LightsFn | None, supersample: int = 2,
                    specular: bool = True, dtype: torch.dtype = torch.float32) -> dict[str, torch.Tensor]:
    """:func:`render_view` of one camera under a sequence of P extra lights (the patterns of a projector, the
    positions of a sweeping laser sheet): rays, hits, surfaces and the supersampled edge pixels are found once,
    and only the shading runs per light.

    ``lights_fn(points (N, 3), normals (N, 3), ids (N,)) -> (N, P)`` (grey) or :math:`(N, P, 3)` gives every
    light's irradiance at once; light ``k`` is added to the diffuse term like ``render_view``'s
    ``extra_light_fn`` (so ``render_sequence(..., lambda p, n, i: f(p, n, i)[:, None])["images"][0]`` is
    ``render_view(..., extra_light_fn=f, compiled=False)["image"]``); None renders one image without extra
    light. Torch path; returns render_view's dict with ``images`` :math:`(P, 3, H, W)` in place of ``image``.
    """
    return _render_torch(scene, camera, _check_supersample(supersample), specular, lights_fn, dtype, None)


def _check_supersample(supersample: int) -> int:
    s = int(supersample)
    if s < 1:
        raise ValueError(f"supersample: expected an integer >= 1, got {supersample}")
    return s


def _render_torch(scene: Scene, camera: Camera, s: int, specular: bool, lights_fn: LightsFn | None,
                  dtype: torch.dtype, second_eye: np.ndarray | None) -> dict[str, torch.Tensor]:
    """The torch reference of :func:`render_view` under each light of ``lights_fn`` (see :func:`shade_lights`):
    ``images`` :math:`(P, 3, H, W)` and the geometry of the centre rays."""
    w, h = camera.size
    grid = camera.grid_rays(1, dtype)
    t, ids, _ = raycast_grid(scene, grid)
    srt = sorted_surface(scene, grid, t, ids)
    rgbs, spec = shade_lights(scene, srt, camera.center, specular, lights_fn)
    points, normals = unsort(srt["points"], srt["order"]), unsort(srt["normals"], srt["order"])
    edges = edge_pixels(ids, normals.reshape(h, w, 3)) if s > 1 else torch.zeros_like(ids, dtype=torch.bool)
    ey, ex = torch.nonzero(edges, as_tuple=True)
    if ey.numel():
        offsets = (torch.arange(s, dtype=dtype) + 0.5) / s - 0.5
        oy, ox = torch.meshgrid(offsets, offsets, indexing="ij")
        sx = (ex.to(dtype)[:, None] + ox.reshape(1, -1)).reshape(-1)  # (M*s*s,)
        sy = (ey.to(dtype)[:, None] + oy.reshape(1, -1)).reshape(-1)
        sub = pixel_surface(scene, camera, sx, sy, 1.0 / (s * float(camera.K[0, 0])))
        for rgb, sub_rgb in zip(rgbs, shade_lights(scene, sub, camera.center, specular, lights_fn)[0]):
            rgb[ey * w + ex] = sub_rgb.reshape(-1, s * s, 3).mean(1)
    images = torch.empty(len(rgbs), 3, h, w, dtype=dtype)
    for k, rgb in enumerate(rgbs):
        images[k] = rgb.reshape(h, w, 3).permute(2, 0, 1).clamp(0.0, 1.0)  # 3xHxW
    out = {"images": images, "depth": t, "ids": ids, "points": points, "normals": normals,
           "specular": spec.reshape(h, w), "edges": edges}
    if second_eye is not None:
        out["specular_second"] = (specular_radiance(scene, ids.reshape(-1), points, normals, second_eye).reshape(h, w)
                                  if specular else torch.zeros(h, w, dtype=dtype))
    return out
