"""Compiled (numba) CPU kernels for the per-ray work of :mod:`data_gen.render`.

The torch code in :mod:`data_gen.render` and :mod:`data_gen.primitives` is the reference; these kernels
compute the same first hits, surfaces, textures and shading one ray at a time in float64 (the torch path
runs many small tensor operations per object, whose overhead dominates at training image sizes). They are
selected automatically when numba is importable (see ``render.USE_KERNELS``) and are tested equal to the
reference in ``tests/data_gen/test_kernels.py``.

Scenes are packed into arrays by :func:`pack_scene`: one row of ``OBJ_FIELDS`` floats per primitive, one
row of ``MAT_FIELDS`` floats per material, polygon edges, blob radius tables, and the bank textures the
materials use, stacked.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from data_gen.primitives import T_EPS, Cylinder, PlanarPatch, Plane, Sphere
from data_gen.textures import _MIP_OFFSETS, BANK_SIZE, MIP_LEVELS, TEXTURE_KINDS, bank_texture

# object row layout
TYPE, SHAPE, CX, E1, E2, NRM, KOFF, SU, SV, RAD, HALF, NEDGE, NBLOB = 0, 1, 2, 5, 8, 11, 14, 15, 16, 17, 18, 19, 20
OBJ_FIELDS = 21
PLANE, PATCH, SPHERE, CYLINDER = 0, 1, 2, 3
SHAPES = {"ellipse": 0, "polygon": 1, "blob": 2}
MAX_EDGES = 16
MAX_BLOB = 256
# material row layout
KIND, COLORS, TEXEL, COS, SIN, OFF, BANK0, BANK1, SCALE2, CONTRAST, PERIOD, DUTY, KS, SHINY = (
    0, 1, 10, 11, 12, 13, 15, 16, 17, 18, 19, 20, 21, 22)
MAT_FIELDS = 23
K_BANK, K_MIX, K_STRIPES, K_GRID, K_CHECKER, K_WEAK, K_FLAT = (TEXTURE_KINDS.index(k) for k in (
    "bank", "bank_mix", "stripes", "grid", "checker", "weak", "flat"))
MIP_OFFSETS = np.asarray(_MIP_OFFSETS.numpy(), dtype=np.int64)


def pack_scene(scene, camera=None) -> dict[str, np.ndarray]:
    """Arrays describing ``scene`` for the kernels; with ``camera``, also each object's pixel bounding box
    ``boxes (K, 4)`` = (x0, x1, y0, y1) in that camera (+-inf = unbounded, NaN row = never visible)."""
    n = len(scene.objects)
    objs = np.zeros((n, OBJ_FIELDS))
    edges = np.zeros((n, MAX_EDGES, 3))
    blobs = np.zeros((n, MAX_BLOB))
    mats = np.zeros((n, MAT_FIELDS))
    boxes = np.tile(np.array([-np.inf, np.inf, -np.inf, np.inf]), (n, 1))
    used: dict[int, int] = {}
    for k, o in enumerate(scene.objects):
        row = objs[k]
        if isinstance(o, Plane):
            row[TYPE] = PLANE
            row[CX:CX + 3] = o.origin
            row[KOFF] = o.k
        elif isinstance(o, PlanarPatch):
            row[TYPE] = PATCH
            row[SHAPE] = SHAPES[o.shape]
            row[CX:CX + 3] = o.centre
            row[SU], row[SV] = o.scale
            if o.shape == "polygon":
                m = len(o.edge_dist)
                if m > MAX_EDGES:
                    raise ValueError(f"angles: at most {MAX_EDGES} polygon vertices in the compiled path, got {m}")
                row[NEDGE] = m
                edges[k, :m, :2] = o.edge_normals
                edges[k, :m, 2] = o.edge_dist
            elif o.shape == "blob":
                m = o.radii.numel()
                if m > MAX_BLOB:
                    raise ValueError(f"radii: at most {MAX_BLOB} blob radii in the compiled path, got {m}")
                row[NBLOB] = m
                blobs[k, :m] = o.radii.numpy()
        elif isinstance(o, Sphere):
            row[TYPE] = SPHERE
            row[CX:CX + 3] = o.centre
            row[RAD] = o.radius
        elif isinstance(o, Cylinder):
            row[TYPE] = CYLINDER
            row[CX:CX + 3] = o.centre
            row[RAD] = o.radius
            row[HALF] = o.half_length
        else:
            raise TypeError(f"scene.objects[{k}]: no compiled kernel for {type(o).__name__}")
        row[E1:E1 + 3] = o.e1
        row[E2:E2 + 3] = o.e2
        row[NRM:NRM + 3] = o.n if isinstance(o, Plane | PlanarPatch) else o.axis
        m = o.material
        mrow = mats[k]
        mrow[KIND] = TEXTURE_KINDS.index(m.kind)
        mrow[COLORS:COLORS + 9] = np.asarray(m.colors, dtype=np.float64).reshape(9)
        mrow[TEXEL] = m.texel_mm
        mrow[COS], mrow[SIN] = math.cos(m.angle), math.sin(m.angle)
        mrow[OFF:OFF + 2] = m.offset
        for j, b in ((BANK0, m.bank[0]), (BANK1, m.bank[1])):
            if m.kind in ("bank", "weak", "bank_mix") and (j == BANK0 or m.kind == "bank_mix"):
                mrow[j] = used.setdefault(int(b), len(used))
        mrow[SCALE2], mrow[CONTRAST], mrow[PERIOD], mrow[DUTY] = m.scale2, m.contrast, m.period, m.duty
        mrow[KS], mrow[SHINY] = m.specular, m.shininess
        if camera is not None:
            bs = o.bounding_sphere()
            if bs is not None:
                box = camera.pixel_bbox(bs[0], bs[1])
                boxes[k] = np.nan if box is None else box
    bank = np.zeros((max(len(used), 1), MIP_OFFSETS[-1]), dtype=np.float32)
    for b, slot in used.items():
        bank[slot] = bank_texture(b).numpy()
    return dict(objs=objs, edges=edges, blobs=blobs, mats=mats, boxes=boxes, bank=bank)


@numba.njit(cache=True)
def _dot(a, i, x, y, z):
    return a[i] * x + a[i + 1] * y + a[i + 2] * z


@numba.njit(cache=True)
def _dot2(a, k, i, x, y, z):
    return a[k, i] * x + a[k, i + 1] * y + a[k, i + 2] * z


@numba.njit(cache=True)
def _origin_constants(objs, ox, oy, oz):  # pragma: no cover - compiled
    """Per object, the ray-independent terms of :func:`_intersect` for rays from (ox, oy, oz):
    planes/patches: (n.o - k or n.c, e1.(o - c), e2.(o - c)); spheres/cylinders: (o - c), |o - c|^2, axis.(o - c)."""
    pre = np.zeros((objs.shape[0], 6))
    for k in range(objs.shape[0]):
        o = objs[k]
        typ = int(o[TYPE])
        mx, my, mz = ox - o[CX], oy - o[CX + 1], oz - o[CX + 2]
        if typ == PLANE:
            pre[k, 0] = o[KOFF] - _dot(o, NRM, ox, oy, oz)
        elif typ == PATCH:
            pre[k, 0] = -_dot(o, NRM, mx, my, mz)
            pre[k, 1] = _dot(o, E1, mx, my, mz)
            pre[k, 2] = _dot(o, E2, mx, my, mz)
        else:
            pre[k, 0], pre[k, 1], pre[k, 2] = mx, my, mz
            pre[k, 3] = mx * mx + my * my + mz * mz
            pre[k, 4] = _dot(o, NRM, mx, my, mz)
    return pre


@numba.njit(cache=True)
def _intersect(objs, pre, edges, blobs, k, dx, dy, dz, dd):  # pragma: no cover - compiled
    """Ray parameter of the first hit of object row ``o`` (inf on a miss), as the torch primitives.

    ``pre``: :func:`_origin_constants` of the objects; ``dd = |d|^2``. (Indexing the full arrays rather than
    passing row views keeps numba from building array views in the inner loop.)
    """
    typ = int(objs[k, TYPE])
    inf = np.inf
    if typ == PLANE or typ == PATCH:
        denom = _dot2(objs, k, NRM, dx, dy, dz)
        if denom == 0.0:
            return inf
        t = pre[k, 0] / denom
        if not t > T_EPS:
            return inf
        if typ == PLANE:
            return t
        un = (pre[k, 1] + t * _dot2(objs, k, E1, dx, dy, dz)) / objs[k, SU]
        vn = (pre[k, 2] + t * _dot2(objs, k, E2, dx, dy, dz)) / objs[k, SV]
        shape = int(objs[k, SHAPE])
        r2 = un * un + vn * vn
        if shape == 0:
            return t if r2 <= 1.0 else inf
        if shape == 1:
            for j in range(int(objs[k, NEDGE])):
                if un * edges[k, j, 0] + vn * edges[k, j, 1] > edges[k, j, 2]:
                    return inf
            return t
        n = int(objs[k, NBLOB])
        if r2 > 1.0:  # blob radii are <= 1
            return inf
        pos = (math.atan2(vn, un) * (n / (2 * math.pi))) % n
        i0 = min(int(pos), n - 1)
        frac = pos - i0
        r = blobs[k, i0] * (1 - frac) + blobs[k, (i0 + 1) % n] * frac
        return t if r2 <= r * r else inf
    mx, my, mz, mm = pre[k, 0], pre[k, 1], pre[k, 2], pre[k, 3]
    dm = dx * mx + dy * my + dz * mz
    r = objs[k, RAD]
    if typ == SPHERE:
        disc = dm * dm - dd * (mm - r * r)
        if disc < 0:
            return inf
        sq = math.sqrt(disc)
        t = (-dm - sq) / dd
        if not t > T_EPS:
            t = (-dm + sq) / dd
        return t if t > T_EPS else inf
    # cylinder: side wall (both roots) and caps
    da = _dot2(objs, k, NRM, dx, dy, dz)
    ma = pre[k, 4]
    L = objs[k, HALF]
    qa = dd - da * da
    qb = dm - da * ma
    qc = mm - ma * ma - r * r
    disc = qb * qb - qa * qc
    best = inf
    if disc >= 0 and qa != 0.0:
        sq = math.sqrt(disc)
        for sign in (-1.0, 1.0):
            t = (-qb + sign * sq) / qa
            if t > T_EPS and abs(ma + t * da) <= L and t < best:
                best = t
    if da != 0.0:
        for cap in (-L, L):
            t = (cap - ma) / da
            rho2 = mm + 2 * t * dm + t * t * dd - cap * cap
            if t > T_EPS and rho2 <= r * r and t < best:
                best = t
    return best


@numba.njit(cache=True)
def _sample_bank(bank, slot, s, t, per_sample):  # pragma: no cover - compiled
    level = 0
    if per_sample > 1.0:
        level = min(int(math.floor(math.log2(per_sample) + 0.5)), MIP_LEVELS - 1)
    scale = math.ldexp(1.0, -level)
    size = BANK_SIZE >> level
    mask = size - 1
    off = MIP_OFFSETS[level]
    x = s * scale - 0.5
    y = t * scale - 0.5
    x0f = math.floor(x)
    y0f = math.floor(y)
    fx = x - x0f
    fy = y - y0f
    x0 = int(x0f) & mask
    y0 = int(y0f) & mask
    x1 = (x0 + 1) & mask
    y1 = (y0 + 1) & mask
    r0 = y0 * size + off
    r1 = y1 * size + off
    top = bank[slot, r0 + x0] * (1 - fx) + bank[slot, r0 + x1] * fx
    bottom = bank[slot, r1 + x0] * (1 - fx) + bank[slot, r1 + x1] * fx
    return top * (1 - fy) + bottom * fy


@numba.njit(cache=True)
def _smooth_square(phase, softness):
    return min(max(0.5 + math.sin(phase) / (2 * max(softness, 1e-3) * math.pi), 0.0), 1.0)


@numba.njit(cache=True)
def _albedo(m, bank, u, v, footprint, out, i):  # pragma: no cover - compiled
    """Material row ``m`` at surface coordinates (u, v), written to ``out[i]`` (as ``Material.albedo``)."""
    inv = 1.0 / m[TEXEL]
    s = (m[COS] * inv) * u - (m[SIN] * inv) * v + m[OFF]
    t = (m[SIN] * inv) * u + (m[COS] * inv) * v + m[OFF + 1]
    per_sample = footprint / m[TEXEL]
    kind = int(m[KIND])
    g2 = 0.5
    if kind == K_FLAT:
        g1 = 0.5
    elif kind == K_BANK or kind == K_WEAK:
        g1 = _sample_bank(bank, int(m[BANK0]), s, t, per_sample)
    elif kind == K_MIX:
        g1 = _sample_bank(bank, int(m[BANK0]), s, t, per_sample)
        g2 = _sample_bank(bank, int(m[BANK1]), s / m[SCALE2] + 17.0, t / m[SCALE2] + 5.0, per_sample / m[SCALE2])
    else:
        period = m[PERIOD]
        if kind == K_STRIPES:
            g1 = _smooth_square(s * (2 * math.pi / period), 0.15)
            mean = 0.5
        elif kind == K_GRID:
            fs = (s / period) % 1.0
            ft = (t / period) % 1.0
            g1 = 1.0 if (fs < m[DUTY] or ft < m[DUTY]) else 0.0
            mean = 1 - (1 - m[DUTY]) ** 2
        else:
            w = 2 * math.pi / period
            a = _smooth_square(s * w, 0.1) * 2 - 1
            g1 = 0.5 + 0.5 * a * (_smooth_square(t * w, 0.1) * 2 - 1)
            mean = 0.5
        keep = min(max((period / per_sample - 2.0) / 2.0, 0.0), 1.0)
        g1 = mean + keep * (g1 - mean)
    g1 = 0.5 + m[CONTRAST] * (g1 - 0.5)
    for c in range(3):
        val = m[COLORS + c] + g1 * (m[COLORS + 3 + c] - m[COLORS + c]) + (g2 - 0.5) * m[COLORS + 6 + c]
        out[i, c] = min(max(val, 0.0), 1.0)


@numba.njit(cache=True)
def _blinn_phong(ks, shininess, nx, ny, nz, vx, vy, vz, light):  # pragma: no cover - compiled
    """``ks max(0, n . h)^shininess`` with h the unit half vector of the view direction v and the light."""
    vn = max(math.sqrt(vx * vx + vy * vy + vz * vz), 1e-12)
    hx, hy, hz = vx / vn + light[0], vy / vn + light[1], vz / vn + light[2]
    hn = max(math.sqrt(hx * hx + hy * hy + hz * hz), 1e-12)
    return ks * max((nx * hx + ny * hy + nz * hz) / hn, 0.0) ** shininess


@numba.njit(cache=True)
def trace_shade(dirs, pix, origin, objs, edges, blobs, mats, boxes, bank, spacing, light, ambient, specular,
                eye2, t_out, ids_out, points_out, normals_out, rgb_out, spec_out, spec2_out
                ):  # pragma: no cover - compiled
    """First hit, surface, albedo and shading of every ray ``origin + t dirs[i]`` (pixel ``pix[i]``).

    ``spec2_out`` receives the specular radiance of the same points towards a second viewpoint ``eye2``
    (e.g. the other camera of the rig; ignored when ``eye2`` has no element).
    """
    n_obj = objs.shape[0]
    ox, oy, oz = origin[0], origin[1], origin[2]
    pre = _origin_constants(objs, ox, oy, oz)
    albedo = np.zeros((1, 3))
    for i in range(dirs.shape[0]):
        dx, dy, dz = dirs[i, 0], dirs[i, 1], dirs[i, 2]
        dd = dx * dx + dy * dy + dz * dz
        px, py = pix[i, 0], pix[i, 1]
        best = np.inf
        bid = -1
        for k in range(n_obj):
            if not (px >= boxes[k, 0] and px <= boxes[k, 1] and py >= boxes[k, 2] and py <= boxes[k, 3]):
                continue
            t = _intersect(objs, pre, edges, blobs, k, dx, dy, dz, dd)
            if t < best:
                best = t
                bid = k
        t_out[i] = best
        ids_out[i] = bid
        if bid < 0:
            for c in range(3):
                points_out[i, c] = 0.0
                normals_out[i, c] = 0.0
                rgb_out[i, c] = 0.0
            spec_out[i] = 0.0
            continue
        if eye2.shape[0] == 3:
            spec2_out[i] = 0.0
        o = objs[bid]
        p0, p1, p2 = ox + best * dx, oy + best * dy, oz + best * dz
        points_out[i, 0], points_out[i, 1], points_out[i, 2] = p0, p1, p2
        typ = int(o[TYPE])
        r0, r1, r2 = p0 - o[CX], p1 - o[CX + 1], p2 - o[CX + 2]
        if typ == PLANE or typ == PATCH:
            nx, ny, nz = o[NRM], o[NRM + 1], o[NRM + 2]
            u = _dot(o, E1, r0, r1, r2)
            v = _dot(o, E2, r0, r1, r2)
        elif typ == SPHERE:
            rad = o[RAD]
            nx, ny, nz = r0 / rad, r1 / rad, r2 / rad
            x = _dot(o, E1, nx, ny, nz)
            y = _dot(o, E2, nx, ny, nz)
            z = min(max(_dot(o, NRM, nx, ny, nz), -1.0), 1.0)
            u = rad * math.atan2(y, x)
            v = rad * math.acos(z)
        else:
            h = _dot(o, NRM, r0, r1, r2)
            q0, q1, q2 = r0 - h * o[NRM], r1 - h * o[NRM + 1], r2 - h * o[NRM + 2]
            rho = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2)
            x = _dot(o, E1, q0, q1, q2)
            y = _dot(o, E2, q0, q1, q2)
            if abs(rho - o[RAD]) < abs(abs(h) - o[HALF]):
                rr = max(rho, 1e-12)
                nx, ny, nz = q0 / rr, q1 / rr, q2 / rr
                u = o[RAD] * math.atan2(y, x)
                v = h
            else:
                sg = 1.0 if h > 0 else (-1.0 if h < 0 else 0.0)
                nx, ny, nz = sg * o[NRM], sg * o[NRM + 1], sg * o[NRM + 2]
                u = x
                v = y
        nd = nx * dx + ny * dy + nz * dz
        if nd > 0:
            nx, ny, nz, nd = -nx, -ny, -nz, -nd
        normals_out[i, 0], normals_out[i, 1], normals_out[i, 2] = nx, ny, nz
        footprint = best * dd * spacing / max(abs(nd), 0.05 * math.sqrt(dd))
        m = mats[bid]
        _albedo(m, bank, u, v, footprint, albedo, 0)
        nl = nx * light[0] + ny * light[1] + nz * light[2]
        irradiance = max(nl * (1 - ambient), 0.0) + ambient
        spec = 0.0
        if specular and m[KS] > 0 and nl > 0:
            spec = _blinn_phong(m[KS], m[SHINY], nx, ny, nz, ox - p0, oy - p1, oz - p2, light)
            if eye2.shape[0] == 3:
                spec2_out[i] = _blinn_phong(m[KS], m[SHINY], nx, ny, nz, eye2[0] - p0, eye2[1] - p1, eye2[2] - p2,
                                            light)
        spec_out[i] = spec
        for c in range(3):
            rgb_out[i, c] = albedo[0, c] * irradiance + spec


@numba.njit(cache=True)
def hidden_points(points, pix, origin, objs, edges, blobs, boxes, rel_eps, out):  # pragma: no cover - compiled
    """``out[i]`` = the segment from ``origin`` to ``points[i]`` crosses a surface before the point
    (planes: the point is on the far side; others: a hit with t < 1 - rel_eps), as ``render.visible_from``."""
    ox, oy, oz = origin[0], origin[1], origin[2]
    pre = _origin_constants(objs, ox, oy, oz)
    for i in range(points.shape[0]):
        px, py = pix[i, 0], pix[i, 1]
        dx, dy, dz = points[i, 0] - ox, points[i, 1] - oy, points[i, 2] - oz
        dd = dx * dx + dy * dy + dz * dz
        hidden = False
        for k in range(objs.shape[0]):
            o = objs[k]
            if int(o[TYPE]) == PLANE:
                side_cam = -pre[k, 0]  # n.o - k
                side_pt = _dot(o, NRM, points[i, 0], points[i, 1], points[i, 2]) - o[KOFF]
                sg = 1.0 if side_cam >= 0 else -1.0
                if side_pt * sg < -rel_eps * abs(side_cam):
                    hidden = True
                    break
                continue
            if not (px >= boxes[k, 0] and px <= boxes[k, 1] and py >= boxes[k, 2] and py <= boxes[k, 3]):
                continue
            if _intersect(objs, pre, edges, blobs, k, dx, dy, dz, dd) < 1 - rel_eps:
                hidden = True
                break
        out[i] = hidden
