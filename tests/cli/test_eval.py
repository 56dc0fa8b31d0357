"""eval.py: argument parsing, bad input (one line, non-zero exit), memory meter, the run on a tiny dataset."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from stereonet.cli import common
from stereonet.cli import eval as ev

REPO = Path(__file__).resolve().parents[2]
ROW_KEYS = {"method", "dataset", "pairs", "epe", "bad1", "bad2", "bad4", "d1", "density", "seconds", "peak_mib"}


def run_script(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(REPO / "eval.py"), *args], capture_output=True, text=True,
                          cwd=REPO, timeout=120)


def tiny_dataset(spec: str, n: int = 2) -> list[dict]:
    """Random-texture fronto-parallel pairs with constant disparity 4 + i; the right border is occluded."""
    g = torch.Generator().manual_seed(len(spec))
    items = []
    for i in range(n):
        d = 4 + i
        big = torch.rand(3, 48, 136, generator=g)
        occ = torch.zeros(1, 48, 112, dtype=torch.bool)
        occ[..., :d] = True
        items.append({"left": big[..., 12:124], "right": big[..., 12 + d:124 + d],
                      "disparity": torch.full((1, 48, 112), float(d)), "valid": torch.ones(1, 48, 112, dtype=torch.bool),
                      "occlusion": occ, "name": f"pair{i}", "max_disp": 16})
    return items


def test_parse_methods_all_and_unknown():
    names = ev.parse_methods("all")
    assert {"opencv-bm", "opencv-sgbm"} <= set(names)
    assert ev.parse_methods("opencv-sgbm,opencv-bm,opencv-sgbm") == ["opencv-sgbm", "opencv-bm"]
    with pytest.raises(ValueError, match="valid names: .*opencv-bm"):
        ev.parse_methods("opencv-bm,nonsense")


def test_expand_data_specs(tmp_path):
    for kind in ("middlebury2001", "kitti2015"):
        (tmp_path / kind).mkdir()
    specs = ev.expand_data_specs("synthetic:6, real", shared=tmp_path)
    assert specs == ["synthetic:6", f"middlebury2001:{tmp_path / 'middlebury2001'}",
                     f"kitti2015:{tmp_path / 'kitti2015'}"]
    assert [ev.dataset_label(s) for s in specs] == ["synthetic:6", "middlebury2001", "kitti2015"]
    assert ev.dataset_label("folder:/x/my_pairs/") == "folder:my_pairs"
    with pytest.raises(FileNotFoundError, match="real"):
        ev.expand_data_specs("real", shared=tmp_path / "absent")
    notes: list[str] = []  # beside other specs, missing real data is left out with a note (make demo)
    assert ev.expand_data_specs("synthetic:2,real", shared=tmp_path / "absent", notes=notes) == ["synthetic:2"]
    assert len(notes) == 1 and "real" in notes[0]


@pytest.mark.parametrize("text, expected", [(None, (0, 1)), ("1/3", (1, 3))])
def test_parse_shard(text, expected):
    assert ev.parse_shard(text) == expected


@pytest.mark.parametrize("text", ["3/2", "a/b", "1", "-1/2"])
def test_parse_shard_rejects(text):
    with pytest.raises(ValueError, match="--shard"):
        ev.parse_shard(text)


@pytest.mark.parametrize("args, needle", [
    (["--methods", "nonsense", "--data", "synthetic:1"], "valid names"),
    (["--methods", "opencv-bm", "--data", "synthetic:1", "--shard", "5/2"], "--shard"),
    (["--methods", "opencv-bm"], "--data"),
    (["--methods", "opencv-bm", "--data", "middlebury2001:/no/such/folder"], "middlebury2001"),
])
def test_bad_input_one_line_nonzero(args, needle, capsys):
    try:
        code = ev.main(args)
    except SystemExit as e:  # argparse usage errors
        code = e.code
    err = capsys.readouterr().err
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("eval.py: error:") and needle in lines[0]


@pytest.mark.slow
def test_script_wrapper_reports_one_line():
    r = run_script("--methods", "nonsense", "--data", "synthetic:1")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stderr.strip().splitlines() == [r.stderr.strip()] and "valid names" in r.stderr


def test_peak_memory_sees_torch_allocation():
    with common.PeakMemory() as small:
        torch.zeros(10)
    with common.PeakMemory() as big:
        x = torch.ones(40 * 2 ** 20 // 4)  # 40 MiB, touched
        del x
    assert big.peak_mib > 30
    assert small.peak_mib < big.peak_mib


def test_run_evaluation_rows_and_noc(tmp_path):
    result = ev.run_evaluation(["opencv-bm", "opencv-sgbm"], ["fake:a", "fake:b"], progress=False,
                               load=tiny_dataset)
    assert [(r["method"], r["dataset"]) for r in result.rows] == [
        ("opencv-bm", "fake:a"), ("opencv-sgbm", "fake:a"), ("opencv-bm", "fake:b"), ("opencv-sgbm", "fake:b")]
    for r in result.rows:
        assert ROW_KEYS <= set(r) and {"epe_noc", "bad2_noc"} <= set(r)
        assert r["pairs"] == 2 and r["failed"] == 0
        assert 0 <= r["bad2"] <= 100 and 0 < r["density"] <= 100 and r["seconds"] > 0
    sgbm = result.rows[1]
    assert sgbm["bad2_noc"] <= sgbm["bad2"] + 1e-9  # the occluded border only adds errors
    assert len(result.pairs) == 8
    table = ev.format_table(result.rows)
    assert table.count("opencv-sgbm") == 2 and "bad-2" in table


def test_plots_written(tmp_path):
    ev.run_evaluation(["opencv-bm", "opencv-sgbm"], ["fake:a"], progress=False, load=tiny_dataset,
                      plots=tmp_path / "plots")
    assert (tmp_path / "plots" / "bad2.png").stat().st_size > 0
    panels = sorted((tmp_path / "plots" / "fake_a").iterdir())
    assert [p.name for p in panels] == ["pair0.png", "pair1.png"]
    import cv2

    panel = cv2.imread(str(panels[0]))
    assert panel.shape[0] >= 48 and panel.shape[1] >= 6 * 112  # left, GT, two methods x (disparity, error)


def test_invalid_pixels_count_as_errors_and_fill_makes_dense():
    sparse = ev.run_evaluation(["opencv-bm"], ["fake"], progress=False, load=tiny_dataset)
    dense = ev.run_evaluation(["opencv-bm"], ["fake"], fill=True, progress=False, load=tiny_dataset)
    assert sparse.rows[0]["density"] < 100
    assert dense.rows[0]["density"] == pytest.approx(100)
    assert dense.rows[0]["bad2"] < sparse.rows[0]["bad2"]


def test_failing_method_is_reported_not_fatal(monkeypatch):
    from stereonet import matchers

    def broken(left, right, max_disp):
        raise RuntimeError("boom")

    monkeypatch.setitem(matchers._REGISTRY, "broken-test", matchers.MatcherSpec("broken-test", broken, "classical", "x"))
    result = ev.run_evaluation(["opencv-sgbm", "broken-test"], ["fake"], progress=False, load=tiny_dataset)
    ok, bad = result.rows
    assert ok["failed"] == 0 and ok["bad2"] is not None
    assert bad["failed"] == 2 and bad["pairs"] == 0 and bad["bad2"] is None and "boom" in bad["error"]
    assert "broken-test!" in ev.format_table(result.rows)


def test_json_rows_written(tmp_path, monkeypatch):
    monkeypatch.setattr(ev, "expand_data_specs", lambda text, **k: ["fake"])
    real_run = ev.run_evaluation
    monkeypatch.setattr(ev, "run_evaluation", lambda *a, **k: real_run(*a, **{**k, "load": tiny_dataset}))
    out = tmp_path / "r.json"
    assert ev.main(["--methods", "opencv-bm,opencv-sgbm", "--data", "fake", "--json", str(out), "--no-progress"]) == 0
    rows = json.loads(out.read_text())
    assert len(rows) == 2 and all(ROW_KEYS <= set(r) for r in rows)


def test_all_skips_methods_without_weights(monkeypatch, tmp_path):
    from stereonet import matchers

    monkeypatch.setitem(matchers._REGISTRY, "weightless-test",
                        matchers.MatcherSpec("weightless-test", lambda *a: None, "learned", "x", needs_weights=True))
    monkeypatch.setenv("STEREONET_WEIGHTS_DIR", str(tmp_path / "no-weights"))
    skipped: list[str] = []
    assert "weightless-test" not in ev.parse_methods("all", skipped)
    assert "weightless-test" in skipped
    with pytest.raises(FileNotFoundError, match="weights"):
        ev.parse_methods("opencv-bm,weightless-test")


def test_budget_skips_remaining_pairs():
    result = ev.run_evaluation(["opencv-bm"], ["fake"], progress=False, load=lambda s: tiny_dataset(s, n=3),
                               budget=1e-9)
    row = result.rows[0]
    assert row["pairs"] == 1 and row["skipped"] == 2 and row["failed"] == 0
    assert "skipped (time budget)" in ev.format_table(result.rows)


def test_middlebury2014_folder_end_to_end(tmp_path):
    """Issue 2, item 8: eval.py --methods opencv-bm,opencv-sgbm --data middlebury2014:DIR --json out.json,
    through the real dataset reader, on two tiny scenes written in the Middlebury 2014 layout."""
    from stereonet.io import write_disparity_pfm, write_image

    root = tmp_path / "mb2014"
    for i, item in enumerate(tiny_dataset("mb2014")):
        scene = root / f"scene{i}"
        scene.mkdir(parents=True)
        write_image(scene / "im0.png", item["left"])
        write_image(scene / "im1.png", item["right"])
        write_disparity_pfm(scene / "disp0GT.pfm", item["disparity"][0], item["valid"][0])
        mask = np.where(item["occlusion"][0].numpy(), 128, 255).astype(np.uint8)
        write_image(scene / "mask0nocc.png", mask)
    out = tmp_path / "out.json"
    code = ev.main(["--methods", "opencv-bm,opencv-sgbm", "--data", f"middlebury2014:{root}", "--json", str(out),
                    "--no-progress"])
    assert code == 0
    rows = json.loads(out.read_text())
    assert [r["method"] for r in rows] == ["opencv-bm", "opencv-sgbm"]
    for r in rows:
        assert ROW_KEYS <= set(r) and r["dataset"] == "middlebury2014:mb2014" and r["pairs"] == 2
        assert r["bad2_noc"] is not None and r["bad2_noc"] <= r["bad2"] + 1e-9
        assert 0 < r["density"] < 100  # invalid OpenCV pixels are reported, not hidden


def test_pair_cap_skips_projected_slow_pairs():
    result = ev.run_evaluation(["opencv-bm"], ["fake"], progress=False, load=lambda s: tiny_dataset(s, n=3),
                               pair_cap=1e-9)
    row = result.rows[0]
    assert row["pairs"] == 1 and row["skipped"] == 2  # the first pair runs: nothing to project from yet


def test_repeats_interleave_methods_and_report_the_median(monkeypatch):
    """repeats=3: a pair's calls go round by round (A B, A B, A B), the pair's seconds is the median of its three
    timed calls, the metrics are the first call's, the budget counts the median, and skipped pairs keep their place."""
    from stereonet import matchers

    calls: list[str] = []
    times = {"A": iter([0.9, 0.2, 0.4, 7.0, 0.6, 0.5]), "B": iter([0.1, 5.0, 3.0])}

    class FakeClock:  # each timed call "takes" the next of its method's times
        def __enter__(self):
            self.seconds = 0.0
            return self

        def __exit__(self, *exc):
            self.seconds = next(times[calls[-1]])

    def make(tag):
        def fn(left, right, max_disp, **_):
            if left.shape[-1] > 100:  # not the untimed warm-up crop
                calls.append(tag)
            return matchers.match("opencv-bm", left, right, max_disp)
        return fn

    once = ev.run_evaluation(["opencv-bm"], ["fake"], progress=False, load=lambda s: tiny_dataset(s, n=2))
    for tag in "AB":
        monkeypatch.setitem(matchers._REGISTRY, f"fake-{tag}",
                            matchers.MatcherSpec(f"fake-{tag}", make(tag), "classical", "x"))
    from stereonet import evaluation

    monkeypatch.setattr(evaluation, "Stopwatch", FakeClock)
    result = ev.run_evaluation(["fake-A", "fake-B"], ["fake"], progress=False, repeats=3, budget=1.0,
                               load=lambda s: tiny_dataset(s, n=2))
    assert calls == ["A", "B", "A", "B", "A", "B", "A", "A", "A"]
    assert [(p.method, p.pair) for p in result.pairs] == [("fake-A", "pair0"), ("fake-B", "pair0"),
                                                           ("fake-A", "pair1"), ("fake-B", "pair1")]
    a0, b0, a1, b1 = result.pairs
    assert (a0.seconds, b0.seconds, a1.seconds) == (0.4, 3.0, 0.6)  # medians, not the first call's 0.9 / 0.1 / 7.0
    assert b1.skipped and not a1.skipped  # B's median 3.0 on pair0 is over the budget, A's 0.4 is not
    assert [a0.metrics["bad2"], a1.metrics["bad2"]] == [p.metrics["bad2"] for p in once.pairs]


def test_repeats_must_be_a_positive_count():
    for bad in (0, -1, 1.5, True):
        with pytest.raises(ValueError, match="repeats: expected an integer >= 1"):
            ev.run_evaluation(["opencv-bm"], ["fake"], progress=False, repeats=bad, load=tiny_dataset)


def test_align_removes_a_residual_vertical_offset_before_every_method(capsys):
    """align=True: a pair whose right view is a row low is aligned once (listed in Evaluation.aligned, a note on
    stderr) and no method does worse on it (sgm much better); a pair without an offset is left alone."""
    g = torch.Generator().manual_seed(7)
    big = torch.rand(3, 130, 260, generator=g)  # texture at the pixel scale: a row off breaks every match

    def load(spec):
        items = []
        for i, dy in enumerate((1, 0)):  # the right view dy rows low, disparity 6
            items.append({"left": big[:, 12:108, 12:236], "right": big[:, 12 - dy:108 - dy, 18:242],
                          "disparity": torch.full((1, 96, 224), 6.0), "valid": torch.ones(1, 96, 224, dtype=torch.bool),
                          "name": f"pair{i}", "max_disp": 16})
        return items

    plain = ev.run_evaluation(["sgm", "opencv-sgbm"], ["fake"], progress=False, load=load, fill=True)
    aligned = ev.run_evaluation(["sgm", "opencv-sgbm"], ["fake"], progress=False, load=load, fill=True, align=True)
    assert [a[:2] for a in aligned.aligned] == [("fake", "pair0")] and plain.aligned == []
    assert aligned.aligned[0][2] == pytest.approx(1.0, abs=0.1)
    for a, b in zip(plain.pairs, aligned.pairs):
        if a.pair == "pair0":  # sgm's census suffers much from the offset; opencv-sgbm's cost less
            margin = 5.0 if a.method == "sgm" else 0.0
            assert b.metrics["bad1"] <= a.metrics["bad1"] - margin, (a.method, a.metrics["bad1"], b.metrics["bad1"])
        else:
            assert b.metrics == a.metrics


def test_output_paths_are_checked_before_the_run(tmp_path, capsys, monkeypatch):
    def no_run(*a, **k):
        raise AssertionError("the evaluation ran before --json/--plots were checked")

    monkeypatch.setattr(ev, "run_evaluation", no_run)
    a_file = tmp_path / "f.png"
    a_file.write_text("x")
    for args, needle in ((["--json", str(tmp_path)], "--json"), (["--plots", str(a_file)], "--plots"),
                         (["--json", str(a_file / "rows.json")], "--json")):
        code = ev.main(["--methods", "opencv-bm", "--data", "synthetic:1", *args])
        lines = capsys.readouterr().err.strip().splitlines()
        assert code == 2 and len(lines) == 1 and lines[0].startswith(f"eval.py: error: {needle}"), lines



def test_a_folder_without_ground_truth_is_noted(tmp_path, capsys):
    import cv2

    rng = np.random.default_rng(0)
    img = (rng.random((40, 64)) * 255).astype(np.uint8)
    for side, im in (("left", img), ("right", np.roll(img, -3, 1))):
        (tmp_path / side).mkdir()
        cv2.imwrite(str(tmp_path / side / "p.png"), im)
    assert ev.main(["--methods", "opencv-bm", "--data", f"folder:{tmp_path}", "--no-progress"]) == 0
    err = capsys.readouterr().err
    assert "has no ground truth; only times and memory are reported" in err


def test_a_max_disp_wider_than_a_pair_is_bad_input(capsys):
    code = ev.main(["--methods", "opencv-bm", "--data", "synthetic:1", "--max-disp", "5000", "--no-progress"])
    lines = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("eval.py: error: --max-disp: expected less"), lines
