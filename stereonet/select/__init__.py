"""Selection, the third stage of the data path (cost/ -> aggregate/ -> select/): winner-takes-all, sub-pixel
refinement, uniqueness, the left-right check, occlusion filling, median, speckle and image-guided weighted median filters, confidence.

All functions take cost volumes ``(B, D, H, W)`` (lower = better) or disparities ``(B, 1, H, W)``.
"""

from stereonet.select.confidence import cost_margin_confidence
from stereonet.select.fill import fill_occlusions
from stereonet.select.filters import median_filter, speckle_filter, weighted_median_filter
from stereonet.select.lr_check import left_right_check, left_right_difference, right_cost_volume, wta_right
from stereonet.select.subpixel import subpixel_refine
from stereonet.select.wta import select_disparity, uniqueness_mask, wta

__all__ = [
    "cost_margin_confidence", "fill_occlusions", "left_right_check", "left_right_difference", "median_filter",
    "right_cost_volume", "select_disparity", "speckle_filter", "subpixel_refine", "uniqueness_mask",
    "weighted_median_filter", "wta", "wta_right",
]
