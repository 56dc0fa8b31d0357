"""Census transform and Hamming distance on bit-packed codes (Zabih & Woodfill 1994).

The census code of a pixel has one bit per neighbour of its ``window x window`` square (centre excluded):
bit = 1 where the neighbour is darker than the centre (``I(q) < I(p)``). Neighbours outside the image are
replicated from the border. Codes are packed 62 bits per int64 word (the sign bit stays 0, so arithmetic
shifts are safe), and the Hamming distance is a branch-free SWAR popcount of ``code_l XOR code_r``.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from stereonet.checks import StereoInputError, check_image, check_window

BITS_PER_WORD = 62

_M1 = 0x5555555555555555 & 0x7FFFFFFFFFFFFFFF
_M2 = 0x3333333333333333
_M4 = 0x0F0F0F0F0F0F0F0F


def to_grey(img: torch.Tensor) -> torch.Tensor:
    """(B, C, H, W) -> (B, 1, H, W): ITU-R BT.601 luma for C = 3, identity for C = 1.

    Written as elementwise sums in a fixed order (the same bits as a channel reduction in torch, and as
    :func:`grey_numpy`), so that an exported graph (onnxruntime) computes the same bits too: census comparisons of a
    photo's many equal grey values would flip on a rounding difference of a reduction's order."""
    if img.shape[1] == 1:
        return img
    return (img[:, 0:1] * 0.299 + img[:, 1:2] * 0.587) + img[:, 2:3] * 0.114


def grey_numpy(img: torch.Tensor) -> np.ndarray:
    """:func:`to_grey` of one image ``(C, H, W)`` as a float32 ``(H, W)`` numpy array, computed by
    :func:`stereonet.kernels.cost.grey_planar` with the same float32 operations (bit-identical to the torch result;
    no torch threading, no numpy temporaries)."""
    from stereonet.kernels.cost import grey_planar

    a = img.detach().to("cpu", torch.float32).numpy()
    if a.shape[0] == 1:
        return np.ascontiguousarray(a[0])
    return grey_planar(a)


def _check_census_args(img: torch.Tensor, window: int) -> None:
    check_image(img, "img")
    check_window(window, "census_window")
    if window < 3:
        raise StereoInputError(f"census_window: expected an odd integer >= 3, got {window}")


def census_transform(img: torch.Tensor, window: int = 5) -> torch.Tensor:
    """Bit-packed census codes.

    Args:
        img: :math:`(B, C, H, W)` image (colour is converted to grey first).
        window: odd census window size (>= 3); ``window**2 - 1`` bits per pixel.

    Returns:
        :math:`(B, K, H, W)` int64 with ``K = ceil((window**2 - 1) / 62)`` words per pixel.
    """
    _check_census_args(img, window)
    grey = to_grey(img)
    r = window // 2
    padded = F.pad(grey, (r, r, r, r), mode="replicate")
    h, w = grey.shape[-2:]
    offsets = [(dy, dx) for dy in range(window) for dx in range(window) if (dy, dx) != (r, r)]
    n_words = (len(offsets) + BITS_PER_WORD - 1) // BITS_PER_WORD
    words = []
    for k in range(n_words):
        word = torch.zeros(grey.shape, dtype=torch.int64, device=img.device)
        for bit, (dy, dx) in enumerate(offsets[k * BITS_PER_WORD:(k + 1) * BITS_PER_WORD]):
            darker = padded[:, :, dy:dy + h, dx:dx + w] < grey
            word |= darker.to(torch.int64) << bit
        words.append(word)
    return torch.cat(words, dim=1)  # BxKxHxW


def census_signs(img: torch.Tensor, window: int = 5, pad: bool = True) -> torch.Tensor:
    """The census comparisons as a unit-length float feature vector per pixel, for networks that match with
    correlations (:func:`stereonet.cost.correlation.correlation_1d` and the warped correlations of the models).

    Channel k is ``+1 / sqrt(n)`` where neighbour k is darker than the centre (the bit of
    :func:`census_transform`), ``-1 / sqrt(n)`` otherwise, ``n = window**2 - 1``; so the dot product of two
    pixels' vectors is ``1 - 2 h / n`` for their Hamming distance ``h``. No parameters: the features do not
    change under any monotonic change of intensity, whatever images a network was trained on.

    Args:
        img: :math:`(B, C, H, W)` image (colour is converted to grey first).
        window: odd census window size (>= 3).
        pad: replicate-pad the image by ``window // 2`` so every pixel gets its comparisons (default); False: only
            the pixels whose whole window lies inside the image, ``window // 2`` fewer per side (the same values there).

    Returns:
        :math:`(B, n, H, W)` float, the image's dtype (``H - 2r, W - 2r`` without ``pad``).
    """
    _check_census_args(img, window)
    grey = to_grey(img)
    r = window // 2
    if pad:
        grey = F.pad(grey, (r, r, r, r), mode="replicate")
    b, _, hp, wp = grey.shape
    h, w = hp - 2 * r, wp - 2 * r
    patches = F.unfold(grey, window).view(b, window * window, h, w)
    centre = (window * window) // 2
    neighbours = torch.cat([patches[:, :centre], patches[:, centre + 1:]], dim=1)
    n = window * window - 1
    unit = 1.0 / float(np.sqrt(n))
    return torch.where(neighbours < patches[:, centre:centre + 1], unit, -unit).to(grey.dtype)


def popcount(x: torch.Tensor) -> torch.Tensor:
    """Number of set bits of non-negative int64 values (SWAR, no loops over bits)."""
    x = x - ((x >> 1) & _M1)
    x = (x & _M2) + ((x >> 2) & _M2)
    x = (x + (x >> 4)) & _M4
    x = x + (x >> 8)
    x = x + (x >> 16)
    x = x + (x >> 32)
    return x & 0x7F


def hamming(code_a: torch.Tensor, code_b: torch.Tensor) -> torch.Tensor:
    """Hamming distance of packed codes :math:`(B, K, H, W)` -> :math:`(B, 1, H, W)` int64."""
    return popcount(code_a ^ code_b).sum(1, keepdim=True)
