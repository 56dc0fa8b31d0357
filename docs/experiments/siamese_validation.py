"""Siamese towers compared where they serve: ``siamese-census-sgm`` and ``sgm-refine`` (the shipped ``refine.pt``
reading each tower's map) with eval.py's fill on data_gen validation sets (val_sets.py), or on the real pairs
(evaluation only), against the shipped ``siamese.pt``.

    python docs/experiments/siamese_validation.py W1.pt[,W2.pt,...] [SPECS]     (default "val2h;val4h"; e.g. "real")

Each tower runs from a temporary weights folder holding it as ``siamese.pt`` beside the other shipped files
(``$STEREONET_WEIGHTS_DIR``), so that ``sgm-refine`` reads it too. First used by the twentieth session's SGM-loss
fine-tuning (docs/experiments/siamese_sgm_loss.txt).
"""
import functools
import os
import sys
import tempfile
from pathlib import Path

from val_sets import compare

from stereonet.matchers.learned import sgm_refine_matcher, siamese_census_sgm_matcher
from stereonet.models.weights import WEIGHTS_DIR_ENV, weights_dir


def in_folder(fn, folder, left, right, max_disp, **options):
    old = os.environ.get(WEIGHTS_DIR_ENV)
    os.environ[WEIGHTS_DIR_ENV] = str(folder)
    try:
        return fn(left, right, max_disp, **options)
    finally:
        if old is None:
            del os.environ[WEIGHTS_DIR_ENV]
        else:
            os.environ[WEIGHTS_DIR_ENV] = old


def folder_with(tower: Path, root: Path) -> Path:
    folder = root / tower.stem
    folder.mkdir()
    for f in weights_dir().glob("*.pt"):
        (folder / f.name).symlink_to(f.resolve())
    (folder / "siamese.pt").unlink()
    (folder / "siamese.pt").symlink_to(tower.resolve())
    return folder


towers = [Path(p) for p in sys.argv[1].split(",")]
specs = sys.argv[2].split(";") if len(sys.argv) > 2 else ["val2h", "val4h"]
with tempfile.TemporaryDirectory() as tmp:
    folders = {"shipped": weights_dir(), **{t.stem: folder_with(t, Path(tmp)) for t in towers}}
    variants = {}
    for label, folder in folders.items():
        variants[f"census-sgm-{label}"] = (functools.partial(in_folder, siamese_census_sgm_matcher, folder), {})
        variants[f"sgm-refine-{label}"] = (functools.partial(in_folder, sgm_refine_matcher, folder), {})
    compare(variants, specs)
