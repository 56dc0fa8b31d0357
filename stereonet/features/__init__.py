"""Keypoint matching for uncalibrated pairs: OpenCV SIFT (built in, nothing downloaded) + Lowe's ratio."""

from stereonet.features.matching import image_to_uint8, match_descriptors, match_sift

__all__ = ["image_to_uint8", "match_descriptors", "match_sift"]
