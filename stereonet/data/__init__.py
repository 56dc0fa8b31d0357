"""Datasets: ``load_dataset(spec)`` -> a torch ``Dataset`` of item dicts (see :mod:`stereonet.data.base`).

Specs (as in DESIGN.md): ``synthetic[:N]``, ``middlebury2001:DIR``, ``middlebury2003:DIR``,
``middlebury2014:DIR``, ``kitti2012:DIR``, ``kitti2015:DIR``, ``folder:DIR`` and ``real`` (every dataset in
``../shared/data`` beside the repository). DIR holds the scene folders (or is one scene); for KITTI it holds
``training/``. A spec that does not exist or has the wrong layout raises a one-line
:class:`~stereonet.checks.StereoInputError` naming the spec and what was expected.
"""

from __future__ import annotations

import os
from pathlib import Path

from torch.utils.data import Dataset

from stereonet.checks import StereoInputError
from stereonet.data.base import (
    PairRecord,
    StereoPairDataset,
    collate_stereo,
    item_max_disp,
    load_pair,
    occlusion_from_lr_check,
    round_up_max_disp,
)
from stereonet.data.layouts import (
    FOLDER_EXPECTED,
    MIDDLEBURY2001_EXPECTED,
    MIDDLEBURY2003_EXPECTED,
    MIDDLEBURY2014_EXPECTED,
    folder_records,
    kitti_expected,
    kitti_records,
    middlebury2001_records,
    middlebury2003_records,
    middlebury2014_records,
)

__all__ = [
    "BENCHMARK_SEED", "DATASET_KINDS", "PairRecord", "StereoPairDataset", "collate_stereo", "item_max_disp",
    "load_dataset", "load_pair", "occlusion_from_lr_check", "round_up_max_disp", "shared_data_dir",
]

# Seed of the synthetic benchmark set: fixed, and far from the small seeds training configs use, so the
# benchmark pairs are never training pairs.
BENCHMARK_SEED = 7_000_001
DEFAULT_SYNTHETIC_COUNT = 8

_READERS = {
    "middlebury2001": (middlebury2001_records, MIDDLEBURY2001_EXPECTED),
    "middlebury2003": (middlebury2003_records, MIDDLEBURY2003_EXPECTED),
    "middlebury2014": (middlebury2014_records, MIDDLEBURY2014_EXPECTED),
    "kitti2012": (lambda root: kitti_records(root, "kitti2012"), kitti_expected("kitti2012")),
    "kitti2015": (lambda root: kitti_records(root, "kitti2015"), kitti_expected("kitti2015")),
    "folder": (folder_records, FOLDER_EXPECTED),
}
DATASET_KINDS = ("synthetic", *_READERS, "real")
# Folders of ../shared/data that ``real`` reads, each with the reader of the same name.
_REAL_KINDS = ("middlebury2001", "middlebury2003", "middlebury2014", "kitti2012", "kitti2015")


def shared_data_dir() -> Path | None:
    """``$STEREONET_SHARED_DATA``, else ``../shared/data`` beside the repository (resolved from the package
    location, then from the working directory); None when none exists."""
    env = os.environ.get("STEREONET_SHARED_DATA")
    candidates = [Path(env)] if env else []
    candidates += [Path(__file__).resolve().parents[2].parent / "shared" / "data",
                   Path.cwd().parent / "shared" / "data", Path.cwd() / "shared" / "data"]
    return next((c for c in candidates if c.is_dir()), None)


def load_dataset(spec: str) -> Dataset:
    """Open a dataset by spec (see the module docstring); files are read lazily, item by item."""
    if not isinstance(spec, str) or not spec.strip():
        raise StereoInputError(f"spec: expected a data spec like 'middlebury2014:DIR' or 'synthetic:8', got {spec!r}")
    spec = spec.strip()
    kind, sep, arg = spec.partition(":")
    if kind == "synthetic":
        return _synthetic(spec, arg if sep else None)
    if kind == "real":
        if sep:
            raise StereoInputError(f"data spec {spec!r}: 'real' takes no argument")
        return _real(spec)
    if kind not in _READERS:
        raise StereoInputError(f"data spec {spec!r}: unknown kind {kind!r}; expected one of "
                               f"{', '.join(k + ('[:N]' if k == 'synthetic' else '' if k == 'real' else ':DIR') for k in DATASET_KINDS)}")
    if not arg:
        raise StereoInputError(f"data spec {spec!r}: expected {kind}:DIR with the folder after the colon")
    root = Path(arg).expanduser()
    if not root.is_dir():
        raise StereoInputError(f"data spec {spec!r}: folder {root} does not exist"
                               if not root.exists() else f"data spec {spec!r}: {root} is not a folder")
    reader, expected = _READERS[kind]
    records = reader(root)
    if not records:
        raise StereoInputError(f"data spec {spec!r}: no pairs found in {root}; expected {expected}")
    return StereoPairDataset(records, spec)


class _SyntheticItems(Dataset):
    """data_gen's dataset with the item dict completed (``name``, ``max_disp``) where it leaves them out."""

    def __init__(self, inner: Dataset, spec: str):
        self.inner, self.spec = inner, spec

    def __len__(self) -> int:
        return len(self.inner)

    def __getitem__(self, index: int) -> dict:
        item = dict(self.inner[index])
        item.setdefault("name", f"synthetic-{index:04d}")
        if "max_disp" not in item:
            item["max_disp"] = item_max_disp(item)
        item["max_disp"] = int(item["max_disp"])
        return item

    def __repr__(self) -> str:
        return f"SyntheticDataset({self.spec!r}, {len(self)} pairs, seed {BENCHMARK_SEED})"


def _synthetic(spec: str, count_text: str | None) -> Dataset:
    count = DEFAULT_SYNTHETIC_COUNT
    if count_text is not None:
        try:
            count = int(count_text)
        except ValueError:
            count = -1
        if count <= 0:
            raise StereoInputError(f"data spec {spec!r}: expected synthetic[:N] with a positive integer N, "
                                   f"got {count_text!r}")
    try:
        import data_gen  # written by its own engineer; imported only when asked for
        make = data_gen.SyntheticStereo
    except (ImportError, AttributeError) as e:
        raise StereoInputError(f"data spec {spec!r}: data_gen.SyntheticStereo is not available ({e})") from None
    return _SyntheticItems(make(count=count, seed=BENCHMARK_SEED), spec)


def _real(spec: str) -> Dataset:
    shared = shared_data_dir()
    if shared is None:
        raise StereoInputError(f"data spec {spec!r}: no ../shared/data folder beside the repository "
                               f"(or set STEREONET_SHARED_DATA)")
    records: list[PairRecord] = []
    for kind in _REAL_KINDS:
        if (shared / kind).is_dir():
            for r in _READERS[kind][0](shared / kind):
                records.append(PairRecord(**{**r.__dict__, "name": f"{kind}/{r.name}"}))
    if not records:
        raise StereoInputError(f"data spec {spec!r}: no datasets found in {shared}; expected sub-folders "
                               f"{', '.join(_REAL_KINDS)}")
    return StereoPairDataset(records, spec)
