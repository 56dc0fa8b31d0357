"""Post-filters for disparity maps: median filter and speckle (small connected component) removal."""

from __future__ import annotations

import numba
import numpy as np
import torch
import torch.nn.functional as F

from stereonet.checks import StereoInputError, check_shape, check_window


@numba.njit(inline="always", fastmath=False)
def _sort2(a, b):
    return (a, b) if a <= b else (b, a)


@numba.njit(cache=True, fastmath=False)
def _median9(p0, p1, p2, p3, p4, p5, p6, p7, p8):
    """Median of nine values by the 19-exchange network (Paeth's opt_med9): the 5th smallest, the value the
    insertion sort of :func:`_median_kernel` picks for nine samples."""
    p1, p2 = _sort2(p1, p2)
    p4, p5 = _sort2(p4, p5)
    p7, p8 = _sort2(p7, p8)
    p0, p1 = _sort2(p0, p1)
    p3, p4 = _sort2(p3, p4)
    p6, p7 = _sort2(p6, p7)
    p1, p2 = _sort2(p1, p2)
    p4, p5 = _sort2(p4, p5)
    p7, p8 = _sort2(p7, p8)
    p0, p3 = _sort2(p0, p3)
    p5, p8 = _sort2(p5, p8)
    p4, p7 = _sort2(p4, p7)
    p3, p6 = _sort2(p3, p6)
    p1, p4 = _sort2(p1, p4)
    p2, p5 = _sort2(p2, p5)
    p4, p7 = _sort2(p4, p7)
    p4, p2 = _sort2(p4, p2)
    p6, p4 = _sort2(p6, p4)
    p4, p2 = _sort2(p4, p2)
    return p4


# fastmath=False: comparisons only (exact), and NaN disparities must not be assumed away
@numba.njit(parallel=True, cache=True, fastmath=False)
def _median_kernel(disp: np.ndarray, valid: np.ndarray, size: int) -> np.ndarray:
    """Lower median of the valid samples of each size x size window (replicated border). Interior 3x3
    windows with nine valid samples take the sorting network :func:`_median9` (the same value)."""
    h, w = disp.shape
    r = size // 2
    out = np.empty_like(disp)
    for y in numba.prange(h):
        buf = np.empty(size * size, disp.dtype)
        for x in range(w):
            if size == 3 and 0 < y < h - 1 and 0 < x < w - 1 and (
                    valid[y - 1, x - 1] & valid[y - 1, x] & valid[y - 1, x + 1] & valid[y, x - 1] & valid[y, x]
                    & valid[y, x + 1] & valid[y + 1, x - 1] & valid[y + 1, x] & valid[y + 1, x + 1]):
                out[y, x] = _median9(disp[y - 1, x - 1], disp[y - 1, x], disp[y - 1, x + 1], disp[y, x - 1],
                                     disp[y, x], disp[y, x + 1], disp[y + 1, x - 1], disp[y + 1, x],
                                     disp[y + 1, x + 1])
                continue
            n = 0
            for yy in range(y - r, y + r + 1):
                yc = min(max(yy, 0), h - 1)
                for xx in range(x - r, x + r + 1):
                    xc = min(max(xx, 0), w - 1)
                    if valid[yc, xc]:
                        v = disp[yc, xc]
                        j = n  # insertion sort
                        while j > 0 and buf[j - 1] > v:
                            buf[j] = buf[j - 1]
                            j -= 1
                        buf[j] = v
                        n += 1
            out[y, x] = buf[(n - 1) // 2] if n > 0 else disp[y, x]
    return out


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
    if backend == "numba" or (backend == "auto" and disp.device.type == "cpu"
                              and not (torch.is_grad_enabled() and disp.requires_grad)):
        d = disp.detach().cpu().numpy()
        v = np.ones(d.shape, np.bool_) if valid is None else valid.detach().cpu().numpy()
        out = np.stack([_median_kernel(d[b, 0], v[b, 0], size) for b in range(d.shape[0])])[:, None]
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


@numba.njit(cache=True)
def _speckle_kernel(disp: np.ndarray, valid: np.ndarray, max_size: int, max_diff: float) -> np.ndarray:
    """Flood fill of 4-connected regions of valid pixels whose neighbours differ by <= max_diff."""
    h, w = disp.shape
    label = np.zeros((h, w), dtype=np.int32)
    out = valid.copy()
    stack = np.empty(h * w, dtype=np.int64)
    members = np.empty(h * w, dtype=np.int64)
    current = 0
    for y0 in range(h):
        for x0 in range(w):
            if not valid[y0, x0] or label[y0, x0] != 0:
                continue
            current += 1
            label[y0, x0] = current
            top = 0
            stack[top] = y0 * w + x0
            top += 1
            count = 0
            while top > 0:
                top -= 1
                p = stack[top]
                members[count] = p
                count += 1
                y = p // w
                x = p - y * w
                dp = disp[y, x]
                for k in range(4):
                    ny, nx = y, x
                    if k == 0:
                        ny = y - 1
                    elif k == 1:
                        ny = y + 1
                    elif k == 2:
                        nx = x - 1
                    else:
                        nx = x + 1
                    if ny < 0 or ny >= h or nx < 0 or nx >= w:
                        continue
                    if not valid[ny, nx] or label[ny, nx] != 0:
                        continue
                    if abs(disp[ny, nx] - dp) <= max_diff:
                        label[ny, nx] = current
                        stack[top] = ny * w + nx
                        top += 1
            if count < max_size:
                for i in range(count):
                    p = members[i]
                    out[p // w, p - (p // w) * w] = False
    return out


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
    if max_size < 0 or max_diff < 0:
        raise StereoInputError(f"max_size/max_diff: expected non-negative values, got {max_size}, {max_diff}")
    if max_size == 0:
        return valid.clone()
    d = disp.detach().to("cpu", torch.float32).numpy()
    v = valid.detach().to("cpu").numpy().astype(np.bool_)
    out = np.stack([_speckle_kernel(d[b, 0], v[b, 0], int(max_size), float(max_diff)) for b in range(d.shape[0])])
    return torch.from_numpy(out[:, None]).to(valid.device)
