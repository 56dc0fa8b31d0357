"""``python train.py fit --config configs/NAME.yaml [--trainer.max_steps N] [--ckpt_path last]``.

A LightningCLI over the LightningModules of :mod:`stereonet.training.module` (chosen by ``model.class_path``
in the YAML) and :class:`~stereonet.training.data.SyntheticStereoDataModule`. Every run gets the curriculum
callback and atomic checkpoint writes; seeds are fixed by ``seed_everything`` (default 0).
"""

from __future__ import annotations

from lightning.pytorch.cli import LightningCLI

from stereonet.training.callbacks import AtomicCheckpointIO, CurriculumCallback
from stereonet.training.data import SyntheticStereoDataModule
from stereonet.training.module import StereoModule


class StereoCLI(LightningCLI):
    """LightningCLI with stereonet's defaults (curriculum, atomic checkpoints)."""

    def instantiate_trainer(self, **kwargs):
        trainer = super().instantiate_trainer(**kwargs)
        if not any(isinstance(cb, CurriculumCallback) for cb in trainer.callbacks):
            trainer.callbacks.append(CurriculumCallback())
        trainer.strategy.checkpoint_io = AtomicCheckpointIO()
        return trainer


def main(args: list[str] | None = None, run: bool = True) -> StereoCLI:
    """Entry point of ``train.py`` / ``stereonet-train``; ``args``/``run`` as LightningCLI's (for tests)."""
    return StereoCLI(
        StereoModule,
        SyntheticStereoDataModule,
        subclass_mode_model=True,
        seed_everything_default=0,
        save_config_kwargs={"overwrite": True},
        args=args,
        run=run,
    )


if __name__ == "__main__":
    main()
