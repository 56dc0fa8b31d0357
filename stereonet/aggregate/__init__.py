"""Cost aggregation, the second stage of the data path (cost/ -> aggregate/ -> select/): semi-global matching,
scanline dynamic programming, belief propagation, graph cuts (alpha-expansion), the differentiable soft
versions, and the MRF energy they share (:mod:`stereonet.aggregate.mrf`).

All functions take cost volumes ``(B, D, H, W)`` (lower = better); SGM and the soft pieces return aggregated
volumes for :mod:`stereonet.select`, DP / BP / graph cuts return disparities ``(B, 1, H, W)`` directly.
"""

from stereonet.aggregate.bp import belief_propagation
from stereonet.aggregate.dp import energy_dp, scanline_dp, scanline_dp_path
from stereonet.aggregate.dsi import dsi_scanline, plot_dsi
from stereonet.aggregate.graphcut import alpha_expansion
from stereonet.aggregate.sgm import sgm_aggregate, sgm_aggregate_torch
from stereonet.aggregate.soft import soft_argmax, soft_argmin, soft_dp_aggregate, soft_sgm_aggregate

__all__ = [
    "alpha_expansion", "belief_propagation", "dsi_scanline", "energy_dp", "plot_dsi", "scanline_dp",
    "scanline_dp_path", "sgm_aggregate", "sgm_aggregate_torch", "soft_argmax", "soft_argmin", "soft_dp_aggregate",
    "soft_sgm_aggregate",
]
