"""Matching costs and cost-volume builders: SAD, SSD, ZSAD, LS-SAD, NCC, census, AD-census, correlation.

Cost volumes are ``(B, D, H, W)`` with ``D = max_disp + 1`` and lower = better; similarity volumes say
``similarity`` in their name. See :mod:`stereonet.cost.volume` for the exact definitions.
"""

from stereonet.cost.box import box_mean, box_sum, min_filter
from stereonet.cost.census import census_signs, census_transform, hamming, popcount, to_grey
from stereonet.cost.volume import (
    COSTS,
    DEFAULT_MEMORY_BUDGET,
    ad_cost_volume,
    adaptive_cost_volume,
    build_cost_volume,
    census_ad_cost_volume,
    census_cost_volume,
    correlation_similarity,
    lssad_cost_volume,
    ncc_cost_volume,
    sad_cost_volume,
    shifted_stack,
    ssd_cost_volume,
    sweep_cost_volume,
    zsad_cost_volume,
)

__all__ = [
    "COSTS", "DEFAULT_MEMORY_BUDGET", "ad_cost_volume", "adaptive_cost_volume", "box_mean", "box_sum",
    "build_cost_volume", "census_ad_cost_volume", "census_cost_volume", "census_signs", "census_transform",
    "correlation_similarity", "hamming", "lssad_cost_volume", "min_filter", "ncc_cost_volume", "popcount",
    "sad_cost_volume", "shifted_stack", "ssd_cost_volume", "sweep_cost_volume", "to_grey", "zsad_cost_volume",
]
