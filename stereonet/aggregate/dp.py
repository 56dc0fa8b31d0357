"""Scanline dynamic programming: the three-case occlusion DP and the per-scanline energy DP (Viterbi).

Both optimise each scanline (image row) independently over a cost volume :math:`(B, D, H, W)`
(lower = better, disparity ``d`` matches left pixel ``x`` with right pixel ``x - d``).

* :func:`scanline_dp` — the textbook stereo DP (Cox et al. 1996; Szeliski, *Computer Vision*, §12.5):
  a monotone path through the (left x, right x) grid, each step being a **match** (cost = dissimilarity),
  a **left-occluded** pixel (visible in the left image only) or a **right-occluded** pixel, the latter two
  at a constant occlusion cost. Monotonicity of the path is the ordering constraint. Backtracking labels
  every left pixel as matched (with its disparity) or occluded.
* :func:`energy_dp` — minimises ``sum_x C(x, d_x) + λ·w_x·min(|d_x - d_{x+1}|, T)`` per scanline exactly
  (Viterbi), in O(W·D) per scanline thanks to the linear distance transform.

On CPU a numba kernel (parallel over scanlines) runs by default; the plain torch loops below are the
reference it is tested against (``backend="torch"``). Neither is differentiable (see
:mod:`stereonet.aggregate.soft` for the smooth-min versions).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch

from stereonet.aggregate.mrf import check_edge_weights, check_smoothness
from stereonet.checks import StereoInputError, check_cost_volume, check_finite
from stereonet.kernels import use_numba
from stereonet.select.fill import scanline_fill

_MATCH, _LEFT_OCCLUDED, _RIGHT_OCCLUDED = 0, 1, 2


class ScanlineDPResult(NamedTuple):
    """Output of :func:`scanline_dp`.

    disparity: :math:`(B, 1, H, W)` float (cost dtype); occluded pixels hold the disparity of the nearest
    matched pixel on their left (on their right at the left border), the textbook fill.
    occlusion: :math:`(B, 1, H, W)` bool, True = left-occluded (no match in the right image).
    energy: :math:`(B, H)` float64 optimal path cost per scanline.
    """

    disparity: torch.Tensor
    occlusion: torch.Tensor
    energy: torch.Tensor


class EnergyDPResult(NamedTuple):
    """Output of :func:`energy_dp`: ``disparity`` :math:`(B, 1, H, W)` float, ``energy`` :math:`(B, H)` float64."""

    disparity: torch.Tensor
    energy: torch.Tensor


def _resolve_backend(backend: str, cost: torch.Tensor) -> str:
    return "numba" if use_numba(cost, backend=backend, float32_only=False) else "torch"


def _rows(cost: torch.Tensor) -> torch.Tensor:
    """(B, D, H, W) -> scanline-major (B*H, D, W)."""
    b, d, h, w = cost.shape
    return cost.permute(0, 2, 1, 3).reshape(b * h, d, w)  # (BH)xDxW


def _check_cost(cost: torch.Tensor) -> torch.Tensor:
    cost = check_cost_volume(cost, "cost")
    check_finite(cost, "cost")  # (skipped for a volume the caller built from checked images: inputs_checked)
    return cost


def _volume_numpy(cost: torch.Tensor):
    """The (B, D, H, W) volume as a numpy view for the kernels (no copy for a CPU float32/64 tensor)."""
    c = cost.detach().cpu()
    return (c if c.dtype in (torch.float32, torch.float64) else c.double()).numpy()


def scanline_dp(cost: torch.Tensor, occlusion_cost: float, backend: str = "auto") -> ScanlineDPResult:
    """Three-case scanline DP with the ordering constraint and occlusion labelling.

    States ``(i, d)`` mean "``i`` left pixels and ``i - d`` right pixels consumed". Start at ``(0, 0)``;
    end at ``(W, d)`` for any ``d`` (right pixels past the last left pixel belong to left pixels outside
    the image, so they cost nothing). Left pixels ``x < d`` at the left border can only be left-occluded.
    Ties prefer match, then left-occluded, then right-occluded.

    Args:
        cost: :math:`(B, D, H, W)` finite costs, lower = better.
        occlusion_cost: constant cost of one occluded pixel (> 0; on the scale of a bad match).
        backend: ``"auto"`` (numba on CPU), ``"numba"`` or ``"torch"`` (the reference loops).
    Returns:
        :class:`ScanlineDPResult`.
    """
    cost = _check_cost(cost)
    if isinstance(occlusion_cost, bool) or not isinstance(occlusion_cost, int | float) \
            or not math.isfinite(occlusion_cost) or occlusion_cost <= 0:
        raise StereoInputError(f"occlusion_cost: expected a finite number > 0, got {occlusion_cost!r}")
    b, _, h, w = cost.shape
    if _resolve_backend(backend, cost) == "numba":
        from stereonet.kernels.dp import scanline_dp_three_case

        disp, occ, energy = scanline_dp_three_case(_volume_numpy(cost), float(occlusion_cost))
        disp, occ, energy = torch.from_numpy(disp), torch.from_numpy(occ), torch.from_numpy(energy)
    else:
        disp, occ, energy = _scanline_dp_reference(_rows(cost.detach()).double(), float(occlusion_cost))
    disparity = disp.view(b, h, 1, w).permute(0, 2, 1, 3).to(device=cost.device, dtype=cost.dtype)
    occlusion = occ.view(b, h, 1, w).permute(0, 2, 1, 3).to(cost.device)
    return ScanlineDPResult(disparity.contiguous(), occlusion.contiguous(), energy.view(b, h).to(cost.device))


def _scanline_dp_reference(rows: torch.Tensor, occlusion_cost: float, moves: list | None = None
                           ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Torch reference of the three-case DP, vectorised over scanlines. ``rows`` (R, D, W) float64.

    When ``moves`` is a list, the backtracked moves ``(x_left, d, move)`` of row 0 are appended (last first).
    """
    R, D, W = rows.shape
    inf = torch.tensor(math.inf, dtype=rows.dtype, device=rows.device)
    table = torch.full((W + 1, R, D), math.inf, dtype=rows.dtype, device=rows.device)
    back = torch.zeros((W + 1, R, D), dtype=torch.int8, device=rows.device)
    table[0, :, 0] = 0.0
    d_index = torch.arange(D, device=rows.device)
    for i in range(1, W + 1):
        prev = table[i - 1]  # RxD
        match = torch.where(d_index <= i - 1, prev + rows[:, :, i - 1], inf)
        left = torch.cat([inf.expand(R, 1), prev[:, :-1] + occlusion_cost], dim=1)
        take_left = left < match
        cur = torch.where(take_left, left, match)
        arg = torch.where(take_left, _LEFT_OCCLUDED, _MATCH).to(torch.int8)
        for d in range(min(i, D - 1) - 1, -1, -1):
            v = cur[:, d + 1] + occlusion_cost
            better = v < cur[:, d]
            cur[:, d] = torch.where(better, v, cur[:, d])
            arg[:, d] = torch.where(better, torch.tensor(_RIGHT_OCCLUDED, dtype=torch.int8), arg[:, d])
        table[i], back[i] = cur, arg
    energy, d_end = table[W].min(dim=1)
    disp = torch.zeros((R, W), dtype=torch.int32)
    occ = torch.zeros((R, W), dtype=torch.bool)
    back_np = back.cpu().numpy()
    for r in range(R):
        i, d = W, int(d_end[r])
        while i > 0:
            move = back_np[i, r, d]
            if moves is not None and r == 0:
                moves.append((i - 1 if move != _RIGHT_OCCLUDED else i, d, int(move)))
            if move == _MATCH:
                disp[r, i - 1] = d
                i -= 1
            elif move == _LEFT_OCCLUDED:
                occ[r, i - 1] = True
                i, d = i - 1, d - 1
            else:
                d += 1
    return scanline_fill(disp, ~occ, "left"), occ, energy.cpu()


class ScanlinePath(NamedTuple):
    """One scanline's disparity space image and optimal three-case DP path (for teaching plots).

    dsi: :math:`(D, W)` the costs ``cost[b, :, y, :]``.
    path: :math:`(N, 3)` long rows ``(x_left, d, move)`` in left-to-right order, one per DP move: ``move``
    0 = match of left ``x_left`` with right ``x_left - d``; 1 = left pixel ``x_left`` occluded; 2 = right pixel
    ``x_left - d`` occluded (``x_left`` = the next left pixel). ``d`` is the DP state's disparity after the move.
    energy: optimal path cost.
    """

    dsi: torch.Tensor
    path: torch.Tensor
    energy: float


def scanline_dp_path(cost: torch.Tensor, occlusion_cost: float, row: int, batch: int = 0) -> ScanlinePath:
    """The DSI of scanline ``row`` of item ``batch`` and the path :func:`scanline_dp` takes through it.

    Args:
        cost: :math:`(B, D, H, W)`.
        occlusion_cost: as for :func:`scanline_dp`.
        row, batch: which scanline.
    Returns:
        :class:`ScanlinePath` (plot ``dsi`` as an image with ``x`` across and ``d`` down, and the path on it).
    """
    cost = _check_cost(cost)
    b, _, h, _ = cost.shape
    if not (0 <= batch < b and 0 <= row < h):
        raise StereoInputError(f"row, batch: expected 0 <= row < {h} and 0 <= batch < {b}, got {row}, {batch}")
    if not occlusion_cost > 0 or not math.isfinite(occlusion_cost):
        raise StereoInputError(f"occlusion_cost: expected a finite number > 0, got {occlusion_cost!r}")
    dsi = cost[batch, :, row, :].detach()
    moves = []
    energy = _scanline_dp_reference(dsi[None].double(), float(occlusion_cost), moves)[2]
    return ScanlinePath(dsi, torch.tensor(moves[::-1], dtype=torch.long).view(-1, 3), float(energy[0]))


def energy_dp(cost: torch.Tensor, smoothness: float, truncation: float = math.inf,
              weights: torch.Tensor | None = None, backend: str = "auto") -> EnergyDPResult:
    """Exact per-scanline minimiser of ``sum_x C(x, d_x) + smoothness·w_x·min(|d_x - d_{x+1}|, truncation)``.

    Args:
        cost: :math:`(B, D, H, W)` finite costs.
        smoothness: ``λ >= 0``.
        truncation: ``T > 0`` (``inf`` = plain linear, ``1`` = Potts).
        weights: optional :math:`(B, 1, H, W)` non-negative weight of edge ``(x, x+1)`` stored at ``x``
            (e.g. from :func:`stereonet.aggregate.mrf.contrast_edge_weights`).
        backend: ``"auto"`` (numba on CPU), ``"numba"`` or ``"torch"`` (O(D²) reference).
    Returns:
        :class:`EnergyDPResult` (integer-valued disparity, energy per scanline).
    """
    cost = _check_cost(cost)
    if truncation == math.inf:
        smoothness = check_smoothness(smoothness, 1.0)[0]
    else:
        smoothness, truncation = check_smoothness(smoothness, truncation)
    weights = check_edge_weights(weights, cost, "weights")
    b, d, h, w = cost.shape
    wrows = (torch.ones(b * h, w, dtype=torch.float64) if weights is None
             else weights.detach().reshape(b * h, w).double().cpu())
    truncation = min(float(truncation), float(d))  # |d - d'| < D, so larger truncations change nothing
    if _resolve_backend(backend, cost) == "numba":
        from stereonet.kernels.dp import scanline_viterbi

        disp, energy = scanline_viterbi(_volume_numpy(cost), wrows.contiguous().numpy(), float(smoothness),
                                        truncation)
        disp, energy = torch.from_numpy(disp), torch.from_numpy(energy)
    else:
        rows = _rows(cost.detach()).double()
        disp, energy = _viterbi_reference(rows, wrows.to(rows.device), smoothness, truncation)
    disparity = disp.view(b, h, 1, w).permute(0, 2, 1, 3).to(device=cost.device, dtype=cost.dtype)
    return EnergyDPResult(disparity.contiguous(), energy.view(b, h).to(cost.device))


def _viterbi_reference(rows: torch.Tensor, weights: torch.Tensor, smoothness: float, truncation: float
                       ) -> tuple[torch.Tensor, torch.Tensor]:
    """O(D²) Viterbi reference, vectorised over scanlines. ``rows`` (R, D, W), ``weights`` (R, W)."""
    R, D, W = rows.shape
    labels = torch.arange(D, dtype=rows.dtype, device=rows.device)
    penalty = (labels[:, None] - labels[None, :]).abs().clamp(max=truncation)  # DxD, [d, d_prev]
    acc = rows[:, :, 0]
    back = torch.zeros((R, W, D), dtype=torch.long, device=rows.device)
    for x in range(1, W):
        s = (smoothness * weights[:, x - 1]).view(R, 1, 1)
        total = acc[:, None, :] + s * penalty  # RxDxD over (d, d_prev)
        best, back[:, x] = total.min(dim=2)
        acc = best + rows[:, :, x]
    energy, d = acc.min(dim=1)
    disp = torch.zeros((R, W), dtype=torch.long, device=rows.device)
    for x in range(W - 1, -1, -1):
        disp[:, x] = d
        d = back[:, x].gather(1, d[:, None])[:, 0]
    return disp.cpu(), energy.cpu()
