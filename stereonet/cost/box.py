"""Box filters in O(1) per pixel (separable integral images) and a min filter for shiftable windows.

Border rule (used by every windowed cost): a window that sticks out of the image is truncated to its
in-image part and :func:`box_mean` divides by the number of in-image pixels, so border pixels are averaged
over fewer samples instead of over invented (padded) values.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from stereonet.checks import check_shape, check_window


def _box_sum_1d(x: torch.Tensor, radius: int, dim: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Sum over ``[i - radius, i + radius] ∩ [0, n)`` along ``dim`` by one cumulative sum.

    Returns the sums (same shape as ``x``) and the per-index sample counts, shape ``(n,)``.
    """
    n = x.shape[dim]
    cs = torch.cumsum(x, dim=dim)
    zeros = torch.zeros_like(cs.narrow(dim, 0, 1)).expand_as(cs.narrow(dim, 0, 1))
    last = cs.narrow(dim, n - 1, 1)
    size = list(cs.shape)
    size[dim] = radius
    # S = [0] * (radius + 1) ++ cumsum ++ [total] * radius, so that sum(x[lo:hi]) = S[i + 2r + 1] - S[i]
    padded = torch.cat([zeros.expand(*size[:dim], radius + 1, *size[dim + 1:]), cs,
                        last.expand(*size)], dim=dim)
    out = padded.narrow(dim, 2 * radius + 1, n) - padded.narrow(dim, 0, n)
    i = torch.arange(n, device=x.device)
    count = (i + radius + 1).clamp(max=n) - (i - radius).clamp(min=0)
    return out, count.to(x.dtype)


def _box(x: torch.Tensor, window: int, normalize: bool) -> torch.Tensor:
    check_shape(x, ["B", "C", "H", "W"], "x")
    check_window(window)
    if window == 1:
        return x
    r = window // 2
    out, count_w = _box_sum_1d(x, r, dim=3)
    out, count_h = _box_sum_1d(out, r, dim=2)
    return out / (count_h[:, None] * count_w[None, :]) if normalize else out  # HxW counts


def box_sum(x: torch.Tensor, window: int) -> torch.Tensor:
    """Sum over a ``window x window`` square around each pixel (truncated at the image border).

    Args:
        x: :math:`(B, C, H, W)` floating tensor (C may be a disparity axis).
        window: odd window size.

    Returns:
        :math:`(B, C, H, W)`; O(1) operations per pixel whatever the window size.
    """
    return _box(x, window, normalize=False)


def box_mean(x: torch.Tensor, window: int) -> torch.Tensor:
    """Mean over the in-image part of a ``window x window`` square around each pixel.

    Args:
        x: :math:`(B, C, H, W)` floating tensor.
        window: odd window size.

    Returns:
        :math:`(B, C, H, W)`; O(1) per pixel (integral image along W then H).
    """
    return _box(x, window, normalize=True)


def min_filter(x: torch.Tensor, window: int) -> torch.Tensor:
    """Minimum over a ``window x window`` square around each pixel (border: in-image part only).

    Applied to a box-aggregated cost this gives the *shiftable window* cost: the best of all
    ``window x window`` windows that contain the pixel.

    Args:
        x: :math:`(B, C, H, W)`.
        window: odd window size.
    """
    check_shape(x, ["B", "C", "H", "W"], "x")
    check_window(window)
    if window == 1:
        return x
    r = window // 2
    # separable: max_pool of -x with -inf padding (max_pool2d pads with -inf itself)
    out = -F.max_pool2d(-x, kernel_size=(1, window), stride=1, padding=(0, r))
    out = -F.max_pool2d(-out, kernel_size=(window, 1), stride=1, padding=(r, 0))
    return out
