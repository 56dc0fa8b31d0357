"""Scale-out on the CPU: two DDP processes (gloo, forked) train together; each rank sees its own pairs and
both end with the same weights (gradients were all-reduced).

The two ranks are forked from a fresh interpreter (tests/training/ddp_worker.py), not from the test process:
a process whose OpenMP thread pool has run (every earlier test) may deadlock in a forked child's first
parallel operation, which once stalled this test in a full run.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch.distributed as dist

WORKER = Path(__file__).resolve().parent / "ddp_worker.py"
ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.skipif(not dist.is_available() or not dist.is_gloo_available(), reason="torch built without gloo")
def test_two_ddp_processes_see_different_pairs_and_train_together(tmp_path):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    run = subprocess.run([sys.executable, str(WORKER), str(tmp_path)], cwd=tmp_path, env=env, capture_output=True,
                         text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    r0, r1 = (json.loads((tmp_path / f"rank{r}.json").read_text()) for r in (0, 1))
    assert (r0["rank"], r1["rank"], r0["world"], r0["backend"]) == (0, 1, 2, "gloo")
    assert r0["steps"] == r1["steps"] == 4 and len(r0["batches"]) == len(r1["batches"]) == 4
    assert not set(r0["batches"]) & set(r1["batches"])  # rank-aware stream seeds: no shared pair
    assert r0["weights"] == pytest.approx(r1["weights"], rel=1e-6)  # all-reduced gradients: one model
    assert r0["initial"] == pytest.approx(r1["initial"], rel=1e-9)  # both started from the same weights
    assert r0["weights"] != pytest.approx(r0["initial"], rel=1e-6)  # and the run trained
