"""Numba kernel of :func:`stereonet.select.confidence.cost_margin_confidence` (same maths, float32).

Input layout ``(H, W, D)`` (the layout the SGM kernel aggregates in, so the inner loop over disparities
is contiguous); rows in parallel. No fastmath: the kernel compares against +inf and must see NaN as
"not a cost", which fastmath's no-NaN/no-inf assumptions would allow the compiler to drop.
"""

from __future__ import annotations

import numba
import numpy as np
from numba import prange


@numba.njit(inline="always", fastmath=False)
def clipped_margin(c1, c2, eps):
    """The cost-margin confidence of a finite best ``c1`` and competitor ``c2``:
    ``clip((c2 - c1) / (|c2| + eps), 0, 1)`` (float32; the one formula every kernel here uses)."""
    m = (c2 - c1) / (abs(c2) + eps)
    return min(max(m, np.float32(0.0)), np.float32(1.0))


@numba.njit(parallel=True, cache=True, fastmath=False)
def cost_margin_hwd(cost, exclude, eps):
    """cost (H, W, D) float32 -> confidence (H, W) float32 in [0, 1] (see the torch version)."""
    h, w, n = cost.shape
    out = np.zeros((h, w), dtype=np.float32)
    inf = np.float32(np.inf)
    for y in prange(h):
        for x in range(w):
            c = cost[y, x]
            c1 = inf
            i1 = -1
            for d in range(n):
                v = c[d]
                if v < c1:  # NaN and +inf never win
                    c1 = v
                    i1 = d
            if i1 < 0:
                continue  # no finite cost: confidence 0
            c2 = inf
            for d in range(n):
                if abs(d - i1) > exclude:
                    v = c[d]
                    if v < c2:
                        c2 = v
            if c2 == inf:
                out[y, x] = 1.0
                continue
            out[y, x] = clipped_margin(c1, c2, eps)
    return out
