"""Scene and rig sampling: the difficulty curriculum, random rigs (rectified or not) and random scenes.

Units are millimetres. The left camera is the world frame. Scenes are laid out in *disparity space* of the
left camera (``d = f B / z``): every plane is an affine function of the pixel coordinates there, which makes it
easy to keep every ground-truth disparity inside ``[0, max_disp]``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np
import torch

from data_gen.camera import Camera, PointRays
from data_gen.primitives import Cylinder, PlanarPatch, Plane, Primitive, Sphere
from data_gen.textures import BANK_COUNT, Material

MAX_DIFFICULTY = 4
REFERENCE_WIDTH = 512  # disparity ranges below are for this width and scale linearly with the image width

# One row per difficulty level. max_disp at REFERENCE_WIDTH; objects = (min, max) count; slant in degrees;
# kinds = probabilities of (patch, sphere, cylinder); textures = probabilities over Material kinds;
# photometric = strength of per-camera gain/bias/gamma differences; noise = sensor noise std; blur = max
# Gaussian sigma (pixels); walls = probabilities of (floor, side wall); spec = probability of a shiny object;
# texel_px = texel size range in pixels; size = object radius range as a fraction of min(H, W); spread = range
# of object centres as a fraction of the image size.
DIFFICULTY: list[dict] = [
    dict(max_disp=32, objects=(2, 4), slant=0.0, kinds=(1.0, 0.0, 0.0), bg_slope=0.0, walls=(0.0, 0.0),
         textures=dict(bank=0.6, bank_mix=0.4), spec=0.0, photometric=0.0, noise=0.002, blur=0.0,
         texel_px=(1.0, 2.5), shapes=("rectangle", "ellipse"), size=(0.12, 0.35), spread=(0.1, 0.9)),
    dict(max_disp=64, objects=(3, 6), slant=35.0, kinds=(0.8, 0.2, 0.0), bg_slope=0.4, walls=(0.3, 0.0),
         textures=dict(bank=0.45, bank_mix=0.35, stripes=0.08, grid=0.06, checker=0.06), spec=0.0,
         photometric=0.02, noise=0.004, blur=0.3, texel_px=(0.9, 2.5),
         shapes=("rectangle", "ellipse", "polygon", "blob"), size=(0.06, 0.3), spread=(0.0, 1.0)),
    dict(max_disp=96, objects=(5, 10), slant=60.0, kinds=(0.6, 0.25, 0.15), bg_slope=0.7, walls=(0.5, 0.3),
         textures=dict(bank=0.35, bank_mix=0.3, stripes=0.08, grid=0.06, checker=0.06, weak=0.1, flat=0.05),
         spec=0.15, photometric=0.05, noise=0.006, blur=0.5, texel_px=(0.8, 3.0),
         shapes=("rectangle", "ellipse", "polygon", "blob"), size=(0.04, 0.3), spread=(-0.1, 1.1)),
    dict(max_disp=128, objects=(8, 14), slant=70.0, kinds=(0.55, 0.25, 0.2), bg_slope=0.9, walls=(0.5, 0.4),
         textures=dict(bank=0.3, bank_mix=0.25, stripes=0.1, grid=0.07, checker=0.05, weak=0.15, flat=0.08),
         spec=0.3, photometric=0.1, noise=0.01, blur=0.7, texel_px=(0.7, 3.5),
         shapes=("rectangle", "ellipse", "polygon", "blob"), size=(0.04, 0.3), spread=(-0.1, 1.1)),
    dict(max_disp=192, objects=(10, 20), slant=80.0, kinds=(0.5, 0.25, 0.25), bg_slope=1.2, walls=(0.6, 0.5),
         textures=dict(bank=0.25, bank_mix=0.2, stripes=0.14, grid=0.08, checker=0.06, weak=0.17, flat=0.1),
         spec=0.4, photometric=0.15, noise=0.015, blur=0.9, texel_px=(0.6, 4.0),
         shapes=("rectangle", "ellipse", "polygon", "blob"), size=(0.04, 0.3), spread=(-0.1, 1.1)),
]


def check_difficulty(difficulty: object) -> int:
    """Return ``difficulty`` as an int in ``0..MAX_DIFFICULTY`` or raise naming the parameter."""
    if isinstance(difficulty, bool) or not isinstance(difficulty, int | np.integer):
        raise TypeError(f"difficulty: expected an integer in 0..{MAX_DIFFICULTY}, got {difficulty!r}")
    if not 0 <= int(difficulty) <= MAX_DIFFICULTY:
        raise ValueError(f"difficulty: expected an integer in 0..{MAX_DIFFICULTY}, got {difficulty}")
    return int(difficulty)


def check_probability(value: object, name: str) -> float:
    """``value`` as a float in [0, 1] or a ValueError naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating) \
            or not 0.0 <= float(value) <= 1.0:
        raise ValueError(f"{name}: expected a probability in [0, 1], got {value!r}")
    return float(value)


def check_textures(textures: object) -> dict[str, float] | None:
    """``textures`` (a render option): None (the difficulty's mix) or ``{kind: weight}`` over
    :data:`~data_gen.textures.TEXTURE_KINDS`, weights finite and >= 0, at least one > 0; returned as a plain
    dict of floats. Anything else is a ValueError naming the option."""
    from data_gen.textures import TEXTURE_KINDS

    if textures is None:
        return None
    expected = f"expected None or a dict {{kind: weight}} over {TEXTURE_KINDS} with weights >= 0, not all 0"
    if not isinstance(textures, dict) or not textures:
        raise ValueError(f"textures: {expected}, got {textures!r}")
    out = {}
    for kind, weight in textures.items():
        if kind not in TEXTURE_KINDS or isinstance(weight, bool) or not isinstance(weight, int | float) \
                or not math.isfinite(weight) or weight < 0:
            raise ValueError(f"textures: {expected}, got {textures!r}")
        out[kind] = float(weight)
    if sum(out.values()) <= 0:
        raise ValueError(f"textures: {expected}, got {textures!r}")
    return out


def texture_mix(difficulty: int, without: tuple[str, ...] | list[str] = ()) -> dict[str, float]:
    """The texture mix of a difficulty level less the kinds in ``without`` (a value for the ``textures`` render
    option; e.g. ``without=("weak", "flat")``: every surface textured)."""
    return {k: w for k, w in DIFFICULTY[check_difficulty(difficulty)]["textures"].items() if k not in without}


def default_max_disp(difficulty: int, width: int) -> int:
    """Disparity range of a difficulty level, scaled with the image width and kept below ``width / 2``."""
    d = DIFFICULTY[check_difficulty(difficulty)]["max_disp"] * width / REFERENCE_WIDTH
    return int(max(2, min(round(d), (width - 1) // 2)))


@dataclass
class Rig:
    """Two cameras: ``left`` (the world frame, R = I, t = 0) and ``right`` (``X_r = R X_l + t``)."""

    left: Camera
    right: Camera
    baseline: float
    rectified: bool

    @property
    def focal(self) -> float:
        return float(self.left.K[0, 0])


@dataclass
class Scene:
    """A renderable scene.

    Attributes:
        objects: primitives; an object's id is its index here (background walls come first).
        light_dir: unit vector from surfaces towards a directional light :math:`(3,)`.
        ambient: ambient fraction of the Lambertian term in [0, 1].
        max_disp: disparity bound the scene was built for (left camera, ``f B / z``).
        light_strength: irradiance of the directional light on a surface facing it; None (the sampled scenes)
            means ``1 - ambient``, so that a fully lit face receives 1. Other values render on the torch path.
    """

    objects: list[Primitive]
    light_dir: np.ndarray = field(default_factory=lambda: np.array([0.0, -0.5, -1.0]) / math.sqrt(1.25))
    ambient: float = 0.35
    max_disp: int = 0
    num_background: int = 1
    light_strength: float | None = None


def _rotation(axis_angle: np.ndarray) -> np.ndarray:
    theta = float(np.linalg.norm(axis_angle))
    if theta < 1e-15:
        return np.eye(3)
    k = axis_angle / theta
    Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(theta) * Kx + (1 - math.cos(theta)) * Kx @ Kx


def sample_rig(rng: np.random.Generator, height: int, width: int, rectified: bool = True,
               baseline: float | None = None, distortion: bool | None = None) -> Rig:
    """A random stereo rig; ``baseline`` in mm (random in [60, 300] if None).

    Rectified: identical K, R = I, t = (-B, 0, 0). Unrectified: a small random rotation (<= 2.5 deg),
    off-axis translation of length B, a different K2, and (``distortion`` True, or None with probability 1/2)
    radial distortion ``k1, k2`` on both cameras.
    """
    f = width * rng.uniform(0.8, 1.25)
    cx = (width - 1) / 2 + rng.uniform(-0.03, 0.03) * width
    cy = (height - 1) / 2 + rng.uniform(-0.03, 0.03) * height
    B = rng.uniform(60.0, 300.0) if baseline is None else float(baseline)
    K1 = np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])
    left = Camera(K1, np.eye(3), np.zeros(3), (width, height))
    if rectified:
        return Rig(left, Camera(K1.copy(), np.eye(3), np.array([-B, 0.0, 0.0]), (width, height)), B, True)
    axis = rng.normal(size=3)
    R = _rotation(axis / np.linalg.norm(axis) * math.radians(rng.uniform(0.5, 2.5)))
    c_r = np.array([1.0, rng.uniform(-0.06, 0.06), rng.uniform(-0.06, 0.06)])
    c_r *= B / np.linalg.norm(c_r)
    f2 = f * rng.uniform(0.95, 1.05)
    K2 = np.array([[f2, 0.0, cx + rng.uniform(-0.04, 0.04) * width],
                   [0.0, f2, cy + rng.uniform(-0.03, 0.03) * height], [0.0, 0.0, 1.0]])
    use_dist = bool(rng.random() < 0.5) if distortion is None else bool(distortion)
    d1 = np.array([rng.uniform(-0.12, 0.08), rng.uniform(-0.03, 0.03), 0.0, 0.0, 0.0])
    d2 = np.array([rng.uniform(-0.12, 0.08), rng.uniform(-0.03, 0.03), 0.0, 0.0, 0.0])
    left = Camera(K1, np.eye(3), np.zeros(3), (width, height), d1 if use_dist else None)
    right = Camera(K2, R, -R @ c_r, (width, height), d2 if use_dist else None)
    return Rig(left, right, B, False)


def disparity_plane(rig: Rig, alpha: float, beta: float, d_centre: float, roll: float,
                    material: Material) -> Plane:
    """The plane whose left disparity is ``d(x, y) = d_centre + alpha (x - cx) + beta (y - cy)``."""
    n, k = _disparity_plane_nk(rig, alpha, beta, d_centre)
    return Plane(n * k, n, roll=roll, material=material)


def _disparity_plane_nk(rig: Rig, alpha: float, beta: float, d_centre: float) -> tuple[np.ndarray, float]:
    """Unit normal ``n`` and offset ``k`` (plane ``n . X = k``, k > 0) of a left-camera disparity plane."""
    f = rig.left.K[0, 0]
    v = np.array([alpha * f, beta * f, d_centre])  # d = v . (xn, yn, 1)
    norm = float(np.linalg.norm(v))
    return v / norm, f * rig.baseline / norm  # plane n . X = k, depth z = f B / d


def _boundary_rays(camera: Camera, samples: int = 17) -> np.ndarray:
    """Undistorted normalized rays ``(xn, yn, 1)`` :math:`(4 samples, 3)` through the image border (pixel edges),
    cached on the camera."""
    key = ("boundary_rays", samples)
    if key not in camera._bbox_cache:
        camera._bbox_cache[key] = _compute_boundary_rays(camera, samples)
    return camera._bbox_cache[key]


def _compute_boundary_rays(camera: Camera, samples: int) -> np.ndarray:
    w, h = camera.size
    s = np.linspace(0.0, 1.0, samples)
    x = np.concatenate([-0.5 + w * s, np.full_like(s, w - 0.5), w - 0.5 - w * s, np.full_like(s, -0.5)])
    y = np.concatenate([np.full_like(s, -0.5), -0.5 + h * s, np.full_like(s, h - 0.5), h - 0.5 - h * s])
    xn, yn = camera.pixel_to_normalized(x, y)
    return np.stack([xn, yn, np.ones_like(xn)], axis=-1)


def plane_max_disparity(rig: Rig, n: np.ndarray, k: float) -> float:
    """Largest depth disparity ``f B / z`` of the plane ``n . X = k`` seen by either camera of ``rig``
    (each camera with its own focal length and depth), or inf when the right camera is not on the left
    camera's side of the plane (it would see the plane's back, and everything in front of it hidden).

    Inverse depth ``1 / z`` of a plane is affine in undistorted normalized coordinates, so its maximum over an
    image lies on the image border (sampled densely, through the distortion).
    """
    side_left = -k  # n . 0 - k
    worst = 0.0
    for cam in (rig.left, rig.right):
        n_c = cam.R @ n  # plane in the camera frame: n_c . X_c = k_c
        k_c = k + float(n_c @ cam.t)
        side = float(n @ cam.center) - k
        if side * side_left <= 0 or abs(k_c) < 1e-12:
            return math.inf
        inv_z = _boundary_rays(cam) @ n_c / k_c
        worst = max(worst, float(cam.K[0, 0]) * rig.baseline * float(inv_z.max()))
    return worst


def fit_disparity_plane(rig: Rig, alpha: float, beta: float, d_centre: float, limit: float
                        ) -> tuple[float, float, float]:
    """Scale a disparity plane ``(alpha, beta, d_centre)`` (moving the 3D plane away, parallel to itself)
    until both cameras see it with disparity ``f B / z <= limit``; returns the (possibly unchanged) plane.

    The scaled plane ``s v`` is ``n . X = k / s``: its disparity in every camera on the left camera's side
    grows monotonically with s, so bisection finds the largest admissible scale.
    """
    n, k = _disparity_plane_nk(rig, alpha, beta, d_centre)
    if plane_max_disparity(rig, n, k) <= limit:
        return alpha, beta, d_centre
    lo, hi = 0.0, 1.0
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        if mid > 0 and plane_max_disparity(rig, n, k / mid) <= limit:
            lo = mid
        else:
            hi = mid
    return alpha * lo, beta * lo, d_centre * lo


def _pick(rng: np.random.Generator, weights) -> int:
    """Index drawn with probability proportional to ``weights`` (one uniform draw; ``rng.choice`` with ``p``
    costs ~50 us)."""
    u = rng.random() * sum(weights)
    acc = 0.0
    for i, w in enumerate(weights):
        acc += w
        if u < acc:
            return i
    return len(weights) - 1


def _choice(rng: np.random.Generator, probs: dict[str, float]) -> str:
    names = list(probs)
    return names[_pick(rng, [probs[n] for n in names])]


WEAK_BACKGROUND_FACTOR = (0.05, 0.5)
"""Range (log-uniform) of the factor on the background walls' texture contrast in a :func:`weaken_background` scene."""


def weaken_background(scene: Scene, rng: np.random.Generator, probability: float) -> None:
    """With ``probability``, weaken the texture of the scene's background walls (in place).

    In the sampled scenes every surface is textured alike, so at a depth edge neither side's texture dominates a
    window that straddles it: 27-48 % of ``sgm``'s errors near depth edges are the foreground fattened into the
    background on render sets, 63 % on the six photos (thirty-first session, docs/experiments/edge_fattening.py). In
    photos objects often stand in front of weaker-textured surfaces (walls, road, sky), whose windows the
    foreground's texture and silhouette dominate; with every scene's walls weakened here, that share rises by 13-17
    points. Every background wall's texture contrast is multiplied by one factor,
    log-uniform in :data:`WEAK_BACKGROUND_FACTOR` (a weak texture, not none). Geometry, lights and every other draw
    of the scene are unchanged (``rng`` should be a stream of its own).
    """
    probability = check_probability(probability, "weak_background")
    if probability == 0.0 or rng.random() >= probability:
        return
    lo, hi = WEAK_BACKGROUND_FACTOR
    factor = math.exp(rng.uniform(math.log(lo), math.log(hi)))
    for wall in scene.objects[:scene.num_background]:
        wall.material = dataclasses.replace(wall.material, contrast=wall.material.contrast * factor)


THIN_COUNT = (1, 6)
"""Range (uniform integers) of the number of rods an :func:`add_thin_structures` scene gets."""
THIN_RADIUS_PX = (0.5, 3.0)
"""Range (log-uniform) of a rod's radius in left-image pixels at its centre's depth."""
THIN_LENGTH = (0.15, 0.8)
"""Range (log-uniform) of a rod's length as a fraction of ``min(H, W)`` in left-image pixels."""


def add_thin_structures(scene: Scene, rng: np.random.Generator, rig: Rig, level: dict, max_disp: int,
                        probability: float) -> None:
    """With ``probability``, add a few thin rods to the scene (in place): poles, branches, cables, legs.

    The sampled objects are blobs, polygons, spheres and cylinders whose radius is >= 4 % of the image's smaller
    side, so a surface narrower than a matching window is rare in the renders (a narrow or steeply slanted patch
    now and then); photos are full of them (lamp arms, chair legs, poles and signs, branches, wires), and there
    a matcher that has never seen one paints the background across it. Each rod is a solid
    :class:`~data_gen.primitives.Cylinder` with a radius of :data:`THIN_RADIUS_PX` pixels and a length of
    :data:`THIN_LENGTH` of the image's smaller side (both at its centre's depth), its axis at any angle in the
    image plane (tilted out of it by up to ~27 degrees), its centre in front of the back wall at a disparity
    drawn as the objects' are, textured with a material of the level. :data:`THIN_COUNT` rods per scene. Both
    cameras' disparity bounds hold as for every object (bounding sphere; a rod pushed back to fit keeps its
    size in pixels). Everything already in the scene is unchanged (``rng`` should be a stream of its own); the
    rods are appended after the objects.
    """
    probability = check_probability(probability, "thin_structures")
    if probability == 0.0 or rng.random() >= probability:
        return
    W, H = rig.left.size
    f, cx, cy = float(rig.left.K[0, 0]), float(rig.left.K[0, 2]), float(rig.left.K[1, 2])
    back = scene.objects[0]
    for _ in range(int(rng.integers(THIN_COUNT[0], THIN_COUNT[1] + 1))):
        x = rng.uniform(*level["spread"]) * W
        y = rng.uniform(*level["spread"]) * H
        ray = np.array([(x - cx) / f, (y - cy) / f, 1.0])
        z_wall = float(back.intersect(PointRays(np.zeros(3), torch.as_tensor(ray)[None]))[0])  # t = z on this ray
        d_wall = f * rig.baseline / z_wall if 0.0 < z_wall < math.inf else 0.0
        d_lo = min(d_wall * 1.15 + 0.02 * max_disp, 0.9 * max_disp)
        z = f * rig.baseline / rng.uniform(d_lo, max_disp)
        r_px = math.exp(rng.uniform(math.log(THIN_RADIUS_PX[0]), math.log(THIN_RADIUS_PX[1])))
        length_px = math.exp(rng.uniform(math.log(THIN_LENGTH[0]), math.log(THIN_LENGTH[1]))) * min(H, W)
        angle = rng.uniform(0.0, math.pi)
        axis = np.array([math.cos(angle), math.sin(angle), rng.uniform(-0.5, 0.5)])
        size = math.hypot(r_px, 0.5 * length_px) / f  # bounding radius per unit depth (pixel sizes kept)
        for _ in range(8):  # pushed back to fit both bounds, at the same size in pixels (converges: size << 1)
            z_fit = _min_centre_depth(rig, ray, size * z, max_disp)
            if z_fit <= z:
                break
            z = z_fit
        radius, half = r_px * z / f, 0.5 * length_px * z / f
        z = max(z, _min_centre_depth(rig, ray, math.hypot(radius, half), max_disp))  # the bound, strictly
        mat = sample_material(rng, level, z / f)
        scene.objects.append(Cylinder(z * ray, axis, radius, half, roll=rng.uniform(0, 2 * math.pi), material=mat))


def sample_material(rng: np.random.Generator, level: dict, texel_mm_per_px: float) -> Material:
    """A random material for a surface where one pixel covers ``texel_mm_per_px`` scene units."""
    kind = _choice(rng, level["textures"])
    sat = rng.uniform(0.0, 1.0) ** 1.5
    hue0, hue1 = rng.random(3), rng.random(3)
    grey0, grey1 = rng.uniform(0.0, 0.35), rng.uniform(0.6, 1.0)
    c0 = (1 - sat) * grey0 + sat * hue0 * grey0 * 2
    c1 = (1 - sat) * grey1 + sat * (0.4 + 0.6 * hue1) * grey1
    c2 = rng.uniform(-0.5, 0.5, 3) * rng.uniform(0.2, 1.0)
    lo, hi = level["texel_px"]
    texel_px = math.exp(rng.uniform(math.log(lo), math.log(hi)))
    mat = Material(kind=kind, colors=np.stack([c0, c1, c2]), texel_mm=texel_px * texel_mm_per_px,
                   angle=rng.uniform(0, 2 * math.pi), offset=tuple(rng.uniform(0, 256, 2)),
                   bank=(int(rng.integers(BANK_COUNT)), int(rng.integers(BANK_COUNT))),
                   scale2=math.exp(rng.uniform(math.log(1.7), math.log(5.0))),
                   period=rng.uniform(3.0, 24.0) / texel_px * math.exp(rng.uniform(0, 1)),
                   duty=rng.uniform(0.08, 0.3))
    if kind == "weak":
        mat.contrast = rng.uniform(0.02, 0.08)
    elif kind == "flat":
        mat.contrast = 0.0
    if rng.random() < level["spec"]:
        mat.specular = rng.uniform(0.3, 0.9)
        mat.shininess = math.exp(rng.uniform(math.log(20.0), math.log(200.0)))
    return mat


def _sample_background(rng: np.random.Generator, rig: Rig, level: dict,
                       max_disp: int) -> tuple[list[Primitive], tuple[float, float, float]]:
    """Background walls (back wall first) and the back wall's disparity plane ``(alpha, beta, d_centre)``."""
    W, H = rig.left.size
    d_c = max_disp * rng.uniform(0.05, 0.3)
    slope = level["bg_slope"]
    ax, ay = rng.uniform(-1, 1, 2) * slope * d_c / W
    # keep the wall's disparity >= d_c / 4 over the image extended by half its size each side (the right
    # camera sees a shifted and rotated window), and <= max_disp / 2 inside the image
    ext = np.array([[x, y] for x in (-W, W) for y in (-H, H)], dtype=np.float64)
    lowest = d_c + (ext @ np.array([ax, ay])).min()
    if lowest < d_c / 4:
        shrink = (d_c * 0.75) / (d_c - lowest)
        ax, ay = ax * shrink, ay * shrink
    ax, ay, d_c = fit_disparity_plane(rig, ax, ay, d_c, max_disp)
    mm_per_px = rig.baseline / d_c  # at depth z = f B / d_c one pixel covers z / f = B / d_c
    walls: list[Primitive] = [disparity_plane(rig, ax, ay, d_c, rng.uniform(0, 2 * math.pi),
                                              sample_material(rng, level, mm_per_px))]
    cy = rig.left.K[1, 2]
    cx = rig.left.K[0, 2]
    if rng.random() < level["walls"][0]:  # floor: disparity grows downwards from a horizon row
        horizon = rng.uniform(0.15, 0.6) * H
        d_bottom = max_disp * rng.uniform(0.3, 0.8)
        beta = d_bottom / (H - 0.5 - horizon)
        alpha = rng.uniform(-0.1, 0.1) * d_bottom / W
        d_centre = beta * (cy - horizon)
        alpha, beta, d_centre = fit_disparity_plane(rig, alpha, beta, d_centre, max_disp)
        walls.append(disparity_plane(rig, alpha, beta, d_centre, rng.uniform(0, 2 * math.pi),
                                     sample_material(rng, level, rig.baseline / (0.5 * d_bottom))))
    if rng.random() < level["walls"][1]:  # side wall: disparity grows towards one image side
        side = 1.0 if rng.random() < 0.5 else -1.0
        x_v = cx + side * rng.uniform(0.1, 0.4) * W
        d_edge = max_disp * rng.uniform(0.3, 0.7)
        alpha = side * d_edge / (abs((cx + side * W / 2) - x_v) + 1.0)
        beta = rng.uniform(-0.1, 0.1) * d_edge / H
        d_centre = alpha * (cx - x_v)
        alpha, beta, d_centre = fit_disparity_plane(rig, alpha, beta, d_centre, max_disp)
        walls.append(disparity_plane(rig, alpha, beta, d_centre, rng.uniform(0, 2 * math.pi),
                                     sample_material(rng, level, rig.baseline / (0.5 * d_edge))))
    return walls, (ax, ay, d_c)


def _blob_radii(rng: np.random.Generator, n: int = 64) -> np.ndarray:
    theta = np.arange(n) * (2 * math.pi / n)
    r = np.ones(n)
    for k in range(1, 6):
        r += rng.uniform(0, 0.35) / k * np.cos(k * theta + rng.uniform(0, 2 * math.pi))
    r = np.clip(r, 0.2, None)
    return r / r.max()


def _min_centre_depth(rig: Rig, ray: np.ndarray, radius: float, max_disp: int) -> float:
    """Smallest left depth z of a bounding sphere of ``radius`` centred at ``z ray`` (ray = (xn, yn, 1)) whose
    every point has depth disparity ``f B / z_cam <= max_disp`` in both cameras (each with its own focal
    length): ``z_cam(centre) - radius >= f_cam B / max_disp``."""
    z = 0.0
    for cam in (rig.left, rig.right):
        z_min = float(cam.K[0, 0]) * rig.baseline / max_disp * (1 + 1e-6)
        rz = float(cam.R[2] @ ray)  # z_cam(z ray) = z rz + t_z
        if rz <= 1e-3:
            raise ValueError("rig: an object ray points away from the right camera; rotation too large")
        z = max(z, (z_min + radius - float(cam.t[2])) / rz)
    return z


def _sample_object(rng: np.random.Generator, rig: Rig, level: dict, max_disp: int,
                   back: tuple[float, float, float]) -> Primitive:
    W, H = rig.left.size
    K = rig.left.K
    f, cx, cy = K[0, 0], K[0, 2], K[1, 2]
    B = rig.baseline
    x = rng.uniform(*level["spread"]) * W
    y = rng.uniform(*level["spread"]) * H
    d_wall = back[2] + back[0] * (x - cx) + back[1] * (y - cy)
    d_lo = min(max(d_wall, 0.0) * 1.15 + 0.02 * max_disp, 0.9 * max_disp)
    d = rng.uniform(d_lo, max_disp)
    z = f * B / d
    r_px = math.exp(rng.uniform(math.log(level["size"][0]), math.log(level["size"][1]))) * min(H, W)
    radius = r_px * z / f
    ray = np.array([(x - cx) / f, (y - cy) / f, 1.0])
    z = max(z, _min_centre_depth(rig, ray, radius, max_disp))
    centre = z * ray
    mat = sample_material(rng, level, z / f)
    kind = ("patch", "sphere", "cylinder")[_pick(rng, level["kinds"])]
    roll = rng.uniform(0, 2 * math.pi)
    if kind == "sphere":
        return Sphere(centre, radius, axis=rng.normal(size=3), roll=roll, material=mat)
    if kind == "cylinder":
        axis = rng.normal(size=3)
        cyl_r = radius * rng.uniform(0.25, 0.55)
        half = math.sqrt(max(radius ** 2 - cyl_r ** 2, 1e-12)) * rng.uniform(0.5, 1.0)
        return Cylinder(centre, axis, cyl_r, half, roll=roll, material=mat)
    tilt = math.radians(rng.uniform(0, level["slant"]))
    az = rng.uniform(0, 2 * math.pi)
    normal = np.array([math.sin(tilt) * math.cos(az), math.sin(tilt) * math.sin(az), -math.cos(tilt)])
    shape = level["shapes"][int(rng.integers(len(level["shapes"])))]
    scale = (radius, radius * rng.uniform(0.35, 1.0))
    if shape == "rectangle":
        a = rng.uniform(0.3, 1.2)
        return PlanarPatch(centre, normal, scale, "polygon", roll, angles=np.array([a, math.pi - a, math.pi + a, -a]),
                           material=mat)
    if shape == "polygon":
        k = int(rng.integers(3, 9))
        angles = (np.arange(k) + rng.uniform(-0.2, 0.2, k)) * (2 * math.pi / k) + rng.uniform(0, 2 * math.pi)
        return PlanarPatch(centre, normal, scale, "polygon", roll, angles=angles, material=mat)
    if shape == "blob":
        return PlanarPatch(centre, normal, scale, "blob", roll, radii=_blob_radii(rng), material=mat)
    return PlanarPatch(centre, normal, scale, "ellipse", roll, material=mat)


# What an object copies from its donor under :func:`share_materials`: its look (colours, texture kind and bank,
# contrast, pattern, shininess); it keeps its own texel size, angle and offset (another phase of the same stuff)
SHARED_LOOK = ("kind", "colors", "bank", "scale2", "contrast", "period", "duty", "specular", "shininess")


def share_materials(scene: Scene, rng: np.random.Generator, probability: float) -> None:
    """Give each object, with ``probability``, the look of the surface behind it (in place).

    In the sampled scenes every surface has its own random material, so every depth edge is also an edge of
    colour and texture statistics, a cue that a network can learn to place depth edges by; in photos objects
    often stand in front of surfaces of the same colour and material. The donor is the nearest other surface
    behind the object's centre on the left camera's ray through it (the back wall when the ray meets none);
    the object takes its colours, texture kind and bank, contrast, pattern and specular terms
    (:data:`SHARED_LOOK`) and keeps its own texel size, angle and offset, so the edge shows the same material
    in another phase rather than a continued texture. Geometry, lights and every other draw of the scene are
    unchanged (``rng`` should be a stream of its own).
    """
    probability = check_probability(probability, "shared_material")
    if probability == 0.0:
        return
    looks = [obj.material for obj in scene.objects]  # donors keep the look they were sampled with
    for i in range(scene.num_background, len(scene.objects)):
        if rng.random() >= probability:
            continue
        centre = scene.objects[i].bounding_sphere()[0]
        ray = PointRays(np.zeros(3), torch.as_tensor(centre, dtype=torch.float64)[None])  # t = 1 at the centre
        behind = [(float(obj.intersect(ray)[0]), k) for k, obj in enumerate(scene.objects) if k != i]
        _, donor = min(((t, k) for t, k in behind if 1.0 < t < math.inf), default=(0.0, 0))
        scene.objects[i].material = dataclasses.replace(looks[i], **{k: getattr(looks[donor], k) for k in SHARED_LOOK})


def sample_scene(rng: np.random.Generator, difficulty: int, rig: Rig, max_disp: int,
                 num_objects: int | None = None, textures: dict[str, float] | None = None) -> Scene:
    """A random scene for ``rig``: background walls plus objects, all disparities in ``(0, max_disp]``.

    Both cameras are bounded: every object's bounding sphere has depth ``z_cam >= f_cam B / max_disp`` in each
    camera, and walls are moved back (parallel to themselves) until both images see them within the range,
    with the right camera on the left camera's side of every wall.

    Args:
        rng: numpy Generator (the only source of randomness).
        difficulty: 0..MAX_DIFFICULTY (see ``DIFFICULTY``).
        rig: from :func:`sample_rig`; max_disp: disparity bound in pixels (left camera).
        num_objects: objects in front of the background (default: random in the level's range), >= 1.
        textures: ``{kind: weight}`` instead of the level's texture mix (:func:`check_textures`; None = the
            level's). Every other choice is the level's; the random stream differs once a kind that draws more
            (``weak``'s contrast) is chosen differently.
    """
    level = DIFFICULTY[check_difficulty(difficulty)]
    textures = check_textures(textures)
    if textures is not None:
        level = {**level, "textures": textures}
    if num_objects is None:
        num_objects = int(rng.integers(level["objects"][0], level["objects"][1] + 1))
    elif isinstance(num_objects, bool) or not isinstance(num_objects, int | np.integer) or num_objects < 1:
        raise ValueError(f"num_objects: expected an integer >= 1, got {num_objects!r}")
    walls, back = _sample_background(rng, rig, level, max_disp)
    objects = [_sample_object(rng, rig, level, max_disp, back) for _ in range(num_objects)]
    az = rng.uniform(-0.6, 0.6)
    light = np.array([az, -rng.uniform(0.2, 1.0), -rng.uniform(0.6, 1.2)])
    ambient = rng.uniform(0.45, 0.6) if difficulty == 0 else rng.uniform(0.2, 0.5)
    return Scene(walls + objects, light / np.linalg.norm(light), ambient, max_disp, num_background=len(walls))
