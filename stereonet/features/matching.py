"""SIFT keypoints (``cv2.SIFT_create``) matched by nearest neighbour, Lowe's ratio test and a mutual check."""

from __future__ import annotations

import numpy as np
import torch

from stereonet.checks import DegenerateGeometryError, StereoInputError, check_image, check_image_pair
from stereonet.cost.census import to_grey

__all__ = ["image_to_uint8", "match_descriptors", "match_sift"]


def image_to_uint8(image: torch.Tensor) -> np.ndarray:
    """First image of a batch :math:`(B, C, H, W)` in [0, 1] -> grey uint8 :math:`(H, W)` (ITU-R 601 luma)."""
    check_image(image, "image")
    img = to_grey(image[:1].detach().float().cpu().clamp(0, 1))[0, 0]
    return (img * 255).round().to(torch.uint8).numpy()


def match_descriptors(
    desc1: torch.Tensor, desc2: torch.Tensor, ratio: float = 0.75, mutual: bool = True
) -> torch.Tensor:
    """Nearest-neighbour matching with Lowe's ratio test.

    Args:
        desc1: :math:`(N1, D)`, desc2: :math:`(N2, D)` float descriptors (N2 >= 2).
        ratio: keep a match when ``d(best) < ratio * d(second best)``.
        mutual: also require that the match is the nearest neighbour the other way round.

    Returns:
        index pairs :math:`(M, 2)` long (row into desc1, row into desc2).
    """
    if not 0 < ratio <= 1:
        raise StereoInputError(f"ratio: expected a number in (0, 1], got {ratio!r}")
    if desc1.shape[0] == 0 or desc2.shape[0] < 2:
        return torch.zeros(0, 2, dtype=torch.long)
    dist = torch.cdist(desc1.float(), desc2.float())  # N1xN2
    two = dist.topk(2, dim=1, largest=False)
    keep = two.values[:, 0] < ratio * two.values[:, 1]
    idx1 = torch.arange(desc1.shape[0])
    idx2 = two.indices[:, 0]
    if mutual:
        keep &= dist.argmin(dim=0)[idx2] == idx1
    return torch.stack([idx1[keep], idx2[keep]], dim=1)


def match_sift(
    left: torch.Tensor,
    right: torch.Tensor,
    ratio: float = 0.75,
    max_features: int = 4000,
    min_matches: int = 8,
    mutual: bool = True,
) -> tuple[torch.Tensor, torch.Tensor]:
    """SIFT matches between the first images of two batches.

    Args:
        left, right: :math:`(B, C, H, W)` float in [0, 1] (sizes may differ; only element 0 is used).
        ratio: Lowe's ratio; max_features: keypoints kept per image; mutual: mutual nearest neighbours only.
        min_matches: raise when fewer matches survive.

    Returns:
        (pts1, pts2) :math:`(M, 2)` float64 pixel coordinates (x, y) in the left / right image.

    Raises:
        DegenerateGeometryError: fewer than ``min_matches`` matches (textureless or unrelated images).
    """
    import cv2

    if left.shape[-2:] == right.shape[-2:]:
        check_image_pair(left, right)
    else:
        check_image(left, "left")
        check_image(right, "right")
    sift = cv2.SIFT_create(nfeatures=max_features)
    kp1, d1 = sift.detectAndCompute(image_to_uint8(left), None)
    kp2, d2 = sift.detectAndCompute(image_to_uint8(right), None)
    if d1 is None or d2 is None:
        pairs = torch.zeros(0, 2, dtype=torch.long)
    else:
        pairs = match_descriptors(torch.from_numpy(d1), torch.from_numpy(d2), ratio=ratio, mutual=mutual)
    if pairs.shape[0] < min_matches:
        raise DegenerateGeometryError(
            f"left, right: only {pairs.shape[0]} SIFT matches pass the ratio test {ratio} "
            f"(keypoints: {len(kp1)} and {len(kp2)}); need at least {min_matches}. The images may be "
            "textureless or unrelated."
        )
    xy1 = torch.tensor([kp1[i].pt for i in pairs[:, 0].tolist()], dtype=torch.float64)
    xy2 = torch.tensor([kp2[i].pt for i in pairs[:, 1].tolist()], dtype=torch.float64)
    return xy1, xy2
