"""A seeded, indexable torch Dataset of synthetic stereo pairs rendered on the fly, and its collate function."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch.utils.data import Dataset

from data_gen.pair import check_render_args, render_pair
from data_gen.scene import check_probability, check_textures

ITEM_TENSOR_KEYS = ("left", "right", "disparity", "disparity_right", "valid", "valid_right", "occlusion", "depth",
                    "specular", "correspondence")


class SyntheticStereo(Dataset):
    """``count`` synthetic pairs; item ``i`` is ``render_pair(seed, i, ...)`` (same pair in any worker/order).

    Items are dicts: ``left``, ``right`` float32 :math:`(3, H, W)` in [0, 1]; ``disparity``,
    ``disparity_right``, ``depth`` float32 :math:`(1, H, W)`; ``valid``, ``valid_right``, ``occlusion``
    (True = left pixel occluded in the right view), ``specular`` bool :math:`(1, H, W)`; ``correspondence``
    float32 :math:`(2, H, W)`; ``calib`` (:class:`stereonet.types.Calibration`); ``name`` str; ``max_disp`` int;
    ``difficulty`` int. Construction is cheap (nothing is rendered until indexed).

    Args:
        count: number of pairs (>= 1); seed: dataset seed; difficulty, height, width, rectified, supersample:
            as :func:`data_gen.render_pair`; ``**render_options``: its keyword-only options (num_objects,
            max_disp, baseline, distortion, noise, photometric, blur, specular, occlusion_right,
            shared_material, textures, weak_background, thin_structures).
    """

    def __init__(self, count: int, seed: int = 0, difficulty: int = 2, height: int = 256, width: int = 512,
                 rectified: bool = True, supersample: int = 2, **render_options):
        if isinstance(count, bool) or not isinstance(count, int) or count < 1:
            raise ValueError(f"count: expected an integer >= 1, got {count!r}")
        unknown = set(render_options) - {"num_objects", "max_disp", "baseline", "distortion", "noise",
                                         "photometric", "blur", "specular", "occlusion_right", "shared_material",
                                         "textures", "weak_background", "thin_structures"}
        if unknown:
            raise TypeError(f"render_options: unknown option(s) {sorted(unknown)}")
        for name in ("shared_material", "weak_background", "thin_structures"):
            if name in render_options:
                check_probability(render_options[name], name)
        if "textures" in render_options:
            render_options = {**render_options, "textures": check_textures(render_options["textures"])}
        _, _, difficulty, height, width, supersample, max_disp = check_render_args(
            seed, 0, difficulty, height, width, supersample, render_options.get("max_disp"),
            render_options.get("baseline"), render_options.get("num_objects"))
        self.count, self.seed, self.difficulty = count, int(seed), difficulty
        self.height, self.width, self.rectified, self.supersample = height, width, bool(rectified), supersample
        self.max_disp = max_disp
        self.render_options = render_options

    def __len__(self) -> int:
        return self.count

    def __getitem__(self, index: int) -> dict:
        if isinstance(index, bool) or not isinstance(index, int) and not hasattr(index, "__index__"):
            raise TypeError(f"index: expected an integer, got {type(index).__name__}")
        index = int(index)
        if index < 0:
            index += self.count
        if not 0 <= index < self.count:
            raise IndexError(f"index: expected 0 <= index < {self.count}, got {index}")
        pair = render_pair(self.seed, index, self.difficulty, self.height, self.width, self.rectified,
                           self.supersample, **self.render_options)
        item = {k: pair[k] for k in ITEM_TENSOR_KEYS + ("occlusion_right",) if k in pair}
        item.update(calib=pair["calib"], name=pair["name"], max_disp=pair["max_disp"], difficulty=self.difficulty)
        return item


def collate(batch: Sequence[dict]) -> dict:
    """DataLoader collate for item dicts: tensors of equal shape are stacked into a batch; everything else
    (Calibration, str, int, tensors of differing shapes, keys missing from some items) becomes a list."""
    if not batch:
        raise ValueError("batch: expected at least one item, got an empty sequence")
    out: dict = {}
    for key in batch[0]:
        values = [item.get(key) for item in batch]
        if all(isinstance(v, torch.Tensor) for v in values) and len({tuple(v.shape) for v in values}) == 1:
            out[key] = torch.stack(values)
        else:
            out[key] = values
    return out
