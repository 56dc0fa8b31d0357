"""Registered global matchers ``dp``, ``bp`` and ``graphcut`` (one signature: ``fn(left, right, max_disp)``).

Each builds a cost volume with :func:`stereonet.cost.build_cost_volume` (default AD-Census on a 3×3
window: robust to the radiometric differences of real photos, see :mod:`stereonet.cost.volume`), runs its
optimizer and returns a :class:`~stereonet.types.StereoOutput` with the data cost volume attached.
Defaults were tuned on the Middlebury pairs of ``../shared/data`` (see ``scripts/bench_global.py``), except
graphcut's move pruning, chosen on data_gen sets only (``docs/experiments/graphcut_pruning.txt``).

* ``dp``: the three-case scanline DP (:func:`stereonet.aggregate.dp.scanline_dp`); left-occluded pixels are
  ``valid = False``, filled from their left neighbour on the scanline, and labelled in
  ``extras["occlusion"]``. ``mode="energy"`` runs the per-scanline energy DP instead.
* ``bp``: coarse-to-fine min-sum loopy BP (:func:`stereonet.aggregate.bp.belief_propagation`) with
  contrast-weighted truncated-linear smoothness; ``extras["beliefs"]`` holds the final beliefs when asked for
  (``keep_beliefs=True``).
* ``graphcut``: α-expansion (:func:`stereonet.aggregate.graphcut.alpha_expansion`) from the WTA labels,
  same energy as ``bp``, each move pruned to the pixels whose SGM-ranked candidates hold its label (see
  :func:`graphcut_matcher`); ``extras["energy"]`` holds the final energy per batch item.

``bp``, ``graphcut`` and ``dp`` with ``mode="energy"`` do not model occlusions in their energy; the pixels their
own map declares hidden in the right view (a pixel further right lands on the same right pixel or beyond it,
:func:`~stereonet.aggregate.mrf.left_occlusions_from_disparity`) are returned ``valid = False``,
labelled in ``extras["occlusion"]`` and filled from their left neighbour like ``dp``'s.

Sub-pixel disparities come from a parabola fit on the data cost (``dp``, ``graphcut``) or on the beliefs
(``bp``) around the integer optimum (``subpixel=False`` keeps integers).
"""

from __future__ import annotations

import torch

from stereonet.aggregate.bp import belief_propagation
from stereonet.aggregate.dp import energy_dp, scanline_dp
from stereonet.aggregate.graphcut import alpha_expansion
from stereonet.aggregate.mrf import contrast_edge_weights, left_occlusions_from_disparity
from stereonet.checks import StereoInputError, check_stereo_inputs, inputs_checked
from stereonet.matchers import register
from stereonet.select.fill import scanline_fill
from stereonet.types import StereoOutput

DEFAULT_COST = "census_ad"
DEFAULT_WINDOW = 3


def _cost_volume(left: torch.Tensor, right: torch.Tensor, max_disp: int, cost: str, window: int,
                 cost_options: dict | None, layout: str = "hwd") -> torch.Tensor:
    from stereonet.cost import build_cost_volume

    options = dict(cost_options or {})
    options.setdefault("layout", layout)
    return build_cost_volume(left, right, max_disp, cost=cost, window=window, **options)


def _refine(volume: torch.Tensor, disp: torch.Tensor, subpixel: bool) -> torch.Tensor:
    if not subpixel:
        return disp
    from stereonet.select.subpixel import subpixel_refine

    return subpixel_refine(volume, disp)


def _occlusion_filled(labels: torch.Tensor, refined: torch.Tensor
                      ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Integer labels and their refined map -> (disparity, valid, occlusion): pixels the labels themselves declare
    left-occluded (:func:`~stereonet.aggregate.mrf.left_occlusions_from_disparity`) are invalid and take the
    disparity of their nearest visible left neighbour (the textbook scanline fill); the rest keep ``refined``."""
    occlusion = left_occlusions_from_disparity(labels)
    disp = scanline_fill(refined, ~occlusion, "left")
    return disp, ~occlusion, occlusion


@register("dp", kind="classical",
          description="Scanline DP (Cox et al.): match / left-occluded / right-occluded moves with the ordering "
                      "constraint on an AD-Census cost; occlusions labelled and filled")
def dp_matcher(left: torch.Tensor, right: torch.Tensor, max_disp: int, cost: str = DEFAULT_COST,
               window: int = 5, occlusion_cost: float = 0.6, mode: str = "occlusion",
               smoothness: float = 0.3, truncation: float = 2.0, subpixel: bool = True,
               cost_options: dict | None = None) -> StereoOutput:
    """Scanline dynamic programming. ``left``/``right`` :math:`(B, C, H, W)` -> :class:`StereoOutput`.

    Args:
        cost, window, cost_options: the cost volume (see :func:`stereonet.cost.build_cost_volume`).
        occlusion_cost: cost of one occluded pixel in ``mode="occlusion"`` (on the scale of the cost).
        mode: ``"occlusion"`` (three-case DP) or ``"energy"`` (Viterbi with ``smoothness``·min(|Δd|, ``truncation``)).
        subpixel: parabola refinement on the data cost.
    """
    if mode not in ("occlusion", "energy"):
        raise StereoInputError(f"mode: expected 'occlusion' or 'energy', got {mode!r}")
    left, right, max_disp = check_stereo_inputs(left, right, max_disp)
    volume = _cost_volume(left, right, max_disp, cost, window, cost_options)
    with inputs_checked(volume):
        return _dp(left, volume, mode, occlusion_cost, smoothness, truncation, subpixel)


def _dp(left, volume, mode, occlusion_cost, smoothness, truncation, subpixel) -> StereoOutput:
    extras: dict[str, torch.Tensor] = {}
    if mode == "occlusion":
        res = scanline_dp(volume, occlusion_cost)
        valid = ~res.occlusion
        disp = torch.where(valid, _refine(volume, res.disparity, subpixel), res.disparity)
        extras["occlusion"] = res.occlusion
        extras["energy"] = res.energy
    else:  # "energy"
        weights, _ = contrast_edge_weights(left)
        res = energy_dp(volume, smoothness, truncation, weights=weights)
        disp, valid, extras["occlusion"] = _occlusion_filled(res.disparity, _refine(volume, res.disparity, subpixel))
        extras["energy"] = res.energy
    return StereoOutput(disp, valid, cost_volume=volume, extras=extras)


def _mrf_problem(left: torch.Tensor, right: torch.Tensor, max_disp: int, cost: str, window: int,
                 cost_options: dict | None, contrast_threshold: float, contrast_factor: float, layout: str = "hwd"
                 ) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor | None]:
    """Checked inputs -> (cost volume, weights_right, weights_down) of the MRF shared by ``bp`` and ``graphcut``
    (``layout``: the volume's memory order, see :data:`stereonet.cost.volume.LAYOUTS`)."""
    left, right, max_disp = check_stereo_inputs(left, right, max_disp)
    volume = _cost_volume(left, right, max_disp, cost, window, cost_options, layout)
    if contrast_factor == 1.0:
        return volume, None, None
    return (volume, *contrast_edge_weights(left, contrast_threshold, contrast_factor))


@register("bp", kind="classical",
          description="Coarse-to-fine min-sum loopy belief propagation (Felzenszwalb-Huttenlocher), 4-connected, "
                      "contrast-weighted truncated-linear smoothness on an AD-Census cost")
def bp_matcher(left: torch.Tensor, right: torch.Tensor, max_disp: int, cost: str = DEFAULT_COST,
               window: int = DEFAULT_WINDOW, smoothness: float = 0.3, truncation: float = 4.0,
               iterations: int = 5, levels: int = 5, contrast_threshold: float = 0.03,
               contrast_factor: float = 3.0, subpixel: bool = True, cost_options: dict | None = None,
               precision: str = "int16", keep_beliefs: bool = False) -> StereoOutput:
    """Loopy BP. ``left``/``right`` :math:`(B, C, H, W)` -> :class:`StereoOutput`.

    The smoothness weight is multiplied by ``contrast_factor`` across edges whose colour difference is below
    ``contrast_threshold`` (see :func:`stereonet.aggregate.mrf.contrast_edge_weights`). ``precision="int16"``
    (default) runs the finest pyramid levels in 16-bit fixed point on the CPU (costs on a 1/1024 grid: half the
    message memory, and in ``make bench`` about 1.5x faster; every real pair's bad-2 within 0.1 of ``"float"``,
    see :func:`stereonet.aggregate.bp.belief_propagation`); ``"float"`` keeps the cost's dtype throughout.
    ``keep_beliefs``: also return the final belief volume as ``extras["beliefs"]`` (off by default: the sub-pixel
    fit needs only three beliefs per pixel, and without the volume a KITTI pair touches ~30 % less memory; the
    same disparities either way).
    """
    # the volume in image rows of D runs of W costs: the memory order bp's kernels read (no transposing pass)
    volume, wr, wd = _mrf_problem(left, right, max_disp, cost, window, cost_options, contrast_threshold,
                                  contrast_factor, layout="hdw")
    with inputs_checked(volume):  # built here from checked images: no second pass over it
        res = belief_propagation(volume, smoothness, truncation, iterations, levels, wr, wd, precision=precision,
                                 keep_beliefs=keep_beliefs)
    refined = res.disparity
    if subpixel:  # the parabola through the beliefs at d - 1, d, d + 1 (subpixel_refine on the belief volume)
        from stereonet.select.subpixel import refine_from_neighbours

        refined = refine_from_neighbours(res.disparity.long(), *res.near.split(1, dim=1), volume.shape[1])
    disp, valid, occlusion = _occlusion_filled(res.disparity, refined)
    extras = {"energy": res.energy, "occlusion": occlusion}
    if keep_beliefs:
        extras["beliefs"] = res.beliefs
    return StereoOutput(disp, valid, cost_volume=volume, extras=extras)


def candidate_labels(volume: torch.Tensor, k: int, smoothness: float, truncation: float,
                     weights_right: torch.Tensor | None, weights_down: torch.Tensor | None,
                     census: int = 0, left: torch.Tensor | None = None,
                     right: torch.Tensor | None = None) -> torch.Tensor:
    """The ``k`` best labels per pixel (B, k, H, W) of an 8-path SGM aggregation of the MRF's own energy, the
    candidates of ``graphcut``'s pruned moves: ``P1`` = ``λ·w̄`` for a change of one label and ``P2`` =
    ``λ·w̄·T`` for larger ones, ``w̄`` the mean contrast weight of the edges (SGM's path minimisation
    approximates the energy's min-marginals, so its best labels are the ones the expansion moves keep: on Cones
    its 4 best hold the label of ~98 % of the pixels of the unpruned result, the data cost's 4 best ~90 %).
    ``census > 0`` adds that many best labels of ``sgm``'s own aggregation (census 7x7, its penalties; needs
    ``left``/``right``): proposals from a stronger cost where the MRF's own (a 3x3 AD-census) is weak, as on
    low-texture surfaces (fusion of another method's proposals, as in Lempitsky et al.'s fusion moves)."""
    from stereonet.aggregate.sgm import sgm_aggregate

    mean_weight = 1.0
    if weights_right is not None:
        across, down = weights_right[..., :, :-1], weights_down[..., :-1, :]
        if across.numel() and down.numel():
            mean_weight = 0.5 * float(across.mean() + down.mean())
        elif across.numel() or down.numel():  # a one-pixel-tall (or -wide) image has edges one way only
            mean_weight = float((across if across.numel() else down).mean())
    P1 = smoothness * mean_weight
    n = volume.shape[1]
    aggregated = sgm_aggregate(volume, P1, P1 * min(truncation, float(n)), paths=8)
    labels = aggregated.topk(min(k, n), dim=1, largest=False).indices
    if census > 0:
        from stereonet.matchers.local import sgm

        out = sgm(left, right, n - 1, keep_volume="fixed")  # int16 on the CPU path: the same ranking, no float copy
        proposals = out.extras.get("aggregate_fixed", out.cost_volume)
        labels = torch.cat([labels, proposals.topk(min(census, n), dim=1, largest=False).indices], dim=1)
    return labels


@register("graphcut", kind="classical",
          description="Graph cuts: alpha-expansion (Boykov-Veksler-Zabih) with PyMaxflow, contrast-weighted "
                      "truncated-linear smoothness on an AD-Census cost, started from WTA, moves pruned to SGM's "
                      "best labels")
def graphcut_matcher(left: torch.Tensor, right: torch.Tensor, max_disp: int, cost: str = DEFAULT_COST,
                     window: int = DEFAULT_WINDOW, smoothness: float = 0.3, truncation: float = 2.0,
                     cycles: int = 1, contrast_threshold: float = 0.03, contrast_factor: float = 3.0,
                     subpixel: bool = True, cost_options: dict | None = None, candidates: int | None = 1,
                     candidate_radius: int = 2, census_candidates: int = 1) -> StereoOutput:
    """α-expansion. ``left``/``right`` :math:`(B, C, H, W)` -> :class:`StereoOutput`.

    ``cycles`` passes over the ``max_disp + 1`` labels. Label pruning (default): the move for ``α`` frees only
    the pixels within ``candidate_radius`` of a pixel that lists ``α`` among its candidates, and each move is one
    max-flow on those pixels' graph: the ``candidates`` best labels of an 8-path SGM aggregation of the same energy
    (:func:`candidate_labels`) and the ``census_candidates`` best of ``sgm``'s census aggregation (proposals from
    a stronger cost where the MRF's 3x3 AD-census is weak). Chosen on fresh data_gen sets only
    (``docs/experiments/graphcut_pruning.txt``): with 2 + 2 candidates it was 7-10x faster than the unpruned
    moves and lower in bad-2 (val2q 41.9 -> 29.6, val4q 81.2 -> 65.8); 1 + 1 within 2 px (the default) was as
    accurate as 2 + 2 on two more fresh sets and faster; with the energy's own candidates alone it lost 2-3 points
    on low-texture renders. ``candidates=None``: every move is a max-flow on the whole
    ``H·W``-node grid (the textbook method, before the twenty-eighth session the default).
    """
    volume, wr, wd = _mrf_problem(left, right, max_disp, cost, window, cost_options, contrast_threshold,
                                  contrast_factor)
    labels = None
    from stereonet.aggregate.mrf import check_smoothness

    smoothness, truncation = check_smoothness(smoothness, truncation)  # before the candidates use them
    if candidates is not None:
        if isinstance(candidates, bool) or not isinstance(candidates, int) or candidates < 1:
            raise StereoInputError(f"candidates: expected an integer >= 1 or None, got {candidates!r}")
        if isinstance(census_candidates, bool) or not isinstance(census_candidates, int) or census_candidates < 0:
            raise StereoInputError(f"census_candidates: expected an integer >= 0, got {census_candidates!r}")
        labels = candidate_labels(volume, candidates, smoothness, truncation, wr, wd, census_candidates, left, right)
    with inputs_checked(volume):  # built here from checked images: no second pass over it
        res = alpha_expansion(volume, smoothness, truncation, cycles, None, wr, wd, labels, candidate_radius)
    disp, valid, occlusion = _occlusion_filled(res.disparity, _refine(volume, res.disparity, subpixel))
    return StereoOutput(disp, valid, cost_volume=volume, extras={"energy": res.energy, "occlusion": occlusion})
