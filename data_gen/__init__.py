"""data_gen: procedurally rendered synthetic stereo pairs with exact ground truth.

Main entry points
-----------------
* :func:`render_pair` ``(seed, index, difficulty=2, height=256, width=512, rectified=True, supersample=2, ...)``
  -> dict (images, disparities, occlusion/specular masks, depth, correspondences, calibration); a pure function
  of ``(seed, index)`` and its options. Ground truth comes from one ray through each pixel centre (exact
  there); images use the same ray inside surfaces (textures mip-filtered to the pixel footprint) and
  ``supersample x supersample`` rays on object boundaries and normal creases. Keyword options switch off
  noise / photometric differences / blur / speculars without changing the scene, and ``occlusion_right=True``
  adds the right-view occlusion mask.
* :class:`SyntheticStereo` ``(count, seed=0, difficulty=2, height=256, width=512, ...)`` — a torch Dataset
  rendering on the fly; use :func:`collate` with a DataLoader (``Calibration`` objects are kept in lists).
* :data:`MAX_DIFFICULTY` — the curriculum runs 0 (few fronto-parallel textured planes, small disparity, clean)
  to MAX_DIFFICULTY (many slanted/curved objects, disparity up to 192 at width 512, hard textures, speculars,
  photometric differences). Disparity ranges scale with the image width and stay below ``width / 2``.
* ``python -m data_gen --out DIR --count N --seed S [--difficulty K] [--unrectified]`` writes the Middlebury
  2014 layout; ``python -m data_gen --bench`` measures pairs per second on one core.

Building blocks (for other renderers, e.g. active stereo with a projector)
------------------------------------------------------------------------
Units are millimetres; the left camera is the world frame.

* :class:`Camera` ``(K, R, t, size=(width, height), dist=None)`` — pinhole, ``X_cam = R X + t``, OpenCV
  distortion ``(k1, k2, p1, p2, k3)``; ``project(points (*, 3)) -> (pixels (*, 2), depth (*))``,
  ``center``, ``ray_dirs(x, y)``, ``grid_rays(supersample)``, ``relative_to(other)``;
  ``Camera.pinhole(focal, width, height, eye, target=None, up=(0, -1, 0))`` with :func:`look_at`. The same
  model as :mod:`stereonet.geometry.camera` (tested equal), and the cameras of :mod:`stereonet.active`.
* :func:`sample_rig` ``(rng, height, width, rectified=True, baseline=None, distortion=None)`` -> :class:`Rig`
  (``left``, ``right`` cameras, ``baseline``).
* :func:`sample_scene` ``(rng, difficulty, rig, max_disp, num_objects=None)`` -> :class:`Scene`
  (``objects``: primitives :class:`Plane`, :class:`PlanarPatch`, :class:`Sphere`, :class:`Cylinder`, each with a
  :class:`Material`; ``light_dir``; ``ambient``; ``light_strength``). Objects can also be built by hand:
  ``Scene([Plane(...), *box_faces(lo, hi), ...])``.
* :func:`raycast` ``(scene, origins (N, 3) | (3,), dirs (N, 3))`` -> :class:`RayHits`
  ``(t (N,), ids (N,), points (N, 3), normals (N, 3), uv (N, 2))``; ``t = inf``, ``ids = -1`` on a miss;
  :func:`albedo_of_hits` ``(scene, hits, dirs)`` -> albedo (N, 3) of those hits. :func:`raycast_grid` /
  :func:`surface_fields` do the same for a camera's whole pixel grid (each object tested only inside its
  projected bounding box).
* :func:`visible_from` ``(scene, camera, points)`` -> bool (N,): seen by the camera (shadow/occlusion tests,
  e.g. whether a projector illuminates a point); :func:`visible_from_point` ``(scene, source, points)``: lit
  by a point source (no frustum).
* :func:`shade` ``(scene, ids, points, normals, albedo, eye, specular=True, extra_light_fn=None)`` and
  :func:`render_view` ``(scene, camera, supersample=2, specular=True, extra_light_fn=None)`` -> dict with
  ``image (3, H, W)`` and centre-ray ``depth``, ``ids``, ``points``, ``normals``, ``specular``.
  ``extra_light_fn(points (N, 3), normals (N, 3), ids (N,)) -> (N,) | (N, 3)`` is extra irradiance added to
  the diffuse term (multiplied by the albedo): a projector pattern is ``pattern(projector.project(points))``
  times ``max(0, n . l_p)``, masked by ``visible_from(scene, projector, points)``.
  :func:`render_sequence` ``(scene, camera, lights_fn, ...)`` renders P such lights at once
  (``lights_fn -> (N, P)``; ``images (P, 3, H, W)``), tracing the rays once.
* :func:`apply_camera_response` (blur, vignetting, gain/bias/gamma, noise) and :class:`Material`
  ``.albedo(uv)`` (textures: dead-leaves, 1/f noise, Voronoi bank textures; stripes, grids, checkers, weak,
  flat; ``Material.flat(color)``).

Speed: :func:`render_view` and :func:`visible_from` run compiled numba kernels (:mod:`data_gen._kernels`,
float64): an object-by-object z-buffer over each object's pixel box, one shading pass over the winning hits,
numba edge detection and supersampling of the edge pixels, ground truth and the camera response fused per
pixel (:func:`render_view_arrays` skips the torch conversions). ``compiled=False`` (or
``data_gen.render.USE_KERNELS = False``) selects the vectorized torch reference they are tested against. An
``extra_light_fn`` always uses the torch path. Rendering runs torch single-threaded; parallelize over pairs
(DataLoader workers). ``python -m data_gen --bench``: 10.4-11.0 pairs/s per core at 256x512 (difficulty 4, 14.5
objects, 2x supersampling; idle machine), ~50 at 128x256 (measured at load 4).
"""

from data_gen.camera import Camera, GridRays, PointRays, look_at
from data_gen.dataset import SyntheticStereo, collate
from data_gen.pair import apply_camera_response, calibration_of, render_pair
from data_gen.primitives import Cylinder, PlanarPatch, Plane, Primitive, Sphere, box_faces
from data_gen.render import (
    RayHits,
    albedo_of_hits,
    raycast,
    raycast_grid,
    render_sequence,
    render_view,
    render_view_arrays,
    shade,
    specular_radiance,
    surface_fields,
    visible_from,
    visible_from_point,
)
from data_gen.scene import (
    DIFFICULTY,
    MAX_DIFFICULTY,
    Rig,
    Scene,
    check_difficulty,
    default_max_disp,
    sample_rig,
    sample_scene,
)
from data_gen.textures import Material

__all__ = [
    "DIFFICULTY", "MAX_DIFFICULTY", "Camera", "Cylinder", "GridRays", "Material", "PlanarPatch", "Plane",
    "PointRays", "Primitive", "RayHits", "Rig", "Scene", "Sphere", "SyntheticStereo", "albedo_of_hits",
    "apply_camera_response", "box_faces", "specular_radiance", "surface_fields",
    "calibration_of", "check_difficulty", "collate", "default_max_disp", "look_at", "raycast", "raycast_grid",
    "render_pair", "render_sequence", "render_view", "render_view_arrays", "sample_rig", "sample_scene", "shade",
    "visible_from", "visible_from_point",
]
