"""Datasets: ``load_dataset(spec)`` -> a torch ``Dataset`` of item dicts (see :mod:`stereonet.data.base`).

Specs (as in DESIGN.md): ``synthetic[:N]``, ``middlebury2001:DIR``, ``middlebury2003:DIR``,
``middlebury2006:DIR``, ``middlebury2014:DIR``, ``kitti2012:DIR``, ``kitti2015:DIR``, ``eth3d:DIR``,
``sceneflow[-clean|-final][-train|-test]:DIR``, ``folder:DIR`` and ``real`` (every dataset in
``../shared/data`` beside the repository; without one, the four Middlebury pairs bundled in
``stereonet/data/bundled``). DIR holds the scene folders (or is one scene); for KITTI it holds
``training/``; for SceneFlow it holds ``frames_finalpass/`` (or ``frames_cleanpass/``) and ``disparity/``, or
sub-folders that do (FlyingThings3D, Monkaa, Driving side by side).

- ``middlebury2006:DIR``: Middlebury 2005 and 2006 scenes (``view1``/``view5``, ``disp1``/``disp5``) at full,
  half or third size; the disparity scale comes from the ``FullSize``/``HalfSize``/``ThirdSize`` folder
  (or the image width), see :func:`stereonet.data.layouts.middlebury2006_records`.
- ``sceneflow:DIR`` reads the final pass and every pair; ``-clean`` picks the clean pass (``-final`` says
  the default), ``-train``/``-test`` FlyingThings3D's official split (the ``TRAIN``/``TEST`` folders), in
  that order: ``sceneflow-clean-test:DIR``.
- ``eth3d:DIR``: the ETH3D two-view training scenes; ``mask0nocc.png`` gives the ``*_noc`` pixels.

A spec that does not exist or has the wrong layout raises a one-line
:class:`~stereonet.checks.StereoInputError` naming the spec and what was expected; a scene with a missing
view or ground truth file, or a truncated or corrupt file, raises one naming the file.
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
    ETH3D_EXPECTED,
    FOLDER_EXPECTED,
    MIDDLEBURY2001_EXPECTED,
    MIDDLEBURY2003_EXPECTED,
    MIDDLEBURY2006_EXPECTED,
    MIDDLEBURY2014_EXPECTED,
    SCENEFLOW_EXPECTED,
    SCENEFLOW_PASSES,
    SCENEFLOW_SPLITS,
    eth3d_records,
    folder_records,
    kitti_expected,
    kitti_records,
    middlebury2001_records,
    middlebury2003_records,
    middlebury2006_records,
    middlebury2014_records,
    sceneflow_records,
)

__all__ = [
    "BENCHMARK_SEED", "DATASET_KINDS", "PairRecord", "StereoPairDataset", "collate_stereo", "item_max_disp",
    "REAL_KINDS", "load_dataset", "load_pair", "occlusion_from_lr_check", "real_data_dir", "round_up_max_disp", "shared_data_dir",
]

# Seed of the synthetic benchmark set: fixed, and far from the small seeds training configs use, so the
# benchmark pairs are never training pairs.
BENCHMARK_SEED = 7_000_001
DEFAULT_SYNTHETIC_COUNT = 8

_READERS = {
    "middlebury2001": (middlebury2001_records, MIDDLEBURY2001_EXPECTED),
    "middlebury2003": (middlebury2003_records, MIDDLEBURY2003_EXPECTED),
    "middlebury2006": (middlebury2006_records, MIDDLEBURY2006_EXPECTED),
    "middlebury2014": (middlebury2014_records, MIDDLEBURY2014_EXPECTED),
    "kitti2012": (lambda root: kitti_records(root, "kitti2012"), kitti_expected("kitti2012")),
    "kitti2015": (lambda root: kitti_records(root, "kitti2015"), kitti_expected("kitti2015")),
    "eth3d": (eth3d_records, ETH3D_EXPECTED),
    "sceneflow": (sceneflow_records, SCENEFLOW_EXPECTED),
    "folder": (folder_records, FOLDER_EXPECTED),
}
DATASET_KINDS = ("synthetic", *_READERS, "real")
# How each kind is written in an error that lists them (the ones with options show them).
_KIND_SYNTAX = {"synthetic": "synthetic[:N]", "real": "real",
                "sceneflow": f"sceneflow[-{'|-'.join(SCENEFLOW_PASSES[::-1])}][-{'|-'.join(SCENEFLOW_SPLITS)}]:DIR"}
# Folders of ../shared/data that ``real`` reads, each with the reader of the same name.
REAL_KINDS = ("middlebury2001", "middlebury2003", "middlebury2006", "middlebury2014", "eth3d", "kitti2012", "kitti2015")


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
    reader_kind = "sceneflow" if kind.startswith("sceneflow-") else kind
    if kind == "synthetic":
        return _synthetic(spec, arg if sep else None)
    if kind == "real":
        if sep:
            raise StereoInputError(f"data spec {spec!r}: 'real' takes no argument")
        return _real(spec)
    if reader_kind not in _READERS:
        raise StereoInputError(f"data spec {spec!r}: unknown kind {kind!r}; expected one of "
                               f"{', '.join(_KIND_SYNTAX.get(k, k + ':DIR') for k in DATASET_KINDS)}")
    if not arg:
        raise StereoInputError(f"data spec {spec!r}: expected {kind}:DIR with the folder after the colon")
    root = Path(arg).expanduser()
    if not root.is_dir():
        raise StereoInputError(f"data spec {spec!r}: folder {root} does not exist"
                               if not root.exists() else f"data spec {spec!r}: {root} is not a folder")
    reader, expected = _sceneflow_reader(spec, kind) if reader_kind == "sceneflow" else _READERS[kind]
    records = reader(root)
    if not records:
        raise StereoInputError(f"data spec {spec!r}: no pairs found in {root}; expected {expected}")
    return StereoPairDataset(records, spec)


def _sceneflow_reader(spec: str, kind: str):
    """``sceneflow[-clean|-final][-train|-test]`` -> (reader, expected) with the pass and split bound."""
    parts = kind.split("-")[1:]
    frames = parts.pop(0) if parts and parts[0] in SCENEFLOW_PASSES else SCENEFLOW_PASSES[0]
    split = parts.pop(0) if parts and parts[0] in SCENEFLOW_SPLITS else None
    if parts:
        raise StereoInputError(f"data spec {spec!r}: unknown sceneflow option {'-'.join(parts)!r}; expected "
                               f"{_KIND_SYNTAX['sceneflow']} (pass, then split)")
    expected = SCENEFLOW_EXPECTED + (f", with a {split.upper()}/ folder in the path" if split else "")
    return (lambda root: sceneflow_records(root, frames, split)), expected


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


def bundled_data_dir() -> Path:
    """The real pairs shipped inside the package (four Middlebury 2001/2003 scenes, see its README)."""
    return Path(__file__).resolve().parent / "bundled"


def real_data_dir() -> tuple[Path, str]:
    """Where ``real`` reads: (the shared data folder, "shared"), else (the bundled pairs, "bundled").
    The two are never mixed: a shared folder, whatever it holds, replaces the bundled pairs."""
    shared = shared_data_dir()
    return (shared, "shared") if shared is not None else (bundled_data_dir(), "bundled")


def _real(spec: str) -> Dataset:
    """Every folder of ``REAL_KINDS`` in :func:`real_data_dir` (so a fresh clone evaluates on the bundled
    real photos)."""
    root, source = real_data_dir()
    records: list[PairRecord] = []
    for kind in REAL_KINDS:
        if (root / kind).is_dir():
            for r in _READERS[kind][0](root / kind):
                records.append(PairRecord(**{**r.__dict__, "name": f"{kind}/{r.name}"}))
    if not records:
        raise StereoInputError(f"data spec {spec!r}: no datasets found in {root}; expected sub-folders "
                               f"{', '.join(REAL_KINDS)}")
    dataset = StereoPairDataset(records, spec)
    dataset.source = source
    return dataset
