"""Matching under a memory budget (stereonet.tiling): strips with overlap equal the untiled run within the
issue's tolerance (bad-2 within 0.1 points), the plan covers every row once, and a budget too small for one
strip is one line naming the budget."""

from __future__ import annotations

import pytest
import torch

from data_gen import render_pair
from stereonet import matchers
from stereonet.checks import StereoInputError
from stereonet.metrics import evaluate
from stereonet.tiling import match_with_budget, plan_strips


def test_plan_covers_each_row_once():
    for h, rows, ov in ((100, 40, 8), (37, 36, 10), (500, 200, 48)):
        plan = plan_strips(h, rows, ov)
        covered = []
        for y0, y1, top, bottom in plan:
            assert 0 <= y0 < y1 <= h and 0 <= top < bottom <= y1 - y0
            covered += list(range(y0 + top, y0 + bottom))
        assert covered == list(range(h))


@pytest.mark.parametrize("name", ["sgm", "bm-census"])
def test_strips_match_the_untiled_run(name):
    p = render_pair(11, 0, difficulty=2, height=192, width=256)
    left, right = p["left"][None], p["right"][None]
    fn = matchers.get_matcher(name)
    info: dict = {}
    whole = match_with_budget(fn, left, right, 64, budget_mib=1e6, overlap=32, info=info)
    assert info["strips"] == 1
    info = {}
    tiled = match_with_budget(fn, left, right, 64, overlap=32, info=info, rows_per_strip=100)
    assert info["strips"] == 6  # 36-row cores over 192 rows
    assert tiled.disparity.shape == whole.disparity.shape
    gt, gv = p["disparity"][None], p["valid"][None]
    b_whole = evaluate(whole.disparity, gt, gv, pred_valid=whole.valid, see=False)["bad2"]
    b_tiled = evaluate(tiled.disparity, gt, gv, pred_valid=tiled.valid, see=False)["bad2"]
    assert abs(b_whole - b_tiled) <= 0.1, (b_whole, b_tiled)  # the tolerance
    same = (whole.disparity - tiled.disparity).abs() <= 1.0
    assert float(same.float().mean()) > 0.97  # differences only near seams (speckle regions, SGM's long paths)


def test_the_budget_sets_the_strip_height(monkeypatch):
    """With a measured 0.05 MiB per row, strips of int(0.7 * budget / 0.05) rows (minus 2 x 16 overlap rows
    of core): more budget, fewer strips; below one strip, the one-line error."""
    import stereonet.tiling as tiling

    class FakePeak:  # a deterministic measurement: 0.05 MiB per probe row
        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.peak_mib = 0.05 * self.rows
            return False

    calls = []

    def fn(left, right, max_disp):
        FakePeak.rows = left.shape[-2]
        calls.append(left.shape[-2])
        return matchers.match("bm-sad", left, right, max_disp)

    monkeypatch.setattr(tiling, "PeakMemory", lambda: type("P", (FakePeak,), {})())
    left = torch.rand(1, 3, 300, 64)
    for budget, strips in ((100.0, 1), (8.0, 4), (4.0, 14)):
        info: dict = {}
        FakePeak.rows = min(300, tiling.PROBE_ROWS + 2 * 16)
        out = match_with_budget(fn, left, left, 40, budget_mib=budget, overlap=16, info=info)
        assert info["strips"] == strips and out.disparity.shape[-2] == 300, (budget, info)
    with pytest.raises(StereoInputError, match="--memory-budget: 2 MiB is too small"):
        match_with_budget(fn, left, left, 40, budget_mib=2.0, overlap=16)


def test_too_small_a_budget_is_one_line():
    left = torch.rand(1, 3, 120, 160)
    with pytest.raises(StereoInputError, match="--memory-budget: 0.001 MiB is too small") as e:
        match_with_budget(matchers.get_matcher("sgm"), left, left, 32, budget_mib=0.001)
    assert "\n" not in str(e.value)
    with pytest.raises(StereoInputError, match="positive"):
        match_with_budget(matchers.get_matcher("sgm"), left, left, 32, budget_mib=0)


def test_eval_memory_budget(tmp_path, capsys):
    """eval.py --memory-budget: the same table within the tolerance when strips are needed; too small a budget
    is one line, exit 2 (bad input, not a failed method)."""
    from stereonet.cli import eval as ev

    assert ev.main(["--methods", "bm-sad", "--data", "synthetic:1", "--memory-budget", "0.001", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--memory-budget" in err[0] and "too small" in err[0]
    assert ev.main(["--methods", "bm-sad", "--data", "synthetic:1", "--memory-budget", "-1", "--no-progress"]) == 2
    assert ev.main(["--methods", "bm-sad", "--data", "synthetic:1", "--memory-budget", "40", "--no-progress"]) == 0
