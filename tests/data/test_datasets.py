import sys
import types

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from stereonet.checks import StereoInputError
from stereonet.data import (
    BENCHMARK_SEED,
    collate_stereo,
    load_dataset,
    occlusion_from_lr_check,
    round_up_max_disp,
)
from stereonet.io import write_disparity_pfm, write_disparity_png16, write_image
from stereonet.types import Calibration

H, W = 12, 40


def _check_item(item, channels=3):
    assert item["left"].shape == item["right"].shape and item["left"].shape[0] == channels
    h, w = item["left"].shape[-2:]
    assert item["left"].dtype == torch.float32 and 0 <= item["left"].min() and item["left"].max() <= 1
    assert item["disparity"].shape == (1, h, w) and item["disparity"].dtype == torch.float32
    assert item["valid"].shape == (1, h, w) and item["valid"].dtype == torch.bool
    assert (item["disparity"][~item["valid"]] == 0).all()
    if "occlusion" in item:
        assert item["occlusion"].dtype == torch.bool and not (item["occlusion"] & ~item["valid"]).any()
    assert isinstance(item["name"], str) and isinstance(item["max_disp"], int) and 0 < item["max_disp"] < w


def _pair(d=4):
    """Random texture pair with constant disparity d, plus its left GT."""
    g = torch.Generator().manual_seed(3)
    big = torch.rand(3, H, W + d, generator=g)
    return big[..., d:W + d], big[..., :W], np.full((H, W), float(d), np.float32)


def _write_2014_scene(folder, with_mask=True, with_calib=True, with_right=False):
    left, right, disp = _pair()
    write_image(folder / "im0.png", left)
    write_image(folder / "im1.png", right)
    valid = np.ones((H, W), bool)
    valid[0, :5] = False
    write_disparity_pfm(folder / "disp0GT.pfm", disp, valid)
    if with_right:
        write_disparity_pfm(folder / "disp1GT.pfm", disp)
    if with_mask:
        mask = np.full((H, W), 255, np.uint8)
        mask[:, :4] = 128
        mask[0, :5] = 0
        write_image(folder / "mask0nocc.png", mask)
    if with_calib:
        (folder / "calib.txt").write_text(f"cam0=[100 0 20; 0 100 6; 0 0 1]\ncam1=[100 0 22; 0 100 6; 0 0 1]\n"
                                          f"doffs=2\nbaseline=50\nwidth={W}\nheight={H}\nndisp=24\n")
    return disp, valid


# ------------------------------------------------------------------------- real data
def test_middlebury2001_real(shared_data):
    ds = load_dataset(f"middlebury2001:{shared_data / 'middlebury2001'}")
    assert len(ds) == 2 and ds.names == ["tsukuba", "venus"]
    tsukuba = ds[0]
    _check_item(tsukuba)
    v = tsukuba["valid"][0]
    assert not v[:18].any() and not v[:, -18:].any() and v[18:-18, 18:-18].all()  # 18-px unknown border
    d = tsukuba["disparity"][0][v]
    assert d.min() >= 5 and d.max() <= 14 and tsukuba["max_disp"] == 16  # scale 16: 5..14 px
    venus = ds[1]
    _check_item(venus)
    assert venus["disparity"].max() < 20 and venus["max_disp"] == 32  # scale 8: up to 19.75 px
    one = load_dataset(f"middlebury2001:{shared_data / 'middlebury2001' / 'venus'}")  # DIR is one scene
    assert len(one) == 1 and one[0]["name"] == "venus"


def test_middlebury2003_real_occlusion_is_consistent(shared_data):
    ds = load_dataset(f"middlebury2003:{shared_data / 'middlebury2003'}")
    assert ds.names == ["cones", "teddy"]
    for item in ds:
        _check_item(item)
        occ, valid = item["occlusion"][0], item["valid"][0]
        assert 0.03 < occ[valid].float().mean() < 0.25
        # invariant: warping the right image by the GT reproduces the left image on visible pixels,
        # much better than on the pixels the LR check calls occluded
        h, w = valid.shape
        xs = torch.arange(w)[None].float() - item["disparity"][0]
        xr = xs.round().long().clamp(0, w - 1)
        warped = torch.gather(item["right"], 2, xr[None].expand(3, h, w))
        diff = (warped - item["left"]).abs().mean(0)
        visible = valid & ~occ
        assert diff[visible].mean() < 0.05 and diff[occ].mean() > 2 * diff[visible].mean()


def test_kitti_real(shared_data):
    for kind, root in (("kitti2012", shared_data / "kitti2012"), ("kitti2015", shared_data / "kitti2015" / "training")):
        ds = load_dataset(f"{kind}:{root}")
        assert len(ds) == 1
        item = ds[0]
        _check_item(item)
        assert item["name"] == "000000_10" and item["max_disp"] % 16 == 0
        assert 0.1 < item["valid"].float().mean() < 0.6


def test_real_spec(shared_data):
    ds = load_dataset("real")
    assert len(ds) == 6 and ds.names[0] == "middlebury2001/tsukuba" and "kitti2015/000000_10" in ds.names


# ------------------------------------------------------------------------- Middlebury 2014 (tmp)
def test_middlebury2014_layout(tmp_path):
    for scene in ("b_scene", "a_scene"):
        (tmp_path / scene).mkdir()
        disp, valid = _write_2014_scene(tmp_path / scene)
    (tmp_path / "not_a_scene").mkdir()
    ds = load_dataset(f"middlebury2014:{tmp_path}")
    assert ds.names == ["a_scene", "b_scene"]
    item = ds[0]
    _check_item(item)
    assert torch.equal(item["valid"][0], torch.from_numpy(valid))  # inf in the PFM = invalid
    assert torch.allclose(item["disparity"][0][item["valid"][0]], torch.tensor(4.0))
    assert item["occlusion"][0, :, :4][item["valid"][0, :, :4]].all() and not item["occlusion"][0, :, 4:].any()
    assert isinstance(item["calib"], Calibration) and item["calib"].doffs == 2 and item["calib"].baseline == 50
    assert item["max_disp"] == 24  # calib ndisp wins over the GT maximum


def test_middlebury2014_single_scene_lr_check_and_no_calib(tmp_path):
    _write_2014_scene(tmp_path, with_mask=False, with_calib=False, with_right=True)
    ds = load_dataset(f"middlebury2014:{tmp_path}")
    item = ds[0]
    assert item["name"] == tmp_path.name and "calib" not in item
    # constant disparity 4: the 4 leftmost columns look outside the right image -> occluded
    occ = item["occlusion"][0]
    assert occ[1:, :4].all() and not occ[:, 4:].any()
    assert item["max_disp"] == 16


# ------------------------------------------------------------------------- folder layouts
def test_folder_left_right_subfolders(tmp_path):
    left, right, disp = _pair()
    for sub in ("left", "right", "disparity"):
        (tmp_path / sub).mkdir()
    write_image(tmp_path / "left" / "p1.png", left)
    write_image(tmp_path / "right" / "p1.png", right)
    write_image(tmp_path / "left" / "p2.png", left[:1])
    write_image(tmp_path / "right" / "p2.png", right[:1])
    write_disparity_png16(tmp_path / "disparity" / "p1.png", disp)
    ds = load_dataset(f"folder:{tmp_path}")
    assert ds.names == ["p1", "p2"]
    a, b = ds[0], ds[1]
    _check_item(a)
    assert a["valid"].all() and torch.allclose(a["disparity"], torch.tensor(4.0))
    _check_item(b, channels=1)
    assert not b["valid"].any() and b["max_disp"] == 16  # no GT: a quarter of the width, rounded up to 16


def test_folder_suffix_and_im0_layouts(tmp_path):
    left, right, disp = _pair()
    write_image(tmp_path / "flat" / "x_left.png", left)
    write_image(tmp_path / "flat" / "x_right.png", right)
    write_disparity_pfm(tmp_path / "flat" / "x_disp.pfm", disp)
    ds = load_dataset(f"folder:{tmp_path / 'flat'}")
    assert ds.names == ["x"] and ds[0]["valid"].all()
    write_image(tmp_path / "scenes" / "s1" / "im0.png", left)
    write_image(tmp_path / "scenes" / "s1" / "im1.png", right)
    ds = load_dataset(f"folder:{tmp_path / 'scenes'}")
    assert ds.names == ["s1"] and not ds[0]["valid"].any()


def test_dataloader_collate(tmp_path):
    for scene in ("a", "b"):
        (tmp_path / scene).mkdir()
        _write_2014_scene(tmp_path / scene)
    batch = next(iter(DataLoader(load_dataset(f"middlebury2014:{tmp_path}"), batch_size=2,
                                 collate_fn=collate_stereo)))
    assert batch["left"].shape == (2, 3, H, W) and batch["valid"].dtype == torch.bool
    assert batch["name"] == ["a", "b"] and len(batch["calib"]) == 2 and batch["max_disp"] == [24, 24]


# ------------------------------------------------------------------------- bad specs
@pytest.mark.parametrize("spec,msg", [
    ("nosuchkind:/tmp", r"data spec 'nosuchkind:/tmp': unknown kind 'nosuchkind'; expected one of synthetic\[:N\]"),
    ("middlebury2014:", "expected middlebury2014:DIR"),
    ("synthetic:abc", r"expected synthetic\[:N\] with a positive integer N"),
    ("synthetic:0", "positive integer"),
    ("real:x", "takes no argument"),
    ("", "spec: expected a data spec"),
])
def test_bad_specs(spec, msg):
    with pytest.raises(StereoInputError, match=msg) as e:
        load_dataset(spec)
    assert "\n" not in str(e.value)  # one line, for the command-line error


def test_missing_and_wrong_layout(tmp_path):
    with pytest.raises(StereoInputError, match=r"data spec 'kitti2015:.*nothere': folder .*nothere does not exist"):
        load_dataset(f"kitti2015:{tmp_path / 'nothere'}")
    (tmp_path / "empty").mkdir()
    for kind, expected in (("middlebury2014", "im0.png, im1.png and disp0GT.pfm"), ("kitti2012", "colored_0/"),
                           ("middlebury2001", "disp3.pgm"), ("folder", "left/ and right/")):
        with pytest.raises(StereoInputError, match=rf"data spec '{kind}:.*empty': no pairs found in .*; expected .*{expected}"):
            load_dataset(f"{kind}:{tmp_path / 'empty'}")


def test_mismatched_files_named(tmp_path):
    left, right, disp = _pair()
    write_image(tmp_path / "a_left.png", left)
    write_image(tmp_path / "a_right.png", right[..., :-2])
    with pytest.raises(StereoInputError, match=r"a_right\.png: expected the same shape as a_left\.png"):
        load_dataset(f"folder:{tmp_path}")[0]


# ------------------------------------------------------------------------- synthetic delegation
def test_synthetic_delegates_to_data_gen(monkeypatch):
    calls = []

    class FakeSynthetic(torch.utils.data.Dataset):
        def __init__(self, count, seed=0, **kw):
            calls.append((count, seed))
            self.count = count

        def __len__(self):
            return self.count

        def __getitem__(self, i):
            left, right, disp = _pair()
            return {"left": left, "right": right, "disparity": torch.from_numpy(disp)[None],
                    "valid": torch.ones(1, H, W, dtype=torch.bool)}

    monkeypatch.setitem(sys.modules, "data_gen", types.SimpleNamespace(SyntheticStereo=FakeSynthetic))
    ds = load_dataset("synthetic:3")
    assert len(ds) == 3 and calls == [(3, BENCHMARK_SEED)]
    item = ds[2]
    _check_item(item)
    assert item["name"] == "synthetic-0002" and item["max_disp"] == 16
    load_dataset("synthetic")
    assert calls[-1][0] > 0


# ------------------------------------------------------------------------- helpers
def test_lr_check_hand_example():
    # one row: left disparities [0, 1, 1, 2]; right GT that agrees except at column 1 (target x' = 0)
    dl = np.array([[0.0, 1.0, 1.0, 2.0]])
    dr = np.array([[0.0, 1.0, 0.0, 0.0]])   # right x'=0 has d=0 (disagrees with 1), x'=1 has 1 (agrees)
    vl = np.ones((1, 4), bool)
    vr = np.ones((1, 4), bool)
    occ = occlusion_from_lr_check(dl, vl, dr, vr)
    # col0 -> x'=0, d_r=0 ok; col1 -> x'=0, d_r=0 vs 1 -> 1 > tol? |0-1| = 1 <= 1 -> visible;
    # col2 -> x'=1, d_r=1 ok; col3 -> x'=1, d_r=1 vs 2 -> visible at tol 1, occluded at tol 0.5
    assert not occ.any()
    assert occlusion_from_lr_check(dl, vl, dr, vr, tol=0.5).tolist() == [[False, True, False, True]]
    dl2 = np.array([[3.0, 0.0, 0.0, 0.0]])  # x - d < 0: outside the right image
    assert occlusion_from_lr_check(dl2, vl, np.zeros((1, 4)), vr).tolist() == [[True, False, False, False]]


def test_round_up_max_disp():
    assert round_up_max_disp(0.0, 100) == 16
    assert round_up_max_disp(16.0, 100) == 16
    assert round_up_max_disp(16.1, 100) == 32
    assert round_up_max_disp(200.0, 100) == 99


# ------------------------------------------------------------------------- data_gen output (Middlebury 2014 layout)
def test_reads_data_gen_output_exactly(tmp_path):
    from data_gen.cli import generate
    from data_gen.pair import render_pair

    generate(tmp_path, count=1, seed=5, difficulty=0, height=48, width=96, supersample=1, progress=False)
    ds = load_dataset(f"middlebury2014:{tmp_path}")
    assert len(ds) == 1
    item = ds[0]
    _check_item(item)
    ref = render_pair(5, 0, 0, 48, 96, True, 1)
    assert torch.equal(item["valid"], ref["valid"])
    assert torch.equal(item["disparity"][item["valid"]], ref["disparity"][ref["valid"]])  # PFM is lossless
    assert torch.equal(item["occlusion"], ref["occlusion"] & ref["valid"])
    assert (item["left"] - ref["left"]).abs().max() <= 0.5 / 255 + 1e-6  # 8-bit PNG
    assert item["max_disp"] == ref["max_disp"] == item["calib"].ndisp
    assert torch.allclose(item["calib"].K1, ref["calib"].K1, atol=1e-5)
    assert item["calib"].baseline == pytest.approx(ref["calib"].baseline, rel=1e-6)


def test_synthetic_spec_builds_data_gen_dataset():
    import data_gen

    ds = load_dataset("synthetic:5")
    assert len(ds) == 5 and isinstance(ds.inner, data_gen.SyntheticStereo) and ds.inner.seed == BENCHMARK_SEED
