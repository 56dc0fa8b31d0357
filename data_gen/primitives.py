"""Ray-traceable primitives: infinite planes (background walls), planar patches (polygons, ellipses, blobs),
spheres and finite cylinders with caps; :func:`box_faces` builds a box from six rectangular patches.

Every primitive implements

* ``bounding_sphere() -> (centre (3,), radius) | None`` (None = unbounded: tested against every ray),
* ``intersect(rays) -> t``: the nearest positive ray parameter of a hit, ``inf`` on a miss, over any ray set of
  :mod:`data_gen.camera` (``GridBlock`` or ``PointRays``), using only the ray set's scalar products,
* ``surface(points (N, 3), dirs (N, 3)) -> (normals (N, 3), uv (N, 2))``: unit normals turned towards the
  incoming ray and texture coordinates in the surface's own frame (scene units).

Geometry parameters are float64 numpy; ray quantities stay in the ray set's dtype (float32 for images).
"""

from __future__ import annotations

import abc
import math

import numpy as np
import torch

from data_gen.textures import Material

T_EPS = 1e-6  # smallest accepted ray parameter (rays start at camera centres; scene depths are >> 1)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product of two 3-vectors (np.cross is ~20x slower on single vectors)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def orthonormal_frame(normal: np.ndarray, roll: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit ``e1, e2, n`` with ``e1 x e2 = n``; ``roll`` rotates (e1, e2) about n."""
    n = np.asarray(normal, dtype=np.float64)
    n = n / math.sqrt(float(n @ n))
    helper = np.array([0.0, 1.0, 0.0]) if abs(n[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = _cross(helper, n)
    e1 /= math.sqrt(float(e1 @ e1))
    e2 = _cross(n, e1)
    c, s = math.cos(roll), math.sin(roll)
    return c * e1 + s * e2, -s * e1 + c * e2, n


def _face_ray(normals: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
    flip = (normals * dirs).sum(-1, keepdim=True) > 0
    return torch.where(flip, -normals, normals)


def _planar_surface(origin: np.ndarray, e1: np.ndarray, e2: np.ndarray, n: np.ndarray, points: torch.Tensor,
                    dirs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Normals (turned towards the rays) and in-plane (u, v) of points on the plane through ``origin``."""
    axes = torch.as_tensor(np.stack([e1, e2], axis=1), dtype=points.dtype)  # 3x2
    uv = points @ axes - torch.as_tensor(origin @ np.stack([e1, e2], axis=1), dtype=points.dtype)
    n_t = torch.as_tensor(n, dtype=points.dtype)
    side = torch.where(dirs @ n_t > 0, -1.0, 1.0).to(points.dtype)
    return side[:, None] * n_t, uv


def _vec(a, like: torch.Tensor) -> torch.Tensor:
    return torch.as_tensor(np.asarray(a, dtype=np.float64), dtype=like.dtype)


def _miss_to_inf(t: torch.Tensor, hit: torch.Tensor) -> torch.Tensor:
    return torch.where(hit & (t > T_EPS), t, torch.full_like(t, math.inf))


class Primitive(abc.ABC):
    """Base class: a surface with a :class:`Material`."""

    kind = "primitive"

    def __init__(self, material: Material | None = None):
        self.material = material if material is not None else Material()

    def bounding_sphere(self) -> tuple[np.ndarray, float] | None:
        return None

    @abc.abstractmethod
    def intersect(self, rays) -> torch.Tensor:
        """Ray parameter of the first hit per ray (``inf`` on a miss)."""

    @abc.abstractmethod
    def surface(self, points: torch.Tensor, dirs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(normals, uv) at hit ``points`` seen along ``dirs``."""


class Plane(Primitive):
    """Infinite plane ``n . X = k`` through ``origin`` with in-plane axes ``e1, e2`` for texture coordinates."""

    kind = "plane"

    def __init__(self, origin, normal, roll: float = 0.0, material: Material | None = None):
        super().__init__(material)
        self.e1, self.e2, self.n = orthonormal_frame(normal, roll)
        self.origin = np.asarray(origin, dtype=np.float64)
        self.k = float(self.n @ self.origin)

    def intersect(self, rays) -> torch.Tensor:
        denom = rays.dot_d(self.n)
        t = (self.k - rays.dot_o(self.n)) / denom
        return _miss_to_inf(t, torch.isfinite(t))

    def surface(self, points, dirs):
        return _planar_surface(self.origin, self.e1, self.e2, self.n, points, dirs)


class PlanarPatch(Primitive):
    """A bounded planar patch: a star-shaped region of its plane, in normalized coordinates scaled by ``scale``.

    Args:
        centre: :math:`(3,)`; normal: :math:`(3,)`; roll: in-plane rotation of the shape (radians).
        scale: ``(su, sv)`` half-sizes along e1, e2 (scene units).
        shape: ``"ellipse"`` (unit disc), ``"polygon"`` (convex polygon inscribed in the unit circle,
            vertex angles ``angles``), or ``"blob"`` (radius table ``radii`` over [0, 2 pi), linearly
            interpolated, values <= 1).
    """

    kind = "patch"

    def __init__(self, centre, normal, scale: tuple[float, float], shape: str = "ellipse", roll: float = 0.0,
                 angles: np.ndarray | None = None, radii: np.ndarray | None = None,
                 material: Material | None = None):
        super().__init__(material)
        if shape not in ("ellipse", "polygon", "blob"):
            raise ValueError(f"shape: expected 'ellipse', 'polygon' or 'blob', got {shape!r}")
        self.centre = np.asarray(centre, dtype=np.float64)
        self.e1, self.e2, self.n = orthonormal_frame(normal, roll)
        self.scale = (float(scale[0]), float(scale[1]))
        self.shape = shape
        if shape == "polygon":
            a = np.sort(np.asarray(angles, dtype=np.float64) % (2 * math.pi))
            nxt = np.concatenate([a[1:], a[:1] + 2 * math.pi])
            if np.max(nxt - a) >= math.pi:
                raise ValueError("angles: consecutive polygon vertices must be less than pi apart")
            mid = 0.5 * (a + nxt)
            self.edge_normals = np.stack([np.cos(mid), np.sin(mid)], axis=-1)
            self.edge_dist = np.cos(0.5 * (nxt - a))
        elif shape == "blob":
            self.radii = torch.as_tensor(np.asarray(radii, dtype=np.float64))

    def bounding_sphere(self):
        return self.centre, max(self.scale)

    def _inside(self, u: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        un = u / self.scale[0]
        vn = v / self.scale[1]
        if self.shape == "ellipse":
            return un * un + vn * vn <= 1.0
        if self.shape == "polygon":
            inside = torch.ones_like(un, dtype=torch.bool)
            for (cx, cy), d in zip(self.edge_normals, self.edge_dist):
                inside &= un * float(cx) + vn * float(cy) <= float(d)
            return inside
        table = self.radii.to(u.dtype)
        n = table.numel()
        pos = (torch.atan2(vn, un) * (n / (2 * math.pi))) % n
        i0 = pos.long().clamp_(max=n - 1)
        frac = pos - i0
        r = table[i0] * (1 - frac) + table[(i0 + 1) % n] * frac
        return un * un + vn * vn <= r * r

    def intersect(self, rays) -> torch.Tensor:
        t = (float(self.n @ self.centre) - rays.dot_o(self.n)) / rays.dot_d(self.n)
        u = (rays.dot_o(self.e1) - float(self.e1 @ self.centre)) + t * rays.dot_d(self.e1)
        v = (rays.dot_o(self.e2) - float(self.e2 @ self.centre)) + t * rays.dot_d(self.e2)
        return _miss_to_inf(t, self._inside(u, v))

    def surface(self, points, dirs):
        return _planar_surface(self.centre, self.e1, self.e2, self.n, points, dirs)


class Sphere(Primitive):
    """Sphere of ``radius`` around ``centre``; texture (u, v) = radius x (longitude, colatitude) about ``axis``."""

    kind = "sphere"

    def __init__(self, centre, radius: float, axis=(0.0, -1.0, 0.0), roll: float = 0.0,
                 material: Material | None = None):
        super().__init__(material)
        self.centre = np.asarray(centre, dtype=np.float64)
        self.radius = float(radius)
        self.e1, self.e2, self.axis = orthonormal_frame(axis, roll)

    def bounding_sphere(self):
        return self.centre, self.radius

    def intersect(self, rays) -> torch.Tensor:
        c = self.centre
        b = rays.do() - rays.dot_d(c)  # d . (o - c)
        cc = rays.oo - 2 * rays.dot_o(c) + float(c @ c) - self.radius ** 2
        dd = rays.dd()
        disc = b * b - dd * cc
        sq = torch.sqrt(torch.clamp(disc, min=0.0))
        t = (-b - sq) / dd
        t = torch.where(t > T_EPS, t, (-b + sq) / dd)  # origin inside: the far root
        return _miss_to_inf(t, disc >= 0)

    def surface(self, points, dirs):
        nrm = (points - _vec(self.centre, points)) / self.radius
        x = nrm @ _vec(self.e1, points)
        y = nrm @ _vec(self.e2, points)
        z = (nrm @ _vec(self.axis, points)).clamp(-1.0, 1.0)
        uv = torch.stack([self.radius * torch.atan2(y, x), self.radius * torch.acos(z)], dim=-1)
        return _face_ray(nrm, dirs), uv


class Cylinder(Primitive):
    """Solid finite cylinder: ``radius``, axis through ``centre``, ``half_length`` each side, flat caps.

    Texture (u, v): on the side radius x angle and height; on the caps the in-cap coordinates.
    """

    kind = "cylinder"

    def __init__(self, centre, axis, radius: float, half_length: float, roll: float = 0.0,
                 material: Material | None = None):
        super().__init__(material)
        self.centre = np.asarray(centre, dtype=np.float64)
        self.e1, self.e2, self.axis = orthonormal_frame(axis, roll)
        self.radius = float(radius)
        self.half_length = float(half_length)

    def bounding_sphere(self):
        return self.centre, math.hypot(self.radius, self.half_length)

    def intersect(self, rays) -> torch.Tensor:
        a, c, r, L = self.axis, self.centre, self.radius, self.half_length
        da = rays.dot_d(a)
        ma = rays.dot_o(a) - float(a @ c)  # (o - c) . a
        dm = rays.do() - rays.dot_d(c)  # d . (o - c)
        mm = rays.oo - 2 * rays.dot_o(c) + float(c @ c)  # |o - c|^2
        dd = rays.dd()
        qa = dd - da * da
        qb = dm - da * ma
        qc = mm - ma * ma - r * r
        disc = qb * qb - qa * qc
        sq = torch.sqrt(torch.clamp(disc, min=0.0))
        inf = torch.full_like(qa, math.inf)
        best = inf
        for sign in (-1.0, 1.0):  # side wall, both roots
            t = (-qb + sign * sq) / qa
            h = ma + t * da
            ok = (disc >= 0) & (t > T_EPS) & (torch.abs(h) <= L)
            best = torch.minimum(best, torch.where(ok, t, inf))
        for cap in (-L, L):  # flat caps
            t = (cap - ma) / da
            rho2 = mm + 2 * t * dm + t * t * dd - cap * cap  # |(o + t d - c)_perp|^2
            ok = (t > T_EPS) & (rho2 <= r * r)
            best = torch.minimum(best, torch.where(ok, t, inf))
        return torch.nan_to_num(best, nan=math.inf, posinf=math.inf)

    def surface(self, points, dirs):
        rel = points - _vec(self.centre, points)
        axis = _vec(self.axis, points)
        h = rel @ axis
        q = rel - h[:, None] * axis
        rho = torch.linalg.norm(q, dim=-1)
        x = q @ _vec(self.e1, points)
        y = q @ _vec(self.e2, points)
        on_side = torch.abs(rho - self.radius) < torch.abs(torch.abs(h) - self.half_length)
        side_n = q / rho.clamp(min=1e-12)[:, None]
        cap_n = torch.sign(h)[:, None] * axis
        normals = torch.where(on_side[:, None], side_n, cap_n)
        uv_side = torch.stack([self.radius * torch.atan2(y, x), h], dim=-1)
        uv_cap = torch.stack([x, y], dim=-1)
        uv = torch.where(on_side[:, None], uv_side, uv_cap)
        return _face_ray(normals, dirs), uv


def box_faces(lo, hi, material: Material | None = None) -> list[PlanarPatch]:
    """The six rectangular faces of the axis-aligned box between corners ``lo`` and ``hi`` :math:`(3,)`, as
    :class:`PlanarPatch` polygons (outward normals) sharing ``material``; texture (u, v) in each face's frame."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    if not np.all(hi > lo):
        raise ValueError(f"hi: expected every coordinate above lo={lo.tolist()}, got {hi.tolist()}")
    centre, half = (lo + hi) / 2, (hi - lo) / 2
    corners = np.array([math.pi / 4, 3 * math.pi / 4, 5 * math.pi / 4, 7 * math.pi / 4])  # square in the unit circle
    faces = []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            normal = np.zeros(3)
            normal[axis] = sign
            e1, e2, _ = orthonormal_frame(normal)  # axis-aligned for an axis-aligned normal
            scale = (math.sqrt(2) * float(np.abs(e1) @ half), math.sqrt(2) * float(np.abs(e2) @ half))
            faces.append(PlanarPatch(centre + half[axis] * normal, normal, scale, "polygon",
                                     angles=corners, material=material))
    return faces
