"""Differentiable pieces: soft-argmin disparity regression and smooth-min (soft) DP / SGM aggregation.

The hard ``min`` of the scanline recurrences is replaced by the smooth minimum
``softmin_τ(x) = -τ · log Σ_i exp(-x_i / τ)`` (log-sum-exp, ``τ > 0``), which is differentiable everywhere,
lies within ``[min x - τ log n, min x]`` and tends to ``min`` as ``τ → 0`` (Mensch & Blondel, "Differentiable
dynamic programming for structured prediction and attention", ICML 2018). All functions are plain torch,
autograd-friendly (no in-place updates of tensors that need gradients), any dtype/device.
"""

from __future__ import annotations

import math

import torch

from stereonet.checks import StereoInputError, check_cost_volume

DIRECTIONS = ("left", "right", "up", "down")  # where each path comes *from*


def _check_temperature(temperature: float, name: str = "temperature") -> float:
    if isinstance(temperature, bool) or not isinstance(temperature, int | float) \
            or not math.isfinite(temperature) or temperature <= 0:
        raise StereoInputError(f"{name}: expected a finite number > 0, got {temperature!r}")
    return float(temperature)


def softmin(x: torch.Tensor, temperature: float, dim: int) -> torch.Tensor:
    """Smooth minimum ``-τ log Σ exp(-x/τ)`` along ``dim`` (dimension removed)."""
    return -temperature * torch.logsumexp(-x / temperature, dim=dim)


def soft_argmin(cost: torch.Tensor, temperature: float = 1.0) -> torch.Tensor:
    """Soft-argmin disparity regression (Kendall et al., GC-Net 2017): ``Σ_d d · softmax_d(-cost / τ)``.

    Args:
        cost: :math:`(B, D, H, W)` cost volume, lower = better (use :func:`soft_argmax` for similarities).
        temperature: ``τ > 0``; small ``τ`` approaches the hard argmin, large ``τ`` the mean disparity.
    Returns:
        :math:`(B, 1, H, W)` disparity in ``[0, D - 1]``, differentiable w.r.t. ``cost``.
    """
    cost = check_cost_volume(cost, "cost")
    temperature = _check_temperature(temperature)
    prob = torch.softmax(-cost / temperature, dim=1)  # BxDxHxW
    d = torch.arange(cost.shape[1], dtype=cost.dtype, device=cost.device).view(1, -1, 1, 1)
    return (prob * d).sum(dim=1, keepdim=True)


def soft_argmax(similarity: torch.Tensor, temperature: float = 1.0) -> torch.Tensor:
    """Soft-argmax of a similarity volume :math:`(B, D, H, W)` (higher = better) -> :math:`(B, 1, H, W)`."""
    similarity = check_cost_volume(similarity, "similarity")
    return soft_argmin(-similarity, temperature)


def sgm_penalty_matrix(num_disp: int, P1: float, P2: float, dtype: torch.dtype = torch.float64,
                       device: torch.device | str = "cpu") -> torch.Tensor:
    """SGM's transition penalty :math:`(D, D)`: 0 on the diagonal, ``P1`` for ``|d - d'| = 1``, ``P2`` beyond."""
    idx = torch.arange(num_disp, device=device)
    jump = (idx[:, None] - idx[None, :]).abs()
    return torch.where(jump == 0, 0.0, torch.where(jump == 1, float(P1), float(P2))).to(dtype)


def truncated_linear_penalty_matrix(num_disp: int, smoothness: float, truncation: float,
                                    dtype: torch.dtype = torch.float64, device: torch.device | str = "cpu"
                                    ) -> torch.Tensor:
    """``λ·min(|d - d'|, T)`` as a :math:`(D, D)` matrix (the pairwise term of the energy DP)."""
    idx = torch.arange(num_disp, device=device, dtype=dtype)
    return float(smoothness) * (idx[:, None] - idx[None, :]).abs().clamp(max=float(truncation))


def _oriented(cost: torch.Tensor, direction: str) -> torch.Tensor:
    """Rearrange (B, D, H, W) so the path runs along the last axis from index 0."""
    if direction in ("up", "down"):
        cost = cost.transpose(2, 3)  # BxDxWxH
    return cost.flip(3) if direction in ("right", "down") else cost


def _restored(oriented: torch.Tensor, direction: str) -> torch.Tensor:
    """Inverse of :func:`_oriented`."""
    if direction in ("right", "down"):
        oriented = oriented.flip(3)
    return oriented.transpose(2, 3) if direction in ("up", "down") else oriented


def soft_path_aggregate(cost: torch.Tensor, penalty: torch.Tensor, temperature: float,
                        direction: str = "left", normalize: bool = True) -> torch.Tensor:
    """Smooth-min scanline recursion along one direction (one SGM path, or the forward pass of a soft DP).

    ``L(p, d) = C(p, d) + softmin_d'(L(p - r, d') + P[d, d']) - [softmin_k L(p - r, k)]`` where ``r`` steps
    from ``direction`` (``"left"``: paths run left to right). The bracketed term (SGM's normalisation) is
    subtracted when ``normalize`` is True; without it ``L`` is the soft-Viterbi forward value function.

    Args:
        cost: :math:`(B, D, H, W)`.
        penalty: :math:`(D, D)` transition cost ``P[d, d']`` from ``d'`` (previous pixel) to ``d``.
        temperature: ``τ > 0``.
        direction: one of :data:`DIRECTIONS`.
    Returns:
        :math:`(B, D, H, W)` aggregated costs, differentiable w.r.t. ``cost`` (and ``penalty``).
    """
    cost = check_cost_volume(cost, "cost")
    temperature = _check_temperature(temperature)
    if direction not in DIRECTIONS:
        raise StereoInputError(f"direction: expected one of {DIRECTIONS}, got {direction!r}")
    n = cost.shape[1]
    if tuple(penalty.shape) != (n, n):
        raise StereoInputError(f"penalty: expected shape ({n}, {n}), got {tuple(penalty.shape)}")
    c = _oriented(cost, direction)
    pen = penalty.to(dtype=cost.dtype, device=cost.device).view(1, n, n, 1)  # 1xDxD'x1
    out = [c[..., 0]]  # each BxDxH'
    for x in range(1, c.shape[-1]):
        prev = out[-1]
        step = softmin(prev[:, None, :, :] + pen, temperature, dim=2)  # BxDxH' (min over d')
        if normalize:
            step = step - softmin(prev, temperature, dim=1)[:, None]
        out.append(c[..., x] + step)
    return _restored(torch.stack(out, dim=-1), direction)


def soft_sgm_aggregate(cost: torch.Tensor, P1: float, P2: float, temperature: float = 1.0,
                       directions: tuple[str, ...] = DIRECTIONS) -> torch.Tensor:
    """Soft semi-global aggregation: the sum of :func:`soft_path_aggregate` over ``directions``.

    As in Hirschmüller's SGM the aggregate is ``Σ_r L_r`` (each ``L_r`` includes ``C``).
    Differentiable; O(len(directions)·D²·H·W) time and memory.

    Args:
        cost: :math:`(B, D, H, W)`.
        P1, P2: SGM penalties, ``0 <= P1 <= P2``.
        temperature: ``τ > 0`` of the smooth minimum.
        directions: subset of :data:`DIRECTIONS` (4-path SGM by default).
    Returns:
        :math:`(B, D, H, W)`.
    """
    cost = check_cost_volume(cost, "cost")
    if not (0 <= P1 <= P2) or not math.isfinite(P2):
        raise StereoInputError(f"P1, P2: expected 0 <= P1 <= P2 < inf, got P1={P1!r}, P2={P2!r}")
    if not directions:
        raise StereoInputError("directions: expected at least one direction")
    penalty = sgm_penalty_matrix(cost.shape[1], P1, P2, cost.dtype, cost.device)
    return sum(soft_path_aggregate(cost, penalty, temperature, r) for r in directions)


def soft_dp_aggregate(cost: torch.Tensor, smoothness: float, truncation: float = math.inf,
                      temperature: float = 1.0) -> torch.Tensor:
    """Soft min-marginals of the per-scanline energy DP (smooth-min forward–backward along rows).

    ``M(x, d) = F(x, d) + G(x, d) - C(x, d)`` where ``F`` / ``G`` are the smooth-min Viterbi value functions
    from the left / right with pairwise ``λ·min(|d - d'|, T)``. As ``τ → 0``, ``min_d M(x, d)`` equals the
    optimal scanline energy of :func:`stereonet.aggregate.dp.energy_dp` at every ``x`` and ``argmin_d M`` its
    solution; for ``τ > 0`` ``soft_argmin(M, τ)`` is a differentiable scanline-DP disparity.

    Args:
        cost: :math:`(B, D, H, W)`.
        smoothness: ``λ >= 0``; truncation: ``T > 0``; temperature: ``τ > 0``.
    Returns:
        :math:`(B, D, H, W)` soft min-marginals.
    """
    cost = check_cost_volume(cost, "cost")
    if not math.isfinite(smoothness) or smoothness < 0 or not truncation > 0:
        raise StereoInputError(f"smoothness, truncation: expected λ >= 0 and T > 0, got {smoothness!r}, {truncation!r}")
    penalty = truncated_linear_penalty_matrix(cost.shape[1], smoothness, truncation, cost.dtype, cost.device)
    forward = soft_path_aggregate(cost, penalty, temperature, "left", normalize=False)
    backward = soft_path_aggregate(cost, penalty, temperature, "right", normalize=False)
    return forward + backward - cost
