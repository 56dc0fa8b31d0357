"""Pictures: disparity in colour on a fixed scale, KITTI-style error maps, titled side-by-side panels,
bar charts and curves. Every array returned is ``uint8`` RGB :math:`(H, W, 3)`; every file is written
atomically.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import cv2
import numpy as np

from stereonet.checks import StereoInputError
from stereonet.io.atomic import atomic_path
from stereonet.io.image import to_uint8_rgb, write_image

__all__ = ["KITTI_ERROR_COLORS", "colorize_disparity", "error_map", "panel", "plot_bars", "plot_curves", "save_png"]

# KITTI stereo devkit error colour map (io_disp.h, errorImage): bins of the normalised error
# min(E / 3 px, (E / |D_gt|) / 5 %), so 1.0 is exactly the D1 outlier boundary; colours RGB, blue = small.
KITTI_ERROR_COLORS = (
    (0.0, 0.0625, (49, 54, 149)), (0.0625, 0.125, (69, 117, 180)), (0.125, 0.25, (116, 173, 209)),
    (0.25, 0.5, (171, 217, 233)), (0.5, 1.0, (224, 243, 248)), (1.0, 2.0, (254, 224, 144)),
    (2.0, 4.0, (253, 174, 97)), (4.0, 8.0, (244, 109, 67)), (8.0, 16.0, (215, 48, 39)),
    (16.0, math.inf, (165, 0, 38)),
)


def _as_hw(x, name: str, dtype=np.float64) -> np.ndarray:
    """(H, W), (1, H, W) or (1, 1, H, W), numpy or torch -> numpy (H, W)."""
    a = x.detach().cpu().numpy() if hasattr(x, "detach") else np.asarray(x)
    while a.ndim > 2 and a.shape[0] == 1:
        a = a[0]
    if a.ndim != 2 or a.size == 0:
        raise StereoInputError(f"{name}: expected shape (H, W) (or with leading 1s), got {np.shape(x)}")
    if dtype is bool:
        if a.dtype != np.bool_:
            raise TypeError(f"{name}: expected a bool mask, got {a.dtype}")
        return a
    return a.astype(dtype)


def _mask(valid, shape, name: str) -> np.ndarray:
    if valid is None:
        return np.ones(shape, bool)
    v = _as_hw(valid, name, bool)
    if v.shape != shape:
        raise StereoInputError(f"{name}: expected shape {shape}, got {v.shape}")
    return v


def colorize_disparity(disp, max_disp: float, valid=None, colormap: int = cv2.COLORMAP_TURBO) -> np.ndarray:
    """Disparity in colour on a **fixed** scale: ``0 .. max_disp`` through the perceptual turbo colour map
    (values above ``max_disp`` saturate), so maps of different methods on one scene compare directly.

    Args:
        disp: :math:`(H, W)` (or with leading 1s), numpy or torch.
        max_disp: the top of the scale in pixels (> 0), e.g. the dataset's ``max_disp``.
        valid: optional bool mask; invalid and non-finite pixels are black.
    Returns:
        uint8 RGB :math:`(H, W, 3)`.
    """
    if not (isinstance(max_disp, int | float) and max_disp > 0 and math.isfinite(max_disp)):
        raise StereoInputError(f"max_disp: expected a positive number, got {max_disp!r}")
    d = _as_hw(disp, "disp")
    v = _mask(valid, d.shape, "valid") & np.isfinite(d)
    level = np.rint(np.clip(np.where(v, d, 0.0) / float(max_disp), 0.0, 1.0) * 255.0).astype(np.uint8)
    rgb = cv2.cvtColor(cv2.applyColorMap(level, colormap), cv2.COLOR_BGR2RGB)
    rgb[~v] = 0
    return rgb


def with_colour_bar(rgb: np.ndarray, low: float, high: float, unit: str, colormap: int = cv2.COLORMAP_TURBO,
                    ticks: int = 5) -> np.ndarray:
    """``rgb`` :math:`(H, W, 3)` uint8 with a vertical colour bar on its right: ``low`` (bottom) to ``high``
    (top) in ``colormap``, ``ticks`` labelled values and the ``unit`` above. Returns uint8 :math:`(H, W + 90, 3)`."""
    h, w = rgb.shape[:2]
    bar_w, pad = 18, 90
    out = np.full((h, w + pad, 3), 255, np.uint8)
    out[:, :w] = rgb
    top, bottom = 22, h - 8
    if bottom - top < 10:
        return out
    level = np.linspace(255, 0, bottom - top).astype(np.uint8)[:, None].repeat(bar_w, 1)
    out[top:bottom, w + 6:w + 6 + bar_w] = cv2.cvtColor(cv2.applyColorMap(level, colormap), cv2.COLOR_BGR2RGB)
    font = cv2.FONT_HERSHEY_SIMPLEX
    cv2.putText(out, unit, (w + 6, 15), font, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    for i in range(ticks):
        frac = i / max(1, ticks - 1)
        y = int(round(bottom - 1 - frac * (bottom - top - 1)))
        value = low + frac * (high - low)
        label = f"{value:.3g}"
        cv2.line(out, (w + 6 + bar_w, y), (w + 10 + bar_w, y), (0, 0, 0), 1)
        cv2.putText(out, label, (w + 13 + bar_w, y + 4), font, 0.38, (0, 0, 0), 1, cv2.LINE_AA)
    return out


def colorize_depth(depth, unit: str, valid=None, low: float | None = None, high: float | None = None) -> np.ndarray:
    """Depth in colour with a colour bar in ``unit``: near = red, far = blue (turbo reversed), on a scale
    from the 2nd to the 98th percentile of the valid depths (or ``low``/``high``); invalid pixels black.
    Returns uint8 RGB :math:`(H, W + 90, 3)`."""
    z = _as_hw(depth, "depth")
    v = _mask(valid, z.shape, "valid") & np.isfinite(z) & (z > 0)
    if low is None or high is None:
        vals = z[v]
        lo, hi = (float(np.percentile(vals, 2)), float(np.percentile(vals, 98))) if vals.size else (0.0, 1.0)
        low = lo if low is None else low
        high = hi if high is None else high
    if not high > low:
        high = low + 1.0
    frac = np.clip((np.where(v, z, high) - low) / (high - low), 0.0, 1.0)
    level = np.rint((1.0 - frac) * 255.0).astype(np.uint8)  # near = top of the colour map
    rgb = cv2.cvtColor(cv2.applyColorMap(level, cv2.COLORMAP_TURBO), cv2.COLOR_BGR2RGB)
    rgb[~v] = 0
    # the bar runs from high (top) to low: its colours must be the reversed map as well
    return with_colour_bar(rgb, high, low, unit)


def error_map(pred, gt, valid, pred_valid=None) -> np.ndarray:
    """KITTI-devkit error image: colour by ``min(|pred - gt| / 3, |pred - gt| / |gt| / 0.05)`` on a log scale
    (:data:`KITTI_ERROR_COLORS`; blue = accurate, red = outlier, the boundary at 1 is D1's).

    Args:
        pred, gt: :math:`(H, W)` (or with leading 1s) disparities; valid: bool GT mask (invalid GT = black).
        pred_valid: optional bool mask of predicted pixels; missing predictions get the worst colour.
    Returns:
        uint8 RGB :math:`(H, W, 3)`.
    """
    p, g = _as_hw(pred, "pred"), _as_hw(gt, "gt")
    if p.shape != g.shape:
        raise StereoInputError(f"pred: expected the shape of gt {g.shape}, got {p.shape}")
    v = _mask(valid, g.shape, "valid") & np.isfinite(g)
    pv = _mask(pred_valid, g.shape, "pred_valid") & np.isfinite(p)
    with np.errstate(divide="ignore", invalid="ignore"):
        err = np.abs(np.where(pv, p, 0.0) - np.where(v, g, 0.0))
        norm = np.minimum(err / 3.0, np.where(np.abs(g) > 0, err / np.abs(g) / 0.05, np.inf))
    norm = np.where(pv, norm, np.inf)
    out = np.zeros((*g.shape, 3), np.uint8)
    for lo, hi, color in KITTI_ERROR_COLORS:
        out[v & (norm >= lo) & (norm < hi)] = color
    out[v & np.isinf(norm)] = KITTI_ERROR_COLORS[-1][2]
    return out


def _to_rgb(img, name: str) -> np.ndarray:
    a = to_uint8_rgb(img, name)
    return np.repeat(a[:, :, None], 3, axis=2) if a.ndim == 2 else a


def panel(images: Sequence, titles: Sequence[str] | None = None, gap: int = 4) -> np.ndarray:
    """Images side by side (left | GT | prediction | error ...) with a title above each, on white.

    Args:
        images: uint8 RGB/grey numpy arrays or float tensors in [0, 1] (see :func:`to_uint8_rgb`); each is
            resized to the height of the first, keeping its aspect ratio.
        titles: one string per image (or None), drawn with ``cv2.putText``.
        gap: white pixels between images.
    Returns:
        uint8 RGB :math:`(H_{title} + H, \\sum W + gaps, 3)`.
    """
    if not images:
        raise StereoInputError("images: expected at least one image, got an empty list")
    titles = [""] * len(images) if titles is None else list(titles)
    if len(titles) != len(images):
        raise StereoInputError(f"titles: expected {len(images)} titles (one per image), got {len(titles)}")
    tiles = [_to_rgb(im, f"images[{i}]") for i, im in enumerate(images)]
    h = tiles[0].shape[0]
    tiles = [t if t.shape[0] == h else cv2.resize(t, (max(1, round(t.shape[1] * h / t.shape[0])), h),
                                                  interpolation=cv2.INTER_AREA) for t in tiles]
    scale = max(0.4, min(1.0, h / 400.0))
    thickness = 1 if scale < 0.8 else 2
    (_, th), base = cv2.getTextSize("Ag", cv2.FONT_HERSHEY_SIMPLEX, scale, thickness)
    title_h = th + base + 8 if any(titles) else 0
    width = sum(t.shape[1] for t in tiles) + gap * (len(tiles) - 1)
    out = np.full((title_h + h, width, 3), 255, np.uint8)
    x = 0
    for tile, title in zip(tiles, titles):
        w = tile.shape[1]
        out[title_h:, x:x + w] = tile
        if title:
            text = str(title)
            while len(text) > 1 and cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, thickness)[0][0] > w - 4:
                text = text[:-2] + "~"  # shorten to fit the tile
            cv2.putText(out, text, (x + 2, th + 4), cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), thickness,
                        cv2.LINE_AA)
        x += w + gap
    return out


def save_png(path: str | os.PathLike, img) -> None:
    """Write an RGB uint8 :math:`(H, W, 3)` / grey image (or a float tensor in [0, 1]) as PNG, atomically."""
    if Path(path).suffix.lower() != ".png":
        raise StereoInputError(f"path: expected a .png file, got {str(path)!r}")
    write_image(path, img)


def _save_figure(fig, path: str | os.PathLike) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120)


def plot_bars(path: str | os.PathLike, categories: Sequence[str], series: Mapping[str, Sequence[float]],
              ylabel: str = "", title: str = "", logy: bool = False) -> None:
    """Grouped bar chart (one group per category, one bar per series), written atomically (PNG/SVG/PDF).

    ``series[name][i]`` is the value of ``name`` on ``categories[i]``; NaN/None bars are left out.
    Uses matplotlib's object API with the Agg canvas (no display, no global pyplot state).
    """
    from matplotlib.figure import Figure

    for name, vals in series.items():
        if len(vals) != len(categories):
            raise StereoInputError(f"series[{name!r}]: expected {len(categories)} values (one per category), got {len(vals)}")
    n = max(1, len(series))
    fig = Figure(figsize=(max(5.0, 0.6 * len(categories) * n + 2.0), 4.0))
    ax = fig.add_subplot(1, 1, 1)
    width = 0.8 / n
    x = np.arange(len(categories), dtype=float)
    for i, (name, vals) in enumerate(series.items()):
        y = np.array([np.nan if v is None else float(v) for v in vals])
        ok = np.isfinite(y)
        ax.bar(x[ok] - 0.4 + width * (i + 0.5), y[ok], width, label=name)
    ax.set_xticks(x)
    ax.set_xticklabels(list(categories), rotation=30 if len(categories) > 4 else 0, ha="right" if len(categories) > 4 else "center")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    if logy:
        ax.set_yscale("log")
    if len(series) > 1:
        ax.legend(fontsize="small")
    ax.grid(axis="y", alpha=0.3)
    _save_figure(fig, path)


def plot_curves(path: str | os.PathLike, curves: Mapping[str, tuple[Sequence[float], Sequence[float]]],
                xlabel: str = "", ylabel: str = "", title: str = "", logx: bool = False, logy: bool = False) -> None:
    """Line plot of named ``(xs, ys)`` curves (e.g. bad-τ against τ, loss against step), written atomically."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.0, 4.0))
    ax = fig.add_subplot(1, 1, 1)
    for name, (xs, ys) in curves.items():
        if len(xs) != len(ys):
            raise StereoInputError(f"curves[{name!r}]: expected as many x as y values, got {len(xs)} and {len(ys)}")
        ax.plot(np.asarray(xs, float), np.asarray(ys, float), marker="o" if len(xs) < 30 else None, label=name)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    if logx:
        ax.set_xscale("log")
    if logy:
        ax.set_yscale("log")
    if len(curves) > 1:
        ax.legend(fontsize="small")
    ax.grid(alpha=0.3)
    _save_figure(fig, path)
