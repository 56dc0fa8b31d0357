"""Active stereo: structured light, laser stripes, and aligning range scans — rendered through data_gen.

Cameras and projectors are :class:`data_gen.Camera` s (``Camera.pinhole(focal, width, height, eye, target)``),
scenes are data_gen scenes, and every image comes from data_gen's renderer with the active light sources
added as emitters (data_gen light functions: projector patterns, laser sheets) and data_gen's shadow tests.

* :mod:`stereonet.active.scenes` — seeded room-corner scenes of data_gen primitives and materials
  (textureless / repetitive / textured) and a rectified rig with a projector.
* :mod:`stereonet.active.render` — camera captures under an emitter's states, range scans.
* :mod:`stereonet.active.structured_light` — random-dot, Gray-code and phase-shift patterns; the projector
  emitter; decoding with invalid-pixel detection; camera + projector depth; active vs passive stereo pairs.
* :mod:`stereonet.active.datagen_bridge` — the same projector on data_gen's sampled rigs and scenes.
* :mod:`stereonet.active.laser` — laser-sheet emitter and sweep, sub-pixel stripe peaks, ray ∩ plane
  triangulation.
* :mod:`stereonet.active.icp` — point-to-point / point-to-plane ICP, multi-scan alignment, merging.
* :mod:`stereonet.active.triangulate` — the ray ∩ light-plane maths both sensors share.
* ``python -m stereonet.active.demo structured-light|laser|align -o OUT`` — runnable examples.
"""

from stereonet.active.icp import ICPResult, align_scans, icp, merge_scans, rotation_error_deg
from stereonet.active.laser import laser_scan, stripe_peaks, sweep_planes
from stereonet.active.render import render_captures, render_range_scan
from stereonet.active.scenes import make_rig, make_scene
from stereonet.active.structured_light import (
    coded_light_scan,
    decode_gray_code,
    decode_phase_shift,
    gray_code_patterns,
    phase_shift_patterns,
    projector_light,
    random_dot_pattern,
    render_active_pair,
    unwrap_phase,
)
from stereonet.active.triangulate import ray_plane_depth

__all__ = [
    "ICPResult", "align_scans", "coded_light_scan", "decode_gray_code", "decode_phase_shift",
    "gray_code_patterns", "icp", "laser_scan", "make_rig", "make_scene", "merge_scans", "phase_shift_patterns",
    "projector_light", "random_dot_pattern", "ray_plane_depth", "render_active_pair", "render_captures",
    "render_range_scan", "rotation_error_deg", "stripe_peaks", "sweep_planes", "unwrap_phase",
]
