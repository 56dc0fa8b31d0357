"""Compiled (numba) CPU kernels for the per-ray work of :mod:`data_gen.render`.

The torch code in :mod:`data_gen.render` and :mod:`data_gen.primitives` is the reference; these kernels
compute the same first hits, surfaces, textures and shading one ray at a time in float64 (the torch path
runs many small tensor operations per object, whose overhead dominates at training image sizes). They are
selected automatically when numba is importable (see ``render.USE_KERNELS``) and are tested equal to the
reference in ``tests/data_gen/test_kernels.py``.

Scenes are packed into arrays by :func:`pack_scene`: one row of ``OBJ_FIELDS`` floats per primitive, one
row of ``MAT_FIELDS`` floats per material (bank textures by their index into ``textures.bank_table()``),
polygon edges, blob radius tables.

Speed note: inner loops are written inline. A numba call that takes arrays costs ~100 ns when it is not
inlined, which made the earlier one-ray-at-a-time kernels 10x slower than these object-by-object ones.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from data_gen.primitives import T_EPS, Cylinder, PlanarPatch, Plane, Sphere
from data_gen.textures import _MIP_OFFSETS, BANK_SIZE, MIP_LEVELS, TEXTURE_KINDS, bank_table, bank_texture

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
                mrow[j] = int(b)
                bank_texture(int(b))  # generated on first use
        mrow[SCALE2], mrow[CONTRAST], mrow[PERIOD], mrow[DUTY] = m.scale2, m.contrast, m.period, m.duty
        mrow[KS], mrow[SHINY] = m.specular, m.shininess
    if camera is not None:
        bounded = [(k, bs) for k, bs in enumerate(o.bounding_sphere() for o in scene.objects) if bs is not None]
        if bounded:
            rows = [k for k, _ in bounded]
            boxes[rows] = camera.pixel_bboxes(np.array([bs[0] for _, bs in bounded]),
                                              np.array([bs[1] for _, bs in bounded]))
    return dict(objs=objs, edges=edges, blobs=blobs, mats=mats, boxes=boxes, bank=bank_table())


@numba.njit(cache=True, error_model="numpy")
def zbuffer(dirs, pix, origin, objs, edges, blobs, boxes, grid_w, skip_planes, t_out, ids_out, t_max=np.inf
            ):  # pragma: no cover - compiled
    """Nearest hit ``t_out[i]`` (inf on a miss) and its object ``ids_out[i]`` (-1) of every ray
    ``origin + t dirs[i]``, object by object: each object is intersected only with the rays inside its pixel
    box ``boxes[k] = (x0, x1, y0, y1)`` (NaN row = never visible).

    ``grid_w > 0``: the rays are a row-major pixel grid of that width (ray ``i`` through pixel
    ``(i % grid_w, i // grid_w)``), so each box is a block of rows and ``pix`` is unused; else ``pix[i]`` is
    the pixel of ray i. ``skip_planes``: leave infinite planes out; ``t_max``: only hits with t < t_max count
    (others leave ``t_out = t_max``, id -1). Same first hits as the torch primitives.

    """
    n = dirs.shape[0]
    ox, oy, oz = origin[0], origin[1], origin[2]
    for i in range(n):
        t_out[i] = t_max
        ids_out[i] = -1
    h = n // grid_w if grid_w > 0 else 1
    if grid_w <= 0:  # bucket the rays by pixel row (counting sort) so that objects visit only their rows
        order, row_start, y_base, n_rows = _row_buckets(pix)
    else:
        order, row_start, y_base, n_rows = np.empty(0, dtype=np.int64), np.empty(0, dtype=np.int64), 0.0, 0
    for k in range(objs.shape[0]):
        typ = int(objs[k, TYPE])
        if skip_planes and typ == PLANE:
            continue
        x0, x1, y0, y1 = boxes[k, 0], boxes[k, 1], boxes[k, 2], boxes[k, 3]
        if not (x0 <= x1 and y0 <= y1):
            continue
        # ray-independent terms
        cx, cy, cz = objs[k, CX], objs[k, CX + 1], objs[k, CX + 2]
        mx, my, mz = ox - cx, oy - cy, oz - cz
        a0, a1, a2 = objs[k, NRM], objs[k, NRM + 1], objs[k, NRM + 2]
        u0, u1, u2 = objs[k, E1], objs[k, E1 + 1], objs[k, E1 + 2]
        v0, v1, v2 = objs[k, E2], objs[k, E2 + 1], objs[k, E2 + 2]
        if typ == PLANE:
            num = objs[k, KOFF] - (a0 * ox + a1 * oy + a2 * oz)
        else:
            num = -(a0 * mx + a1 * my + a2 * mz)
        pu = u0 * mx + u1 * my + u2 * mz
        pv = v0 * mx + v1 * my + v2 * mz
        mm = mx * mx + my * my + mz * mz
        ma = a0 * mx + a1 * my + a2 * mz  # (o - c) . axis
        inv_su, inv_sv = 1.0 / max(objs[k, SU], 1e-300), 1.0 / max(objs[k, SV], 1e-300)
        shape = int(objs[k, SHAPE])
        n_edge = int(objs[k, NEDGE])
        n_blob = int(objs[k, NBLOB])
        rad = objs[k, RAD]
        half = objs[k, HALF]
        if grid_w > 0:
            r0 = max(0, int(math.ceil(max(y0, -1.0))))
            r1 = min(h - 1, int(math.floor(min(y1, h + 1.0))))
            c0 = max(0, int(math.ceil(max(x0, -1.0))))
            c1 = min(grid_w - 1, int(math.floor(min(x1, grid_w + 1.0))))
            if r1 < r0 or c1 < c0:
                continue
            n_seg, seg_len = r1 - r0 + 1, c1 - c0 + 1
        else:
            b0 = 0 if not y0 > y_base else min(int(y0 - y_base), n_rows - 1)
            b1 = n_rows - 1 if not y1 < y_base + n_rows else max(int(y1 - y_base), 0)
            r0, c0 = row_start[b0], 0
            n_seg, seg_len = 1, row_start[b1 + 1] - r0
        for sgi in range(n_seg):
            start = (r0 + sgi) * grid_w + c0 if grid_w > 0 else r0
            for j in range(start, start + seg_len):
                i = j
                if grid_w <= 0:
                    i = order[j]
                    px, py = pix[i, 0], pix[i, 1]
                    if not (px >= x0 and px <= x1 and py >= y0 and py <= y1):
                        continue
                dx, dy, dz = dirs[i, 0], dirs[i, 1], dirs[i, 2]
                best = t_out[i]
                t = np.inf
                if typ == PLANE or typ == PATCH:
                    denom = a0 * dx + a1 * dy + a2 * dz
                    if denom == 0.0:
                        continue
                    t = num / denom
                    if not (t > T_EPS and t < best):
                        continue
                    if typ == PATCH:
                        un = (pu + t * (u0 * dx + u1 * dy + u2 * dz)) * inv_su
                        vn = (pv + t * (v0 * dx + v1 * dy + v2 * dz)) * inv_sv
                        r2 = un * un + vn * vn
                        if shape == 0:
                            if r2 > 1.0:
                                continue
                        elif shape == 1:
                            out = False
                            for j in range(n_edge):
                                if un * edges[k, j, 0] + vn * edges[k, j, 1] > edges[k, j, 2]:
                                    out = True
                                    break
                            if out:
                                continue
                        else:
                            if r2 > 1.0:  # blob radii are <= 1
                                continue
                            pos = math.atan2(vn, un) * (n_blob / (2 * math.pi))
                            if pos < 0:
                                pos += n_blob
                            i0 = min(int(pos), n_blob - 1)
                            frac = pos - i0
                            i1 = i0 + 1 if i0 + 1 < n_blob else 0
                            rb = blobs[k, i0] * (1 - frac) + blobs[k, i1] * frac
                            if r2 > rb * rb:
                                continue
                else:
                    dd = dx * dx + dy * dy + dz * dz
                    dm = dx * mx + dy * my + dz * mz
                    if typ == SPHERE:
                        disc = dm * dm - dd * (mm - rad * rad)
                        if disc < 0:
                            continue
                        sq = math.sqrt(disc)
                        t = (-dm - sq) / dd
                        if not t > T_EPS:
                            t = (-dm + sq) / dd
                        if not (t > T_EPS and t < best):
                            continue
                    else:  # cylinder: side wall (both roots) and caps
                        da = a0 * dx + a1 * dy + a2 * dz
                        qa = dd - da * da
                        qb = dm - da * ma
                        qc = mm - ma * ma - rad * rad
                        disc = qb * qb - qa * qc
                        if disc >= 0 and qa != 0.0:
                            sq = math.sqrt(disc)
                            tc = (-qb - sq) / qa
                            if tc > T_EPS and abs(ma + tc * da) <= half and tc < t:
                                t = tc
                            tc = (-qb + sq) / qa
                            if tc > T_EPS and abs(ma + tc * da) <= half and tc < t:
                                t = tc
                        if da != 0.0:
                            tc = (-half - ma) / da
                            if tc > T_EPS and tc < t and mm + 2 * tc * dm + tc * tc * dd - half * half <= rad * rad:
                                t = tc
                            tc = (half - ma) / da
                            if tc > T_EPS and tc < t and mm + 2 * tc * dm + tc * tc * dd - half * half <= rad * rad:
                                t = tc
                        if not t < best:
                            continue
                t_out[i] = t
                ids_out[i] = k


@numba.njit(cache=True)
def _row_buckets(pix):  # pragma: no cover - compiled
    """Rays sorted by pixel row: ``order`` (N,), ``row_start`` (R + 1,) (rays of bucket b are
    ``order[row_start[b]:row_start[b + 1]]``), ``y_base`` and R; bucket b holds ``y_base + b <= y < y_base + b + 1``
    (rays beyond +-1e7 or NaN go to the first / last bucket)."""
    n = pix.shape[0]
    lo, hi = np.inf, -np.inf
    for i in range(n):
        y = pix[i, 1]
        if abs(y) < 1e7:
            lo = min(lo, y)
            hi = max(hi, y)
    if not lo <= hi:
        lo = hi = 0.0
    y_base = math.floor(lo)
    n_rows = int(math.floor(hi) - y_base) + 1
    bucket = np.empty(n, dtype=np.int64)
    row_start = np.zeros(n_rows + 1, dtype=np.int64)
    for i in range(n):
        y = pix[i, 1]
        b = 0
        if y > y_base:
            b = min(int(y - y_base), n_rows - 1)
        bucket[i] = b
        row_start[b + 1] += 1
    for b in range(n_rows):
        row_start[b + 1] += row_start[b]
    fill = row_start[:-1].copy()
    order = np.empty(n, dtype=np.int64)
    for i in range(n):
        order[fill[bucket[i]]] = i
        fill[bucket[i]] += 1
    return order, row_start, float(y_base), n_rows


@numba.njit(cache=True)
def _bank_taps(s, t, per_sample):  # pragma: no cover - compiled
    """Bilinear taps of a bank lookup: flat indices (i00, i01, i10, i11) into a mip pyramid and weights.

    Mip level ``round(log2(per_sample))`` (clamped to the pyramid), found by halving instead of a log.
    """
    level = 0
    x = per_sample * 1.4142135623730951  # level = floor(log2(per_sample) + 1/2)
    while x >= 2.0 and level < MIP_LEVELS - 1:
        x *= 0.5
        level += 1
    scale = 1.0 / (1 << level)
    size = BANK_SIZE >> level
    mask = size - 1
    off = MIP_OFFSETS[level]
    x = s * scale - 0.5
    y = t * scale - 0.5
    xi = int(x)
    if xi > x:
        xi -= 1
    yi = int(y)
    if yi > y:
        yi -= 1
    fx = x - xi
    fy = y - yi
    x0 = xi & mask
    y0 = yi & mask
    x1 = (x0 + 1) & mask
    y1 = (y0 + 1) & mask
    return y0 * size + off + x0, y0 * size + off + x1, y1 * size + off + x0, y1 * size + off + x1, fx, fy


@numba.njit(cache=True)
def _smooth_square(phase, softness):
    return min(max(0.5 + math.sin(phase) / (2 * max(softness, 1e-3) * math.pi), 0.0), 1.0)


SPEC_CUTOFF = 1e-5  # specular lobes below this fraction of ks are skipped (set to 0) without a pow
LOG_SPEC_CUTOFF = math.log(SPEC_CUTOFF)


@numba.njit(cache=True)
def _blinn_phong(ks, shininess, nx, ny, nz, vx, vy, vz, lx, ly, lz):  # pragma: no cover - compiled
    """``ks max(0, n . h)^shininess`` with h the unit half vector of the view direction v and the light l
    (0 where the lobe is below ``SPEC_CUTOFF``)."""
    vn = max(math.sqrt(vx * vx + vy * vy + vz * vz), 1e-12)
    hx, hy, hz = vx / vn + lx, vy / vn + ly, vz / vn + lz
    hn = max(math.sqrt(hx * hx + hy * hy + hz * hz), 1e-12)
    ndh = (nx * hx + ny * hy + nz * hz) / hn
    # ndh^s < cutoff  <=>  ndh < cutoff^(1/s) ~ 1 + ln(cutoff) / s (the tangent bound is below it: safe)
    if ndh * shininess <= shininess + LOG_SPEC_CUTOFF:
        return 0.0
    return ks * ndh ** shininess


@numba.njit(cache=True, error_model="numpy")
def shade(dirs, origin, t_hit, ids, objs, mats, bank, spacing, light, ambient, specular, eye2, points_out,
          normals_out, rgb_out, spec_out, spec2_out):  # pragma: no cover - compiled
    """Surface, albedo and shading of the hits ``origin + t_hit[i] dirs[i]`` on objects ``ids[i]`` (misses,
    id < 0, get zeros): points, normals (facing the ray), rgb radiance, specular radiance towards the origin
    and (``eye2`` of 3 elements) towards a second viewpoint. As ``shade`` / ``Material.albedo`` of the torch
    path; written inline (no array-taking calls in the loop)."""
    ox, oy, oz = origin[0], origin[1], origin[2]
    lx, ly, lz = light[0], light[1], light[2]
    second = eye2.shape[0] == 3
    ex, ey, ez = (eye2[0], eye2[1], eye2[2]) if second else (0.0, 0.0, 0.0)
    for i in range(dirs.shape[0]):
        bid = ids[i]
        spec2_out[i] = 0.0
        spec_out[i] = 0.0
        if bid < 0:
            for c in range(3):
                points_out[i, c] = 0.0
                normals_out[i, c] = 0.0
                rgb_out[i, c] = 0.0
            continue
        best = t_hit[i]
        dx, dy, dz = dirs[i, 0], dirs[i, 1], dirs[i, 2]
        dd = dx * dx + dy * dy + dz * dz
        p0, p1, p2 = ox + best * dx, oy + best * dy, oz + best * dz
        points_out[i, 0], points_out[i, 1], points_out[i, 2] = p0, p1, p2
        typ = int(objs[bid, TYPE])
        r0, r1, r2 = p0 - objs[bid, CX], p1 - objs[bid, CX + 1], p2 - objs[bid, CX + 2]
        a0, a1, a2 = objs[bid, NRM], objs[bid, NRM + 1], objs[bid, NRM + 2]
        u0, u1, u2 = objs[bid, E1], objs[bid, E1 + 1], objs[bid, E1 + 2]
        v0, v1, v2 = objs[bid, E2], objs[bid, E2 + 1], objs[bid, E2 + 2]
        if typ == PLANE or typ == PATCH:
            nx, ny, nz = a0, a1, a2
            u = u0 * r0 + u1 * r1 + u2 * r2
            v = v0 * r0 + v1 * r1 + v2 * r2
        elif typ == SPHERE:
            rad = objs[bid, RAD]
            nx, ny, nz = r0 / rad, r1 / rad, r2 / rad
            x = u0 * nx + u1 * ny + u2 * nz
            y = v0 * nx + v1 * ny + v2 * nz
            z = min(max(a0 * nx + a1 * ny + a2 * nz, -1.0), 1.0)
            u = rad * math.atan2(y, x)
            v = rad * math.acos(z)
        else:
            hh = a0 * r0 + a1 * r1 + a2 * r2
            q0, q1, q2 = r0 - hh * a0, r1 - hh * a1, r2 - hh * a2
            rho = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2)
            x = u0 * q0 + u1 * q1 + u2 * q2
            y = v0 * q0 + v1 * q1 + v2 * q2
            if abs(rho - objs[bid, RAD]) < abs(abs(hh) - objs[bid, HALF]):
                rr = max(rho, 1e-12)
                nx, ny, nz = q0 / rr, q1 / rr, q2 / rr
                u = objs[bid, RAD] * math.atan2(y, x)
                v = hh
            else:
                sg = 1.0 if hh > 0 else (-1.0 if hh < 0 else 0.0)
                nx, ny, nz = sg * a0, sg * a1, sg * a2
                u = x
                v = y
        nd = nx * dx + ny * dy + nz * dz
        if nd > 0:
            nx, ny, nz, nd = -nx, -ny, -nz, -nd
        normals_out[i, 0], normals_out[i, 1], normals_out[i, 2] = nx, ny, nz
        footprint = best * dd * spacing / max(abs(nd), 0.05 * math.sqrt(dd))
        # albedo (Material.albedo): texel coordinates, then the texture kind
        inv = 1.0 / mats[bid, TEXEL]
        cs, sn = mats[bid, COS] * inv, mats[bid, SIN] * inv
        ts = cs * u - sn * v + mats[bid, OFF]
        tt = sn * u + cs * v + mats[bid, OFF + 1]
        per_sample = footprint * inv
        kind = int(mats[bid, KIND])
        g2 = 0.5
        if kind == K_FLAT:
            g1 = 0.5
        elif kind == K_BANK or kind == K_WEAK or kind == K_MIX:
            slot = int(mats[bid, BANK0])
            i00, i01, i10, i11, fx, fy = _bank_taps(ts, tt, per_sample)
            g1 = ((bank[slot, i00] * (1 - fx) + bank[slot, i01] * fx) * (1 - fy)
                  + (bank[slot, i10] * (1 - fx) + bank[slot, i11] * fx) * fy)
            if kind == K_MIX:
                slot = int(mats[bid, BANK1])
                sc2 = mats[bid, SCALE2]
                i00, i01, i10, i11, fx, fy = _bank_taps(ts / sc2 + 17.0, tt / sc2 + 5.0, per_sample / sc2)
                g2 = ((bank[slot, i00] * (1 - fx) + bank[slot, i01] * fx) * (1 - fy)
                      + (bank[slot, i10] * (1 - fx) + bank[slot, i11] * fx) * fy)
        else:
            period = mats[bid, PERIOD]
            if kind == K_STRIPES:
                g1 = _smooth_square(ts * (2 * math.pi / period), 0.15)
                mean = 0.5
            elif kind == K_GRID:
                fs = (ts / period) % 1.0
                ft = (tt / period) % 1.0
                duty = mats[bid, DUTY]
                g1 = 1.0 if (fs < duty or ft < duty) else 0.0
                mean = 1 - (1 - duty) ** 2
            else:
                w = 2 * math.pi / period
                sq_s = _smooth_square(ts * w, 0.1) * 2 - 1
                g1 = 0.5 + 0.5 * sq_s * (_smooth_square(tt * w, 0.1) * 2 - 1)
                mean = 0.5
            keep = min(max((period / per_sample - 2.0) / 2.0, 0.0), 1.0)
            g1 = mean + keep * (g1 - mean)
        g1 = 0.5 + mats[bid, CONTRAST] * (g1 - 0.5)
        g2 -= 0.5
        nl = nx * lx + ny * ly + nz * lz
        irradiance = max(nl * (1 - ambient), 0.0) + ambient
        spec = 0.0
        ks = mats[bid, KS]
        if specular and ks > 0 and nl > 0:
            spec = _blinn_phong(ks, mats[bid, SHINY], nx, ny, nz, ox - p0, oy - p1, oz - p2, lx, ly, lz)
            if second:
                spec2_out[i] = _blinn_phong(ks, mats[bid, SHINY], nx, ny, nz, ex - p0, ey - p1, ez - p2, lx, ly, lz)
        spec_out[i] = spec
        for c in range(3):
            col0 = mats[bid, COLORS + c]
            val = col0 + g1 * (mats[bid, COLORS + 3 + c] - col0) + g2 * mats[bid, COLORS + 6 + c]
            rgb_out[i, c] = min(max(val, 0.0), 1.0) * irradiance + spec


@numba.njit(cache=True)
def trace_shade(dirs, pix, origin, objs, edges, blobs, mats, boxes, bank, spacing, light, ambient, specular,
                eye2, t_out, ids_out, points_out, normals_out, rgb_out, spec_out, spec2_out, grid_w=0
                ):  # pragma: no cover - compiled
    """First hit (:func:`zbuffer`), surface, albedo and shading (:func:`shade`) of every ray
    ``origin + t dirs[i]`` through pixel ``pix[i]`` (or, ``grid_w > 0``, of a row-major pixel grid).

    ``spec2_out`` receives the specular radiance of the same points towards a second viewpoint ``eye2``
    (e.g. the other camera of the rig; ignored when ``eye2`` has no element).
    """
    zbuffer(dirs, pix, origin, objs, edges, blobs, boxes, grid_w, False, t_out, ids_out)
    shade(dirs, origin, t_out, ids_out, objs, mats, bank, spacing, light, ambient, specular, eye2, points_out,
          normals_out, rgb_out, spec_out, spec2_out)


@numba.njit(cache=True)
def hidden_points(points, pix, origin, objs, edges, blobs, boxes, rel_eps, out):  # pragma: no cover - compiled
    """``out[i]`` = the segment from ``origin`` to ``points[i]`` crosses a surface before the point
    (planes: the point is on the far side; others: a hit with t < 1 - rel_eps), as ``render.visible_from``."""
    n = points.shape[0]
    ox, oy, oz = origin[0], origin[1], origin[2]
    dirs = np.empty((n, 3))
    for i in range(n):
        dirs[i, 0], dirs[i, 1], dirs[i, 2] = points[i, 0] - ox, points[i, 1] - oy, points[i, 2] - oz
    t = np.empty(n)
    ids = np.empty(n, dtype=np.int64)
    zbuffer(dirs, pix, origin, objs, edges, blobs, boxes, 0, True, t, ids, 1 - rel_eps)
    for i in range(n):
        out[i] = ids[i] >= 0
    for k in range(objs.shape[0]):
        if int(objs[k, TYPE]) != PLANE:
            continue
        a0, a1, a2, off = objs[k, NRM], objs[k, NRM + 1], objs[k, NRM + 2], objs[k, KOFF]
        side_cam = a0 * ox + a1 * oy + a2 * oz - off
        sg = 1.0 if side_cam >= 0 else -1.0
        lim = -rel_eps * abs(side_cam)
        for i in range(n):
            if (a0 * points[i, 0] + a1 * points[i, 1] + a2 * points[i, 2] - off) * sg < lim:
                out[i] = True


@numba.njit(cache=True)
def edge_mask(ids, normals, crease, out):  # pragma: no cover - compiled
    """``out[r, c]``: pixel whose object id differs from one of its 8 neighbours (replicated border), or
    whose normal turns by more than ``1 - cos = crease`` towards a 4-neighbour; ``normals`` :math:`(H W, 3)`
    (as ``render.edge_pixels``)."""
    h, w = ids.shape
    lim = 1 - crease
    for r in range(h):
        for c in range(w):
            out[r, c] = False
    for r in range(h):
        for c in range(w):
            k = ids[r, c]
            i = r * w + c
            # the 8-neighbour relation is symmetric: compare with the right and lower neighbours, mark both
            if c + 1 < w:
                if ids[r, c + 1] != k:
                    out[r, c] = True
                    out[r, c + 1] = True
                j = i + 1
                if normals[i, 0] * normals[j, 0] + normals[i, 1] * normals[j, 1] + normals[i, 2] * normals[j, 2] < lim:
                    out[r, c] = True
                    out[r, c + 1] = True
            if r + 1 < h:
                for dc in range(-1, 2):
                    if 0 <= c + dc < w and ids[r + 1, c + dc] != k:
                        out[r, c] = True
                        out[r + 1, c + dc] = True
                j = i + w
                if normals[i, 0] * normals[j, 0] + normals[i, 1] * normals[j, 1] + normals[i, 2] * normals[j, 2] < lim:
                    out[r, c] = True
                    out[r + 1, c] = True


@numba.njit(cache=True)
def grid_dirs(M, h, w):  # pragma: no cover - compiled
    """Directions ``M (x, y, 1)`` :math:`(H W, 3)` of the pixel-centre rays of an undistorted camera, row-major."""
    out = np.empty((h * w, 3))
    for r in range(h):
        for c in range(w):
            i = r * w + c
            for j in range(3):
                out[i, j] = M[j, 0] * c + M[j, 1] * r + M[j, 2]
    return out


GAMMA_LUT_SIZE = 4096
NOISE_TABLE_SIZE = 1 << 21  # standard normal samples shared by all images (a window per image)
_NOISE_TABLE: np.ndarray | None = None


def noise_table() -> np.ndarray:
    """``NOISE_TABLE_SIZE`` float32 standard normal samples (fixed seed, generated once per process)."""
    global _NOISE_TABLE
    if _NOISE_TABLE is None:
        _NOISE_TABLE = np.random.default_rng(20240612).standard_normal(NOISE_TABLE_SIZE, dtype=np.float32)
    return _NOISE_TABLE


@numba.njit(cache=True)
def camera_response(img, out, gain, bias, gamma, vignetting, photometric, noise, table, offset
                    ):  # pragma: no cover - compiled
    """Sensor response of an :math:`(H, W, 3)` float32 radiance image into ``out`` :math:`(3, H, W)`:
    (``photometric``) ``clip(img gain (1 - v (x^2 + y^2) / 2) + bias, 0, 1) ^ gamma`` (gamma from a table)
    with x, y in [-1, 1]
    over the image, then (``noise > 0``) ``+ noise sqrt(0.25 + I) g`` with standard normal samples g read from
    ``table`` at ``offset + (flat index in out)`` (wrapping), clipped to [0, 1] (``pair.apply_camera_response``).
    """
    h, w = img.shape[0], img.shape[1]
    sx = 2.0 / (w - 1) if w > 1 else 0.0
    sy = 2.0 / (h - 1) if h > 1 else 0.0
    mask = table.shape[0] - 1
    n_lut = GAMMA_LUT_SIZE
    lut = np.empty(n_lut + 2)  # x^gamma on a regular grid of [0, 1] (linear interpolation: error < 4e-4)
    for j in range(n_lut + 1):
        lut[j] = (j / n_lut) ** gamma
    lut[n_lut + 1] = 1.0
    amp = np.empty(n_lut + 2)  # noise sqrt(0.25 + x) on the same grid
    for j in range(n_lut + 2):
        amp[j] = noise * math.sqrt(0.25 + min(j / n_lut, 1.0))
    for r in range(h):
        yy = (-1.0 + r * sy) ** 2
        for c in range(w):
            xx = (-1.0 + c * sx) ** 2
            fall = 1 - vignetting * 0.5 * (xx + yy)
            for ch in range(3):
                v = np.float64(img[r, c, ch])
                if photometric:
                    v = min(max(v * gain[ch] * fall + bias, 0.0), 1.0)
                    if gamma != 1.0:
                        pos = v * n_lut
                        j = int(pos)
                        v = lut[j] + (pos - j) * (lut[j + 1] - lut[j])
                if noise > 0:
                    pos = min(max(v, 0.0), 1.0) * n_lut
                    j = int(pos)
                    v += (amp[j] + (pos - j) * (amp[j + 1] - amp[j])) * table[(offset + (ch * h + r) * w + c) & mask]
                out[ch, r, c] = min(max(v, 0.0), 1.0)


@numba.njit(cache=True)
def project(points, R, t, K, dist, pix_out, z_out):  # pragma: no cover - compiled
    """``Camera.project``: world points :math:`(N, 3)` to pixels (OpenCV distortion ``dist`` (5,), zeros = none)
    and depths."""
    k1, k2, p1, p2, k3 = dist[0], dist[1], dist[2], dist[3], dist[4]
    distorted = k1 != 0 or k2 != 0 or p1 != 0 or p2 != 0 or k3 != 0
    for i in range(points.shape[0]):
        x, y, zz = points[i, 0], points[i, 1], points[i, 2]
        xc = R[0, 0] * x + R[0, 1] * y + R[0, 2] * zz + t[0]
        yc = R[1, 0] * x + R[1, 1] * y + R[1, 2] * zz + t[1]
        zc = R[2, 0] * x + R[2, 1] * y + R[2, 2] * zz + t[2]
        zs = zc if abs(zc) > 1e-12 else 1e-12
        xn, yn = xc / zs, yc / zs
        if distorted:
            r2 = xn * xn + yn * yn
            radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
            xd = xn * radial + 2 * p1 * xn * yn + p2 * (r2 + 2 * xn * xn)
            yd = yn * radial + p1 * (r2 + 2 * yn * yn) + 2 * p2 * xn * yn
        else:
            xd, yd = xn, yn
        pix_out[i, 0] = K[0, 0] * xd + K[0, 1] * yd + K[0, 2]
        pix_out[i, 1] = K[1, 1] * yd + K[1, 2]
        z_out[i] = zc


@numba.njit(cache=True)
def ground_truth_maps(w, h, ids_l, depth_l, corr, z_r, hidden_l, ids_r, depth_r, corr_l, z_l, spec_l, spec2_l,
                      fb_l, fb_r, limit, rectified, spec_threshold, disp, valid, disp_r, valid_r, occlusion, depth,
                      specular, correspondence):  # pragma: no cover - compiled
    """Per-pixel ground truth of ``pair._ground_truth`` from the projections of each view's surface points
    into the other camera (``corr``, ``z_r``: left points in the right camera; ``corr_l``, ``z_l``: right points
    in the left camera) and the hidden flags of the left points seen from the right camera."""
    for i in range(h * w):
        x = float(i % w)
        hit = ids_l[i] >= 0
        d = x - corr[i, 0]
        ok = hit and z_r[i] > 0 and fb_l <= limit * depth_l[i] and fb_r <= limit * z_r[i]
        if rectified:
            ok = ok and d > 0
        valid[i] = ok
        disp[i] = d if ok else 0.0
        correspondence[0, i] = corr[i, 0] if ok else 0.0
        correspondence[1, i] = corr[i, 1] if ok else 0.0
        inside = (z_r[i] > 0 and corr[i, 0] >= -0.5 and corr[i, 0] <= w - 0.5 and corr[i, 1] >= -0.5
                  and corr[i, 1] <= h - 0.5)
        occlusion[i] = ok and not (inside and not hidden_l[i])
        depth[i] = depth_l[i] if hit else 0.0
        specular[i] = hit and (spec_l[i] > spec_threshold or spec2_l[i] > spec_threshold)
        dr = corr_l[i, 0] - x  # right-referenced: x_left = x_right + d_right
        ok = ids_r[i] >= 0 and z_l[i] > 0 and fb_r <= limit * depth_r[i] and fb_l <= limit * z_l[i]
        if rectified:
            ok = ok and dr > 0
        valid_r[i] = ok
        disp_r[i] = dr if ok else 0.0


@numba.njit(cache=True)
def edge_subsamples(edges, s):  # pragma: no cover - compiled
    """Flat indices :math:`(M,)` of the ``edges`` pixels and the pixel coordinates :math:`(M s^2, 2)` of their
    ``s x s`` sub-samples at offsets ``(k + 1/2) / s - 1/2`` (row-major within each pixel)."""
    h, w = edges.shape
    m = 0
    for r in range(h):
        for c in range(w):
            if edges[r, c]:
                m += 1
    index = np.empty(m, dtype=np.int64)
    pix = np.empty((m * s * s, 2))
    j = 0
    for r in range(h):
        for c in range(w):
            if edges[r, c]:
                index[j] = r * w + c
                for a in range(s):
                    for b in range(s):
                        q = (j * s + a) * s + b
                        pix[q, 0] = c + (b + 0.5) / s - 0.5
                        pix[q, 1] = r + (a + 0.5) / s - 0.5
                j += 1
    return index, pix


@numba.njit(cache=True)
def pixel_dirs(M, pix):  # pragma: no cover - compiled
    """Directions ``M (x, y, 1)`` :math:`(N, 3)` of the rays through pixel coordinates ``pix`` :math:`(N, 2)`."""
    out = np.empty((pix.shape[0], 3))
    for i in range(pix.shape[0]):
        for j in range(3):
            out[i, j] = M[j, 0] * pix[i, 0] + M[j, 1] * pix[i, 1] + M[j, 2]
    return out


@numba.njit(cache=True)
def finish_image(rgb, index, sub_rgb, s2, out):  # pragma: no cover - compiled
    """``out`` :math:`(H, W, 3)` float32 = ``rgb`` :math:`(H W, 3)` with pixels ``index`` replaced by the mean of
    their ``s2`` sub-sample radiances ``sub_rgb`` :math:`(M s2, 3)`, clipped to [0, 1]."""
    h, w = out.shape[0], out.shape[1]
    for i in range(index.shape[0]):
        for c in range(3):
            acc = 0.0
            for q in range(i * s2, (i + 1) * s2):
                acc += sub_rgb[q, c]
            rgb[index[i], c] = acc / s2
    for r in range(h):
        for col in range(w):
            i = r * w + col
            for c in range(3):
                out[r, col, c] = min(max(rgb[i, c], 0.0), 1.0)
