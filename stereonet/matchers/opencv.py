"""OpenCV baselines ``opencv-bm`` and ``opencv-sgbm`` behind the matcher signature.

OpenCV returns fixed-point disparities (value / 16); pixels it marks invalid (below ``minDisparity``) come
back with ``valid = False``. Images are converted to 8-bit (grey for BM, colour or grey for SGBM).
"""

from __future__ import annotations

import cv2
import numpy as np
import torch

from stereonet.checks import StereoInputError, check_stereo_inputs
from stereonet.matchers import register
from stereonet.types import StereoOutput


def _to_uint8(img: torch.Tensor, grey: bool) -> np.ndarray:
    """(C, H, W) float in [0, 1] -> (H, W[, 3]) uint8 (BGR order for colour, as OpenCV expects)."""
    a = (img.detach().float().clamp(0, 1) * 255.0 + 0.5).to(torch.uint8).permute(1, 2, 0).cpu().numpy()
    if a.shape[2] == 3:
        a = a[:, :, ::-1]
        if grey:
            a = cv2.cvtColor(np.ascontiguousarray(a), cv2.COLOR_BGR2GRAY)
    else:
        a = a[:, :, 0]
    return np.ascontiguousarray(a)


def _num_disparities(max_disp: int) -> int:
    return int(16 * np.ceil((max_disp + 1) / 16))


def _int_options(**options) -> None:
    """OpenCV's integer knobs: whole numbers (a float or a string would fail inside cv2), a one-line error
    naming the option otherwise."""
    for name, value in options.items():
        if isinstance(value, bool) or not isinstance(value, int | np.integer):
            raise StereoInputError(f"{name}: expected an integer (OpenCV's), got {value!r}")


def _check_block(block_size: int, left: torch.Tensor, lowest: int, name: str) -> None:
    """An odd ``block_size`` >= ``lowest`` that fits the image (OpenCV asserts otherwise)."""
    if block_size < lowest or block_size % 2 == 0:
        raise StereoInputError(f"block_size: expected an odd window >= {lowest} for {name}, got {block_size}")
    h, w = left.shape[-2:]
    if block_size > min(h, w):
        raise StereoInputError(f"left: a {h}x{w} image is smaller than {name}'s {block_size} px window")


def _run(left: torch.Tensor, right: torch.Tensor, make, grey: bool) -> StereoOutput:
    outs = []
    for b in range(left.shape[0]):
        l8, r8 = _to_uint8(left[b], grey), _to_uint8(right[b], grey)
        try:
            d = make().compute(l8, r8).astype(np.float32) / 16.0
        except cv2.error as e:  # the inputs are checked uint8 images: OpenCV refuses their size for its range
            raise StereoInputError(f"left: OpenCV cannot match a {l8.shape[1]}x{l8.shape[0]} pair with these settings "
                                   f"({str(e).strip().splitlines()[-1].strip()})") from None
        outs.append(torch.from_numpy(d))
    disp = torch.stack(outs)[:, None].to(device=left.device, dtype=left.dtype)
    valid = disp >= 0
    return StereoOutput(torch.where(valid, disp, torch.zeros_like(disp)), valid)


@register("opencv-bm", kind="opencv", description="OpenCV StereoBM (SAD block matching, prefilter, texture/uniqueness checks)")
def opencv_bm(left: torch.Tensor, right: torch.Tensor, max_disp: int, block_size: int = 15,
              uniqueness_ratio: int = 15, texture_threshold: int = 10, speckle_window: int = 100,
              speckle_range: int = 2) -> StereoOutput:
    """OpenCV ``cv2.StereoBM_create``; ``left``/``right`` :math:`(B, C, H, W)`."""
    left, right, max_disp = check_stereo_inputs(left, right, max_disp)
    _int_options(block_size=block_size, uniqueness_ratio=uniqueness_ratio, texture_threshold=texture_threshold,
                 speckle_window=speckle_window, speckle_range=speckle_range)
    _check_block(block_size, left, 5, "opencv-bm")
    if texture_threshold < 0 or uniqueness_ratio < 0:
        raise StereoInputError(f"texture_threshold/uniqueness_ratio: expected values >= 0, got {texture_threshold}, "
                               f"{uniqueness_ratio}")

    def make():
        m = cv2.StereoBM_create(numDisparities=_num_disparities(max_disp), blockSize=block_size)
        m.setUniquenessRatio(uniqueness_ratio)
        m.setTextureThreshold(texture_threshold)
        m.setSpeckleWindowSize(speckle_window)
        m.setSpeckleRange(speckle_range)
        return m

    return _run(left, right, make, grey=True)


@register("opencv-sgbm", kind="opencv", description="OpenCV StereoSGBM (Birchfield-Tomasi cost, 5-path SGM, uniqueness, LR, speckle)")
def opencv_sgbm(left: torch.Tensor, right: torch.Tensor, max_disp: int, block_size: int = 5,
                uniqueness_ratio: int = 10, speckle_window: int = 100, speckle_range: int = 2,
                disp12_max_diff: int = 1, mode: str = "sgbm") -> StereoOutput:
    """OpenCV ``cv2.StereoSGBM_create`` with the P1 = 8·cn·bs², P2 = 32·cn·bs² settings of its samples."""
    left, right, max_disp = check_stereo_inputs(left, right, max_disp)
    _int_options(block_size=block_size, uniqueness_ratio=uniqueness_ratio, speckle_window=speckle_window,
                 speckle_range=speckle_range, disp12_max_diff=disp12_max_diff)
    _check_block(block_size, left, 1, "opencv-sgbm")
    cn = left.shape[1]
    modes = {"sgbm": cv2.STEREO_SGBM_MODE_SGBM, "hh": cv2.STEREO_SGBM_MODE_HH,
             "3way": cv2.STEREO_SGBM_MODE_SGBM_3WAY}
    if mode not in modes:
        raise StereoInputError(f"mode: expected one of {sorted(modes)}, got {mode!r}")

    def make():
        return cv2.StereoSGBM_create(
            minDisparity=0, numDisparities=_num_disparities(max_disp), blockSize=block_size,
            P1=8 * cn * block_size ** 2, P2=32 * cn * block_size ** 2, disp12MaxDiff=disp12_max_diff,
            uniquenessRatio=uniqueness_ratio, speckleWindowSize=speckle_window, speckleRange=speckle_range,
            mode=modes[mode])

    return _run(left, right, make, grey=False)
