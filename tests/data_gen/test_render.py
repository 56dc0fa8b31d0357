"""Ground truth of data_gen proven on rendered pairs: warping, occlusion, depth, epipolar geometry, determinism."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import torch
import torch.nn.functional as F

import data_gen
from data_gen.textures import Material

H, W = 96, 160
CLEAN = dict(noise=False, photometric=False, blur=False, specular=False)


def warp_right_to_left(right: torch.Tensor, disp: torch.Tensor) -> torch.Tensor:
    """Sample ``right`` (C, H, W) at ``x - disp`` (1, H, W), bilinear."""
    _, h, w = right.shape
    ys, xs = torch.meshgrid(torch.arange(h, dtype=torch.float32), torch.arange(w, dtype=torch.float32), indexing="ij")
    grid = torch.stack([(xs - disp[0]) / (w - 1) * 2 - 1, ys / (h - 1) * 2 - 1], dim=-1)  # HxWx2
    return F.grid_sample(right[None], grid[None], align_corners=True)[0]


def near_discontinuity(disp: torch.Tensor, jump: float = 1.0) -> torch.Tensor:
    d = disp[0]
    edge = torch.zeros_like(d, dtype=torch.bool)
    gx = (d[:, 1:] - d[:, :-1]).abs() > jump
    gy = (d[1:] - d[:-1]).abs() > jump
    edge[:, 1:] |= gx
    edge[:, :-1] |= gx
    edge[1:] |= gy
    edge[:-1] |= gy
    return edge


def lr_check_failure(disp: torch.Tensor, disp_right: torch.Tensor, tol: float = 1.0) -> torch.Tensor:
    d = disp[0]
    h, w = d.shape
    xr = torch.round(torch.arange(w).expand(h, w) - d).long()
    inside = (xr >= 0) & (xr < w)
    dr = disp_right[0].gather(1, xr.clamp(0, w - 1))
    return ~inside | ((d - dr).abs() > tol)


@pytest.mark.parametrize("difficulty", [0, 2, 4])
def test_warp_right_to_left_reproduces_left(difficulty):
    p = data_gen.render_pair(5, 0, difficulty=difficulty, height=H, width=W, **CLEAN)
    assert p["left"].shape == (3, H, W) and p["left"].dtype == torch.float32
    mask = (p["valid"] & ~p["occlusion"] & ~p["specular"])[0] & ~near_discontinuity(p["disparity"])
    assert mask.float().mean() > 0.5
    err = (warp_right_to_left(p["right"], p["disparity"]) - p["left"]).abs().mean(0)[mask]
    wrong = (warp_right_to_left(p["right"], p["disparity"] + 1.5) - p["left"]).abs().mean(0)[mask]
    assert err.mean() < 0.02
    assert torch.quantile(err, 0.9) < 0.05
    assert wrong.mean() > 3 * err.mean()


@pytest.mark.parametrize("seed,difficulty", [(1, 1), (2, 3), (3, 4)])
def test_occlusion_mask_is_lr_check_failure(seed, difficulty):
    p = data_gen.render_pair(seed, 0, difficulty=difficulty, height=H, width=W, **CLEAN)
    valid = p["valid"][0]
    occ = p["occlusion"][0]
    assert occ.any() and (~occ).any()
    lr_fail = lr_check_failure(p["disparity"], p["disparity_right"])
    agree = (lr_fail == occ)[valid].float().mean()
    assert agree > 0.98
    # disagreements only where the rounding of the LR check meets a depth edge
    off = (lr_fail != occ) & valid
    assert (off & ~near_discontinuity(p["disparity"], 0.5) & ~near_discontinuity(p["disparity_right"], 0.5)
            ).float().mean() < 0.01


def test_right_occlusion_is_the_mirrored_lr_check():
    p = data_gen.render_pair(2, 1, difficulty=3, height=H, width=W, occlusion_right=True, **CLEAN)
    occ_r = p["occlusion_right"][0]
    assert occ_r.dtype == torch.bool and occ_r.any()
    # mirror the pair: the right view becomes a left-referenced view of the flipped images
    lr_fail = lr_check_failure(p["disparity_right"].flip(-1), p["disparity"].flip(-1)).flip(-1)
    valid = p["valid_right"][0]
    assert (lr_fail == occ_r)[valid].float().mean() > 0.98
    assert "occlusion_right" not in data_gen.render_pair(2, 1, difficulty=0, height=32, width=64)


def test_depth_is_f_b_over_disparity_and_disparity_in_range():
    for difficulty in range(data_gen.MAX_DIFFICULTY + 1):
        p = data_gen.render_pair(7, difficulty, difficulty=difficulty, height=H, width=W)
        calib = p["calib"]
        assert calib.is_rectified()
        v = p["valid"]
        assert v.float().mean() > 0.99
        d, z = p["disparity"][v].double(), p["depth"][v].double()
        torch.testing.assert_close(z * d, torch.full_like(z, calib.focal * calib.baseline), rtol=1e-4, atol=0)
        assert p["max_disp"] == data_gen.default_max_disp(difficulty, W) < W / 2
        assert float(d.min()) > 0 and float(d.max()) <= p["max_disp"] + 1e-3


def test_difficulty_zero_is_fronto_parallel_and_scales_with_width():
    p = data_gen.render_pair(3, 0, difficulty=0, height=H, width=W)
    d = p["disparity"][p["valid"]]
    distinct = torch.unique(torch.round(d * 100))
    assert len(distinct) <= len(p["scene"].objects)  # one constant disparity per plane
    assert data_gen.default_max_disp(data_gen.MAX_DIFFICULTY, 512) == 192
    assert data_gen.default_max_disp(data_gen.MAX_DIFFICULTY, 256) == 96
    assert data_gen.default_max_disp(0, 512) < data_gen.default_max_disp(2, 512)


@pytest.mark.parametrize("distortion", [False, True])
def test_unrectified_correspondences_satisfy_epipolar_constraint(distortion):
    p = data_gen.render_pair(11, 0, difficulty=2, height=H, width=W, rectified=False, distortion=distortion)
    c = p["calib"]
    assert not c.is_rectified()
    assert (c.dist1 is not None) == distortion
    seen = (p["valid"] & ~p["occlusion"])[0]
    ys, xs = torch.nonzero(seen, as_tuple=True)
    x1 = torch.stack([xs, ys], -1).double().numpy()
    x2 = p["correspondence"][:, seen].T.double().numpy()
    K1, K2, R, t = (a.numpy() for a in (c.K1, c.K2, c.R, c.t))
    if distortion:  # undistort with OpenCV's model and the written coefficients
        x1 = cv2.undistortPoints(x1[:, None], K1, c.dist1.numpy(), P=K1)[:, 0]
        x2 = cv2.undistortPoints(x2[:, None], K2, c.dist2.numpy(), P=K2)[:, 0]
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    Fm = np.linalg.inv(K2).T @ tx @ R @ np.linalg.inv(K1)
    h1 = np.concatenate([x1, np.ones((len(x1), 1))], 1)
    h2 = np.concatenate([x2, np.ones((len(x2), 1))], 1)
    lines = h1 @ Fm.T  # epipolar lines in the right image
    dist = np.abs((h2 * lines).sum(1)) / np.linalg.norm(lines[:, :2], axis=1)
    assert len(dist) > 0.5 * H * W
    assert np.median(dist) < 1e-3 and dist.max() < 2e-2
    # a wrong pose is detected by the same test
    R_wrong = cv2.Rodrigues(np.array([0.0, 0.02, 0.0]))[0] @ R
    lines_w = h1 @ (np.linalg.inv(K2).T @ tx @ R_wrong @ np.linalg.inv(K1)).T
    assert np.median(np.abs((h2 * lines_w).sum(1)) / np.linalg.norm(lines_w[:, :2], axis=1)) > 0.1


def test_same_seed_and_index_give_the_same_pair_in_any_order():
    a = data_gen.render_pair(4, 2, difficulty=3, height=48, width=96)
    data_gen.render_pair(4, 1, difficulty=3, height=48, width=96)
    b = data_gen.render_pair(4, 2, difficulty=3, height=48, width=96)
    c = data_gen.render_pair(4, 3, difficulty=3, height=48, width=96)
    for key in ("left", "right", "disparity", "occlusion"):
        assert torch.equal(a[key], b[key])
    assert not torch.equal(a["left"], c["left"])


def test_dataset_workers_match_and_collate():
    ds = data_gen.SyntheticStereo(4, seed=9, difficulty=1, height=32, width=64)
    serial = [ds[i] for i in range(len(ds))]
    loader = torch.utils.data.DataLoader(ds, batch_size=2, num_workers=2, collate_fn=data_gen.collate)
    batches = list(loader)
    assert batches[0]["left"].shape == (2, 3, 32, 64)
    assert batches[0]["valid"].dtype == torch.bool and batches[0]["occlusion"].shape == (2, 1, 32, 64)
    assert isinstance(batches[0]["calib"], list) and isinstance(batches[0]["name"], list)
    for b, batch in enumerate(batches):
        for j in range(2):
            item = serial[2 * b + j]
            assert batch["name"][j] == item["name"]
            assert torch.equal(batch["left"][j], item["left"])
            assert torch.equal(batch["disparity"][j], item["disparity"])
    assert ds[-1]["name"] == serial[-1]["name"]
    with pytest.raises(IndexError, match="index"):
        ds[4]


@pytest.mark.parametrize("kwargs,param", [
    (dict(baseline=-10.0), "baseline"),
    (dict(max_disp=200), "max_disp"),
    (dict(max_disp=80), "max_disp"),
    (dict(num_objects=0), "num_objects"),
    (dict(difficulty=7), "difficulty"),
    (dict(difficulty="hard"), "difficulty"),
    (dict(height=0), "height"),
    (dict(supersample=0), "supersample"),
    (dict(shared_material=1.5), "shared_material"),
    (dict(shared_material="often"), "shared_material"),
    (dict(weak_background=-0.5), "weak_background"),
    (dict(thin_structures=1.5), "thin_structures"),
    (dict(thin_structures=float("nan")), "thin_structures"),
    (dict(textures={"marble": 1.0}), "textures"),
    (dict(textures={"bank": -1.0}), "textures"),
    (dict(textures={"bank": 0.0}), "textures"),
    (dict(textures=["bank"]), "textures"),
])
def test_bad_input_names_the_parameter(kwargs, param):
    args = dict(seed=0, index=0, height=H, width=W)
    args.update(kwargs)
    with pytest.raises((ValueError, TypeError), match=param):
        data_gen.render_pair(**args)
    if param != "height":
        with pytest.raises((ValueError, TypeError), match=param):
            data_gen.SyntheticStereo(2, height=H, width=W, **{k: v for k, v in kwargs.items()})


def test_raycast_and_visibility_on_a_hand_built_scene():
    wall = data_gen.Plane([0, 0, 5000], [0, 0, 1], material=Material(kind="flat"))
    ball = data_gen.Sphere([0, 0, 1000], 100.0)
    scene = data_gen.Scene([wall, ball])
    dirs = torch.tensor([[0.0, 0.0, 1.0], [0.5, 0.0, 1.0]], dtype=torch.float64)
    hits = data_gen.raycast(scene, torch.zeros(3, dtype=torch.float64), dirs)
    torch.testing.assert_close(hits.t, torch.tensor([900.0, 5000.0], dtype=torch.float64))
    assert hits.ids.tolist() == [1, 0]
    torch.testing.assert_close(hits.normals[0], torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64))
    torch.testing.assert_close(hits.points[1], torch.tensor([2500.0, 0.0, 5000.0], dtype=torch.float64))
    cam = data_gen.Camera(np.array([[100.0, 0, 50], [0, 100.0, 50], [0, 0, 1]]), np.eye(3), np.zeros(3), (101, 101))
    pts = torch.tensor([[0.0, 0.0, 5000.0], [1500.0, 0.0, 5000.0], [0.0, 0.0, 900.0], [3000.0, 0.0, 5000.0]],
                       dtype=torch.float64)  # behind the ball, beside it, on it, outside the image
    assert data_gen.visible_from(scene, cam, pts).tolist() == [False, True, True, False]
    # an extra light term (a projector) brightens the image where it shines
    base = data_gen.render_view(scene, cam, supersample=1)["image"]
    lit = data_gen.render_view(scene, cam, supersample=1,
                               extra_light_fn=lambda p, n, ids: (p[:, 0] > 0).to(p.dtype) * 0.3)["image"]
    assert torch.all(lit[:, :, 60:] >= base[:, :, 60:]) and torch.equal(lit[:, :, :40], base[:, :, :40])


def test_shared_material_gives_an_object_the_look_of_the_surface_behind_it():
    """A patch in front of a ball in front of a wall, and a ball off to the side: with probability 1 the patch
    takes the ball's look (the nearest surface behind its centre), the side ball the wall's; each keeps its own
    texel size, angle and offset; probability 0 changes nothing and draws nothing."""
    from data_gen.scene import SHARED_LOOK, share_materials

    def looks():
        wall = data_gen.Plane([0, 0, 5000], [0, 0, 1], material=Material(kind="checker", colors=np.full((3, 3), 0.2)))
        ball = data_gen.Sphere([0, 0, 2000], 300.0, material=Material(kind="stripes", period=5.0, specular=0.5))
        patch = data_gen.PlanarPatch([0, 0, 1000], [0, 0, -1], (50.0, 50.0),
                                     material=Material(kind="bank", texel_mm=3.0, angle=1.0, offset=(4.0, 2.0)))
        side = data_gen.Sphere([1500, 0, 3000], 100.0, material=Material(kind="flat", texel_mm=7.0))
        return data_gen.Scene([wall, ball, patch, side], num_background=1)

    scene = looks()
    wall, ball, patch, side = (o.material for o in scene.objects)
    rng = np.random.default_rng(0)
    share_materials(scene, rng, 0.0)
    assert all(o.material is m for o, m in zip(scene.objects, (wall, ball, patch, side)))
    assert rng.random() == np.random.default_rng(0).random()  # nothing drawn at 0
    share_materials(scene, np.random.default_rng(0), 1.0)
    for obj, donor, own in ((scene.objects[2], ball, patch), (scene.objects[3], wall, side)):
        for key in SHARED_LOOK:
            assert np.array_equal(getattr(obj.material, key), getattr(donor, key)), key
        assert (obj.material.texel_mm, obj.material.angle, obj.material.offset) == (own.texel_mm, own.angle, own.offset)
    assert scene.objects[0].material is wall
    assert scene.objects[1].material.kind == "checker"  # the ball took the wall's look, the patch the ball's own
    with pytest.raises(ValueError, match="shared_material"):
        share_materials(scene, rng, -0.1)


def test_shared_material_changes_the_images_only_and_zero_is_the_default_pair():
    plain = data_gen.render_pair(11, 0, difficulty=2, height=H, width=W, supersample=1)
    zero = data_gen.render_pair(11, 0, difficulty=2, height=H, width=W, supersample=1, shared_material=0.0)
    shared = data_gen.render_pair(11, 0, difficulty=2, height=H, width=W, supersample=1, shared_material=1.0)
    for key in ("left", "right", "disparity", "valid", "occlusion"):
        assert torch.equal(plain[key], zero[key]), key
    for key in ("disparity", "disparity_right", "valid", "occlusion", "depth"):
        assert torch.equal(plain[key], shared[key]), key  # same geometry, lights and cameras
    moved = (plain["left"] - shared["left"]).abs().amax(0) > 0.02
    assert 0.02 < float(moved.float().mean()) < 0.9  # the objects changed, not the whole image
    assert data_gen.SyntheticStereo(1, seed=11, difficulty=2, height=H, width=W, supersample=1,
                                    shared_material=1.0)[0]["left"].equal(shared["left"])


def test_cylinder_and_patch_intersections_match_closed_form():
    cyl = data_gen.Cylinder([0, 0, 1000], [0, 1, 0], radius=50.0, half_length=80.0)
    patch = data_gen.PlanarPatch([0, 0, 500], [0, 0, -1], (30.0, 10.0), "polygon",
                                 angles=np.array([0.5, math.pi - 0.5, math.pi + 0.5, -0.5]))
    scene = data_gen.Scene([cyl, patch])
    dirs = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.079, 1.0], [0.0, 0.2, 1.0], [0.02, 0.05, 1.0]], dtype=torch.float64)
    hits = data_gen.raycast(scene, torch.zeros(3, dtype=torch.float64), dirs)
    assert hits.ids.tolist() == [1, 0, -1, 0]  # patch, cylinder side, miss, cylinder above the patch
    assert math.isclose(hits.t[0], 500.0) and math.isclose(hits.t[1], 950.0, rel_tol=1e-9)
    assert math.isinf(hits.t[2])


def test_camera_effects_change_the_images_not_the_scene():
    clean = data_gen.render_pair(6, 0, difficulty=4, height=H, width=W, **CLEAN)
    real = data_gen.render_pair(6, 0, difficulty=4, height=H, width=W)
    assert torch.equal(clean["disparity"], real["disparity"]) and torch.equal(clean["occlusion"], real["occlusion"])
    mask = (clean["valid"] & ~clean["occlusion"] & ~clean["specular"])[0] & ~near_discontinuity(clean["disparity"])

    def warp_error(p):
        return (warp_right_to_left(p["right"], p["disparity"]) - p["left"]).abs().mean(0)[mask].mean()

    # per-camera gain/gamma/vignetting/noise/blur make the two views differ photometrically
    assert warp_error(real) > 2 * warp_error(clean)
    assert (real["left"] - clean["left"]).abs().mean() > 0.005


RANGE_TOL = 0.01  # relative slack on max_disp


@pytest.mark.parametrize("rectified,thin", [(True, 0.0), (False, 0.0), (True, 1.0), (False, 1.0)])
def test_both_disparity_maps_stay_in_range_over_many_scenes(rectified, thin):
    """Every surface lies in front of both cameras with f B / z <= max_disp (regression: objects near the
    right camera and side walls tilted past it gave right-view disparities in the thousands); 80 scenes, also
    with thin rods in every scene. Every pixel that sees a surface counts, not only the ones marked valid."""
    h, w = 24, 64
    for difficulty in range(data_gen.MAX_DIFFICULTY + 1):
        for index in range(8):
            p = data_gen.render_pair(3, index, difficulty=difficulty, height=h, width=w, rectified=rectified,
                                     supersample=1, noise=False, photometric=False, blur=False, thin_structures=thin)
            rig, md = p["rig"], p["max_disp"]
            hi = md * (1 + RANGE_TOL)
            v, vr = p["valid"], p["valid_right"]
            assert v.float().mean() > 0.9 and vr.float().mean() > 0.9, (difficulty, index)
            d, dr = p["disparity"][v], p["disparity_right"][vr]
            z_l = data_gen.render_view(p["scene"], rig.left, supersample=1)["depth"]
            z_r = data_gen.render_view(p["scene"], rig.right, supersample=1)["depth"]
            z_l, z_r = z_l[torch.isfinite(z_l)], z_r[torch.isfinite(z_r)]
            depth_disp = rig.left.K[0, 0] * rig.baseline / z_l.double()
            depth_disp_r = rig.right.K[0, 0] * rig.baseline / z_r.double()
            for name, x in (("left", depth_disp), ("right", depth_disp_r)):
                assert float(x.min()) > 0 and float(x.max()) <= hi, (name, difficulty, index, float(x.max()))
            if rectified:  # the disparities themselves are f B / z
                assert float(d.min()) > 0 and float(d.max()) <= hi, (difficulty, index)
                assert float(dr.min()) > 0 and float(dr.max()) <= hi, (difficulty, index)
            else:  # horizontal correspondence component: f B / z plus the rig's rotation / principal-point shift
                for x in (d, dr):
                    assert float(x.min()) > -0.25 * w and float(x.max()) <= hi + 0.25 * w, (difficulty, index)


def test_ground_truth_marks_unrepresentable_disparities_invalid():
    """A hand-made scene with a sphere far too close for max_disp: its pixels get no ground truth."""
    from data_gen.pair import _ground_truth

    rig = data_gen.sample_rig(np.random.default_rng(0), 32, 64)
    f, b = rig.focal, rig.baseline
    wall = data_gen.Plane([0, 0, f * b / 5], [0, 0, 1])
    near = data_gen.Sphere([0, 0, f * b / 40], f * b / 40 * 0.1)  # disparity ~44 > max_disp = 20
    scene = data_gen.Scene([wall, near], max_disp=20)
    views = [data_gen.render_view(scene, rig.left, 1, second_eye=rig.right.center),
             data_gen.render_view(scene, rig.right, 1)]
    gt = _ground_truth(scene, rig, views[0], views[1])
    on_ball = views[0]["ids"] == 1
    assert on_ball.any() and not gt["valid"][0][on_ball].any()
    assert gt["valid"][0][~on_ball].all() and float(gt["disparity"].max()) <= 20
    assert float(gt["disparity_right"][gt["valid_right"]].max()) <= 20


def test_textures_option_replaces_the_levels_mix():
    """``textures={kind: weight}`` draws every surface's kind from that mix (here: textured kinds only, as opposed
    to difficulty 4's weak and flat surfaces); None is the level's mix, the same pair as without the option; the
    option is in the pair's name, and SyntheticStereo passes it on."""
    from data_gen.scene import sample_scene

    textured = {"bank": 0.5, "bank_mix": 0.5}
    kinds, default_kinds = set(), set()
    for index in range(6):
        rng = np.random.default_rng(index)
        rig = data_gen.sample_rig(rng, H, W)
        state = rng.bit_generator.state
        scene = sample_scene(rng, 4, rig, 32, textures=textured)
        kinds |= {obj.material.kind for obj in scene.objects}
        rng.bit_generator.state = state
        default_kinds |= {obj.material.kind for obj in sample_scene(rng, 4, rig, 32).objects}
    assert kinds <= set(textured) and len(kinds) == 2
    assert default_kinds - set(textured)  # the level's own mix has other kinds on these scenes
    plain = data_gen.render_pair(3, 1, 2, height=H, width=W)
    same = data_gen.render_pair(3, 1, 2, height=H, width=W, textures=None)
    assert torch.equal(plain["left"], same["left"]) and plain["name"] == same["name"]
    tex = data_gen.render_pair(3, 1, 2, height=H, width=W, textures=textured)
    assert tex["name"] == plain["name"] + "_tbank0.5-bank_mix0.5"
    item = data_gen.SyntheticStereo(2, seed=3, difficulty=2, height=H, width=W, textures=textured)[1]
    assert item["name"] == tex["name"] and torch.equal(item["left"], tex["left"])


def test_weaken_background_scales_only_the_walls_contrast():
    """weaken_background: with probability 1 every background wall's texture contrast is multiplied by one factor
    in WEAK_BACKGROUND_FACTOR and the objects keep theirs; probability 0 draws nothing and changes nothing; a
    rendered pair keeps its geometry and its name gets the option."""
    from data_gen.scene import WEAK_BACKGROUND_FACTOR, weaken_background

    def scene():
        wall = data_gen.Plane([0, 0, 5000], [0, 0, 1], material=Material(kind="bank", contrast=0.8))
        floor = data_gen.Plane([0, 800, 0], [0, -1, 0], material=Material(kind="checker", contrast=1.0))
        ball = data_gen.Sphere([0, 0, 2000], 300.0, material=Material(kind="stripes", contrast=1.0))
        return data_gen.Scene([wall, floor, ball], num_background=2)

    s = scene()
    before = [o.material for o in s.objects]
    rng = np.random.default_rng(3)
    weaken_background(s, rng, 0.0)
    assert all(o.material is m for o, m in zip(s.objects, before))
    assert rng.random() == np.random.default_rng(3).random()  # nothing drawn at 0
    weaken_background(s, np.random.default_rng(3), 1.0)
    f0, f1 = s.objects[0].material.contrast / 0.8, s.objects[1].material.contrast / 1.0
    assert WEAK_BACKGROUND_FACTOR[0] <= f0 <= WEAK_BACKGROUND_FACTOR[1] and abs(f0 - f1) < 1e-12
    assert s.objects[2].material is before[2] and before[0].contrast == 0.8  # objects and the old materials untouched
    plain = data_gen.render_pair(11, 0, difficulty=2, height=H, width=W, supersample=1)
    weak = data_gen.render_pair(11, 0, difficulty=2, height=H, width=W, supersample=1, weak_background=1.0)
    zero = data_gen.render_pair(11, 0, difficulty=2, height=H, width=W, supersample=1, weak_background=0.0)
    assert torch.equal(zero["left"], plain["left"]) and zero["name"] == plain["name"]
    assert torch.equal(weak["disparity"], plain["disparity"]) and not torch.equal(weak["left"], plain["left"])
    assert weak["name"] == plain["name"] + "_w1"
    walls = weak["scene"].num_background
    for a, b in zip(plain["scene"].objects[:walls], weak["scene"].objects[:walls]):
        assert b.material.contrast <= a.material.contrast * WEAK_BACKGROUND_FACTOR[1] + 1e-12


def test_thin_structures_add_rods_in_front_of_what_they_cover():
    """add_thin_structures: probability 0 draws nothing; at 1 the scene keeps its objects and gets THIN_COUNT rods
    (cylinders at most THIN_RADIUS_PX across at their depth, inside both cameras' disparity bounds); every pixel
    whose disparity changes shows a nearer surface than before (a rod in front), the rods cover a small share of
    the view, and the name gets the option."""
    from data_gen.primitives import Cylinder
    from data_gen.scene import THIN_COUNT, THIN_LENGTH, THIN_RADIUS_PX, add_thin_structures

    plain = data_gen.render_pair(11, 0, difficulty=2, height=H, width=W, supersample=1)
    rng = np.random.default_rng(3)
    n = len(plain["scene"].objects)
    add_thin_structures(plain["scene"], rng, plain["rig"], data_gen.scene.DIFFICULTY[2], plain["max_disp"], 0.0)
    assert len(plain["scene"].objects) == n and rng.random() == np.random.default_rng(3).random()
    zero = data_gen.render_pair(11, 0, difficulty=2, height=H, width=W, supersample=1, thin_structures=0.0)
    assert torch.equal(zero["left"], plain["left"]) and zero["name"] == plain["name"]
    changed_any = False
    for seed in (11, 12, 13):
        base = data_gen.render_pair(seed, 0, difficulty=2, height=H, width=W, supersample=1)
        thin = data_gen.render_pair(seed, 0, difficulty=2, height=H, width=W, supersample=1, thin_structures=1.0)
        assert thin["name"] == base["name"] + "_r1"
        objs, rods = thin["scene"].objects[:len(base["scene"].objects)], thin["scene"].objects[len(base["scene"].objects):]
        assert [type(o) for o in objs] == [type(o) for o in base["scene"].objects]
        assert THIN_COUNT[0] <= len(rods) <= THIN_COUNT[1] and all(isinstance(r, Cylinder) for r in rods)
        f = thin["rig"].focal
        for rod in rods:  # pixel sizes kept when a rod is pushed back to fit the disparity bound
            r_px, length = rod.radius * f / rod.centre[2], 2 * rod.half_length * f / rod.centre[2]
            assert THIN_RADIUS_PX[0] * 0.95 <= r_px <= THIN_RADIUS_PX[1] + 1e-9
            assert THIN_LENGTH[0] * 0.95 <= length / min(H, W) <= THIN_LENGTH[1] + 1e-9
        for key in ("valid", "valid_right"):  # rods inside both bounds: no pixel loses its ground truth
            assert not bool((base[key] & ~thin[key]).any())
        both = base["valid"] & thin["valid"]
        d0, d1 = base["disparity"][both], thin["disparity"][both]
        moved = (d1 - d0).abs() > 1e-3
        assert bool((d1[moved] > d0[moved]).all())  # only nearer surfaces appear
        assert float(thin["disparity"][thin["valid"]].max()) <= thin["max_disp"] * (1 + 1e-4)
        assert float(moved.float().mean()) < 0.3
        changed_any |= bool(moved.any())
    assert changed_any
    flat = data_gen.render_pair(12, 0, difficulty=2, height=H, width=W, supersample=1, thin_structures=1.0,
                                textures={"flat": 1.0})  # a texture mix given to the scene reaches its rods
    assert all(o.material.kind == "flat" for o in flat["scene"].objects)
