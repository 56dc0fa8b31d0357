"""data_gen's pieces for active sensors: light sequences, point-source shadows, boxes, flat materials, the
directional light strength, and the camera factory (look_at, Camera.pinhole, relative_to, (*, 3) projection)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

import data_gen
from data_gen import Camera, Material


def _sampled(seed: int = 3, difficulty: int = 3, rectified: bool = False):
    rng = np.random.default_rng(seed)
    rig = data_gen.sample_rig(rng, 40, 56, rectified=rectified, distortion=not rectified)
    return rig, data_gen.sample_scene(rng, difficulty, rig, data_gen.default_max_disp(difficulty, 56))


@pytest.mark.parametrize("supersample", [1, 2])
def test_render_sequence_is_render_view_per_light(supersample):
    rig, scene = _sampled()
    f = [lambda p, n, i: 0.3 * torch.sin(p.sum(-1) * 0.05) ** 2,
         lambda p, n, i: torch.stack([0.2 * n[:, 0].abs(), 0.1 * (i % 2), 0.05 + 0 * p[:, 0]], -1)]
    grey = data_gen.render_sequence(scene, rig.left, lambda p, n, i: torch.stack([f[0](p, n, i), 2 * f[0](p, n, i)], 1),
                                    supersample, dtype=torch.float64)
    assert grey["images"].shape == (2, 3, 40, 56)
    for k, scale in enumerate((1, 2)):
        ref = data_gen.render_view(scene, rig.left, supersample, extra_light_fn=lambda p, n, i, c=scale: c * f[0](p, n, i),
                                   dtype=torch.float64, compiled=False)
        assert torch.equal(grey["images"][k], ref["image"])
        for key in ("depth", "ids", "points", "normals", "edges"):
            assert torch.equal(grey[key], ref[key])
    rgb = data_gen.render_sequence(scene, rig.left, lambda p, n, i: f[1](p, n, i)[:, None], supersample)
    ref = data_gen.render_view(scene, rig.left, supersample, extra_light_fn=f[1], compiled=False)
    assert torch.equal(rgb["images"][0], ref["image"])
    off = data_gen.render_sequence(scene, rig.left, None, supersample)
    assert torch.equal(off["images"][0], data_gen.render_view(scene, rig.left, supersample, compiled=False)["image"])


def test_light_strength_scales_the_directional_term():
    rig, scene = _sampled(difficulty=1, rectified=True)
    compiled = data_gen.render_view(scene, rig.left, 1, specular=False)["image"]
    same = data_gen.render_view(_with(scene, light_strength=1 - scene.ambient), rig.left, 1, specular=False)["image"]
    torch.testing.assert_close(same, compiled, atol=1e-5, rtol=0)  # torch path, same lighting as the kernels
    dark = data_gen.render_view(_with(scene, light_strength=0.0), rig.left, 1, specular=False)["image"]
    assert float(dark.max()) <= scene.ambient + 1e-6  # ambient light only: albedo (<= 1) times ambient
    assert bool((dark <= same + 1e-6).all()) and float((same - dark).max()) > 0.1


def _with(scene, **fields):
    from dataclasses import replace

    return replace(scene, **fields)


@pytest.mark.parametrize("seed", [0, 1])
def test_visible_from_point_kernel_matches_reference_and_camera_visibility(seed):
    rig, scene = _sampled(seed, difficulty=4, rectified=bool(seed))
    view = data_gen.render_view(scene, rig.left, 1, dtype=torch.float64)
    pts = view["points"][view["ids"].reshape(-1) >= 0]
    src = rig.right.center
    fast = data_gen.visible_from_point(scene, src, pts, compiled=True)
    ref = data_gen.visible_from_point(scene, src, pts, compiled=False)
    assert torch.equal(fast, ref) and 0.05 < float(fast.float().mean()) < 1.0  # some points are shadowed
    # seen from the right camera = lit from its centre, for the points inside its image
    pix, z = rig.right.project(pts)
    w, h = rig.right.size
    inside = (z > 0) & (pix[:, 0] >= -0.5) & (pix[:, 0] <= w - 0.5) & (pix[:, 1] >= -0.5) & (pix[:, 1] <= h - 0.5)
    assert torch.equal(data_gen.visible_from(scene, rig.right, pts)[inside], fast[inside])


def test_box_faces_give_the_box_surface():
    lo, hi = np.array([-0.3, -0.2, 1.5]), np.array([0.2, 0.4, 2.1])
    scene = data_gen.Scene(data_gen.box_faces(lo, hi, Material.flat((0.5, 0.5, 0.5))))
    assert len(scene.objects) == 6
    g = torch.Generator().manual_seed(0)
    origin = torch.tensor([0.1, -0.1, 0.0], dtype=torch.float64)
    dirs = torch.cat([torch.rand(400, 2, generator=g, dtype=torch.float64) - 0.5,
                      torch.ones(400, 1, dtype=torch.float64)], 1)
    hits = data_gen.raycast(scene, origin, dirs)
    # slab method: the entry parameter of each ray into the box
    inv = 1.0 / dirs
    ta, tb = (torch.as_tensor(lo) - origin) * inv, (torch.as_tensor(hi) - origin) * inv
    t_near, t_far = torch.minimum(ta, tb).amax(-1), torch.maximum(ta, tb).amin(-1)
    inside = t_near < t_far
    assert 0.1 < float(inside.float().mean()) < 0.9
    assert torch.equal(hits.ids >= 0, inside)
    torch.testing.assert_close(hits.t[inside], t_near[inside])
    p = hits.points[inside]
    on_face = torch.isclose(p, torch.as_tensor(lo), atol=1e-9) | torch.isclose(p, torch.as_tensor(hi), atol=1e-9)
    assert on_face.any(-1).all()
    cam = Camera.pinhole(60.0, 48, 36)  # the compiled kernels take the faces too
    assert torch.equal(data_gen.render_view(scene, cam, 2)["ids"], data_gen.render_view(scene, cam, 2, compiled=False)["ids"])
    with pytest.raises(ValueError, match="hi"):
        data_gen.box_faces(hi, lo)


def test_flat_material_is_its_colour():
    m = Material.flat((0.2, 0.5, 0.7), texel_mm=3.0)
    albedo = m.albedo(torch.rand(5, 2, dtype=torch.float64) * 100)
    torch.testing.assert_close(albedo, torch.tensor([0.2, 0.5, 0.7], dtype=torch.float64).expand(5, 3))
    assert m.texel_mm == 3.0


def test_look_at_and_pinhole_factory():
    R, t = data_gen.look_at((0.0, 0.0, 0.0), (0.0, 0.0, 5.0))
    np.testing.assert_allclose(R, np.eye(3), atol=1e-15)
    cam = Camera.pinhole(100.0, 64, 48, eye=(0.3, -0.2, 0.1), target=(0.0, 0.1, 2.0))
    np.testing.assert_allclose(cam.K, [[100.0, 0.0, 31.5], [0.0, 100.0, 23.5], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(cam.center, [0.3, -0.2, 0.1], atol=1e-15)
    np.testing.assert_allclose(cam.R @ cam.R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(cam.R) == pytest.approx(1.0)
    pts = torch.tensor([[0.0, 0.1, 2.0], [0.0, -0.4, 2.0], [0.5, 0.1, 2.0]], dtype=torch.float64)
    pix, z = cam.project(pts)
    torch.testing.assert_close(pix[0], torch.tensor([31.5, 23.5], dtype=torch.float64))  # the target: centre
    assert pix[1, 1] < 23.5 and pix[2, 0] > 31.5  # world up (-y) at the top, world +x on the right
    assert bool((z > 0).all())
    plain = Camera.pinhole(80.0, 40, 30, eye=(0.2, 0.0, 0.0))
    np.testing.assert_allclose(plain.R, np.eye(3))
    np.testing.assert_allclose(plain.t, [-0.2, 0.0, 0.0])
    with pytest.raises(ValueError, match="target"):
        data_gen.look_at((1.0, 2.0, 3.0), (1.0, 2.0, 3.0))
    with pytest.raises(ValueError, match="up"):
        data_gen.look_at((0.0, 0.0, 0.0), (0.0, 3.0, 0.0))


def test_relative_pose_and_batched_projection():
    a = Camera.pinhole(100.0, 64, 48, eye=(0.3, -0.2, 0.1), target=(0.0, 0.1, 2.0))
    b = Camera.pinhole(90.0, 64, 48, eye=(-0.4, 0.1, 0.3), target=(0.2, 0.0, 2.5))
    R, t = a.relative_to(b)
    X = torch.rand(2, 7, 3, dtype=torch.float64) + torch.tensor([0.0, 0.0, 2.0], dtype=torch.float64)
    in_b, in_a = b.to_camera(X), a.to_camera(X)
    torch.testing.assert_close(in_b @ torch.as_tensor(R).T + torch.as_tensor(t), in_a)
    pix, z = a.project(X)  # any leading shape, the same numbers as (N, 3)
    pix_flat, z_flat = a.project(X.reshape(-1, 3))
    assert pix.shape == (2, 7, 2) and z.shape == (2, 7)
    assert torch.equal(pix.reshape(-1, 2), pix_flat) and torch.equal(z.reshape(-1), z_flat)
    dirs = a.ray_dirs(pix_flat[:, 0], pix_flat[:, 1])  # back through the pixels: camera z = 1, towards X
    centre = torch.as_tensor(a.center)
    torch.testing.assert_close(a.to_camera(centre + dirs)[:, 2], torch.ones(14, dtype=torch.float64))
    torch.testing.assert_close(centre + dirs * z_flat[:, None], X.reshape(-1, 3))
