"""``python train.py fit --config configs/NAME.yaml [--trainer.max_steps N] [--ckpt_path last]``.

``--data.train SPEC [--data.train_ratio R]`` mixes random crops of a labelled dataset (any spec eval.py
reads: ``sceneflow:DIR``, ``kitti2015:DIR``, ``folder:DIR`` with ground truth) into the data_gen stream, a
share R of the items (default 0.5; 1 = that dataset only): training or fine-tuning on one's own data.

A LightningCLI over the LightningModules of :mod:`stereonet.training.module` (chosen by ``model.class_path``
in the YAML) and :class:`~stereonet.training.data.SyntheticStereoDataModule`. Every run gets the curriculum
callback and atomic checkpoint writes; seeds are fixed by ``seed_everything`` (default 0).
"""

from __future__ import annotations

import sys

from lightning.pytorch.cli import LightningArgumentParser, LightningCLI

from stereonet.checks import StereoInputError
from stereonet.cli.common import fail
from stereonet.training.callbacks import AtomicCheckpointIO, CurriculumCallback
from stereonet.training.data import SyntheticStereoDataModule
from stereonet.training.module import StereoModule


class OneLineArgumentParser(LightningArgumentParser):
    """LightningCLI's parser, reporting a usage error (a missing config file, a misspelt key) as one line,
    ``train.py: error: ...``, exit 2, instead of the usage text, a tip and the error."""

    def error(self, message: str, ex: Exception | None = None):
        if not self.exit_on_error:  # a caller that asked for the exception gets it
            return super().error(message, ex)
        sys.exit(fail("train.py", f"{message} (see --help)"))


class StereoCLI(LightningCLI):
    """LightningCLI with stereonet's defaults (curriculum, atomic checkpoints)."""

    def instantiate_trainer(self, **kwargs):
        trainer = super().instantiate_trainer(**kwargs)
        if not any(isinstance(cb, CurriculumCallback) for cb in trainer.callbacks):
            trainer.callbacks.append(CurriculumCallback())
        trainer.strategy.checkpoint_io = AtomicCheckpointIO()
        return trainer


def main(args: list[str] | None = None, run: bool = True) -> StereoCLI:
    """Entry point of ``train.py`` / ``stereonet-train``; ``args``/``run`` as LightningCLI's (for tests).

    Bad data input (``--data.train`` naming an unreadable or unlabelled spec) ends in one line, exit 2.
    """
    try:
        return _cli(args, run)
    except StereoInputError as e:
        raise SystemExit(fail("train.py", e)) from None
    except ValueError as e:  # the config parser wraps a model's own input check (subclass mode) in its report
        cause = _input_error_in(e)
        if cause is None:
            raise
        raise SystemExit(fail("train.py", cause)) from None


def _input_error_in(error: BaseException) -> StereoInputError | None:
    """The StereoInputError that caused ``error`` (following ``__cause__`` and ``__context__``), if any."""
    seen = set()
    while error is not None and id(error) not in seen:
        if isinstance(error, StereoInputError):
            return error
        seen.add(id(error))
        error = error.__cause__ or error.__context__
    return None


def _cli(args: list[str] | None, run: bool) -> StereoCLI:
    return StereoCLI(
        StereoModule,
        SyntheticStereoDataModule,
        parser_class=OneLineArgumentParser,
        subclass_mode_model=True,
        seed_everything_default=0,
        save_config_kwargs={"overwrite": True},
        args=args,
        run=run,
    )


if __name__ == "__main__":
    main()
