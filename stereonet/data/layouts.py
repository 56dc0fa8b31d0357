"""Readers for on-disk layouts: Middlebury 2001/2003/2014, KITTI 2012/2015, and a plain folder of pairs.

Each ``*_records(root)`` returns a list of :class:`PairRecord`; an empty list means "not this layout" and
:func:`stereonet.data.load_dataset` turns that into a one-line error saying what was expected.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from stereonet.data.base import PairRecord

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
MIDDLEBURY2003_EXPECTED = ("scene folders with im2.png, im6.png, disp2.png (value / 4, quarter size) and "
                           "optional disp6.png, or those files in DIR itself")


def _mb2003_files(folder: Path):
    paths = (find_file(folder, "im2"), find_file(folder, "im6"), find_file(folder, "disp2", (".png", ".pgm")))
    return paths if all(paths) else None


def middlebury2003_records(root: Path, scale: float = 4.0) -> list[PairRecord]:
    """Middlebury 2003 Cones/Teddy (Scharstein & Szeliski, CVPR 2003), quarter size: ``disp2.png`` = value / 4.

    Occlusion (True = not visible in the right view) from a left-right check of ``disp2`` against the
    right-view ground truth ``disp6`` when present.
    """
    records = []
    for scene in scene_folders(root, lambda p: _mb2003_files(p) is not None):
        left, right, disp = _mb2003_files(scene)
        records.append(PairRecord(_name(root, scene), left, right, disp, scale,
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
