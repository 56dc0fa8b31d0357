"""Readers for on-disk layouts: Middlebury 2001/2003/2005-2006/2014, KITTI 2012/2015, SceneFlow (FlyingThings3D,
Monkaa, Driving), ETH3D two-view, and a plain folder of pairs.

Each ``*_records(root)`` returns a list of :class:`PairRecord`; an empty list means "not this layout" and
:func:`stereonet.data.load_dataset` turns that into a one-line error saying what was expected. A scene that is
this layout but incomplete (a missing view or ground truth file) raises a one-line
:class:`~stereonet.checks.StereoInputError` naming the missing file; truncated or corrupt files are found when
the pair is read (:func:`stereonet.data.base.load_pair`, through :mod:`stereonet.io`).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

from stereonet.checks import StereoInputError
from stereonet.data.base import PairRecord, same_size
from stereonet.io import read_array

IMAGE_EXTENSIONS = (".png", ".ppm", ".pgm", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


def find_file(folder: Path, stem: str, extensions=IMAGE_EXTENSIONS) -> Path | None:
    """``folder/stem.<ext>`` for the first extension that exists (case-insensitive on the extension)."""
    for ext in extensions:
        for cand in (folder / f"{stem}{ext}", folder / f"{stem}{ext.upper()}"):
            if cand.is_file():
                return cand
    return None


def scene_folders(root: Path, is_scene: Callable[[Path], bool]) -> list[Path]:
    """``root`` itself when it is a scene, else its scene sub-folders (or sub-sub-folders), sorted by name."""
    if is_scene(root):
        return [root]
    children = sorted(p for p in root.iterdir() if p.is_dir())
    found = [p for p in children if is_scene(p)]
    if not found:
        found = [g for p in children for g in sorted(q for q in p.iterdir() if q.is_dir()) if is_scene(g)]
    return found


def _name(root: Path, scene: Path) -> str:
    return scene.name if scene != root else root.name


# ------------------------------------------------------------------------------------ Middlebury 2001
# (left, right, left GT, right GT, scale): Tsukuba uses views 3/4 at scale 16; the other 2001 scenes
# (Venus, Sawtooth, Bull, Poster, Barn) views 2/6 at scale 8. Disparity value 0 = unknown.
_MB2001_VIEWS = (("im3", "im4", "disp3", "disp4", 16.0), ("im2", "im6", "disp2", "disp6", 8.0))
MIDDLEBURY2001_EXPECTED = ("scene folders with im3/im4 + disp3.pgm (Tsukuba, scale 16) or im2/im6 + disp2.pgm "
                           "(Venus etc., scale 8), or those files in DIR itself")


def _mb2001_views(folder: Path):
    for lft, rgt, dl, dr, scale in _MB2001_VIEWS:
        paths = (find_file(folder, lft), find_file(folder, rgt), find_file(folder, dl, (".pgm", ".png")))
        if all(paths):
            return (*paths, find_file(folder, dr, (".pgm", ".png")), scale)
    return None


def middlebury2001_records(root: Path) -> list[PairRecord]:
    """Middlebury 2001 (Scharstein & Szeliski, IJCV 2002): 8-bit ``disp*.pgm`` = value / scale."""
    records = []
    for scene in scene_folders(root, lambda p: _mb2001_views(p) is not None):
        left, right, disp, disp_r, scale = _mb2001_views(scene)
        records.append(PairRecord(_name(root, scene), left, right, disp, scale, right_disparity=disp_r))
    return records


# ------------------------------------------------------------------------------------ Middlebury 2003
MIDDLEBURY2003_EXPECTED = ("scene folders with im2.png, im6.png, disp2.png (value / 4 at quarter size, / 2 at "
                           "half, / 1 at full size) and optional disp6.png, or those files in DIR itself")
_MB2003_SCALES = {450: 4.0, 900: 2.0, 1800: 1.0}  # image width -> disparity PNG scale (Cones and Teddy)


def _mb2003_files(folder: Path):
    paths = (find_file(folder, "im2"), find_file(folder, "im6"), find_file(folder, "disp2", (".png", ".pgm")))
    return paths if all(paths) else None


def middlebury2003_records(root: Path, scale: float | None = None) -> list[PairRecord]:
    """Middlebury 2003 Cones/Teddy (Scharstein & Szeliski, CVPR 2003): ``disp2.png`` = value / 4 at quarter size
    (450 px wide), / 2 at half (900), / 1 at full size (1800); ``scale`` None reads it from the width, another
    width is bad input naming the file.

    Occlusion (True = not visible in the right view) from a left-right check of ``disp2`` against the
    right-view ground truth ``disp6`` when present.
    """
    records = []
    for scene in scene_folders(root, lambda p: _mb2003_files(p) is not None):
        left, right, disp = _mb2003_files(scene)
        pair_scale = scale
        if pair_scale is None:
            width = image_size(left)[1]
            if width not in _MB2003_SCALES:
                raise StereoInputError(f"{left}: expected a Middlebury 2003 view of width 450 (quarter size), 900 "
                                       f"(half) or 1800 (full), got {width} px")
            pair_scale = _MB2003_SCALES[width]
        records.append(PairRecord(_name(root, scene), left, right, disp, pair_scale,
                                  right_disparity=find_file(scene, "disp6", (".png", ".pgm"))))
    return records


# ------------------------------------------------------------------------------------ Middlebury 2014
MIDDLEBURY2014_EXPECTED = ("scene folders with im0.png, im1.png and disp0GT.pfm (optional disp1GT.pfm, "
                           "calib.txt, mask0nocc.png), or those files in DIR itself")


def _mb2014_files(folder: Path):
    left, right = find_file(folder, "im0"), find_file(folder, "im1")
    disp = find_file(folder, "disp0GT", (".pfm",)) or find_file(folder, "disp0", (".pfm",))
    return (left, right, disp) if left and right and disp else None


def middlebury2014_records(root: Path) -> list[PairRecord]:
    """Middlebury 2014 layout (also what ``python -m data_gen`` writes): ``disp0GT.pfm`` with inf = unknown,
    ``mask0nocc.png`` 255 = visible in both views, 128 = occluded; ``calib.txt`` for K, baseline, ndisp."""
    records = []
    for scene in scene_folders(root, lambda p: _mb2014_files(p) is not None):
        left, right, disp = _mb2014_files(scene)
        calib = scene / "calib.txt"
        records.append(PairRecord(
            _name(root, scene), left, right, disp,
            right_disparity=find_file(scene, "disp1GT", (".pfm",)) or find_file(scene, "disp1", (".pfm",)),
            occlusion_mask=find_file(scene, "mask0nocc", (".png",)),
            calib=calib if calib.is_file() else None))
    return records


# ------------------------------------------------------------------------------------ Middlebury 2005/2006
MIDDLEBURY2006_EXPECTED = ("scene folders with view1.png, view5.png and disp1.png (optional disp5.png), inside "
                           "FullSize/, HalfSize/ or ThirdSize/ folders (or DIR is one of those, or one scene)")
# Official size folders -> disparity scale (disparity = value / scale), and the image widths of each size
# (2005/2006 full-size views are 1240-1396 px wide; half and third size divide that by 2 and 3).
_MB2006_SCALES = {"fullsize": 1.0, "halfsize": 2.0, "thirdsize": 3.0}
_MB2006_WIDTHS = {1.0: (1200, 1440), 2.0: (600, 720), 3.0: (400, 480)}
_MB2006_SIZE_NAMES = {1.0: "FullSize", 2.0: "HalfSize", 3.0: "ThirdSize"}


def image_size(path: Path) -> tuple[int, int]:
    """``(H, W)`` of an image file: from the PNG header (24 bytes) when it is a PNG, else by decoding it."""
    with open(path, "rb") as f:
        head = f.read(24)
    if head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR":
        return int.from_bytes(head[20:24], "big"), int.from_bytes(head[16:20], "big")
    return tuple(int(n) for n in read_array(path).shape[:2])


def middlebury2006_scale(scene: Path, view1: Path) -> float:
    """Disparity scale of a Middlebury 2005/2006 scene: 1 (FullSize), 2 (HalfSize) or 3 (ThirdSize).

    Read from the nearest ``FullSize``/``HalfSize``/``ThirdSize`` folder above the scene, else from the width
    of ``view1``. A folder name that the width contradicts (a half-size view in ``ThirdSize/``) raises.
    """
    folder = next((_MB2006_SCALES[p.lower()] for p in reversed(scene.parts) if p.lower() in _MB2006_SCALES), None)
    width = image_size(view1)[1]
    by_width = next((s for s, (lo, hi) in _MB2006_WIDTHS.items() if lo <= width <= hi), None)
    if folder is not None and by_width is not None and folder != by_width:
        raise StereoInputError(f"{view1}: width {width} px is {_MB2006_SIZE_NAMES[by_width]}, but the scene is in "
                               f"a {_MB2006_SIZE_NAMES[folder]} folder (disparity scale {folder:g})")
    if folder is None and by_width is None:
        raise StereoInputError(f"{view1}: cannot tell the Middlebury 2005/2006 image size from the width {width} px "
                               f"(full {_MB2006_WIDTHS[1.0]}, half {_MB2006_WIDTHS[2.0]}, third "
                               f"{_MB2006_WIDTHS[3.0]}); put the scene in a FullSize/, HalfSize/ or ThirdSize/ folder")
    return folder if folder is not None else by_width


def middlebury2006_records(root: Path) -> list[PairRecord]:
    """Middlebury 2005/2006 (Scharstein & Pal, CVPR 2007; Hirschmüller & Scharstein, CVPR 2007), two views.

    Per scene ``view1.png`` (left), ``view5.png`` (right), ``disp1.png`` (8-bit, disparity = value / scale,
    0 = unknown; scale 1, 2, 3 for full, half, third size, see :func:`middlebury2006_scale`) and optionally
    ``disp5.png``, the right view's map, from which occlusion is derived by the left-right check
    (:func:`~stereonet.data.base.occlusion_from_lr_check`). A scene with ``view1`` but no ``view5`` or
    ``disp1`` raises. Pairs are named by their path below ``root`` (``HalfSize/Aloe``). ``dmin.txt`` (the
    crop offset, needed for depth, not for disparity) is not read.
    """
    records = []
    for scene in scene_folders(root, lambda p: find_file(p, "view1") is not None):
        left = find_file(scene, "view1")
        right = find_file(scene, "view5")
        disp = find_file(scene, "disp1", (".png", ".pgm"))
        for found, stem, what in ((right, "view5", "right view"), (disp, "disp1", "ground truth")):
            if found is None:
                raise StereoInputError(f"{scene / (stem + '.png')}: no such file (the {what} of {left.name}; a "
                                       f"Middlebury 2005/2006 scene holds view1.png, view5.png and disp1.png)")
        name = scene.relative_to(root).as_posix() if scene != root else root.name
        records.append(PairRecord(name, left, right, disp, middlebury2006_scale(scene, left),
                                  right_disparity=find_file(scene, "disp5", (".png", ".pgm"))))
    return records


# ------------------------------------------------------------------------------------ ETH3D
ETH3D_EXPECTED = ("scene folders with im0.png, im1.png, disp0GT.pfm and mask0nocc.png (optional calib.txt), "
                  "or those files in DIR itself")


def eth3d_records(root: Path) -> list[PairRecord]:
    """ETH3D two-view training layout (Schöps et al., CVPR 2017): ``disp0GT.pfm`` (inf = unknown),
    ``mask0nocc.png`` (255 = non-occluded with ground truth; a pixel with ground truth and any other value is
    occluded, which the ``*_noc`` metrics leave out), ``calib.txt`` (Middlebury format). A scene with the
    images but no ``disp0GT.pfm`` (the test scenes have none), or a mask of another size than ``im0``, raises
    here, before any pair is read."""
    records = []
    for scene in scene_folders(root, lambda p: bool(find_file(p, "im0") and find_file(p, "im1"))):
        disp = find_file(scene, "disp0GT", (".pfm",))
        if disp is None:
            raise StereoInputError(f"{scene / 'disp0GT.pfm'}: no such file (the ground truth of im0; ETH3D "
                                   f"test scenes have none, eth3d:DIR reads the training scenes)")
        left, mask = find_file(scene, "im0"), find_file(scene, "mask0nocc", (".png",))
        if mask is not None:
            same_size(left, image_size(left), mask, image_size(mask))
        calib = scene / "calib.txt"
        records.append(PairRecord(_name(root, scene), left, find_file(scene, "im1"), disp, occlusion_mask=mask,
                                  occlusion_mask_kind="eth3d", calib=calib if calib.is_file() else None))
    return records


# ------------------------------------------------------------------------------------ SceneFlow
SCENEFLOW_PASSES = ("final", "clean")
SCENEFLOW_SPLITS = ("train", "test")
SCENEFLOW_EXPECTED = ("frames_finalpass/ (or frames_cleanpass/) and disparity/ in DIR or in each of its "
                      "sub-folders, with frames_*pass/.../left|right/NNNN.png and disparity/.../left|right/NNNN.pfm")


def _sceneflow_bases(root: Path) -> list[Path]:
    def is_base(p: Path) -> bool:
        return any((p / f"frames_{x}pass").is_dir() for x in SCENEFLOW_PASSES)

    if is_base(root):
        return [root]
    return sorted(p for p in root.iterdir() if p.is_dir() and is_base(p))


def _left_folders(frames: Path) -> list[Path]:
    """Every ``left`` folder below ``frames`` that holds files (not descending into ``left``/``right``)."""
    found = []
    for dirpath, dirnames, _ in os.walk(frames):
        here = Path(dirpath)
        if here.name in ("left", "right"):
            dirnames[:] = []
            if here.name == "left":
                found.append(here)
            continue
        dirnames.sort()
    return sorted(found)


def sceneflow_records(root: Path, frames: str = "final", split: str | None = None) -> list[PairRecord]:
    """SceneFlow (Mayer et al., CVPR 2016): FlyingThings3D, Monkaa and Driving.

    ``root`` holds ``frames_finalpass/`` or ``frames_cleanpass/`` and ``disparity/`` (or sub-folders that each
    do, e.g. ``flyingthings3d/``, ``monkaa/``, ``driving/``). Every ``frames_<frames>pass/<...>/left/NNNN.png``
    is a pair with ``<...>/right/NNNN.png``, ground truth ``disparity/<...>/left/NNNN.pfm`` and, when present,
    the right view's ``disparity/<...>/right/NNNN.pfm``, from which occlusion is derived by the left-right check
    (:func:`~stereonet.data.base.occlusion_from_lr_check`).

    Args:
        frames: ``"final"`` (rendered with motion blur and depth of field) or ``"clean"``.
        split: None for every pair, ``"train"`` or ``"test"`` for FlyingThings3D's official split (the pairs
            with a ``TRAIN``/``TEST`` folder in their path); a tree with neither folder raises (Monkaa and
            Driving have no split).
    Pairs are named by their path below ``root`` without ``frames_*pass/`` and ``left/``
    (``TRAIN/A/0000/0006``). Left frames without their right view or left disparity raise, naming the file.
    """
    if frames not in SCENEFLOW_PASSES:
        raise StereoInputError(f"frames: expected one of {', '.join(SCENEFLOW_PASSES)}, got {frames!r}")
    if split is not None and split not in SCENEFLOW_SPLITS:
        raise StereoInputError(f"split: expected None or one of {', '.join(SCENEFLOW_SPLITS)}, got {split!r}")
    records: list[PairRecord] = []
    seen_split = False
    for base in _sceneflow_bases(root):
        frames_dir = base / f"frames_{frames}pass"
        if not frames_dir.is_dir():
            other = next(x for x in SCENEFLOW_PASSES if x != frames)
            raise StereoInputError(f"{frames_dir}: no such folder (there is frames_{other}pass/; its spec is "
                                   f"sceneflow-{other}:DIR)")
        disp_dir = base / "disparity"
        prefix = "" if base == root else f"{base.name}/"
        for left_dir in _left_folders(frames_dir):
            rel = left_dir.parent.relative_to(frames_dir)
            tags = {p.lower() for p in rel.parts} & set(SCENEFLOW_SPLITS)
            seen_split = seen_split or bool(tags)
            if split is not None and split not in tags:
                continue
            lefts = sorted(p for p in left_dir.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS)
            if not lefts:
                continue
            right_dir, disp_left_dir = left_dir.parent / "right", disp_dir / rel / "left"
            if not disp_left_dir.is_dir():
                raise StereoInputError(f"{disp_left_dir}: no such folder (the ground truth of the {len(lefts)} "
                                       f"left frames in {left_dir}; SceneFlow frames need disparity/ beside "
                                       f"frames_{frames}pass/)")
            disp_right_dir = disp_dir / rel / "right"
            for left in lefts:
                right, disp = right_dir / left.name, disp_left_dir / f"{left.stem}.pfm"
                for path, what in ((right, "right view"), (disp, "ground truth disparity")):
                    if not path.is_file():
                        raise StereoInputError(f"{path}: no such file (the {what} of {left})")
                disp_r = disp_right_dir / f"{left.stem}.pfm"
                name = prefix + "/".join((*rel.parts, left.stem))
                records.append(PairRecord(name, left, right, disp,
                                          right_disparity=disp_r if disp_r.is_file() else None))
    if split is not None and records == [] and not seen_split:
        raise StereoInputError(f"{root}: no TRAIN/ or TEST/ folders below frames_{frames}pass/; the official "
                               f"split is FlyingThings3D's (Monkaa and Driving have none), use sceneflow:DIR "
                               f"for every pair")
    return records


# ------------------------------------------------------------------------------------ KITTI
# (left dir, right dir, GT with occluded pixels, GT without, calib dir) per benchmark, preferred first
_KITTI_LAYOUTS = {
    "kitti2012": (("colored_0", "colored_1", "disp_occ", "disp_noc", "calib"),
                  ("image_0", "image_1", "disp_occ", "disp_noc", "calib")),
    "kitti2015": (("image_2", "image_3", "disp_occ_0", "disp_noc_0", "calib_cam_to_cam"),),
}


def kitti_expected(kind: str) -> str:
    left, right, disp, _, _ = _KITTI_LAYOUTS[kind][0]
    return f"DIR/training/ (or DIR itself) holding {left}/, {right}/ and {disp}/ with *_10.png frames"


def kitti_records(root: Path, kind: str) -> list[PairRecord]:
    """KITTI stereo 2012 / 2015 training layout (Geiger et al. CVPR 2012; Menze & Geiger CVPR 2015).

    Pairs are the frames ``*_10.png`` that have ground truth in the ``disp_occ`` folder (16-bit, value / 256,
    0 = no GT). Occlusion = valid in ``disp_occ`` but not in ``disp_noc`` when that folder exists.
    Calibration from ``calib/`` (2012) or ``calib_cam_to_cam/`` (2015) when present.
    """
    base = root / "training" if (root / "training").is_dir() else root
    for left_dir, right_dir, occ_dir, noc_dir, calib_dir in _KITTI_LAYOUTS[kind]:
        if not all((base / d).is_dir() for d in (left_dir, right_dir, occ_dir)):
            continue
        records = []
        for disp in sorted((base / occ_dir).glob("*_10.png")):
            left, right = base / left_dir / disp.name, base / right_dir / disp.name
            if not (left.is_file() and right.is_file()):
                continue
            noc = base / noc_dir / disp.name
            calib = base / calib_dir / f"{disp.stem.split('_')[0]}.txt"
            records.append(PairRecord(disp.stem, left, right, disp, 256.0,
                                      noc_disparity=noc if noc.is_file() else None,
                                      calib=calib if calib.is_file() else None))
        if records:
            return records
    return []


# ------------------------------------------------------------------------------------ plain folder
FOLDER_EXPECTED = ("left/ and right/ sub-folders with matching file names (optional disparity/ or disp/ "
                   "with .pfm or 16-bit .png), or NAME_left.EXT / NAME_right.EXT files (optional NAME_disp.pfm|png), "
                   "or sub-folders each holding im0 and im1 (optional disp0GT.pfm, calib.txt)")
_GT_EXTENSIONS = (".pfm", ".png")


def folder_records(root: Path) -> list[PairRecord]:
    """A plain folder of pairs, in one of three layouts (see ``FOLDER_EXPECTED``); ground truth optional
    (``.pfm`` in pixels, or 16-bit ``.png`` at KITTI's scale 256)."""
    if (root / "left").is_dir() and (root / "right").is_dir():
        gt_dir = next((root / d for d in ("disparity", "disp", "gt") if (root / d).is_dir()), None)
        records = []
        for left in sorted(p for p in (root / "left").iterdir() if p.suffix.lower() in IMAGE_EXTENSIONS):
            right = find_file(root / "right", left.stem)
            if right is not None:
                gt = find_file(gt_dir, left.stem, _GT_EXTENSIONS) if gt_dir else None
                records.append(PairRecord(left.stem, left, right, gt))
        return records
    records = []
    for left in sorted(p for p in root.iterdir() if p.is_file() and p.stem.endswith("_left")
                       and p.suffix.lower() in IMAGE_EXTENSIONS):
        stem = left.stem[: -len("_left")]
        right = find_file(root, f"{stem}_right")
        if right is not None:
            gt = find_file(root, f"{stem}_disp", _GT_EXTENSIONS) or find_file(root, f"{stem}_disparity", _GT_EXTENSIONS)
            records.append(PairRecord(stem, left, right, gt))
    if records:
        return records
    for scene in scene_folders(root, lambda p: bool(find_file(p, "im0") and find_file(p, "im1"))):
        gt = find_file(scene, "disp0GT", _GT_EXTENSIONS) or find_file(scene, "disp0", _GT_EXTENSIONS)
        calib = scene / "calib.txt"
        records.append(PairRecord(_name(root, scene), find_file(scene, "im0"), find_file(scene, "im1"), gt,
                                  occlusion_mask=find_file(scene, "mask0nocc", (".png",)) if gt else None,
                                  calib=calib if calib.is_file() else None))
    return records
