"""Callbacks and plugins: curriculum updates, atomic checkpoint writes."""

from __future__ import annotations

import os
from typing import Any

import lightning as L
import torch
from lightning.pytorch.callbacks import Timer
from lightning.pytorch.plugins.io import TorchCheckpointIO
from lightning.pytorch.trainer.states import RunningStage

from stereonet.io.atomic import atomic_path
from stereonet.training.curriculum import training_progress


class AtomicCheckpointIO(TorchCheckpointIO):
    """Checkpoint writer that saves to a temporary file beside the target and renames it into place.

    A run killed while saving therefore leaves the previous ``last.ckpt`` intact, and ``--ckpt_path last``
    always resumes from a complete file.
    """

    def save_checkpoint(self, checkpoint: dict[str, Any], path: str | os.PathLike,
                        storage_options: Any | None = None) -> None:
        if storage_options is not None:
            raise TypeError(f"storage_options: {type(self).__name__} takes none, got {storage_options!r}")
        with atomic_path(path) as tmp:
            torch.save(checkpoint, tmp)


def trainer_progress(trainer: L.Trainer, fallback_steps: int) -> float:
    """Training progress in [0, 1]: the larger of steps done / ``max_steps`` and, when ``max_time`` is set,
    time spent / ``max_time`` (so schedules finish even when the time budget ends the run first)."""
    progress = training_progress(trainer.global_step, trainer.max_steps, fallback_steps)
    for cb in trainer.callbacks:
        if isinstance(cb, Timer) and cb._duration:
            progress = max(progress, min(cb.time_elapsed(RunningStage.TRAINING) / cb._duration, 1.0))
    return progress


class CurriculumCallback(L.Callback):
    """Tells the datamodule the training progress before every batch (and epoch), so that the difficulty of
    rendered pairs follows :func:`~stereonet.training.curriculum.difficulty_at`.

    Args:
        fallback_steps: progress horizon when ``trainer.max_steps`` is unset.
    """

    def __init__(self, fallback_steps: int = 10_000) -> None:
        self.fallback_steps = fallback_steps
        self.reached = 0  # the highest level set so far; saved in checkpoints, so that a continuation with a
        # larger max_steps (its progress pulled back inside the ramp) does not go back to easier renders

    def state_dict(self) -> dict[str, Any]:
        return {"reached": self.reached}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        self.reached = int(state_dict.get("reached", 0))

    def update(self, trainer: L.Trainer, start: bool = False) -> None:
        """Set the datamodule's progress (and, with ``start``, its stream's start step) from the trainer."""
        dm = trainer.datamodule
        if dm is None or not hasattr(dm, "set_progress"):
            return
        progress = trainer_progress(trainer, self.fallback_steps)
        dm.set_progress(progress, trainer.global_step if start else None, floor=self.reached)
        self.reached = max(self.reached, int(getattr(dm, "difficulty", 0)))

    def on_train_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self.update(trainer, start=True)

    def on_train_batch_start(self, trainer: L.Trainer, pl_module: L.LightningModule, batch: Any,
                             batch_idx: int) -> None:
        self.update(trainer)
        pl_module.log("train/difficulty", float(getattr(trainer.datamodule, "difficulty", 0)),
                      on_step=True, on_epoch=False)
