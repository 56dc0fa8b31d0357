"""Disparity error metrics: EPE, bad-τ, KITTI D1, density, SMD-Nets soft edge error (SEE).

Every metric runs under ``torch.no_grad`` and returns a Python float; **do not use these as training
losses** (no gradients, thresholded counts). Shapes: ``pred``, ``gt`` are :math:`(B, 1, H, W)`, :math:`(B, H, W)`
or :math:`(H, W)` (torch or numpy); masks are bool of the same shape.

Which pixels count:
    The evaluated set is ``gt_valid & mask`` (``mask`` selects all / noc / occ). A pixel the method leaves
    without an answer (``pred_valid`` False) is an **error** for bad-τ and D1 (its error is taken as +inf),
    so sparse methods cannot look better by abstaining; the share they do answer is reported by
    :func:`density`. EPE (and SEE) have no finite value for a missing answer, so they average only over
    evaluated pixels the method predicts (``gt_valid & mask & pred_valid``); always read them together
    with density.

Averaging:
    ``reduction="pixel"`` (default) pools every evaluated pixel of the batch into one mean / rate (the
    KITTI and Middlebury convention for a single image; for a dataset it weights images by their number of
    valid pixels). ``reduction="image"`` computes the metric per image and then averages over the images
    that have evaluated pixels (each image weighs the same). Rates are percentages in [0, 100]. A metric
    over an empty pixel set is ``nan`` (e.g. ``*_occ`` on an image without occlusions): "undefined", not 0.
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F

from stereonet.checks import StereoInputError

__all__ = [
    "bad_pixel_rate", "d1_kitti", "density", "depth_discontinuities", "end_point_error", "epe", "evaluate",
    "soft_edge_error", "sparsification", "sparsification_ause",
]


def _as_b1hw(x, name: str, dtype: torch.dtype | None = torch.float64) -> torch.Tensor:
    """(H, W), (B, H, W) or (B, 1, H, W), torch or numpy -> (B, 1, H, W) on CPU."""
    if x is None:
        raise TypeError(f"{name}: expected a tensor or array, got None")
    if not isinstance(x, torch.Tensor):
        a = np.asarray(x)
        if a.dtype.kind not in "biuf":
            raise StereoInputError(f"{name}: expected a numeric array, got dtype {a.dtype}")
        t = torch.from_numpy(np.ascontiguousarray(a))  # a reversed or strided view is fine
    else:
        t = x.detach()
    if t.dim() == 2:
        t = t[None, None]
    elif t.dim() == 3:
        t = t[:, None]
    elif t.dim() != 4 or t.shape[1] != 1:
        raise StereoInputError(f"{name}: expected shape (B, 1, H, W), (B, H, W) or (H, W), got {tuple(t.shape)}")
    if dtype is None:
        if t.dtype != torch.bool:
            raise TypeError(f"{name}: expected a bool mask, got {t.dtype}")
        return t.cpu()
    if not (t.is_floating_point() or t.dtype in (torch.uint8, torch.int16, torch.int32, torch.int64)):
        raise TypeError(f"{name}: expected a real-valued disparity, got {t.dtype}")
    return t.cpu().to(dtype)


def _inputs(pred, gt, gt_valid, pred_valid=None, mask=None):
    """Validate and bring everything to (B, 1, H, W): pred/gt float64 (0 where invalid), masks bool."""
    gt_t = _as_b1hw(gt, "gt")
    shape = tuple(gt_t.shape)
    gv = _as_b1hw(gt_valid, "gt_valid", None) if gt_valid is not None else torch.isfinite(gt_t)
    pr = _as_b1hw(pred, "pred")
    pv = _as_b1hw(pred_valid, "pred_valid", None) if pred_valid is not None else torch.ones(shape, dtype=torch.bool)
    m = _as_b1hw(mask, "mask", None) if mask is not None else torch.ones(shape, dtype=torch.bool)
    for name, t in (("pred", pr), ("gt_valid", gv), ("pred_valid", pv), ("mask", m)):
        if tuple(t.shape) != shape:
            raise StereoInputError(f"{name}: expected shape {shape} like gt, got {tuple(t.shape)}")
    if not bool(torch.isfinite(gt_t[gv]).all()):
        raise StereoInputError("gt: expected finite values where gt_valid is True, got NaN or inf")
    if not bool(torch.isfinite(pr[pv]).all()):
        raise StereoInputError("pred: expected finite values where pred_valid is True, got NaN or inf "
                               "(mark such pixels invalid through pred_valid)")
    gt_t = torch.where(gv, gt_t, torch.zeros_like(gt_t))
    pr = torch.where(pv, pr, torch.zeros_like(pr))
    return pr, gt_t, gv, pv, m


def _reduce(values: torch.Tensor, select: torch.Tensor, reduction: str) -> float:
    """Mean of ``values`` over ``select`` (both (B, 1, H, W); bool values count as 0/1), pooled or per image.

    Masked sums instead of boolean indexing: no gather copies, and ``values`` may hold inf/NaN outside
    ``select``.
    """
    if reduction not in ("pixel", "image"):
        raise StereoInputError(f"reduction: expected 'pixel' or 'image', got {reduction!r}")
    zero = torch.zeros((), dtype=torch.float64)
    num = torch.where(select, values.to(torch.float64), zero).sum(dim=(1, 2, 3))  # B
    den = select.sum(dim=(1, 2, 3))  # B
    if reduction == "pixel":
        total = int(den.sum())
        return float(num.sum() / total) if total else math.nan
    ok = den > 0
    return float((num[ok] / den[ok]).mean()) if bool(ok.any()) else math.nan


def _percent(flags: torch.Tensor, select: torch.Tensor, reduction: str) -> float:
    value = _reduce(flags, select, reduction)
    return value * 100.0 if not math.isnan(value) else value


def _error_with_misses(pr, gt, pv) -> torch.Tensor:
    """|pred - gt| with +inf where the method gives no answer (counts as an error at every threshold)."""
    err = (pr - gt).abs()
    return torch.where(pv, err, torch.full_like(err, math.inf))


def _d1_outliers(err_with_misses: torch.Tensor, gt: torch.Tensor) -> torch.Tensor:
    # KITTI devkit: E > 3 px and E / |D_gt| > 5 %; inf (missing prediction) satisfies both
    return (err_with_misses > 3.0) & (err_with_misses > 0.05 * gt.abs())


def _check_tau(tau: float) -> float:
    if isinstance(tau, bool) or not isinstance(tau, int | float) or not tau >= 0:
        raise StereoInputError(f"tau: expected a threshold >= 0 pixels, got {tau!r}")
    return float(tau)


@torch.no_grad()
def end_point_error(pred, gt, gt_valid=None, pred_valid=None, mask=None, reduction: str = "pixel") -> float:
    """EPE: mean absolute disparity error in pixels over ``gt_valid & mask & pred_valid``.

    Pixels without a prediction are excluded (see the module docstring; report :func:`density` beside it).
    Do not use as a loss.
    """
    pr, gt_t, gv, pv, m = _inputs(pred, gt, gt_valid, pred_valid, mask)
    return _reduce((pr - gt_t).abs(), gv & m & pv, reduction)


epe = end_point_error


@torch.no_grad()
def bad_pixel_rate(pred, gt, gt_valid=None, tau: float = 1.0, pred_valid=None, mask=None,
                   reduction: str = "pixel") -> float:
    """Bad-τ: percentage of evaluated pixels (``gt_valid & mask``) with ``|pred - gt| > tau``.

    Pixels without a prediction count as bad. Any ``tau >= 0``. Do not use as a loss.
    """
    tau = _check_tau(tau)
    pr, gt_t, gv, pv, m = _inputs(pred, gt, gt_valid, pred_valid, mask)
    return _percent(_error_with_misses(pr, gt_t, pv) > tau, gv & m, reduction)


@torch.no_grad()
def d1_kitti(pred, gt, gt_valid=None, pred_valid=None, mask=None, reduction: str = "pixel") -> float:
    """KITTI D1: percentage of evaluated pixels with error > 3 px **and** > 5 % of the true disparity.

    Outlier definition of the KITTI 2015 stereo devkit (``E > 3 & E / |D_gt| > 0.05``; Menze & Geiger,
    CVPR 2015). Pixels without a prediction count as outliers. Do not use as a loss.
    """
    pr, gt_t, gv, pv, m = _inputs(pred, gt, gt_valid, pred_valid, mask)
    return _percent(_d1_outliers(_error_with_misses(pr, gt_t, pv), gt_t), gv & m, reduction)


@torch.no_grad()
def density(pred_valid, gt_valid=None, mask=None, reduction: str = "pixel") -> float:
    """Percentage of evaluated pixels (``gt_valid & mask``, all pixels when both are None) that the method
    predicts (``pred_valid``)."""
    pv = _as_b1hw(pred_valid, "pred_valid", None)
    gv = _as_b1hw(gt_valid, "gt_valid", None) if gt_valid is not None else torch.ones_like(pv)
    m = _as_b1hw(mask, "mask", None) if mask is not None else torch.ones_like(pv)
    for name, t in (("gt_valid", gv), ("mask", m)):
        if t.shape != pv.shape:
            raise StereoInputError(f"{name}: expected shape {tuple(pv.shape)} like pred_valid, got {tuple(t.shape)}")
    return _percent(pv, gv & m, reduction)


@torch.no_grad()
def depth_discontinuities(gt, gt_valid=None, threshold: float = 1.0, dilation: int = 0) -> torch.Tensor:
    """Pixels next to a ground-truth disparity jump: bool :math:`(B, 1, H, W)`.

    A valid pixel is marked when one of its 4-neighbours is valid and differs by more than ``threshold``
    pixels (both sides of the jump are marked), then the mask is dilated by a ``dilation`` x ``dilation``
    box when ``dilation > 1`` (as SMD-Nets' ``get_boundaries``, which defaults to threshold 1, no dilation).
    """
    _, gt_t, gv, _, _ = _inputs(gt, gt, gt_valid)
    edges = torch.zeros_like(gv)
    jump_x = ((gt_t[..., :, 1:] - gt_t[..., :, :-1]).abs() > threshold) & gv[..., :, 1:] & gv[..., :, :-1]
    jump_y = ((gt_t[..., 1:, :] - gt_t[..., :-1, :]).abs() > threshold) & gv[..., 1:, :] & gv[..., :-1, :]
    edges[..., :, 1:] |= jump_x
    edges[..., :, :-1] |= jump_x
    edges[..., 1:, :] |= jump_y
    edges[..., :-1, :] |= jump_y
    if dilation > 1:
        pad = (dilation // 2, (dilation - 1) // 2, dilation // 2, (dilation - 1) // 2)
        edges = F.max_pool2d(F.pad(edges.double(), pad), dilation, stride=1) > 0
    return edges & gv


@torch.no_grad()
def soft_edge_error(pred, gt, gt_valid=None, k: int = 3, pred_valid=None, threshold: float = 1.0,
                    dilation: int = 0, reduction: str = "pixel") -> float:
    """Soft edge error (SEE) of SMD-Nets (Tosi, Liao, Schmitt, Geiger, CVPR 2021), in pixels.

    On the depth-discontinuity pixels of the ground truth (:func:`depth_discontinuities` with
    ``threshold``/``dilation``), the error of each prediction against the **closest** ground-truth disparity
    in its ``k`` x ``k`` neighbourhood (``k = 3`` is SMD-Nets' radius 1): ``min_q |pred(p) - gt(q)|``,
    averaged over those pixels. It forgives an edge placed one pixel off but not a blurred edge (a value
    between foreground and background is far from both). Unlike the reference code, neighbours outside
    the image or without ground truth are skipped instead of compared with 0. Pixels without a prediction
    are excluded, as for EPE. Do not use as a loss.
    """
    if isinstance(k, bool) or not isinstance(k, int) or k < 1 or k % 2 == 0:
        raise StereoInputError(f"k: expected an odd positive window size, got {k!r}")
    pr, gt_t, gv, pv, _ = _inputs(pred, gt, gt_valid, pred_valid)
    b, _, h, w = gt_t.shape
    edges = depth_discontinuities(gt_t, gv, threshold, dilation)
    gt_inf = torch.where(gv, gt_t, torch.full_like(gt_t, math.inf))
    neigh = F.unfold(F.pad(gt_inf, (k // 2,) * 4, value=math.inf), k)  # Bx(k*k)x(H*W)
    neigh = neigh.reshape(b, k * k, h, w)  # Bx(k*k)xHxW
    err = (neigh - pr).abs().amin(dim=1, keepdim=True)  # Bx1xHxW, finite wherever gt_valid (centre included)
    return _reduce(err, edges & pv, reduction)


SPARSIFICATION_STEPS = 20  # remove 0 %, 5 %, ..., 95 % of the pixels (the last 5 % always stay)


def _ranking(uncertainty, confidence, shape) -> torch.Tensor:
    """One "how unsure" score per pixel, higher = less trustworthy: ``uncertainty`` or ``-confidence``."""
    if (uncertainty is None) == (confidence is None):
        raise StereoInputError("uncertainty, confidence: expected exactly one of them, got "
                               + ("both" if uncertainty is not None else "neither"))
    name, x = ("uncertainty", uncertainty) if uncertainty is not None else ("confidence", confidence)
    t = _as_b1hw(x, name)
    if tuple(t.shape) != shape:
        raise StereoInputError(f"{name}: expected shape {shape} like gt, got {tuple(t.shape)}")
    t = torch.nan_to_num(t, nan=math.inf if uncertainty is not None else -math.inf)
    return t if uncertainty is not None else -t


@torch.no_grad()
def sparsification(pred, gt, gt_valid=None, uncertainty=None, confidence=None, pred_valid=None,
                   tau: float = 2.0, steps: int = SPARSIFICATION_STEPS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sparsification curves of bad-``tau`` (Ilg et al., ECCV 2018; the AUSE of Poggi et al., CVPR 2020).

    Over the evaluated pixels (``gt_valid``, pooled over the batch) remove the fraction ``f`` that the
    method trusts least (descending ``uncertainty``, or ascending ``confidence``; pixels without a
    prediction are removed before any predicted one and count as errors, as in :func:`bad_pixel_rate`) and
    measure bad-``tau`` of the rest; the oracle removes pixels by descending true error instead. Pixels of equal
    rank are removed in random order, in expectation (a tie group cut by a fraction gives up its errors in
    proportion), so a binary or clipped confidence is scored for what it says and not by the pixels' order.

    Returns:
        ``(fractions, curve, oracle)``: ``fractions = i / steps`` for ``i = 0 .. steps - 1`` and the two
        bad-``tau`` curves in percent at those fractions (numpy float64 arrays of length ``steps``).
    """
    tau = _check_tau(tau)
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
        raise StereoInputError(f"steps: expected a positive number of fractions, got {steps!r}")
    pr, gt_t, gv, pv, _ = _inputs(pred, gt, gt_valid, pred_valid)
    rank = _ranking(uncertainty, confidence, tuple(gt_t.shape))
    rank = torch.where(pv, rank, torch.full_like(rank, math.inf))  # no answer: least trustworthy of all
    err = _error_with_misses(pr, gt_t, pv)[gv]  # N
    bad = (err > tau).to(torch.float64)
    fractions = np.arange(steps, dtype=np.float64) / steps
    n = int(bad.numel())
    if n == 0:
        nan = np.full(steps, math.nan)
        return fractions, nan, nan.copy()
    ks = torch.from_numpy(np.floor(fractions * n).astype(np.int64))
    kept = (n - ks).to(torch.float64)
    curves = []
    for order_key in (rank[gv], err):
        removed_bad = _expected_removed(order_key.to(torch.float64), bad, ks)
        curves.append(((bad.sum() - removed_bad) / kept * 100.0).numpy())
    return fractions, curves[0], curves[1]


def _expected_removed(key: torch.Tensor, bad: torch.Tensor, ks: torch.Tensor) -> torch.Tensor:
    """Bad pixels among the first ``k`` (each of ``ks``) in descending ``key``, in expectation over the order of
    equal keys: a group of ties cut at ``k`` contributes its bad share pro rata, so a ranking is judged by what
    it says, never by the pixel order (a constant ranking keeps the bad rate at every fraction)."""
    order = torch.sort(key, descending=True, stable=True).indices
    _, counts = torch.unique_consecutive(key[order], return_counts=True)
    ends = torch.cumsum(counts, 0)
    starts = ends - counts
    cum = torch.cat([bad.new_zeros(1), torch.cumsum(bad[order], 0)])  # bad among the first k, in sorted order
    group = torch.searchsorted(ends, ks, right=True).clamp(max=counts.numel() - 1)  # the tie group at position k
    share = (cum[ends[group]] - cum[starts[group]]) / counts[group].to(torch.float64)
    return cum[starts[group]] + (ks - starts[group]).to(torch.float64) * share


def sparsification_ause(pred, gt, gt_valid=None, uncertainty=None, confidence=None, pred_valid=None,
                        tau: float = 2.0, steps: int = SPARSIFICATION_STEPS) -> float:
    """Area under the sparsification error (AUSE) of bad-``tau``, in percentage points: the mean over the
    fractions of :func:`sparsification` of (method curve - oracle curve). 0 = the method ranks its own
    errors perfectly; a ranking that knows nothing (constant confidence) gives the full gap between
    bad-``tau`` and the oracle. Lower is better. Do not use as a loss."""
    _, curve, oracle = sparsification(pred, gt, gt_valid, uncertainty, confidence, pred_valid, tau, steps)
    return float(np.mean(curve - oracle))


@torch.no_grad()
def evaluate(pred, gt, gt_valid=None, pred_valid=None, occlusion=None, reduction: str = "pixel",
             see: bool = True) -> dict[str, float]:
    """All standard metrics in one dict (the interface eval.py and training logs share).

    Keys: ``epe``, ``bad1``, ``bad2``, ``bad4``, ``d1``, ``density`` (rates in percent 0–100), ``see``
    (when ``see``), and when ``occlusion`` (bool, True = occluded) is given the same six with suffixes
    ``_noc`` (``gt_valid & ~occlusion``) and ``_occ`` (``gt_valid & occlusion``). Averaging and the
    treatment of missing predictions are described in the module docstring. Do not use as a loss.
    """
    pr, gt_t, gv, pv, _ = _inputs(pred, gt, gt_valid, pred_valid)
    masks = {"": None}
    if occlusion is not None:
        occ = _as_b1hw(occlusion, "occlusion", None)
        if occ.shape != gt_t.shape:
            raise StereoInputError(f"occlusion: expected shape {tuple(gt_t.shape)} like gt, got {tuple(occ.shape)}")
        masks["_noc"] = ~occ
        masks["_occ"] = occ
    err = (pr - gt_t).abs()  # Bx1xHxW
    err_miss = torch.where(pv, err, torch.full_like(err, math.inf))
    outlier = _d1_outliers(err_miss, gt_t)
    bad = {tau: err_miss > tau for tau in (1, 2, 4)}
    out: dict[str, float] = {}
    for suffix, m in masks.items():
        sel = gv if m is None else gv & m
        out["epe" + suffix] = _reduce(err, sel & pv, reduction)
        for tau, flags in bad.items():
            out[f"bad{tau}{suffix}"] = _percent(flags, sel, reduction)
        out["d1" + suffix] = _percent(outlier, sel, reduction)
        out["density" + suffix] = _percent(pv, sel, reduction)
    if see:
        out["see"] = soft_edge_error(pr, gt_t, gv, pred_valid=pv, reduction=reduction)
    return out
