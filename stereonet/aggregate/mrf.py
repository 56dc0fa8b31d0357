"""Shared pieces of the global (MRF) optimizers: smoothness weights, the pairwise term and the energy.

The energy every global optimizer here minimises over integer disparities ``f`` on the 4-connected grid:

.. math::  E(f) = \\sum_p C_p(f_p) + \\sum_{(p,q) \\in N_4} \\lambda\\, w_{pq}\\, \\min(|f_p - f_q|, T)

``C`` is the cost volume :math:`(B, D, H, W)`, ``λ`` the smoothness weight, ``T`` the truncation
(``T = 1`` is the Potts model) and ``w_pq`` optional per-edge weights (contrast-sensitive smoothness).
Edge weights are stored image-shaped: ``weights_right[..., y, x]`` belongs to the edge ``(y, x)-(y, x+1)``
(last column unused) and ``weights_down[..., y, x]`` to ``(y, x)-(y+1, x)`` (last row unused).
"""

from __future__ import annotations

import math

import torch

from stereonet.checks import StereoInputError, check_image, check_shape


def check_smoothness(smoothness: float, truncation: float) -> tuple[float, float]:
    """Check ``smoothness >= 0`` and ``truncation > 0`` (finite numbers); returns them as floats."""
    for name, v, lo_ok in (("smoothness", smoothness, True), ("truncation", truncation, False)):
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or v < 0 or (v == 0 and not lo_ok):
            bound = ">= 0" if lo_ok else "> 0"
            raise StereoInputError(f"{name}: expected a finite number {bound}, got {v!r}")
    return float(smoothness), float(truncation)


def check_edge_weights(weights: torch.Tensor | None, cost: torch.Tensor, name: str) -> torch.Tensor | None:
    """Check optional edge weights :math:`(B, 1, H, W)` against a cost volume :math:`(B, D, H, W)`."""
    if weights is None:
        return None
    b, _, h, w = cost.shape
    check_shape(weights, [str(b), "1", str(h), str(w)], name)
    if not weights.is_floating_point():
        raise TypeError(f"{name}: expected a floating-point tensor, got {weights.dtype}")
    if not bool(torch.isfinite(weights).all()) or bool((weights < 0).any()):
        raise StereoInputError(f"{name}: expected finite non-negative weights")
    return weights


def contrast_edge_weights(image: torch.Tensor, threshold: float = 0.03, factor: float = 2.0
                          ) -> tuple[torch.Tensor, torch.Tensor]:
    """Gradient-dependent smoothness weights (Scharstein & Szeliski's taxonomy, "p" and "g_T" of §4.3).

    An edge whose colour difference (max over channels) is below ``threshold`` gets weight ``factor``,
    other edges weight 1: smoothing is stronger inside uniform regions than across intensity edges.

    Args:
        image: reference (left) image :math:`(B, C, H, W)` in [0, 1].
    Returns:
        ``(weights_right, weights_down)`` each :math:`(B, 1, H, W)` (last column / last row set to 0).
    """
    image = check_image(image, "image")
    if factor < 0 or threshold < 0:
        raise StereoInputError(f"factor, threshold: expected >= 0, got {factor!r}, {threshold!r}")
    diff_x = (image[..., :, 1:] - image[..., :, :-1]).abs().amax(dim=1, keepdim=True)  # Bx1xHx(W-1)
    diff_y = (image[..., 1:, :] - image[..., :-1, :]).abs().amax(dim=1, keepdim=True)  # Bx1x(H-1)xW
    one = image.new_ones(())
    wx = torch.where(diff_x < threshold, one * factor, one)
    wy = torch.where(diff_y < threshold, one * factor, one)
    weights_right = torch.nn.functional.pad(wx, (0, 1, 0, 0))
    weights_down = torch.nn.functional.pad(wy, (0, 0, 0, 1))
    return weights_right, weights_down


def pairwise_penalty(da: torch.Tensor, db: torch.Tensor, truncation: float) -> torch.Tensor:
    """``min(|da - db|, truncation)`` elementwise (float)."""
    return (da - db).abs().to(torch.float64).clamp(max=truncation)


def grid_energy(cost: torch.Tensor, labels: torch.Tensor, smoothness: float, truncation: float,
                weights_right: torch.Tensor | None = None, weights_down: torch.Tensor | None = None
                ) -> torch.Tensor:
    """The 4-connected MRF energy of integer ``labels`` (see the module docstring), in float64.

    Args:
        cost: :math:`(B, D, H, W)` data costs.
        labels: :math:`(B, 1, H, W)` integer disparities in ``[0, D)``.
    Returns:
        :math:`(B,)` float64 energies.
    """
    idx = labels.long()
    data = cost.gather(1, idx).to(torch.float64).flatten(1).sum(1)
    wr = torch.ones_like(cost[:, :1], dtype=torch.float64) if weights_right is None else weights_right.double()
    wd = torch.ones_like(cost[:, :1], dtype=torch.float64) if weights_down is None else weights_down.double()
    horiz = pairwise_penalty(idx[..., :, 1:], idx[..., :, :-1], truncation) * wr[..., :, :-1]
    vert = pairwise_penalty(idx[..., 1:, :], idx[..., :-1, :], truncation) * wd[..., :-1, :]
    return data + smoothness * (horiz.flatten(1).sum(1) + vert.flatten(1).sum(1))


def truncated_linear_min_convolution(h: torch.Tensor, slope: torch.Tensor | float, truncation: float) -> torch.Tensor:
    """Felzenszwalb–Huttenlocher distance transform along dim 1: ``min_d' h(d') + s·min(|d - d'|, T)``.

    Exact in O(D) per pixel: ``min_{d'<=d}(h(d') + s(d - d')) = s·d + cummin_d(h(d) - s·d)`` and the mirror
    image for ``d' >= d``, then the truncation caps the result at ``min_d' h(d') + s·T``.

    Args:
        h: :math:`(B, D, H, W)`.
        slope: scalar or :math:`(B, 1, H, W)` non-negative per-pixel slope ``s``.
    Returns:
        :math:`(B, D, H, W)`.
    """
    d = torch.arange(h.shape[1], dtype=h.dtype, device=h.device).view(1, -1, 1, 1)  # 1xDx1x1
    ramp = d * slope
    forward = torch.cummin(h - ramp, dim=1).values + ramp
    backward = torch.flip(torch.cummin(torch.flip(h + ramp, [1]), dim=1).values, [1]) - ramp
    capped = h.amin(dim=1, keepdim=True) + slope * truncation
    return torch.minimum(torch.minimum(forward, backward), capped)


def left_occlusions_from_disparity(disp: torch.Tensor) -> torch.Tensor:
    """Left-occluded pixels implied by a left disparity map (the occlusion constraint along scanlines).

    Left pixel ``x`` lands at ``x - d(x)`` in the right image. When some pixel ``x' > x`` lands at or to the
    left of it (``x' - d(x') <= x - d(x)``, so ``d(x') > d(x)``: ``x'`` is in front), ``x`` is hidden in the
    right view. Pixels landing outside the right image (``x - d(x) < 0``) have no match either and are
    labelled too. Disparities are rounded first.

    Args:
        disp: :math:`(B, 1, H, W)`.
    Returns:
        :math:`(B, 1, H, W)` bool, True = left-occluded.
    """
    w = disp.shape[-1]
    right_x = torch.arange(w, device=disp.device, dtype=torch.float64) - disp.detach().round().double()
    # smallest landing position of the pixels strictly to the right of x
    suffix_min = torch.flip(torch.cummin(torch.flip(right_x, [-1]), dim=-1).values, [-1])
    after = torch.cat([suffix_min[..., 1:], torch.full_like(suffix_min[..., :1], math.inf)], dim=-1)
    return (right_x >= after) | (right_x < 0)
