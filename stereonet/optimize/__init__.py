"""Disparity optimisation: local selection (WTA, sub-pixel, uniqueness, LR check, filling, filters), scanline
dynamic programming, semi-global matching, belief propagation, graph cuts, and differentiable soft pieces.

All functions take cost volumes ``(B, D, H, W)`` (lower = better) and return disparities ``(B, 1, H, W)``.
"""

from stereonet.optimize.bp import belief_propagation
from stereonet.optimize.dp import energy_dp, scanline_dp, scanline_dp_path
from stereonet.optimize.dsi import dsi_scanline, plot_dsi
from stereonet.optimize.fill import fill_occlusions
from stereonet.optimize.filters import median_filter, speckle_filter
from stereonet.optimize.graphcut import alpha_expansion
from stereonet.optimize.lr_check import left_right_check, right_cost_volume, wta_right
from stereonet.optimize.sgm import sgm_aggregate, sgm_aggregate_torch
from stereonet.optimize.soft import soft_argmax, soft_argmin, soft_dp_aggregate, soft_sgm_aggregate
from stereonet.optimize.subpixel import subpixel_refine
from stereonet.optimize.wta import select_disparity, uniqueness_mask, wta

__all__ = [
    "alpha_expansion", "belief_propagation", "dsi_scanline", "energy_dp", "fill_occlusions", "left_right_check",
    "median_filter", "plot_dsi", "right_cost_volume", "scanline_dp", "scanline_dp_path", "select_disparity",
    "sgm_aggregate", "sgm_aggregate_torch", "soft_argmax", "soft_argmin", "soft_dp_aggregate",
    "soft_sgm_aggregate", "speckle_filter", "subpixel_refine", "uniqueness_mask", "wta", "wta_right",
]
