"""Scale-out on the CPU: two DDP processes (gloo, forked) train together; each rank sees its own pairs and
both end with the same weights (gradients were all-reduced)."""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path
from unittest import mock

import lightning as L
import pytest
import torch
import torch.distributed as dist

CONFIG = Path(__file__).resolve().parents[2] / "configs" / "siamese-quick.yaml"
TINY = ["--data.source", "random-shift", "--data.height", "32", "--data.width", "64", "--data.batch_size", "2",
        "--data.val_pairs", "2", "--data.pool_size", "2", "--data.reuse", "1", "--trainer.logger", "false",
        "--trainer.enable_checkpointing", "false", "--trainer.callbacks", "[]", "--trainer.max_steps", "4",
        "--trainer.val_check_interval", "4", "--trainer.enable_progress_bar", "false"]


class Recorder(L.Callback):
    """Writes, per rank, a hash of every training batch and a checksum of the final weights."""

    def __init__(self, folder: Path) -> None:
        self.folder, self.batches, self.backend = folder, [], None

    def on_train_batch_start(self, trainer, module, batch, batch_idx):
        self.backend = dist.get_backend() if dist.is_initialized() else None
        digest = hashlib.sha1(batch["left"].numpy().tobytes() + batch["disparity"].numpy().tobytes())
        self.batches.append(digest.hexdigest())

    def on_train_end(self, trainer, module):
        weights = torch.cat([p.detach().flatten() for p in module.parameters()])
        record = {"rank": trainer.global_rank, "world": trainer.world_size, "batches": self.batches,
                  "backend": self.backend, "weights": [float(weights.sum()), float(weights.abs().sum())],
                  "steps": trainer.global_step}
        (self.folder / f"rank{trainer.global_rank}.json").write_text(json.dumps(record))


@pytest.mark.skipif(not dist.is_available() or not dist.is_gloo_available(), reason="torch built without gloo")
def test_two_ddp_processes_see_different_pairs_and_train_together(tmp_path, monkeypatch):
    from stereonet.cli.train import main

    monkeypatch.chdir(tmp_path)
    with mock.patch.object(sys, "argv", ["train.py"]):
        cli = main(["--config", str(CONFIG), *TINY, "--trainer.accelerator", "cpu", "--trainer.devices", "2",
                    "--trainer.strategy", "ddp_fork"], run=False)
    initial = torch.cat([p.detach().flatten() for p in cli.model.parameters()]).clone()
    cli.trainer.callbacks.append(Recorder(tmp_path))
    cli.trainer.fit(cli.model, datamodule=cli.datamodule)
    r0, r1 = (json.loads((tmp_path / f"rank{r}.json").read_text()) for r in (0, 1))
    assert (r0["rank"], r1["rank"], r0["world"], r0["backend"]) == (0, 1, 2, "gloo")
    assert r0["steps"] == r1["steps"] == 4 and len(r0["batches"]) == len(r1["batches"]) == 4
    assert not set(r0["batches"]) & set(r1["batches"])  # rank-aware stream seeds: no shared pair
    assert r0["weights"] == pytest.approx(r1["weights"], rel=1e-6)  # all-reduced gradients: one model
    assert r0["weights"] != pytest.approx([float(initial.sum()), float(initial.abs().sum())], rel=1e-6)
