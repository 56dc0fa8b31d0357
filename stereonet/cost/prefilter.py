"""Image pre-filters applied before a matching cost is computed (not to the images the rest of a matcher reads).

A census cost compares each pixel with its neighbours, so sensor noise of the size of the local contrast flips its
bits, and a right view a fraction of a pixel off the scanline (residual rectification error) changes its patterns.
A small binomial smoothing before the transform averages both away at the price of some fine detail:

- ``"vertical"``: ``[1, 2, 1] / 4`` along the columns only: noise is averaged and a sub-pixel vertical offset matters
  less, while the horizontal detail that fixes the disparity is kept.
- ``"binomial"``: the same kernel along both axes (3x3).

Borders are replicated. Each channel is filtered alone, so grey and colour images behave the same.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from stereonet.checks import StereoInputError

PREFILTERS = ("vertical", "binomial")


def prefilter_image(image: torch.Tensor, kind: str | None) -> torch.Tensor:
    """``image`` (B, C, H, W) filtered by ``kind`` (:data:`PREFILTERS`; None returns it unchanged)."""
    if kind is None:
        return image
    if kind not in PREFILTERS:
        raise StereoInputError(f"prefilter: expected None or one of {', '.join(map(repr, PREFILTERS))}, got {kind!r}")
    c = image.shape[1]
    k = torch.tensor([0.25, 0.5, 0.25], dtype=image.dtype, device=image.device)
    out = F.conv2d(F.pad(image, (0, 0, 1, 1), mode="replicate"), k.view(1, 1, 3, 1).expand(c, 1, 3, 1), groups=c)
    if kind == "binomial":
        out = F.conv2d(F.pad(out, (1, 1, 0, 0), mode="replicate"), k.view(1, 1, 1, 3).expand(c, 1, 1, 3), groups=c)
    return out
