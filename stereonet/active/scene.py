"""A small vectorized ray-caster for the active-stereo experiments: pinhole cameras, planes, spheres, boxes.

Active sensing needs three things of a renderer that a passive stereo renderer does not: rays cast from an
arbitrary point (a projector or a laser, for shadows), the surface normal (for the Lambertian term) and the
albedo at the hit (so that a pattern can be multiplied in). This module gives exactly that, in float64 torch:

* :class:`PinholeCamera` — intrinsics ``K`` and a world-to-camera pose ``X_c = R X_w + t``; a projector is the
  same object used the other way round (it emits along its pixel rays).
* :class:`Scene` — infinite planes, spheres and axis-aligned boxes, each with a procedural albedo
  (constant, stripes, checker or value noise); :func:`raycast` returns the nearest hit of every ray.

Conventions: pixel centres sit at integer coordinates ``(u, v)`` = (column, row); the camera looks down +z,
x right, y down. All geometry is float64; rendered images are float32 in [0, 1].
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch

from stereonet.checks import StereoInputError, check_shape

_F64 = torch.float64
_EPS_T = 1e-6  # rays start this far from their origin (self-intersection guard), in scene units
_NO_HIT = math.inf


def _vec(x, name: str, n: int = 3) -> torch.Tensor:
    v = torch.as_tensor(x, dtype=_F64).reshape(-1)
    if v.numel() != n:
        raise StereoInputError(f"{name}: expected {n} values, got shape {tuple(v.shape)}")
    if not bool(torch.isfinite(v).all()):
        raise StereoInputError(f"{name}: expected finite values, got NaN or inf")
    return v


def look_at(eye, target, up=(0.0, -1.0, 0.0)) -> tuple[torch.Tensor, torch.Tensor]:
    """World-to-camera ``(R, t)`` of a camera at ``eye`` looking at ``target`` (y of the image points down).

    ``up`` is the world direction that should appear at the top of the image (default -y: the world is
    y-down like the camera, so the identity pose looks down +z).
    Returns ``R`` :math:`(3, 3)` and ``t`` :math:`(3,)` with ``X_c = R X_w + t``.
    """
    eye, target, up = _vec(eye, "eye"), _vec(target, "target"), _vec(up, "up")
    z = target - eye
    if float(z.norm()) < 1e-12:
        raise StereoInputError("target: expected a point different from eye")
    z = z / z.norm()
    x = torch.linalg.cross(z, -up)  # camera x (right) = forward x down
    if float(x.norm()) < 1e-9:
        raise StereoInputError("up: expected a direction not parallel to the viewing direction")
    x = x / x.norm()
    y = torch.linalg.cross(z, x)
    R = torch.stack([x, y, z])  # rows are the camera axes in world coordinates
    return R, -R @ eye


@dataclass
class PinholeCamera:
    """A pinhole camera (or projector): ``K`` :math:`(3, 3)`, pose ``X_c = R X_w + t``, image ``width x height``."""

    K: torch.Tensor
    R: torch.Tensor
    t: torch.Tensor
    width: int
    height: int

    def __post_init__(self) -> None:
        self.K = torch.as_tensor(self.K, dtype=_F64)
        self.R = torch.as_tensor(self.R, dtype=_F64)
        self.t = torch.as_tensor(self.t, dtype=_F64).reshape(-1)
        check_shape(self.K, ["3", "3"], "K")
        check_shape(self.R, ["3", "3"], "R")
        check_shape(self.t, ["3"], "t")
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise StereoInputError(f"width/height: expected positive sizes, got {self.width}x{self.height}")
        self.width, self.height = int(self.width), int(self.height)

    @staticmethod
    def create(focal: float, width: int, height: int, eye=(0.0, 0.0, 0.0), target=None,
               up=(0.0, -1.0, 0.0), cx: float | None = None, cy: float | None = None) -> PinholeCamera:
        """A camera with square pixels, principal point at the image centre unless given, at ``eye``.

        Without ``target`` it keeps the world axes (looks down +z).
        """
        cx = (width - 1) / 2.0 if cx is None else cx
        cy = (height - 1) / 2.0 if cy is None else cy
        K = torch.tensor([[focal, 0.0, cx], [0.0, focal, cy], [0.0, 0.0, 1.0]], dtype=_F64)
        eye = _vec(eye, "eye")
        if target is None:
            R, t = torch.eye(3, dtype=_F64), -eye
        else:
            R, t = look_at(eye, target, up)
        return PinholeCamera(K, R, t, width, height)

    @property
    def center(self) -> torch.Tensor:
        """Optical centre in world coordinates :math:`(3,)`."""
        return -self.R.T @ self.t

    def pixel_grid(self, samples: int = 1) -> torch.Tensor:
        """Pixel coordinates ``(u, v)`` :math:`(H, W, S, 2)` of ``S = samples**2`` stratified sub-samples per pixel."""
        offs = (torch.arange(samples, dtype=_F64) + 0.5) / samples - 0.5
        v, u = torch.meshgrid(torch.arange(self.height, dtype=_F64), torch.arange(self.width, dtype=_F64),
                              indexing="ij")
        ov, ou = torch.meshgrid(offs, offs, indexing="ij")
        uv = torch.stack([u[..., None] + ou.reshape(-1), v[..., None] + ov.reshape(-1)], dim=-1)
        return uv  # HxWxSx2

    def rays(self, uv: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """World rays through pixel coordinates ``uv`` :math:`(*, 2)`.

        Returns origins :math:`(*, 3)` and directions :math:`(*, 3)` scaled so that a distance ``s`` along the
        ray is the camera depth ``z`` (direction = R^T K^-1 (u, v, 1), its camera z-component is 1).
        """
        uv1 = torch.cat([uv.to(_F64), torch.ones_like(uv[..., :1], dtype=_F64)], dim=-1)
        d_cam = uv1 @ torch.linalg.inv(self.K).T
        d_world = d_cam @ self.R  # (R^T d)^T = d^T R
        return self.center.expand_as(d_world), d_world  # expanded view: no copy

    def to_camera(self, points: torch.Tensor) -> torch.Tensor:
        """World points :math:`(*, 3)` -> camera coordinates :math:`(*, 3)`."""
        return points.to(_F64) @ self.R.T + self.t

    def project(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """World points :math:`(*, 3)` -> pixel coordinates :math:`(*, 2)` and depth z :math:`(*)` (z <= 0: behind)."""
        pc = self.to_camera(points)
        z = pc[..., 2]
        safe = torch.where(z.abs() < 1e-12, torch.full_like(z, 1e-12), z)
        uvw = pc @ self.K.T
        return uvw[..., :2] / safe[..., None], z

    def relative_to(self, other: PinholeCamera) -> tuple[torch.Tensor, torch.Tensor]:
        """Pose of ``self`` in ``other``'s camera frame: ``X_self = R X_other + t``."""
        R = self.R @ other.R.T
        return R, self.t - R @ other.t


# ---------------------------------------------------------------------------------------------- textures
@dataclass
class Texture:
    """Procedural albedo: ``kind`` in {"constant", "stripes", "checker", "noise"}, colours in [0, 1].

    ``stripes`` vary along world ``axis`` with ``period``; ``checker`` alternates on a 3-D lattice of ``period``;
    ``noise`` is smooth value noise of cell size ``period`` (seeded), blending ``color`` and ``color2``.
    """

    kind: str = "constant"
    color: tuple[float, float, float] = (0.6, 0.6, 0.6)
    color2: tuple[float, float, float] = (0.2, 0.2, 0.2)
    period: float = 0.1
    axis: int = 0
    seed: int = 0

    def __post_init__(self) -> None:
        kinds = ("constant", "stripes", "checker", "noise")
        if self.kind not in kinds:
            raise StereoInputError(f"kind: expected one of {kinds}, got {self.kind!r}")
        if self.period <= 0:
            raise StereoInputError(f"period: expected > 0, got {self.period}")

    def __call__(self, points: torch.Tensor) -> torch.Tensor:
        """Albedo :math:`(N, 3)` at world points :math:`(N, 3)`."""
        c1 = torch.tensor(self.color, dtype=_F64)
        c2 = torch.tensor(self.color2, dtype=_F64)
        if self.kind == "constant":
            return c1.expand(points.shape[0], 3).clone()
        if self.kind == "stripes":
            w = 0.5 + 0.5 * torch.cos(2 * math.pi * points[:, self.axis] / self.period)
        elif self.kind == "checker":
            w = (torch.floor(points / self.period).sum(-1) % 2).to(_F64)
        else:
            w = _value_noise(points / self.period, self.seed)
        return c2 + w[:, None] * (c1 - c2)


def _hash01(ijk: torch.Tensor, seed: int) -> torch.Tensor:
    """Deterministic pseudo-random value in [0, 1) per integer lattice point :math:`(N, 3)` (int64)."""
    h = ijk[:, 0] * 73856093 ^ ijk[:, 1] * 19349663 ^ ijk[:, 2] * 83492791 ^ (seed * 2654435761)
    h = (h ^ (h >> 13)) * 1274126177
    h = h ^ (h >> 16)
    return (h & 0xFFFFFF).to(_F64) / float(0x1000000)


def _value_noise(p: torch.Tensor, seed: int) -> torch.Tensor:
    """Trilinearly interpolated lattice noise in [0, 1] at :math:`(N, 3)` points (two octaves)."""
    out = torch.zeros(p.shape[0], dtype=_F64)
    for octave, amp in ((1.0, 0.65), (2.7, 0.35)):
        q = p * octave
        base = torch.floor(q)
        f = q - base
        f = f * f * (3 - 2 * f)  # smoothstep
        b = base.to(torch.int64)
        acc = torch.zeros_like(out)
        for corner in range(8):
            o = torch.tensor([(corner >> 2) & 1, (corner >> 1) & 1, corner & 1], dtype=torch.int64)
            w = torch.prod(torch.where(o.bool(), f, 1 - f), dim=-1)
            acc = acc + w * _hash01(b + o, seed + int(octave * 10))
        out = out + amp * acc
    return out


# ---------------------------------------------------------------------------------------------- primitives
@dataclass
class Plane:
    """Infinite plane ``normal . X = offset`` (normal normalised on creation)."""

    normal: tuple[float, float, float]
    offset: float
    texture: Texture = field(default_factory=Texture)

    def intersect(self, o: torch.Tensor, d: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        n = _vec(self.normal, "normal")
        n = n / n.norm()
        denom = d @ n
        safe = torch.where(denom.abs() < 1e-12, torch.full_like(denom, 1e-12), denom)
        t = (self.offset / float(_vec(self.normal, "normal").norm()) - o @ n) / safe
        t = torch.where((t > _EPS_T) & (denom.abs() >= 1e-12), t, torch.full_like(t, _NO_HIT))
        normal = n.expand_as(d)
        return t, normal


@dataclass
class Sphere:
    center: tuple[float, float, float]
    radius: float
    texture: Texture = field(default_factory=Texture)

    def intersect(self, o: torch.Tensor, d: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        c = _vec(self.center, "center")
        oc = o - c
        a = (d * d).sum(-1)
        b = 2 * (oc * d).sum(-1)
        cc = (oc * oc).sum(-1) - self.radius ** 2
        disc = b * b - 4 * a * cc
        sq = torch.sqrt(disc.clamp_min(0))
        t0 = (-b - sq) / (2 * a)
        t1 = (-b + sq) / (2 * a)
        t = torch.where(t0 > _EPS_T, t0, t1)
        t = torch.where((disc >= 0) & (t > _EPS_T), t, torch.full_like(t, _NO_HIT))
        p = o + torch.where(torch.isfinite(t), t, torch.zeros_like(t))[..., None] * d
        return t, (p - c) / self.radius


@dataclass
class Box:
    """Axis-aligned box between corners ``lo`` and ``hi``."""

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    texture: Texture = field(default_factory=Texture)

    def intersect(self, o: torch.Tensor, d: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        lo, hi = _vec(self.lo, "lo"), _vec(self.hi, "hi")
        safe = torch.where(d.abs() < 1e-12, torch.full_like(d, 1e-12), d)
        inv = 1.0 / safe
        ta, tb = (lo - o) * inv, (hi - o) * inv
        tmin, tmax = torch.minimum(ta, tb), torch.maximum(ta, tb)
        t_near, axis_near = tmin.max(dim=-1)
        t_far, axis_far = tmax.min(dim=-1)
        hit = t_far >= torch.maximum(t_near, torch.full_like(t_near, _EPS_T))
        inside = t_near <= _EPS_T
        t = torch.where(inside, t_far, t_near)
        axis = torch.where(inside, axis_far, axis_near)
        t = torch.where(hit, t, torch.full_like(t, _NO_HIT))
        normal = torch.zeros_like(d)
        sign = -torch.sign(torch.gather(d, -1, axis[..., None]))
        normal.scatter_(-1, axis[..., None], sign)
        return t, normal


Primitive = Plane | Sphere | Box


@dataclass
class Scene:
    """A list of primitives; ``raycast`` finds the nearest hit of every ray."""

    objects: list = field(default_factory=list)

    def __post_init__(self) -> None:
        for i, obj in enumerate(self.objects):
            if not isinstance(obj, Plane | Sphere | Box):
                raise TypeError(f"objects[{i}]: expected Plane, Sphere or Box, got {type(obj).__name__}")


@dataclass
class Hits:
    """Nearest hits of a batch of rays (all :math:`(*, ...)` like the rays).

    ``t`` is the ray parameter (inf where nothing is hit), ``points``/``normals`` world coordinates (normals face
    the ray), ``albedo`` :math:`(*, 3)`, ``object_id`` (-1 for a miss), ``hit`` bool.
    """

    t: torch.Tensor
    points: torch.Tensor
    normals: torch.Tensor
    albedo: torch.Tensor
    object_id: torch.Tensor
    hit: torch.Tensor


def raycast(scene: Scene, origins: torch.Tensor, dirs: torch.Tensor, shade: bool = True) -> Hits:
    """Nearest intersection of rays ``origins + t * dirs`` (both :math:`(*, 3)`) with ``scene``.

    ``shade=False`` skips the albedo (shadow rays only need ``t``).
    """
    check_shape(origins, ["*", "3"], "origins")
    check_shape(dirs, ["*", "3"], "dirs")
    lead = dirs.shape[:-1]
    d = dirs.to(_F64).reshape(-1, 3)  # Nx3
    # one shared origin (a camera centre) stays 1x3 and broadcasts: no N x 3 copy
    shared = origins.numel() == 3 or (origins.dim() > 1 and origins.stride()[:-1] == (0,) * (origins.dim() - 1))
    o = origins.to(_F64).reshape(-1, 3)[:1] if shared else origins.to(_F64).expand_as(dirs).reshape(-1, 3)
    n_rays = d.shape[0]
    best_t = torch.full((n_rays,), _NO_HIT, dtype=_F64)
    best_n = torch.zeros(n_rays, 3, dtype=_F64)
    best_id = torch.full((n_rays,), -1, dtype=torch.int64)
    for i, obj in enumerate(scene.objects):
        t, nrm = obj.intersect(o, d)
        closer = t < best_t
        best_t = torch.where(closer, t, best_t)
        best_n = torch.where(closer[:, None], nrm, best_n)
        best_id = torch.where(closer, torch.full_like(best_id, i), best_id)
    hit = torch.isfinite(best_t)
    points = o + best_t.masked_fill(~hit, 0.0)[:, None] * d
    facing = (best_n * d).sum(-1) > 0
    best_n = torch.where(facing[:, None], -best_n, best_n)
    albedo = torch.zeros(n_rays, 3, dtype=_F64)
    if shade:
        for i, obj in enumerate(scene.objects):
            m = best_id == i
            if bool(m.any()):
                albedo[m] = obj.texture(points[m])
    return Hits(best_t.reshape(lead), points.reshape(*lead, 3), best_n.reshape(*lead, 3),
                albedo.reshape(*lead, 3), best_id.reshape(lead), hit.reshape(lead))


def visible_from(scene: Scene, points: torch.Tensor, normals: torch.Tensor, source: torch.Tensor) -> torch.Tensor:
    """Bool :math:`(*)`: is the straight segment from each surface point to ``source`` :math:`(3,)` unobstructed?"""
    start = points + 1e-6 * normals
    to_src = source.to(_F64) - start
    hits = raycast(scene, start, to_src, shade=False)
    return hits.t >= 1.0 - 1e-6  # t is in units of the full segment: nothing before the source
