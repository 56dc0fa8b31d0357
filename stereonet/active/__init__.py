"""Active stereo: structured light, laser stripe scanning, and aligning range scans.

* :mod:`stereonet.active.scene` / :mod:`~stereonet.active.render` — a small vectorized ray-caster (pinhole
  cameras, planes, spheres, boxes, procedural albedo) and a renderer with pluggable emitters (projector, laser).
* :mod:`stereonet.active.structured_light` — random-dot, Gray-code and phase-shift patterns; decoding with
  invalid-pixel detection; camera + projector depth; active vs passive stereo pairs.
* :mod:`stereonet.active.datagen_bridge` — the same projector on data_gen's rigs and scenes.
* :mod:`stereonet.active.laser` — laser-sheet sweep, sub-pixel stripe peaks, ray ∩ plane triangulation.
* :mod:`stereonet.active.icp` — point-to-point / point-to-plane ICP, multi-scan alignment, merging.
* :mod:`stereonet.active.triangulate` — the ray ∩ light-plane maths both sensors share.
* ``python -m stereonet.active.demo structured-light|laser|align -o OUT`` — runnable examples.
"""

from stereonet.active.icp import ICPResult, align_scans, icp, merge_scans, rotation_error_deg
from stereonet.active.laser import laser_scan, stripe_peaks, sweep_planes
from stereonet.active.scene import PinholeCamera, Scene, raycast
from stereonet.active.structured_light import (
    coded_light_scan,
    decode_gray_code,
    decode_phase_shift,
    gray_code_patterns,
    phase_shift_patterns,
    random_dot_pattern,
    render_active_pair,
    unwrap_phase,
)
from stereonet.active.triangulate import ray_plane_depth

__all__ = [
    "ICPResult", "PinholeCamera", "Scene", "align_scans", "coded_light_scan", "decode_gray_code",
    "decode_phase_shift", "gray_code_patterns", "icp", "laser_scan", "merge_scans", "phase_shift_patterns",
    "random_dot_pattern", "ray_plane_depth", "raycast", "render_active_pair", "rotation_error_deg",
    "stripe_peaks", "sweep_planes", "unwrap_phase",
]
