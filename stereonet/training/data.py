"""LightningDataModule for on-the-fly synthetic training pairs with a curriculum over difficulty.

Training pairs are rendered by :mod:`data_gen` on the fly (a pure function of (seed, start step, worker,
counter), so DataLoader workers never repeat each other); the validation set is a fixed
list of pairs rendered once with a separate seed. The difficulty of training pairs is set by the
:class:`~stereonet.training.callbacks.CurriculumCallback` through :meth:`SyntheticStereoDataModule.set_progress`.

``source="random-shift"`` replaces data_gen by random-texture fronto-parallel pairs (constant disparity per
pair): tiny, dependency-free, used by the fast tests.
"""

from __future__ import annotations

import multiprocessing
import os

import lightning as L
import torch
from torch.utils.data import DataLoader, Dataset, IterableDataset, get_worker_info

from stereonet.training.curriculum import difficulty_at

_TENSOR_KEYS = ("left", "right", "disparity", "valid", "occlusion", "nonoccluded")


def collate_pairs(items: list[dict]) -> dict:
    """Stack the tensor fields of item dicts into a batch dict (B first); other fields become lists."""
    batch: dict = {}
    for key in items[0]:
        values = [it[key] for it in items]
        batch[key] = torch.stack(values) if isinstance(values[0], torch.Tensor) and key in _TENSOR_KEYS else values
    return batch


class RandomShiftStereo(Dataset):
    """Random-texture pairs with one constant disparity each (``x_right = x_left - d``), all pixels valid
    except the left ``d`` columns. Items follow the stereonet item dict; a pure function of (seed, index)."""

    def __init__(self, count: int, seed: int = 0, height: int = 64, width: int = 128, max_disp: int = 16,
                 difficulty: int = 0) -> None:
        self.count, self.seed, self.height, self.width, self.max_disp = count, seed, height, width, max_disp

    def __len__(self) -> int:
        return self.count

    def __getitem__(self, index: int) -> dict:
        g = torch.Generator().manual_seed(self.seed * 1_000_003 + index)
        d = int(torch.randint(1, self.max_disp + 1, (1,), generator=g))
        coarse = torch.rand(3, self.height // 4 + 1, (self.width + d) // 4 + 2, generator=g)
        big = torch.nn.functional.interpolate(coarse[None], scale_factor=4, mode="bilinear", align_corners=False)[0]
        big = (0.7 * big + 0.3 * torch.rand(big.shape, generator=g))[:, : self.height, : self.width + d]
        left = big[:, :, d:].contiguous()
        right = big[:, :, : self.width].contiguous()
        disp = torch.full((1, self.height, self.width), float(d))
        valid = torch.ones(1, self.height, self.width, dtype=torch.bool)
        valid[..., :d] = False
        return {"left": left, "right": right, "disparity": disp, "valid": valid,
                "occlusion": ~valid, "name": f"shift-{self.seed}-{index}", "max_disp": self.max_disp}


def _make_dataset(source: str, count: int, seed: int, difficulty: int, height: int, width: int,
                  supersample: int = 2, max_disp: int | None = None, shared_material: float = 0.0,
                  drop_textures: tuple[str, ...] = (), weak_background: float = 0.0,
                  thin_structures: float = 0.0) -> Dataset:
    if source == "random-shift":
        return RandomShiftStereo(count, seed=seed, height=height, width=width, max_disp=max(1, width // 8))
    if source == "data_gen":
        try:
            import data_gen
        except ImportError as e:  # pragma: no cover - data_gen ships with stereonet
            raise ImportError("source: 'data_gen' needs the data_gen package (pip install -e .)") from e
        options = {"shared_material": float(shared_material)}  # 0: the same pairs as before the option existed
        if weak_background:  # 0: the option is not passed (the same pairs and names as before it existed)
            options["weak_background"] = float(weak_background)
        if thin_structures:  # the same: 0 is not passed
            options["thin_structures"] = float(thin_structures)
        if drop_textures:  # the level's texture mix without these kinds (none dropped: the option is not passed)
            from data_gen.scene import texture_mix

            options["textures"] = texture_mix(difficulty, drop_textures)
        if max_disp is not None:
            options["max_disp"] = int(max_disp)
        return data_gen.SyntheticStereo(count, seed=seed, difficulty=difficulty, height=height, width=width,
                                        supersample=supersample, **options)
    raise ValueError(f"source: expected 'data_gen' or 'random-shift', got {source!r}")


def sample_max_disp(source: str, difficulty: int, width: int, disparity_range: int | None,
                    generator: torch.Generator) -> int | None:
    """Disparity range of one training pair: None (the difficulty's own, scaled with ``width``) or, when
    ``disparity_range`` is set, uniform between the difficulty's and ``disparity_range`` (kept < width / 2),
    so that small training renders still show the large disparities of full-size images."""
    if source != "data_gen" or not disparity_range:
        return None
    import data_gen

    low = data_gen.default_max_disp(difficulty, width)
    high = min(int(disparity_range), (width - 1) // 2)
    if high <= low:
        return None
    return int(torch.randint(low, high + 1, (1,), generator=generator))


def _default_max_disp(source: str, difficulty: int, width: int) -> int | None:
    """The difficulty's own disparity range at ``width`` (data_gen's default), None for other sources."""
    if source != "data_gen":
        return None
    import data_gen

    return int(data_gen.default_max_disp(difficulty, width))


def max_difficulty(source: str) -> int:
    if source == "data_gen":
        import data_gen

        return int(data_gen.MAX_DIFFICULTY)
    return 0


def photometric_augment(item: dict, generator: torch.Generator) -> dict:
    """Independent brightness / contrast / gamma / colour gain / noise per view (in place on a copy).

    Real pairs differ in exposure between the two cameras; this keeps the networks from relying on equal
    intensities.
    """
    item = dict(item)
    for key in ("left", "right"):
        img = item[key]
        u = torch.rand(6, generator=generator)
        gamma = 0.7 + 0.6 * float(u[0])
        contrast = 0.7 + 0.6 * float(u[1])
        brightness = -0.1 + 0.2 * float(u[2])
        gains = 0.9 + 0.2 * torch.rand(img.shape[0], 1, 1, generator=generator)
        img = img.clamp(0, 1) ** gamma
        img = (img - 0.5) * contrast + 0.5 + brightness
        img = img * gains + 0.02 * float(u[3]) * torch.randn(img.shape, generator=generator)
        item[key] = img.clamp(0, 1)
    return item


def vertical_jitter(item: dict, max_offset: float, generator: torch.Generator, warp: float = 0.0) -> dict:
    """Resample the right view ``dy`` rows down, ``dy`` uniform in [-max_offset, max_offset] (bilinear,
    border rows repeated): a small rectification error as real rigs have (HITNet and CREStereo train with
    it), so a matcher cannot rely on rows matching to a fraction of a pixel. Ground truth is unchanged
    (disparity is the horizontal offset).

    ``warp`` > 0 makes the offset vary across the image as a slightly wrong calibration does:
    ``dy(x, y) = a + b u + c v`` with ``u, v`` in [-1, 1] from the left/top to the right/bottom border and
    ``b, c`` uniform in [-warp, warp] rows (a small roll and a vertical scale difference between the views);
    the resampling stays vertical, so the ground truth stays exact. ``warp = 0`` draws nothing more (the
    same stream as before the option existed)."""
    if max_offset <= 0 and warp <= 0:
        return item
    import torch.nn.functional as F

    dy = (2.0 * float(torch.rand(1, generator=generator)) - 1.0) * max_offset
    img = item["right"]  # CxHxW
    c, h, w = img.shape
    ys = torch.arange(h, dtype=img.dtype)[:, None] + dy
    xs = torch.arange(w, dtype=img.dtype)
    if warp > 0:
        b, cc = ((2.0 * torch.rand(2, generator=generator) - 1.0) * warp).tolist()
        u = 2 * xs / max(w - 1, 1) - 1
        v = 2 * torch.arange(h, dtype=img.dtype) / max(h - 1, 1) - 1
        ys = ys + b * u[None, :] + cc * v[:, None]
    ys = ys.expand(h, w)
    grid = torch.stack([(2 * xs / max(w - 1, 1) - 1).expand(h, w), 2 * ys / max(h - 1, 1) - 1], -1)
    out = dict(item)
    out["right"] = F.grid_sample(img[None], grid[None], mode="bilinear", padding_mode="border",
                                 align_corners=True)[0]
    return out


def swap_flip(item: dict) -> dict:
    """Mirror a pair: new left = flipped right, new right = flipped left (a valid rectified pair whose
    left-referenced ground truth is the flipped right-view ground truth). Needs ``disparity_right`` and
    ``valid_right``; items without them are returned unchanged."""
    if "disparity_right" not in item or "valid_right" not in item:
        return item
    flip = lambda t: t.flip(-1)
    out = dict(item)
    out["left"], out["right"] = flip(item["right"]), flip(item["left"])
    out["disparity"], out["disparity_right"] = flip(item["disparity_right"]), flip(item["disparity"])
    valid_right = item["valid_right"]
    if "max_disp" in item:  # data_gen's right-view GT can exceed the range on objects seen only from the right
        valid_right = valid_right & (item["disparity_right"] <= item["max_disp"])
    out["valid"], out["valid_right"] = flip(valid_right), flip(item["valid"])
    out.pop("occlusion", None)  # right-view occlusion is not rendered; the loss uses ``valid`` only
    return out


def random_crop(item: dict, height: int, width: int, generator: torch.Generator) -> dict:
    """A ``height`` x ``width`` window of a labelled pair at a random place (the same columns in both views).

    Left-view pixels whose match falls left of the cropped right view become invalid (their disparity is
    right, but the right crop no longer shows the match). Items already of that size are returned as is.
    """
    h, w = item["left"].shape[-2:]
    if (h, w) == (height, width):
        return item
    if h < height or w < width:
        raise ValueError(f"random_crop: pair {item.get('name', '?')} is {h}x{w}, smaller than the "
                         f"{height}x{width} training crop")
    y0 = int(torch.randint(h - height + 1, (1,), generator=generator))
    x0 = int(torch.randint(w - width + 1, (1,), generator=generator))
    out = {}
    for key, value in item.items():
        if isinstance(value, torch.Tensor) and value.shape[-2:] == (h, w):
            out[key] = value[..., y0:y0 + height, x0:x0 + width]
        elif key not in ("calib",):
            out[key] = value
    xs = torch.arange(width, dtype=out["disparity"].dtype)
    out["valid"] = out["valid"] & (xs - out["disparity"] >= 0)
    if "disparity_right" in out and "valid_right" in out:  # right view: matches at x + d
        out["valid_right"] = out["valid_right"] & (xs + out["disparity_right"] <= width - 1)
    return out


def open_training_spec(spec: str, height: int, width: int) -> Dataset:
    """The labelled dataset ``spec`` (any spec eval.py reads) for training crops of ``height`` x ``width``.

    Raises a one-line :class:`~stereonet.checks.StereoInputError` naming the spec when it cannot be read,
    has no ground truth, or its first pair is smaller than the crop.
    """
    from stereonet.checks import StereoInputError
    from stereonet.data import load_dataset

    if spec.strip().startswith("synthetic"):
        raise StereoInputError(f"--data.train {spec!r}: data_gen pairs are the default source already; "
                               f"expected a dataset spec such as sceneflow:DIR, kitti2015:DIR or folder:DIR")
    try:
        dataset = load_dataset(spec)
    except StereoInputError as e:
        raise StereoInputError(f"--data.train: {e}") from None
    first = dataset[0]
    if not bool(first["valid"].any()):
        raise StereoInputError(f"--data.train {spec!r}: pair {first.get('name', 0)} has no ground-truth "
                               f"disparity; training needs a labelled dataset")
    h, w = first["left"].shape[-2:]
    if h < height or w < width:
        raise StereoInputError(f"--data.train {spec!r}: pair {first.get('name', 0)} is {h}x{w}, smaller than "
                               f"the training crop --data.height {height} x --data.width {width}")
    return dataset


class PooledCurriculumStream(IterableDataset):
    """Endless stream of training pairs rendered on the fly, each reused a few times from a small pool.

    Rendering a pair costs about as much as a training step on CPU, so every ``reuse`` items one new pair
    is rendered (at the difficulty in the shared ``difficulty`` value, set by the curriculum) and replaces
    the oldest one in a pool of ``pool_size``; items are drawn at random from the pool and augmented
    (swap-flip, photometric). With ``extra`` (a labelled dataset) a share ``extra_ratio`` of the items are
    random crops of its pairs instead, augmented the same way (the curriculum sets only the rendered pairs'
    difficulty). Rendering seeds are ``(seed + 7919 * start, rank, worker, counter)``: a pure
    function of the start offset (the global step when training (re)starts), the DDP rank and the
    DataLoader worker, so ranks and workers never repeat each other's pairs (pair index
    ``(counter * workers + worker) * world_size + rank``) and a resumed run does not replay the first
    pairs. With one process (rank 0 of 1) the stream is the same as before ranks were folded in.
    With ``render_scale`` > 1 the pairs are rendered that many times larger (their disparity range drawn for
    ``width``) and every draw is a random ``height`` x ``width`` window of one (:func:`random_crop`).
    """

    def __init__(self, source: str, seed: int, height: int, width: int, pool_size: int, reuse: int,
                 augment: bool, difficulty, start, supersample: int = 2, disparity_range: int | None = None,
                 rank: int = 0, world_size: int = 1, vertical_jitter: float = 0.0,
                 extra: Dataset | None = None, extra_ratio: float = 0.0, vertical_warp: float = 0.0,
                 shared_material: float = 0.0, drop_textures: tuple[str, ...] = (),
                 weak_background: float = 0.0, render_scale: int = 1, thin_structures: float = 0.0) -> None:
        self.source, self.seed, self.height, self.width = source, seed, height, width
        self.render_scale = int(render_scale)
        self.shared_material, self.weak_background = float(shared_material), float(weak_background)
        self.thin_structures = float(thin_structures)
        self.drop_textures = tuple(drop_textures)
        self.extra, self.extra_ratio = extra, float(extra_ratio) if extra is not None else 0.0
        self.vertical_jitter, self.vertical_warp = float(vertical_jitter), float(vertical_warp)
        self.supersample, self.disparity_range = supersample, disparity_range
        self.pool_size, self.reuse, self.augment = max(1, pool_size), max(1, reuse), augment
        self.difficulty, self.start = difficulty, start  # multiprocessing Values shared with workers
        if not 0 <= rank < world_size:
            raise ValueError(f"rank: expected 0 <= rank < world_size ({world_size}), got {rank}")
        self.rank, self.world_size = int(rank), int(world_size)

    def __iter__(self):
        info = get_worker_info()
        wid, nworkers = (info.id, info.num_workers) if info is not None else (0, 1)
        stream_seed = self.seed + 7919 * int(self.start.value)
        g = torch.Generator().manual_seed(stream_seed * 1009 + wid + 1_000_003 * self.rank)
        pool: list[dict] = []
        counter = 0
        while True:
            if self.extra_ratio < 1 and (len(pool) < self.pool_size or counter % self.reuse == 0):
                index = (counter * nworkers + wid) * self.world_size + self.rank
                level = int(self.difficulty.value)
                max_disp = sample_max_disp(self.source, level, self.width, self.disparity_range, g)
                scale = self.render_scale
                if scale > 1 and max_disp is None:  # the crop's range in pixels, not that of the larger render
                    max_disp = _default_max_disp(self.source, level, self.width)
                ds = _make_dataset(self.source, index + 1, stream_seed, level, self.height * scale,
                                   self.width * scale,
                                   self.supersample, max_disp, self.shared_material, self.drop_textures,
                                   self.weak_background, self.thin_structures)
                pool.append(ds[index])
                pool = pool[-self.pool_size:]
            counter += 1
            if self.extra_ratio > 0 and float(torch.rand(1, generator=g)) < self.extra_ratio:
                index = int(torch.randint(len(self.extra), (1,), generator=g))
                item = random_crop(self.extra[index], self.height, self.width, g)
                if item["left"].shape[0] == 1:  # greyscale datasets: the networks take RGB like data_gen's
                    item = {**item, "left": item["left"].expand(3, -1, -1), "right": item["right"].expand(3, -1, -1)}
            else:
                item = pool[int(torch.randint(len(pool), (1,), generator=g))]
                if self.render_scale > 1:  # a new window of the larger render at every draw
                    item = random_crop(item, self.height, self.width, g)
            if self.augment:
                if float(torch.rand(1, generator=g)) < 0.5:
                    item = swap_flip(item)
                item = photometric_augment(item, g)
                if self.vertical_jitter > 0 or self.vertical_warp > 0:
                    item = vertical_jitter(item, self.vertical_jitter, g, self.vertical_warp)
            yield _training_fields(item)


def gt_nonoccluded(disparity: torch.Tensor, disparity_right: torch.Tensor, tol: float | None = None) -> torch.Tensor:
    """Pixels whose ground-truth match agrees with the right view's ground truth (not occluded).

    disparity, disparity_right: :math:`(1, H, W)` left- and right-referenced; returns bool :math:`(1, H, W)`.
    ``tol`` defaults to the one left-right rule's :data:`~stereonet.select.lr_check.LR_TOL`.
    """
    from stereonet.select.lr_check import LR_TOL, left_right_check  # the one LR rule

    return left_right_check(disparity[None], disparity_right[None], LR_TOL if tol is None else tol)[0]


def _training_fields(item: dict) -> dict:
    """The fields a training batch needs, with ``nonoccluded`` (bool (1, H, W)) for the Siamese loss and the
    pair's ``max_disp`` (the range it was rendered in, what a user passes at inference) where the item has one."""
    out = {k: item[k] for k in ("left", "right", "disparity", "valid")}
    if "max_disp" in item:
        out["max_disp"] = int(item["max_disp"])
    if "disparity_right" in item:
        out["nonoccluded"] = item["valid"] & gt_nonoccluded(item["disparity"], item["disparity_right"])
    elif "occlusion" in item:
        out["nonoccluded"] = item["valid"] & ~item["occlusion"]
    else:
        out["nonoccluded"] = item["valid"]
    return out


class SyntheticStereoDataModule(L.LightningDataModule):
    """On-the-fly data_gen training pairs (curriculum over difficulty) and a fixed validation set.

    Args:
        source: "data_gen" (default) or "random-shift" (tests).
        height, width: training image size (pairs are rendered at this size; see ``render_scale``).
        batch_size: pairs per training batch.
        pool_size, reuse: the training stream renders one new pair every ``reuse`` items into a pool of
            ``pool_size`` recent pairs and draws items from the pool (see :class:`PooledCurriculumStream`).
        val_pairs: size of the fixed validation set (rendered once, seed ``val_seed``, difficulties spread
            evenly over 0..max).
        val_height, val_width: validation image size (defaults to the training size).
        seed: base seed of training pairs; val_seed: seed of the validation pairs.
        curriculum_fraction: share of training over which difficulty ramps from ``min_difficulty`` to the
            maximum (0 = no curriculum: full difficulty from the start).
        min_difficulty: difficulty at the start of the curriculum.
        num_workers: DataLoader workers rendering training pairs in parallel with the training step.
        augment: swap-flip and photometric augmentation of training pairs.
        supersample: data_gen anti-aliasing rays per pixel side (2 = like real photos; 1 is ~4x faster).
        disparity_range: when set, each training pair's disparity range is drawn between its difficulty's
            and this value (see :func:`sample_max_disp`); validation pairs keep their difficulty's.
        vertical_jitter: with ``augment``, the right view of each training item is shifted by up to this
            many rows (:func:`vertical_jitter`; 0 = off, the default).
        train: a labelled dataset spec that eval.py reads (``sceneflow:DIR``, ``kitti2015:DIR``,
            ``middlebury2014:DIR``, ``folder:DIR`` with ground truth, ...): its pairs, randomly cropped to
            ``height`` x ``width``, are mixed into the training stream (``--data.train SPEC`` in train.py),
            with the same augmentation; validation stays on data_gen. The way to adapt a model to one's own
            rig; the shipped weights never use it.
        train_ratio: share of training items drawn from ``train`` (1 = only ``train``; the rest are data_gen).
        val_vertical_jitter: the right view of validation pair ``i`` is shifted by a fixed offset drawn
            uniformly in [-v, v] rows (seeded by ``val_seed``; the same for every run), so that selection
            sees the small rectification errors every real rig has (0 = off, the default).
        vertical_warp, val_vertical_warp: the offsets also vary across the image, up to this many rows at
            the borders (a small roll and vertical scale error; :func:`vertical_jitter`'s ``warp``; 0 = off).
        shared_material: probability that an object of a rendered training pair takes the look of another
            surface of its scene (``data_gen.render_pair``'s option: depth edges without a colour edge, as in
            photos; 0 = off, the default). Validation pairs are rendered without it.
        drop_textures: texture kinds (``data_gen.textures.TEXTURE_KINDS``) left out of every level's mix in the
            rendered training pairs, e.g. ``[weak, flat]``: every training surface textured (data_gen's ``textures``
            option). Validation pairs keep the levels' mixes. Empty (the default): the same pairs as before.
        weak_background: probability that a rendered training pair's background walls get a weaker texture
            (``data_gen.render_pair``'s option: objects in front of weakly textured walls, where window matchers
            fatten the foreground, as at most depth edges of photos; 0 = off, the default). Validation pairs are
            rendered without it.
        thin_structures: probability that a rendered training pair's scene gets a few thin rods (poles,
            branches, cables; ``data_gen.render_pair``'s option: surfaces narrower than any window, as in photos;
            0 = off, the default). Validation pairs are rendered without it.
        render_scale: training pairs are rendered at ``render_scale`` times ``height`` x ``width`` (the
            disparity range still drawn for ``width``: the same disparities in pixels) and every draw from the pool
            takes a random ``height`` x ``width`` window of it (:func:`random_crop`): surfaces and textures that
            many times larger in pixels, the disparities a smaller share of the view, as in camera images of 375 px
            and more; 1 (the default) renders at the training size, the same pairs as before the option existed.
            Validation pairs are rendered at their own size.
    """

    def __init__(self, source: str = "data_gen", height: int = 128, width: int = 256, batch_size: int = 4,
                 pool_size: int = 32, reuse: int = 4, val_pairs: int = 16, val_height: int | None = None,
                 val_width: int | None = None, seed: int = 0, val_seed: int = 900_000,
                 curriculum_fraction: float = 0.5, min_difficulty: int = 0, num_workers: int = 0,
                 augment: bool = True, supersample: int = 2, disparity_range: int | None = None,
                 vertical_jitter: float = 0.0, val_vertical_jitter: float = 0.0, train: str | None = None,
                 train_ratio: float = 0.5, vertical_warp: float = 0.0, val_vertical_warp: float = 0.0,
                 shared_material: float = 0.0, drop_textures: list[str] | None = None,
                 weak_background: float = 0.0, render_scale: int = 1, thin_structures: float = 0.0) -> None:
        super().__init__()
        self.save_hyperparameters()
        from stereonet.checks import StereoInputError

        if drop_textures:
            from data_gen.scene import MAX_DIFFICULTY, texture_mix
            from data_gen.textures import TEXTURE_KINDS

            if not isinstance(drop_textures, list | tuple) or any(k not in TEXTURE_KINDS for k in drop_textures) or \
                    not all(texture_mix(level, drop_textures) for level in range(MAX_DIFFICULTY + 1)):
                raise StereoInputError(f"--data.drop_textures: expected texture kinds out of {TEXTURE_KINDS} that "
                                       f"leave every level a kind to draw, got {drop_textures!r}")
        self.drop_textures = tuple(drop_textures or ())

        for name, value in (("shared_material", shared_material), ("weak_background", weak_background),
                            ("thin_structures", thin_structures)):
            if isinstance(value, bool) or not isinstance(value, int | float) or not 0.0 <= value <= 1.0:
                raise StereoInputError(f"--data.{name}: expected a probability in [0, 1], got {value!r}")
        if isinstance(render_scale, bool) or not isinstance(render_scale, int) or render_scale < 1:
            raise StereoInputError(f"--data.render_scale: expected an integer >= 1, got {render_scale!r}")
        if not 0.0 < train_ratio <= 1.0:
            raise StereoInputError(f"--data.train_ratio: expected a share in (0, 1], got {train_ratio}")
        self.train_extra = open_training_spec(train, height, width) if train else None
        if source not in ("data_gen", "random-shift"):
            raise StereoInputError(f"source: expected 'data_gen' or 'random-shift', got {source!r}")
        ctx = multiprocessing.get_context("fork") if hasattr(os, "fork") else multiprocessing.get_context()
        self._difficulty = ctx.Value("i", min_difficulty)
        self._start = ctx.Value("l", 0)
        self.val_items: list[dict] | None = None

    def setup(self, stage: str | None = None) -> None:
        hp = self.hparams
        if self.val_items is None:
            vh, vw = hp.val_height or hp.height, hp.val_width or hp.width
            top = max_difficulty(hp.source)
            self.val_items = []
            for i in range(hp.val_pairs):  # a fixed mix of difficulties, same for every run
                level = round(top * i / max(hp.val_pairs - 1, 1))
                ds = _make_dataset(hp.source, hp.val_pairs, hp.val_seed, level, vh, vw, hp.supersample)
                item = _training_fields(ds[i])
                if hp.val_vertical_jitter > 0 or hp.val_vertical_warp > 0:
                    item = vertical_jitter(item, hp.val_vertical_jitter,
                                           torch.Generator().manual_seed(hp.val_seed * 7919 + i),
                                           hp.val_vertical_warp)
                self.val_items.append(item)

    def set_progress(self, progress: float, start_step: int | None = None, floor: int = 0) -> None:
        """Set the training difficulty from the progress in [0, 1] (called by the curriculum callback), never
        below ``floor`` (the level a resumed run had reached); ``start_step`` (the global step a run starts or
        resumes at) offsets the rendering seeds."""
        hp = self.hparams
        self._difficulty.value = max(int(floor), difficulty_at(progress, max_difficulty(hp.source),
                                                               hp.curriculum_fraction, hp.min_difficulty))
        if start_step is not None:
            self._start.value = int(start_step)

    @property
    def difficulty(self) -> int:
        return int(self._difficulty.value)

    def train_dataloader(self) -> DataLoader:
        hp = self.hparams
        trainer = getattr(self, "trainer", None)
        rank, world = (trainer.global_rank, trainer.world_size) if trainer is not None else (0, 1)
        if trainer is not None:  # Lightning asks for the loader after restoring a checkpoint and starts the stream
            # (it prefetches a batch) before on_train_start: the start step and difficulty must be set here, or a
            # resumed run replays the first run's pairs and renders its first batch at the easiest level
            from stereonet.training.callbacks import CurriculumCallback

            for cb in trainer.callbacks:
                if isinstance(cb, CurriculumCallback):
                    cb.update(trainer, start=True)
        stream = PooledCurriculumStream(hp.source, hp.seed, hp.height, hp.width, hp.pool_size, hp.reuse,
                                        hp.augment, self._difficulty, self._start, hp.supersample,
                                        hp.disparity_range, rank=rank, world_size=world,
                                        vertical_jitter=hp.vertical_jitter, extra=self.train_extra,
                                        extra_ratio=hp.train_ratio, vertical_warp=hp.vertical_warp,
                                        shared_material=hp.shared_material, drop_textures=self.drop_textures,
                                        weak_background=hp.weak_background, render_scale=hp.render_scale,
                                        thin_structures=hp.thin_structures)
        return DataLoader(stream, batch_size=hp.batch_size, num_workers=hp.num_workers,
                          collate_fn=collate_pairs, persistent_workers=hp.num_workers > 0)

    def val_dataloader(self) -> DataLoader:
        return DataLoader(self.val_items, batch_size=min(self.hparams.batch_size, len(self.val_items)) or 1,
                          shuffle=False, num_workers=0, collate_fn=collate_pairs)
