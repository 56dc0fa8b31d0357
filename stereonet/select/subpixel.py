"""Sub-pixel refinement of an integer disparity from its cost neighbours (parabola or equiangular fit)."""

from __future__ import annotations

import torch

from stereonet.checks import StereoInputError, check_cost_volume, check_shape


def subpixel_refine(cost: torch.Tensor, disp: torch.Tensor, method: str = "parabola") -> torch.Tensor:
    """Refine an integer disparity with the costs ``c-, c0, c+`` at ``d - 1, d, d + 1``.

    - ``"parabola"``: vertex of the parabola through the three costs,
      ``offset = (c- - c+) / (2 (c- - 2 c0 + c+))``.
    - ``"equiangular"`` (Shimizu & Okutomi): vertex of the symmetric V through them,
      ``offset = (c- - c+) / (2 max(c- - c0, c+ - c0))``.

    The offset is clamped to [-0.5, 0.5]; it is 0 at ``d = 0``, ``d = D - 1`` and where the fit is
    degenerate (flat or non-convex neighbourhood).

    Args:
        cost: :math:`(B, D, H, W)`.
        disp: :math:`(B, 1, H, W)` integer-valued disparity.
        method: ``"parabola"`` or ``"equiangular"``.

    Returns:
        :math:`(B, 1, H, W)` refined disparity (dtype of ``cost``).
    """
    check_cost_volume(cost)
    b, n, h, w = cost.shape
    check_shape(disp, [str(b), "1", str(h), str(w)], "disp")
    if method not in ("parabola", "equiangular"):
        raise StereoInputError(f"method: expected 'parabola' or 'equiangular', got {method!r}")
    d = disp.round().long().clamp(0, n - 1)
    return refine_from_neighbours(d, *neighbour_costs(cost, d), n, method)


def neighbour_costs(cost: torch.Tensor, d: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The costs :math:`(B, 1, H, W)` at ``d - 1``, ``d``, ``d + 1`` of a volume :math:`(B, D, H, W)` for long labels
    ``d`` in ``0 .. D - 1``; a neighbour outside the range takes the label's own cost."""
    n = cost.shape[1]
    return cost.gather(1, (d - 1).clamp(min=0)), cost.gather(1, d), cost.gather(1, (d + 1).clamp(max=n - 1))


def refine_from_neighbours(d: torch.Tensor, cm: torch.Tensor, c0: torch.Tensor, cp: torch.Tensor, n: int,
                           method: str = "parabola") -> torch.Tensor:
    """:func:`subpixel_refine` from the three costs it reads: integer labels ``d`` (long, in ``0 .. n - 1``) and
    the costs ``cm, c0, cp`` at ``d - 1, d, d + 1`` (any values where a neighbour lies outside the range), all of
    one shape, for a matcher that keeps those values rather than the volume. The same numbers as
    :func:`subpixel_refine` on the volume they came from."""
    inner = (d > 0) & (d < n - 1)
    if method == "parabola":
        denom = 2.0 * (cm - 2.0 * c0 + cp)
    else:
        denom = 2.0 * torch.maximum(cm - c0, cp - c0)
    ok = inner & (denom > 0)
    offset = torch.where(ok, (cm - cp) / torch.where(ok, denom, torch.ones_like(denom)), torch.zeros_like(c0))
    return d.to(c0.dtype) + offset.clamp(-0.5, 0.5)
