"""scripts/bench.py (make bench): BENCHMARKS.md with median tables, ratios to opencv-sgbm and plots, on a tiny fake set."""

from __future__ import annotations

import importlib.util
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("stereonet_bench_script", REPO / "scripts" / "bench.py")
bench = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench)

HERE = Path(__file__).resolve().parent


def _tiny_dataset():
    spec = importlib.util.spec_from_file_location("cli_test_eval", HERE / "test_eval.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.tiny_dataset


def test_bench_writes_report(tmp_path, monkeypatch):
    tiny = _tiny_dataset()
    real_run = bench.run_evaluation
    monkeypatch.setattr(bench, "run_evaluation", lambda *a, **k: real_run(*a, **{**k, "load": tiny}))
    out, docs = tmp_path / "BENCHMARKS.md", tmp_path / "docs" / "bench"
    code = bench.main(["--methods", "opencv-bm,opencv-sgbm", "--synthetic", "2", "--no-real", "--out", str(out),
                       "--docs", str(docs), "--no-progress"])
    assert code == 0
    text = out.read_text()
    assert "## synthetic: median over pairs" in text and "### synthetic:2" in text
    assert "| synthetic | opencv | `opencv-" in text  # the headline names the best of each kind
    header = next(ln for ln in text.splitlines() if ln.startswith("| method | pairs"))
    col = [c.strip() for c in header.split("|")].index("× sgbm time")
    rows = [[c.strip() for c in ln.split("|")] for ln in text.splitlines() if ln.startswith("| `opencv-")]
    ratios = {r[1]: r[col] for r in rows if len(r) > col}
    assert ratios["`opencv-sgbm`"] == "1.0"  # the reference against itself
    assert float(ratios["`opencv-bm`"]) > 0
    mcol = [c.strip() for c in header.split("|")].index("Mde/s")
    mdes = {r[1]: r[mcol] for r in rows if len(r) == len(header.split("|"))}
    assert set(mdes) == {"`opencv-bm`", "`opencv-sgbm`"}
    assert all(float(v) > 0 for v in mdes.values())  # million disparity evaluations per second
    for name in ("speed_accuracy_synthetic.png", "bad2_per_dataset.png"):
        assert (docs / name).stat().st_size > 0
        assert f"(docs/bench/{name})" in text
    assert list(docs.glob("panel_*.jpg"))


def test_bench_bad_method_is_one_line(capsys):
    assert bench.main(["--methods", "nonsense", "--no-real", "--synthetic", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "valid names" in err[0]


def test_bench_merge_adds_methods(tmp_path, monkeypatch):
    tiny = _tiny_dataset()
    real_run = bench.run_evaluation
    monkeypatch.setattr(bench, "run_evaluation", lambda *a, **k: real_run(*a, **{**k, "load": tiny}))
    out, docs = tmp_path / "B.md", tmp_path / "bench"
    common = ["--synthetic", "2", "--no-real", "--out", str(out), "--docs", str(docs), "--no-progress"]
    assert bench.main(["--methods", "opencv-sgbm", *common]) == 0
    assert "`opencv-bm`" not in out.read_text()
    assert bench.main(["--methods", "opencv-bm", "--merge", *common]) == 0
    text = out.read_text()
    assert "| `opencv-bm` |" in text and "| `opencv-sgbm` |" in text
    runs = {p.run for p in bench.load_pairs(docs / "pairs.json")}
    assert runs == {0, 1}
    assert len(list(docs.glob("panel_*_run1.jpg"))) == 1 and len(list(docs.glob("panel_*.jpg"))) == 2
    out.unlink()
    assert bench.main(["--report-only", *common]) == 0  # rewritten from pairs.json, nothing re-run
    assert "| `opencv-bm` |" in out.read_text()


def test_pairs_line_counts_each_datasets_pairs_once():
    dataset_pairs, pairs_line = bench.dataset_pairs, bench.pairs_line
    from stereonet.evaluation import Evaluation, PairResult

    def r(method, dataset, pair):
        return PairResult(method, dataset, pair, {"bad2": 1.0}, {"bad2": 1.0}, 0.1, 1.0)

    ev = Evaluation([r(m, d, p) for m in ("sgm", "bm-sad") for d, p in
                     (("middlebury2001", "tsukuba"), ("middlebury2001", "venus"), ("kitti2012", "000000_10"))])
    assert dataset_pairs(ev, ["middlebury2001", "kitti2012"]) == {"middlebury2001": ["tsukuba", "venus"],
                                                                  "kitti2012": ["000000_10"]}
    line = pairs_line(ev, ["middlebury2001", "kitti2012"])
    assert "**3 pairs**" in line and "middlebury2001 2 (tsukuba, venus)" in line and "kitti2012 1" in line


def test_counterpart_ratios_hold_block_matchers_against_opencv_bm():
    from stereonet.evaluation import Evaluation, PairResult

    seconds = {("opencv-bm", "a"): 1.0, ("opencv-bm", "b"): 2.0, ("opencv-sgbm", "a"): 4.0, ("opencv-sgbm", "b"): 4.0,
               ("bm-sad", "a"): 1.5, ("bm-sad", "b"): 2.0, ("sgm", "a"): 4.0, ("sgm", "b"): 12.0}
    ev = Evaluation([PairResult(m, "d", p, {"bad2": 1.0}, {"bad2": 1.0}, s, 1.0) for (m, p), s in seconds.items()])
    rows = {r["method"]: r for r in bench.counterpart_ratios(ev, {"real": ["d"]})}
    assert set(rows) == {"bm-sad", "sgm"}  # the references are not held against themselves
    assert rows["bm-sad"]["reference"] == "opencv-bm" and rows["sgm"]["reference"] == "opencv-sgbm"
    assert (rows["bm-sad"]["median"], rows["bm-sad"]["worst"]) == (1.25, 1.5)
    assert (rows["sgm"]["median"], rows["sgm"]["worst"]) == (2.0, 3.0)
    lines = bench.counterpart_table(list(rows.values()), ["real"])
    assert "| `bm-sad` | `opencv-bm` | 1.25 | 1.50 |" in lines and "| `sgm` | `opencv-sgbm` | 2.00 | 3.00 |" in lines


def test_bench_classical_bad_method_is_one_line_before_anything_runs(capsys):
    """scripts/bench_classical.py checks --methods and --accuracy names first: a typo is one line and exit 2."""
    import pytest

    spec = importlib.util.spec_from_file_location("stereonet_bench_classical", REPO / "scripts" / "bench_classical.py")
    classical = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(classical)
    for argv in (["--methods", "bm-sad", "--accuracy", "none"], ["--methods", "bm-foo", "--accuracy", ""]):
        with pytest.raises(SystemExit) as e:
            classical.main(argv)
        assert e.value.code == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "unknown matcher" in err and "--methods/--accuracy" in err


def test_bench_bad_repeats_is_one_line(capsys):
    assert bench.main(["--repeats", "0", "--no-real", "--synthetic", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--repeats" in err[0]
