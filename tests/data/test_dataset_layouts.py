"""SceneFlow, Middlebury 2005/2006 and ETH3D readers on small fixtures written here in each layout (pairs
rendered by data_gen, files written with stereonet.io): values read back, occlusion masks, split selection,
and one-line errors naming the file for missing, truncated or mislabelled files (also through eval.py)."""

from __future__ import annotations

import json
from functools import cache
from pathlib import Path

import numpy as np
import pytest

from data_gen import render_pair
from stereonet.checks import StereoInputError
from stereonet.cli import eval as ev
from stereonet.data import load_dataset, occlusion_from_lr_check, round_up_max_disp
from stereonet.io import write_disparity_pfm, write_disparity_png8, write_image, write_pfm

H, W = 64, 128


@cache
def _rendered(index: int) -> dict:
    """A data_gen pair as numpy: images (H, W, 3) uint8, left/right disparities and masks (H, W)."""
    p = render_pair(41, index, difficulty=1, height=H, width=W)
    img = {k: np.rint(p[k].permute(1, 2, 0).numpy() * 255).astype(np.uint8) for k in ("left", "right")}
    return {**img, "disp": p["disparity"][0].numpy(), "valid": p["valid"][0].numpy(),
            "disp_r": p["disparity_right"][0].numpy(), "valid_r": p["valid_right"][0].numpy(),
            "occlusion": p["occlusion"][0].numpy()}


def _one_line_error(excinfo, path: Path) -> str:
    msg = str(excinfo.value)
    assert "\n" not in msg and str(path) in msg, msg
    return msg


def _truncate(path: Path, keep: float = 0.5) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * keep)])


# ------------------------------------------------------------------------------------------ SceneFlow
def _write_sceneflow(base: Path, seq: str, frames: dict[str, int], right_gt: bool = True) -> None:
    """``frames`` maps a frame stem to a data_gen index; clean pass = the render, final pass = its inverse
    (so a test can tell which pass was read)."""
    for stem, index in frames.items():
        p = _rendered(index)
        for pas, f in (("clean", lambda a: a), ("final", lambda a: 255 - a)):
            for view in ("left", "right"):
                folder = base / f"frames_{pas}pass" / seq / view
                folder.mkdir(parents=True, exist_ok=True)
                write_image(folder / f"{stem}.png", f(p[view]))
        for view, d, v in (("left", p["disp"], p["valid"]), ("right", p["disp_r"], p["valid_r"])):
            if view == "right" and not right_gt:
                continue
            folder = base / "disparity" / seq / view
            folder.mkdir(parents=True, exist_ok=True)
            write_disparity_pfm(folder / f"{stem}.pfm", d, v)


@pytest.fixture(scope="module")
def flyingthings(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("sf") / "flyingthings3d"
    _write_sceneflow(root, "TRAIN/A/0000", {"0006": 0, "0007": 1})
    _write_sceneflow(root, "TEST/B/0003", {"0010": 2})
    return root


def test_sceneflow_values_occlusion_and_default_pass(flyingthings):
    ds = load_dataset(f"sceneflow:{flyingthings}")
    assert ds.names == ["TEST/B/0003/0010", "TRAIN/A/0000/0006", "TRAIN/A/0000/0007"]
    item, p = ds[1], _rendered(0)
    assert item["left"].shape == (3, H, W) and item["name"] == "TRAIN/A/0000/0006"
    final_left = (255 - p["left"]).transpose(2, 0, 1) / 255.0
    assert np.abs(item["left"].numpy() - final_left).max() < 1e-6  # final pass by default
    assert np.array_equal(item["disparity"][0].numpy(), np.where(p["valid"], p["disp"], 0).astype(np.float32))
    assert np.array_equal(item["valid"][0].numpy(), p["valid"])
    occ = item["occlusion"][0].numpy()
    assert np.array_equal(occ, occlusion_from_lr_check(p["disp"], p["valid"], p["disp_r"], p["valid_r"]))
    assert occ.any() and (occ == p["occlusion"])[p["valid"]].mean() > 0.95  # agrees with the renderer's mask
    assert item["max_disp"] == round_up_max_disp(float(p["disp"][p["valid"]].max()), W)


@pytest.mark.parametrize("spec, names, pas", [
    ("sceneflow-clean", ["TEST/B/0003/0010", "TRAIN/A/0000/0006", "TRAIN/A/0000/0007"], "clean"),
    ("sceneflow-test", ["TEST/B/0003/0010"], "final"),
    ("sceneflow-clean-train", ["TRAIN/A/0000/0006", "TRAIN/A/0000/0007"], "clean"),
    ("sceneflow-final-test", ["TEST/B/0003/0010"], "final"),
])
def test_sceneflow_pass_and_split(flyingthings, spec, names, pas):
    ds = load_dataset(f"{spec}:{flyingthings}")
    assert ds.names == names
    p = _rendered({"0006": 0, "0007": 1, "0010": 2}[names[0].rsplit("/", 1)[1]])
    want = p["left"] if pas == "clean" else 255 - p["left"]
    assert np.abs(ds[0]["left"].numpy() - want.transpose(2, 0, 1) / 255.0).max() < 1e-6


def test_sceneflow_monkaa_driving_side_by_side(tmp_path):
    _write_sceneflow(tmp_path / "monkaa", "a_rain_of_stones_x2", {"0000": 0})
    _write_sceneflow(tmp_path / "driving", "15mm_focallength/scene_forwards/fast", {"0001": 1}, right_gt=False)
    ds = load_dataset(f"sceneflow:{tmp_path}")
    assert ds.names == ["driving/15mm_focallength/scene_forwards/fast/0001", "monkaa/a_rain_of_stones_x2/0000"]
    assert "occlusion" not in ds[0] and "occlusion" in ds[1]  # no right-view GT: no LR check
    with pytest.raises(StereoInputError, match="official split is FlyingThings3D") as e:
        load_dataset(f"sceneflow-train:{tmp_path}")
    _one_line_error(e, tmp_path)


def test_sceneflow_missing_files_name_the_file(tmp_path):
    _write_sceneflow(tmp_path, "TRAIN/A/0000", {"0006": 0})
    disp = tmp_path / "disparity" / "TRAIN" / "A" / "0000" / "left" / "0006.pfm"
    disp.unlink()
    with pytest.raises(StereoInputError, match="no such file") as e:
        load_dataset(f"sceneflow:{tmp_path}")
    _one_line_error(e, disp)
    (disp.parent.parent / "right" / "0006.pfm").unlink()
    disp.parent.rmdir()
    with pytest.raises(StereoInputError, match="ground truth") as e:  # left frames, no disparity folder
        load_dataset(f"sceneflow:{tmp_path}")
    _one_line_error(e, disp.parent)


def test_sceneflow_missing_right_view_and_pass(tmp_path):
    _write_sceneflow(tmp_path, "A", {"0006": 0})
    right = tmp_path / "frames_cleanpass" / "A" / "right" / "0006.png"
    right.unlink()
    with pytest.raises(StereoInputError, match="right view") as e:
        load_dataset(f"sceneflow-clean:{tmp_path}")
    _one_line_error(e, right)
    for f in (tmp_path / "frames_finalpass").rglob("*.png"):
        f.unlink()
    for d in sorted((tmp_path / "frames_finalpass").rglob("*"), reverse=True):
        d.rmdir()
    (tmp_path / "frames_finalpass").rmdir()
    with pytest.raises(StereoInputError, match="sceneflow-clean:DIR") as e:
        load_dataset(f"sceneflow:{tmp_path}")
    _one_line_error(e, tmp_path / "frames_finalpass")
    with pytest.raises(StereoInputError, match=r"unknown sceneflow option 'foo'"):
        load_dataset(f"sceneflow-clean-foo:{tmp_path}")
    with pytest.raises(StereoInputError, match=r"sceneflow\[-clean\|-final\]\[-train\|-test\]:DIR"):
        load_dataset(f"sceneflows:{tmp_path}")


def test_sceneflow_truncated_png_and_bad_pfm_header(tmp_path):
    _write_sceneflow(tmp_path, "A", {"0006": 0, "0007": 1})
    left = tmp_path / "frames_finalpass" / "A" / "left" / "0006.png"
    _truncate(left)
    pfm = tmp_path / "disparity" / "A" / "left" / "0007.pfm"
    pfm.write_bytes(b"PX\n" + pfm.read_bytes()[3:])
    ds = load_dataset(f"sceneflow:{tmp_path}")
    with pytest.raises(StereoInputError, match="truncated PNG") as e:
        ds[0]
    _one_line_error(e, left)
    with pytest.raises(StereoInputError, match="not a PFM file") as e:
        ds[1]
    _one_line_error(e, pfm)


# ------------------------------------------------------------------------------------ Middlebury 2006
def _write_mb2006(scene: Path, index: int, scale: float, right_gt: bool = True) -> dict:
    scene.mkdir(parents=True, exist_ok=True)
    p = _rendered(index)
    write_image(scene / "view1.png", p["left"])
    write_image(scene / "view5.png", p["right"])
    write_disparity_png8(scene / "disp1.png", p["disp"], p["valid"], scale=scale)
    if right_gt:
        write_disparity_png8(scene / "disp5.png", p["disp_r"], p["valid_r"], scale=scale)
    return p


def _quantized(d: np.ndarray, v: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """What an 8-bit map written at ``scale`` reads back as (valid values are stored as at least 1)."""
    q = np.where(v, np.clip(np.rint(d.astype(np.float64) * scale), 1, 255), 0)
    return (q / scale).astype(np.float32), q > 0


def test_middlebury2006_scale_from_size_folders_and_occlusion(tmp_path):
    for folder, scale in (("FullSize", 1.0), ("HalfSize", 2.0), ("ThirdSize", 3.0)):
        _write_mb2006(tmp_path / folder / "Aloe", 0, scale)
    ds = load_dataset(f"middlebury2006:{tmp_path}")
    assert ds.names == ["FullSize/Aloe", "HalfSize/Aloe", "ThirdSize/Aloe"]
    p = _rendered(0)
    for item, scale in zip(ds, (1.0, 2.0, 3.0)):
        d, v = _quantized(p["disp"], p["valid"], scale)
        dr, vr = _quantized(p["disp_r"], p["valid_r"], scale)
        assert np.allclose(item["disparity"][0].numpy(), d, atol=1e-6)
        assert np.array_equal(item["valid"][0].numpy(), v)
        assert np.array_equal(item["occlusion"][0].numpy(), occlusion_from_lr_check(d, v, dr, vr))
        assert item["occlusion"].any()
        assert item["max_disp"] == round_up_max_disp(float(d[v].max()), W)
    one = load_dataset(f"middlebury2006:{tmp_path / 'HalfSize' / 'Aloe'}")  # DIR is one scene
    assert one.names == ["Aloe"] and np.allclose(one[0]["disparity"][0].numpy(), _quantized(p["disp"], p["valid"], 2)[0])


@pytest.mark.parametrize("width, scale", [(420, 3.0), (650, 2.0), (1300, 1.0)])
def test_middlebury2006_scale_from_width(tmp_path, width, scale):
    rng = np.random.default_rng(0)
    scene = tmp_path / "Bowling1"
    scene.mkdir()
    for name in ("view1.png", "view5.png"):
        write_image(scene / name, rng.integers(0, 256, (4, width, 3), dtype=np.uint8))
    raw = rng.integers(0, 60, (4, width)).astype(np.uint8)
    write_image(scene / "disp1.png", raw)
    item = load_dataset(f"middlebury2006:{tmp_path}")[0]
    assert "occlusion" not in item  # no disp5.png
    assert np.allclose(item["disparity"][0].numpy(), raw / scale) and np.array_equal(item["valid"][0], raw > 0)


def test_middlebury2006_size_unknown_or_mislabelled(tmp_path):
    _write_mb2006(tmp_path / "Aloe", 0, 1.0)  # 128 px wide, in no size folder
    with pytest.raises(StereoInputError, match="cannot tell") as e:
        load_dataset(f"middlebury2006:{tmp_path}")
    _one_line_error(e, tmp_path / "Aloe" / "view1.png")
    scene = tmp_path / "HalfSize" / "Cloth1"
    scene.mkdir(parents=True)
    for name in ("view1.png", "view5.png", "disp1.png"):
        write_image(scene / name, np.zeros((4, 430), np.uint8))  # third-size width in a HalfSize folder
    with pytest.raises(StereoInputError, match="ThirdSize, but the scene is in a HalfSize folder") as e:
        load_dataset(f"middlebury2006:{tmp_path / 'HalfSize'}")
    _one_line_error(e, scene / "view1.png")


@pytest.mark.parametrize("missing", ["view5.png", "disp1.png"])
def test_middlebury2006_missing_view_or_gt(tmp_path, missing):
    scene = tmp_path / "ThirdSize" / "Aloe"
    _write_mb2006(scene, 0, 3.0)
    _write_mb2006(tmp_path / "ThirdSize" / "Baby1", 1, 3.0)
    (scene / missing).unlink()
    with pytest.raises(StereoInputError, match="no such file") as e:
        load_dataset(f"middlebury2006:{tmp_path}")
    _one_line_error(e, scene / missing)


def test_middlebury2006_truncated_disparity(tmp_path):
    scene = tmp_path / "FullSize" / "Aloe"
    _write_mb2006(scene, 0, 1.0)
    _truncate(scene / "disp5.png", 0.8)
    ds = load_dataset(f"middlebury2006:{tmp_path}")
    with pytest.raises(StereoInputError, match="PNG") as e:
        ds[0]
    _one_line_error(e, scene / "disp5.png")


# ---------------------------------------------------------------------------------------------- ETH3D
ETH3D_CALIB = ("cam0=[100 0 64; 0 100 32; 0 0 1]\ncam1=[100 0 64; 0 100 32; 0 0 1]\ndoffs=0\nbaseline=60\n"
               f"width={W}\nheight={H}\nndisp=48\nisint=0\nvmin=1\nvmax=30\ndyavg=0\ndymax=0\n")


def _write_eth3d(scene: Path, index: int, mask_shape: tuple[int, int] | None = None) -> tuple[dict, np.ndarray]:
    """ETH3D's conventions: GT inf where unknown (here a band of rows), mask 255 = non-occluded with GT, else 0."""
    scene.mkdir(parents=True, exist_ok=True)
    p = _rendered(index)
    write_image(scene / "im0.png", p["left"])
    write_image(scene / "im1.png", p["right"])
    valid = p["valid"].copy()
    valid[:6] = False
    write_disparity_pfm(scene / "disp0GT.pfm", p["disp"], valid)
    mask = np.where(valid & ~p["occlusion"], 255, 0).astype(np.uint8)
    write_image(scene / "mask0nocc.png", mask if mask_shape is None else np.zeros(mask_shape, np.uint8))
    (scene / "calib.txt").write_text(ETH3D_CALIB)
    return p, valid


def test_eth3d_values_mask_and_calib(tmp_path):
    p, valid = _write_eth3d(tmp_path / "delivery_area_1l", 0)
    _write_eth3d(tmp_path / "electro_1s", 1)
    ds = load_dataset(f"eth3d:{tmp_path}")
    assert ds.names == ["delivery_area_1l", "electro_1s"]
    item = ds[0]
    assert np.array_equal(item["valid"][0].numpy(), valid)
    assert np.array_equal(item["disparity"][0].numpy(), np.where(valid, p["disp"], 0).astype(np.float32))
    assert np.array_equal(item["occlusion"][0].numpy(), valid & p["occlusion"])  # valid GT, mask != 255
    assert item["calib"].ndisp == 48 and item["max_disp"] == 48


def test_eth3d_bad_files_name_the_file(tmp_path):
    _write_eth3d(tmp_path / "a", 0, mask_shape=(H, W - 8))
    with pytest.raises(StereoInputError, match="expected the size of im0.png") as e:
        load_dataset(f"eth3d:{tmp_path}")  # found from the PNG headers, before any pair is read
    _one_line_error(e, tmp_path / "a" / "mask0nocc.png")
    write_image(tmp_path / "a" / "mask0nocc.png", np.zeros((H, W), np.uint8))
    write_pfm(tmp_path / "a" / "disp0GT.pfm", np.zeros((H, W, 3), np.float32))  # a colour PFM
    with pytest.raises(StereoInputError, match="single-channel") as e:
        load_dataset(f"eth3d:{tmp_path}")[0]
    _one_line_error(e, tmp_path / "a" / "disp0GT.pfm")
    (tmp_path / "a" / "disp0GT.pfm").unlink()
    with pytest.raises(StereoInputError, match="no such file") as e:
        load_dataset(f"eth3d:{tmp_path}")
    _one_line_error(e, tmp_path / "a" / "disp0GT.pfm")


# --------------------------------------------------------------------------------------------- eval.py
def test_eval_runs_on_the_new_layouts(tmp_path, flyingthings):
    _write_eth3d(tmp_path / "eth3d" / "delivery_area_1l", 0)
    _write_mb2006(tmp_path / "mb2006" / "ThirdSize" / "Aloe", 1, 3.0)
    out = tmp_path / "rows.json"
    specs = f"sceneflow-test:{flyingthings},eth3d:{tmp_path / 'eth3d'},middlebury2006:{tmp_path / 'mb2006'}"
    assert ev.main(["--methods", "opencv-bm", "--data", specs, "--json", str(out), "--no-progress"]) == 0
    rows = json.loads(out.read_text())
    assert [r["dataset"] for r in rows] == ["sceneflow-test:flyingthings3d", "eth3d", "middlebury2006:mb2006"]
    assert all(r["pairs"] == 1 and r["failed"] == 0 and r["bad2_noc"] is not None for r in rows)


def _bad_sceneflow(root: Path) -> Path:
    _write_sceneflow(root, "TRAIN/A/0000", {"0006": 0}, right_gt=False)
    gt = root / "disparity" / "TRAIN" / "A" / "0000" / "left"
    (gt / "0006.pfm").unlink()
    gt.rmdir()
    return gt


def _bad_mb2006(root: Path) -> Path:
    _write_mb2006(root / "HalfSize" / "Aloe", 0, 2.0)
    (root / "HalfSize" / "Aloe" / "view5.png").unlink()
    return root / "HalfSize" / "Aloe" / "view5.png"


def _bad_eth3d(root: Path) -> Path:
    _write_eth3d(root / "a", 0, mask_shape=(H // 2, W))
    return root / "a" / "mask0nocc.png"


def _truncated_sceneflow(root: Path) -> Path:
    _write_sceneflow(root, "A", {"0006": 0})
    _truncate(root / "frames_finalpass" / "A" / "right" / "0006.png")
    return root / "frames_finalpass" / "A" / "right" / "0006.png"


@pytest.mark.parametrize("kind, make", [("sceneflow", _bad_sceneflow), ("middlebury2006", _bad_mb2006),
                                        ("eth3d", _bad_eth3d), ("sceneflow", _truncated_sceneflow)])
def test_eval_bad_dataset_file_is_one_line_exit_2(tmp_path, capsys, kind, make):
    bad = make(tmp_path)
    code = ev.main(["--methods", "opencv-bm", "--data", f"{kind}:{tmp_path}", "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1, err
    assert err.startswith("eval.py: error:") and str(bad) in err


def test_real_reads_the_bundled_middlebury_pairs_without_shared_data(monkeypatch):
    import stereonet.data as data

    monkeypatch.setattr(data, "shared_data_dir", lambda: None)
    root, source = data.real_data_dir()
    assert source == "bundled" and root == data.bundled_data_dir()
    ds = data.load_dataset("real")
    assert ds.source == "bundled"
    names = sorted(str(ds[i]["name"]) for i in range(len(ds)))
    assert names == ["middlebury2001/tsukuba", "middlebury2001/venus", "middlebury2003/cones",
                     "middlebury2003/teddy"]
    for i in range(len(ds)):
        item = ds[i]
        assert item["left"].shape == item["right"].shape and bool(item["valid"].any())
    from stereonet.cli import eval as ev

    notes: list[str] = []
    specs = ev.expand_data_specs("real", notes=notes)
    assert [s.split(":")[0] for s in specs] == ["middlebury2001", "middlebury2003"] and "bundled" in notes[0]


def test_bundled_pairs_are_the_shared_files_unchanged():
    import stereonet.data as data

    shared = data.shared_data_dir()
    if shared is None or not (shared / "middlebury2003").is_dir():
        pytest.skip("no ../shared/data to compare the bundled copy with")
    bundled = data.bundled_data_dir()
    files = sorted(p.relative_to(bundled) for p in bundled.rglob("*") if p.is_file() and p.suffix != ".md")
    assert len(files) == 14
    for rel in files:
        assert (bundled / rel).read_bytes() == (shared / rel).read_bytes(), rel


def test_real_reads_every_real_layout_in_the_shared_folder(tmp_path, monkeypatch):
    """A shared data folder with Middlebury 2005/2006 and ETH3D sub-folders: ``real`` reads them too (the
    larger real sets one brings), and never mixes in the bundled pairs."""
    _write_eth3d(tmp_path / "eth3d" / "delivery_area_1l", 0)
    _write_mb2006(tmp_path / "middlebury2006" / "ThirdSize" / "Aloe", 1, 3.0)
    monkeypatch.setenv("STEREONET_SHARED_DATA", str(tmp_path))
    ds = load_dataset("real")
    assert sorted(ds.names) == ["eth3d/delivery_area_1l", "middlebury2006/ThirdSize/Aloe"] and ds.source == "shared"
    assert [s.split(":")[0] for s in ev.expand_data_specs("real")] == ["middlebury2006", "eth3d"]


# ------------------------------------------------------------------------------------------ Middlebury 2003
@pytest.mark.parametrize("width,scale", [(450, 4), (900, 2), (1800, 1)])
def test_middlebury2003_scale_follows_the_image_size(tmp_path, width, scale):
    """disp2.png is value / 4 at quarter size, / 2 at half, / 1 at full size: read from the view's width (a
    half-size Cones was read at a quarter of its disparities before); another width is one line naming the file."""
    import cv2

    scene = tmp_path / "cones"
    scene.mkdir()
    img = np.full((8, width, 3), 128, np.uint8)
    for name in ("im2.png", "im6.png"):
        cv2.imwrite(str(scene / name), img)
    cv2.imwrite(str(scene / "disp2.png"), np.full((8, width), 40, np.uint8))
    item = load_dataset(f"middlebury2003:{tmp_path}")[0]
    assert float(item["disparity"].max()) == pytest.approx(40 / scale)
    cv2.imwrite(str(scene / "im2.png"), np.full((8, 500, 3), 128, np.uint8))
    with pytest.raises(StereoInputError, match="width 450") as e:
        load_dataset(f"middlebury2003:{tmp_path}")
    _one_line_error(e, scene / "im2.png")
