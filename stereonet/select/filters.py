"""Post-filters for disparity maps: median filter, speckle (small connected component) removal and the joint
weighted median guided by the image."""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from stereonet.checks import StereoInputError, check_finite, check_shape, check_window
from stereonet.kernels import use_numba
from stereonet.kernels.filters import (
    WMF_MIN_LOG_WEIGHT,
    median_kernel,
    speckle_kernel,
    weighted_median_kernel,
)
from stereonet.select.fill import fill_occlusions


def median_filter(disp: torch.Tensor, size: int = 3, valid: torch.Tensor | None = None,
                  backend: str = "auto") -> torch.Tensor:
    """Median over a ``size x size`` window (border replicated).

    With ``valid`` given, only valid neighbours vote (a pixel without valid neighbours keeps its value);
    the output is defined everywhere, the mask is for the caller to keep.

    Args:
        disp: :math:`(B, 1, H, W)`.
        size: odd window size.
        valid: optional bool :math:`(B, 1, H, W)`.
        backend: ``"auto"`` (numba for CPU input without gradient), ``"torch"`` (unfold + sort) or ``"numba"``.

    Returns:
        :math:`(B, 1, H, W)`.
    """
    dims = check_shape(disp, ["B", "1", "H", "W"], "disp")
    check_window(size, "size")
    if backend not in ("auto", "torch", "numba"):
        raise StereoInputError(f"backend: expected 'auto', 'torch' or 'numba', got {backend!r}")
    if size == 1:
        return disp
    if valid is not None:
        check_shape(valid, [str(dims["B"]), "1", str(dims["H"]), str(dims["W"])], "valid")
    if use_numba(disp, backend=backend, float32_only=False):
        d = disp.detach().cpu().numpy()
        v = np.ones(d.shape, np.bool_) if valid is None else valid.detach().cpu().numpy()
        out = np.stack([median_kernel(d[b, 0], v[b, 0], size) for b in range(d.shape[0])])[:, None]
        return torch.from_numpy(out).to(disp.device)
    r = size // 2
    patches = F.unfold(F.pad(disp, (r, r, r, r), mode="replicate"), size)  # Bx(size*size)x(H*W)
    if valid is None:
        med = patches.median(dim=1).values
        return med.view_as(disp)
    vpatch = F.unfold(F.pad(valid.to(disp.dtype), (r, r, r, r), mode="replicate"), size) > 0.5
    n_valid = vpatch.sum(1, keepdim=True)
    # invalid samples -> +inf, so the k-th smallest of the valid ones is the median (lower median)
    vals = patches.masked_fill(~vpatch, float("inf")).sort(dim=1).values
    k = ((n_valid - 1).clamp(min=0) // 2)
    med = vals.gather(1, k).squeeze(1)
    med = torch.where(n_valid.squeeze(1) > 0, med, disp.flatten(2).squeeze(1))
    return med.view_as(disp)


def speckle_filter(disp: torch.Tensor, valid: torch.Tensor, max_size: int = 100,
                   max_diff: float = 1.0) -> torch.Tensor:
    """Invalidate speckles: 4-connected regions of valid pixels (neighbours differing by at most
    ``max_diff``) with fewer than ``max_size`` pixels (OpenCV's ``filterSpeckles`` rule).

    Args:
        disp: :math:`(B, 1, H, W)`.
        valid: bool :math:`(B, 1, H, W)`.
        max_size: regions smaller than this are removed (0 disables).
        max_diff: largest disparity step inside a region.

    Returns:
        bool :math:`(B, 1, H, W)` new validity mask (a subset of ``valid``).
    """
    dims = check_shape(disp, ["B", "1", "H", "W"], "disp")
    check_shape(valid, [str(dims["B"]), "1", str(dims["H"]), str(dims["W"])], "valid")
    if not (max_size >= 0 and max_diff >= 0):  # NaN fails too
        raise StereoInputError(f"max_size/max_diff: expected non-negative values, got {max_size}, {max_diff}")
    if max_size == 0:
        return valid.clone()
    d = disp.detach().to("cpu", torch.float32).numpy()
    v = valid.detach().to("cpu").numpy().astype(np.bool_)
    out = np.stack([speckle_kernel(d[b, 0], v[b, 0], int(max_size), float(max_diff)) for b in range(d.shape[0])])
    return torch.from_numpy(out[:, None]).to(valid.device)


# The weighted median after sgm-refine's choice (and sgm's opt-in one): radius 9 px, colour scale 0.2, chosen on
# fresh data_gen sets only (docs/experiments/wmf.txt: selection on wsel2/wsel4/wselb2/wselb4, confirmed on
# wmf2/wmf4/wmfb2/wmfb4); votes every 2nd px of the window, a third of the work (docs/experiments/wmf_stride.txt:
# selection on val2ai/val4ai/wb2h/wb4h, confirmed on val2ak/val4ak/wb2j/wb4j)
WMF_RADIUS = 9
WMF_SIGMA_COLOR = 0.2
WMF_STRIDE = 2
WMF_MAX_HISTOGRAM_SPAN = 65536.0
"""px: maps whose valid values span more are filtered by the torch reference (the numba kernel's histogram has
one bin per pixel of the span)."""


def check_wmf_options(radius, sigma_color, stride=1, radius_name: str = "wmf_radius",
                      sigma_name: str = "wmf_sigma_color", stride_name: str = "wmf_stride") -> None:
    """A matcher's weighted-median options: ``radius`` an integer >= 0 (0 = no filter), ``sigma_color`` > 0,
    ``stride`` an integer >= 1 (the matchers cap it at the radius); a one-line :class:`StereoInputError` naming the
    option otherwise."""
    if isinstance(radius, bool) or not isinstance(radius, int) or radius < 0:
        raise StereoInputError(f"{radius_name}: expected an integer >= 0 (0 = no weighted median), got {radius!r}")
    if not sigma_color > 0:
        raise StereoInputError(f"{sigma_name}: expected a value > 0, got {sigma_color!r}")
    if isinstance(stride, bool) or not isinstance(stride, int) or stride < 1:
        raise StereoInputError(f"{stride_name}: expected an integer >= 1 (1 = every pixel of the window votes), "
                               f"got {stride!r}")


def weighted_median_filter(disp: torch.Tensor, guide: torch.Tensor, radius: int = 7, sigma_color: float = 0.1,
                           sigma_space: float | None = None, valid: torch.Tensor | None = None,
                           jump: float = 1.0, stride: int = 1, band: int | None = None,
                           backend: str = "auto") -> torch.Tensor:
    """Joint weighted median filter guided by the image (the textbook post-step against foreground fattening).

    Each pixel takes the weighted median of the disparities in its ``(2 radius + 1)²`` window (clipped at the
    border; only ``valid`` neighbours vote), the weight of neighbour q of pixel p being
    ``exp(-|I_p - I_q|² / (2 sigma_color²) - |p - q|² / (2 sigma_space²))`` with ``I`` the guide's channels.
    Near a depth edge that lies on an intensity edge, a pixel's votes come mostly from its own side, so a band of
    the foreground's disparity fattened into the background is voted back to the background's. Only pixels with
    a discontinuity of the map in their window are filtered (two valid 4-neighbours differing by more than
    ``jump`` px, the metrics' depth-edge rule); the others are unchanged (elsewhere a median would only blur
    sub-pixel slopes). The weighted median is the
    smallest window value at which the cumulative weight (values in ascending order, ties in raster order)
    reaches half the total; weights and sums in float64, log-weights floored at
    :data:`~stereonet.kernels.filters.WMF_MIN_LOG_WEIGHT` (-45; a pixel's own weight is 1, so the floor only
    matters where the centre pixel does not vote).

    Args:
        disp: :math:`(B, 1, H, W)`.
        guide: :math:`(B, C, H, W)` image in [0, 1] (grey or colour), the same size.
        radius: window radius in pixels (>= 1).
        sigma_color: intensity scale of the weights (> 0, in the guide's units).
        sigma_space: spatial scale in pixels (> 0); ``None`` = ``radius``.
        valid: optional bool :math:`(B, 1, H, W)`: only valid pixels vote, and never a non-finite value (every
            output pixel is defined where some neighbour votes; a pixel without voting neighbours keeps its value).
        jump: the step (px) between 4-neighbours that makes a discontinuity.
        stride: spacing of the window's samples (>= 1): only neighbours at offsets that are multiples of ``stride``
            vote (``radius // stride`` of them each way; 1 = every pixel of the window). Less work by ``stride²``
            with the same spatial reach.
        band: a pixel is filtered when a discontinuity lies within ``band`` px of it (Chebyshev distance, >= 0,
            to the left or upper pixel of the step); ``None`` = ``radius`` (its window holds one).
        backend: ``"auto"`` (numba for CPU input without gradient), ``"torch"`` or ``"numba"``.

    Returns:
        :math:`(B, 1, H, W)` filtered disparity.
    """
    dims = check_shape(disp, ["B", "1", "H", "W"], "disp")
    check_shape(guide, [str(dims["B"]), "C", str(dims["H"]), str(dims["W"])], "guide")
    if valid is not None:
        check_shape(valid, [str(dims["B"]), "1", str(dims["H"]), str(dims["W"])], "valid")
    if isinstance(radius, bool) or not isinstance(radius, int) or radius < 1:
        raise StereoInputError(f"radius: expected an integer >= 1, got {radius!r}")
    sigma_space = float(radius) if sigma_space is None else sigma_space
    for name, value in (("sigma_color", sigma_color), ("sigma_space", sigma_space)):
        if not value > 0:
            raise StereoInputError(f"{name}: expected a value > 0, got {value!r}")
    if not jump >= 0:
        raise StereoInputError(f"jump: expected a value >= 0 pixels, got {jump!r}")
    if isinstance(stride, bool) or not isinstance(stride, int) or not 1 <= stride <= radius:
        raise StereoInputError(f"stride: expected an integer from 1 to radius ({radius}), got {stride!r}")
    band = radius if band is None else band
    if isinstance(band, bool) or not isinstance(band, int) or band < 0:
        raise StereoInputError(f"band: expected an integer >= 0 pixels (or None = radius), got {band!r}")
    if backend not in ("auto", "torch", "numba"):
        raise StereoInputError(f"backend: expected 'auto', 'torch' or 'numba', got {backend!r}")
    check_finite(guide, "guide")  # the kernel's colour weights assume finite guide values
    valid = torch.isfinite(disp) if valid is None else valid & torch.isfinite(disp)  # NaN and inf never vote
    votes = disp[valid]
    span = float(votes.max() - votes.min()) if votes.numel() else 0.0
    # the kernel's histogram has one bin per pixel of the map's range: a map with absurd values (a range of millions
    # of pixels) goes to the banded reference instead, whose memory does not depend on the values
    if span <= WMF_MAX_HISTOGRAM_SPAN and use_numba(disp, guide, backend=backend, float32_only=False):
        d = disp.detach().to("cpu", torch.float32).numpy()
        g = guide.detach().to("cpu", torch.float32).numpy()
        v = valid.detach().cpu().numpy().astype(np.bool_)
        out = np.stack([weighted_median_kernel(d[b, 0], np.ascontiguousarray(g[b]), v[b, 0], int(radius),
                                               float(sigma_color), float(sigma_space), float(jump), int(stride),
                                               int(band))
                        for b in range(d.shape[0])])[:, None]
        return torch.from_numpy(out).to(disp.device, disp.dtype)
    return _weighted_median_torch(disp, guide, valid, radius, sigma_color, sigma_space, jump, stride, band)


def filled_weighted_median(disp: torch.Tensor, valid: torch.Tensor, guide: torch.Tensor, radius: int,
                           sigma_color: float = WMF_SIGMA_COLOR, stride: int = WMF_STRIDE) -> torch.Tensor:
    """The matchers' last step against foreground fattening (``sgm(wmf_radius=)``, ``dispnet``): the invalid pixels
    filled by the shared rule (:func:`~stereonet.select.fill.fill_occlusions`, as ``eval.py --fill``), then
    :func:`weighted_median_filter` guided by ``guide`` with votes every ``stride`` px, capped at the radius."""
    return weighted_median_filter(fill_occlusions(disp, valid), guide, radius=radius, sigma_color=sigma_color,
                                  stride=min(stride, radius))


def _weighted_median_torch(disp, guide, valid, radius, sigma_color, sigma_space, jump, stride=1, band=None, rows=None):
    """The reference of :func:`weighted_median_filter` (unfolded windows, float64 weights), in bands of ``rows``
    rows (default: about 128 MB per unfolded float64 tensor) so that its memory stays bounded at any size."""
    b, c, h, w = guide.shape
    band = radius if band is None else band
    rk = radius // stride  # samples each way, ``stride`` px apart
    k, pad = 2 * rk + 1, rk * stride
    d = disp.to(torch.float32)
    d64 = d.to(torch.float64)
    edge = torch.zeros_like(valid)
    step_x = ((d64[..., 1:] - d64[..., :-1]).abs() > jump) & valid[..., 1:] & valid[..., :-1]
    step_y = ((d64[..., 1:, :] - d64[..., :-1, :]).abs() > jump) & valid[..., 1:, :] & valid[..., :-1, :]
    edge[..., :-1] |= step_x
    edge[..., :-1, :] |= step_y
    near = F.max_pool2d(edge.to(torch.float32), 2 * band + 1, 1, band) > 0
    rows = rows or max(1, 2 ** 27 // (8 * k * k * w * b))
    ky, kx = torch.meshgrid((torch.arange(k) - rk) * stride, (torch.arange(k) - rk) * stride, indexing="ij")
    space = (ky.reshape(-1) ** 2 + kx.reshape(-1) ** 2).to(torch.float64).view(1, k * k, 1).to(d.device)
    out = d.clone()
    for y0 in range(0, h, rows):
        y1 = min(h, y0 + rows)
        a0, a1 = max(0, y0 - pad), min(h, y1 + pad)  # the band with its halo (real rows inside the image)
        bh = a1 - a0
        db, vb, gb = d[..., a0:a1, :], valid[..., a0:a1, :], guide[..., a0:a1, :].to(torch.float64)
        vals = F.unfold(db, k, dilation=stride, padding=pad)  # Bx(k*k)x(bh*W); samples outside are masked below
        votes = F.unfold(vb.to(torch.float32), k, dilation=stride, padding=pad) > 0.5
        diff = F.unfold(gb, k, dilation=stride, padding=pad).view(b, c, k * k, bh * w) - gb.reshape(b, c, 1, bh * w)
        log_w = diff.pow(2).sum(1) * (-0.5 / sigma_color ** 2) + space * (-0.5 / sigma_space ** 2)
        weights = torch.exp(log_w.clamp(min=WMF_MIN_LOG_WEIGHT)).masked_fill(~votes, 0.0)
        order = vals.masked_fill(~votes, float("inf")).sort(dim=1, stable=True).indices
        cum = weights.gather(1, order).cumsum(1)
        first = (cum >= 0.5 * cum[:, -1:]).to(torch.uint8).argmax(1, keepdim=True)  # the first to reach half
        med = vals.gather(1, order.gather(1, first)).view(b, 1, bh, w)
        active = near[..., a0:a1, :] & votes.any(1).view(b, 1, bh, w)
        band = torch.where(active, med, db)
        out[..., y0:y1, :] = band[..., y0 - a0:y1 - a0, :]  # the core rows: their windows lie inside the band
    return out.to(disp.dtype)
