"""Classical confidence from a cost volume: the cost margin of the winner.

The peak-ratio family of confidence measures (Hu & Mordohai, PAMI 2012, "PKRN"): a pixel whose best cost
``c1`` is clearly below the best cost ``c2`` of every disparity that is not a neighbour of the winner is
trustworthy; a flat or double-minimum cost curve (textureless or repetitive surfaces, occlusions) is not::

    confidence(p) = clamp((c2(p) - c1(p)) / (|c2(p)| + eps), 0, 1),
    c1 = min_d C(p, d),  c2 = min_{|d - argmin| > exclude} C(p, d)

in [0, 1], higher = more trustworthy (the convention of :class:`~stereonet.types.StereoOutput`). Matchers
multiply it by their validity (a pixel that failed the left-right check gets 0), so the sparsification of
eval.py removes inconsistent pixels first and then the ones with the weakest margin.
"""

from __future__ import annotations

import numpy as np
import torch

from stereonet.checks import StereoInputError, check_cost_volume
from stereonet.kernels import use_numba

EPS = 1e-6  # keeps the ratio finite where c2 = 0 (then c1 = 0 too and the margin is 0)
CHUNK_ELEMENTS = 1 << 23  # rows per chunk so that a chunk's temporaries stay near 32 MiB of float32


@torch.no_grad()
def cost_margin_confidence(cost: torch.Tensor, exclude: int = 1, backend: str = "auto") -> torch.Tensor:
    """Cost-margin confidence (see the module doc) of a cost volume, lower cost = better.

    Args:
        cost: :math:`(B, D, H, W)`, D >= 2; non-finite entries count as +inf (never a best cost).
        exclude: disparities within ``exclude`` of the winner are not competitors (sub-pixel neighbours).
        backend: ``"auto"`` (the numba kernel for float32 CPU volumes, else torch), ``"torch"`` or ``"numba"``.

    Returns:
        confidence :math:`(B, 1, H, W)` in [0, 1], dtype and device of ``cost``. Rows are processed in
        chunks, so the extra memory stays bounded whatever the volume's size.
    """
    check_cost_volume(cost, "cost")
    if isinstance(exclude, bool) or not isinstance(exclude, int) or exclude < 0:
        raise StereoInputError(f"exclude: expected an integer >= 0, got {exclude!r}")
    b, d, h, w = cost.shape
    if d < 2:
        raise StereoInputError(f"cost: expected at least 2 disparities, got shape {tuple(cost.shape)}")
    if use_numba(cost, backend=backend):
        from stereonet.kernels.confidence import cost_margin_hwd

        hwd = cost.detach().to("cpu", torch.float32).permute(0, 2, 3, 1)  # BxHxWxD (a view for SGM's output)
        out = [torch.from_numpy(cost_margin_hwd(hwd[i].contiguous().numpy(), exclude, np.float32(EPS)))
               for i in range(b)]
        return torch.stack(out)[:, None].to(cost)
    out = cost.new_zeros((b, 1, h, w))
    rows = max(1, CHUNK_ELEMENTS // max(1, b * d * w))
    levels = torch.arange(d, device=cost.device).view(1, d, 1, 1)
    for y0 in range(0, h, rows):
        c = cost[:, :, y0:y0 + rows]
        c = torch.where(torch.isfinite(c), c, torch.full_like(c, float("inf")))  # BxDxhxW
        c1, i1 = c.min(dim=1, keepdim=True)
        near = (levels - i1).abs() <= exclude
        c2 = torch.where(near, torch.full_like(c, float("inf")), c).amin(dim=1, keepdim=True)
        margin = (c2 - c1) / (c2.abs() + EPS)
        margin = torch.where(torch.isinf(c2), torch.ones_like(margin), margin)  # no competitor at all
        margin = torch.where(torch.isfinite(c1), margin, torch.zeros_like(margin))  # no finite cost at all
        out[:, :, y0:y0 + rows] = margin.clamp(0.0, 1.0)
    return out
