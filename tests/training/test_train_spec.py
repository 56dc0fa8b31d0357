"""train.py --data.train SPEC: random crops of a labelled dataset mixed into the data_gen stream (fixtures
written in the folder layout from data_gen renders), and one-line errors for specs that cannot train."""

from __future__ import annotations

import multiprocessing as mp
import sys
from itertools import islice
from pathlib import Path
from unittest import mock

import numpy as np
import pytest
import torch

from data_gen import render_pair
from stereonet.io import write_disparity_pfm, write_image
from stereonet.training.data import PooledCurriculumStream, random_crop

CONFIG = ["--config", str(Path(__file__).resolve().parents[2] / "configs" / "siamese-quick.yaml")]
TINY = ["--data.height", "32", "--data.width", "64", "--data.batch_size", "2", "--data.val_pairs", "2",
        "--data.pool_size", "2", "--data.reuse", "1", "--data.source", "random-shift"]


def _write_folder(root: Path, count: int = 2, gt: bool = True, h: int = 48, w: int = 96) -> Path:
    for sub in ("left", "right", "disparity"):
        (root / sub).mkdir(parents=True, exist_ok=True)
    for i in range(count):
        p = render_pair(77, i, difficulty=1, height=h, width=w)
        for view in ("left", "right"):
            write_image(root / view / f"{i:04d}.png",
                        np.rint(p[view].permute(1, 2, 0).numpy() * 255).astype(np.uint8))
        if gt:
            write_disparity_pfm(root / "disparity" / f"{i:04d}.pfm", p["disparity"][0].numpy(),
                                p["valid"][0].numpy())
    return root


def test_random_crop_keeps_matches_inside_the_crop():
    g = torch.Generator().manual_seed(0)
    d = torch.full((1, 20, 40), 6.0)
    item = {"left": torch.rand(3, 20, 40), "right": torch.rand(3, 20, 40), "disparity": d,
            "valid": torch.ones(1, 20, 40, dtype=torch.bool), "name": "x"}
    out = random_crop(item, 10, 16, g)
    assert out["left"].shape == (3, 10, 16) and out["disparity"].shape == (1, 10, 16)
    assert not out["valid"][..., :6].any() and out["valid"][..., 6:].all()  # x - d < 0 has no match in the crop
    with pytest.raises(ValueError, match="smaller"):
        random_crop(item, 30, 16, g)


def test_stream_mixes_spec_crops_by_ratio(tmp_path):
    from stereonet.data import load_dataset

    extra = load_dataset(f"folder:{_write_folder(tmp_path / 'own')}")
    crops = {tuple(extra[i]["left"].flatten()[:5].tolist()) for i in range(len(extra))}

    def items(ratio):
        stream = PooledCurriculumStream("random-shift", 3, 32, 64, 4, 2, False, mp.Value("i", 0), mp.Value("l", 0),
                                        extra=extra, extra_ratio=ratio)
        return list(islice(iter(stream), 200))

    only = items(1.0)
    assert all(it["left"].shape == (3, 32, 64) for it in only)
    # every item is a crop of one of the two labelled pairs: its ground truth comes from the PFM files
    full = [extra[i] for i in range(len(extra))]
    for it in only[:20]:
        assert any(_is_crop(it["disparity"], f["disparity"]) for f in full)
    mixed = items(0.3)
    from_spec = sum(any(_is_crop(it["disparity"], f["disparity"]) for f in full) for it in mixed)
    assert 35 <= from_spec <= 90, from_spec  # ~60 of 200 expected
    assert crops  # the fixture has distinct pairs


def _is_crop(small: torch.Tensor, big: torch.Tensor) -> bool:
    h, w = small.shape[-2:]
    H, W = big.shape[-2:]
    for y in range(H - h + 1):
        for x in range(W - w + 1):
            if torch.equal(big[..., y:y + h, x:x + w], small):
                return True
    return False


def test_train_py_fine_tunes_on_a_folder_spec(tmp_path, monkeypatch):
    from stereonet.cli.train import main

    own = _write_folder(tmp_path / "own")
    monkeypatch.chdir(tmp_path)
    with mock.patch.object(sys, "argv", ["train.py"]):
        cli = main([*CONFIG, "--trainer.fast_dev_run", "2", "--data.train", f"folder:{own}",
                    "--data.train_ratio", "1.0", *TINY], run=False)
    assert cli.datamodule.train_extra is not None and len(cli.datamodule.train_extra) == 2
    cli.trainer.fit(cli.model, cli.datamodule)
    assert cli.trainer.state.finished


@pytest.mark.parametrize("case", ["no-gt", "missing", "synthetic", "too-small", "ratio"])
def test_bad_train_spec_is_one_line_exit_2(tmp_path, monkeypatch, capsys, case):
    from stereonet.cli.train import main

    args = {"no-gt": lambda: ["--data.train", f"folder:{_write_folder(tmp_path / 'own', gt=False)}"],
            "missing": lambda: ["--data.train", f"sceneflow:{tmp_path / 'absent'}"],
            "synthetic": lambda: ["--data.train", "synthetic:4"],
            "too-small": lambda: ["--data.train", f"folder:{_write_folder(tmp_path / 'own', h=24, w=48)}"],
            "ratio": lambda: ["--data.train", f"folder:{_write_folder(tmp_path / 'own')}",
                              "--data.train_ratio", "0"]}[case]()
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as e, mock.patch.object(sys, "argv", ["train.py"]):
        main([*CONFIG, *TINY, *args], run=False)
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("train.py: error: --data.train"), err
    assert {"no-gt": "ground-truth", "missing": "does not exist", "synthetic": "data_gen", "too-small": "smaller",
            "ratio": "share"}[case] in err[0]


@pytest.mark.parametrize("case", ["missing-config", "misspelt-key"])
def test_config_usage_errors_are_one_line(tmp_path, monkeypatch, capsys, case):
    from stereonet.cli.train import main

    if case == "missing-config":
        args, needle = ["--config", str(tmp_path / "nope.yaml")], "does not exist"
    else:
        text = Path(CONFIG[1]).read_text().replace("batch_size:", "batch_sise:")
        (tmp_path / "typo.yaml").write_text(text)
        args, needle = ["--config", str(tmp_path / "typo.yaml")], "batch_sise"
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as e, mock.patch.object(sys, "argv", ["train.py"]):
        main(args, run=False)
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("train.py: error:") and needle in err[0], err


def test_bad_model_setting_is_one_line(tmp_path, monkeypatch, capsys):
    """A model option out of its range (here the Siamese loss) is bad input: one line naming it, exit 2."""
    from stereonet.cli.train import main

    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as e, mock.patch.object(sys, "argv", ["train.py"]):
        main([*CONFIG, *TINY, "--model.init_args.loss", "mse"], run=False)
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("train.py: error:") and "loss: expected 'hinge' or 'bce'" in err[0], err
