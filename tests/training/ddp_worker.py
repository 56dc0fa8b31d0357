"""Run by tests/training/test_ddp.py in a fresh interpreter: two DDP processes (gloo, forked from this clean
process, which has started no OpenMP thread pool yet) train a tiny Siamese; each rank writes a record.

    python tests/training/ddp_worker.py OUT_DIR
"""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path
from unittest import mock

import lightning as L
import torch
import torch.distributed as dist

CONFIG = Path(__file__).resolve().parents[2] / "configs" / "siamese-quick.yaml"
TINY = ["--data.source", "random-shift", "--data.height", "32", "--data.width", "64", "--data.batch_size", "2",
        "--data.val_pairs", "2", "--data.pool_size", "2", "--data.reuse", "1", "--trainer.logger", "false",
        "--trainer.enable_checkpointing", "false", "--trainer.callbacks", "[]", "--trainer.max_steps", "4",
        "--trainer.val_check_interval", "4", "--trainer.enable_progress_bar", "false"]


class Recorder(L.Callback):
    """Writes, per rank, a hash of every training batch and a checksum of the final weights."""

    def __init__(self, folder: Path, initial: list[float]) -> None:
        self.folder, self.batches, self.backend, self.initial = folder, [], None, initial

    def on_train_batch_start(self, trainer, module, batch, batch_idx):
        self.backend = dist.get_backend() if dist.is_initialized() else None
        digest = hashlib.sha1(batch["left"].numpy().tobytes() + batch["disparity"].numpy().tobytes())
        self.batches.append(digest.hexdigest())

    def on_train_end(self, trainer, module):
        weights = torch.cat([p.detach().flatten() for p in module.parameters()])
        record = {"rank": trainer.global_rank, "world": trainer.world_size, "batches": self.batches,
                  "backend": self.backend, "weights": [float(weights.sum()), float(weights.abs().sum())],
                  "initial": self.initial, "steps": trainer.global_step}
        (self.folder / f"rank{trainer.global_rank}.json").write_text(json.dumps(record))


def main(out: Path) -> None:
    from stereonet.cli.train import main as train_main

    with mock.patch.object(sys, "argv", ["train.py"]):
        cli = train_main(["--config", str(CONFIG), *TINY, "--trainer.accelerator", "cpu", "--trainer.devices", "2",
                          "--trainer.strategy", "ddp_fork", "--trainer.default_root_dir", str(out)], run=False)
    initial = torch.cat([p.detach().flatten() for p in cli.model.parameters()])
    cli.trainer.callbacks.append(Recorder(out, [float(initial.sum()), float(initial.abs().sum())]))
    cli.trainer.fit(cli.model, datamodule=cli.datamodule)


if __name__ == "__main__":
    main(Path(sys.argv[1]))
