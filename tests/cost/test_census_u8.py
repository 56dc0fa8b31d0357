"""The uint8 pixelwise census volume (the numba SGM input) equals the torch census volume."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from stereonet.checks import StereoInputError
from stereonet.cost import build_cost_volume
from stereonet.cost.volume import census_pixel_volumes_u8


@pytest.mark.parametrize("census_window", [3, 7, 9, 15])  # 1, 1, 2 and 4 words of 62 bits
@pytest.mark.parametrize("h, w, max_disp", [(1, 14, 12), (11, 37, 12), (35, 70, 36)])  # D = W - 1, D % 8 != 0
def test_u8_volume_equals_torch(census_window, h, w, max_disp):
    g = torch.Generator().manual_seed(h * w + census_window)
    left, right = torch.rand(2, 3, h, w, generator=g), torch.rand(2, 3, h, w, generator=g)
    ref = build_cost_volume(left, right, max_disp, cost="census", window=1, census_window=census_window,
                            backend="torch")
    vols = census_pixel_volumes_u8(left, right, max_disp, census_window)
    assert len(vols) == 2 and all(v.dtype == np.uint8 and v.shape == (h, w, max_disp + 1) for v in vols)
    fast = torch.from_numpy(np.stack(vols)).permute(0, 3, 1, 2).float()
    assert torch.equal(fast, ref)  # integers, out-of-image positions max + 1 over the batch


def test_u8_volume_rejects_windows_beyond_uint8():
    img = torch.rand(1, 1, 4, 5)
    with pytest.raises(StereoInputError, match="census_window"):
        census_pixel_volumes_u8(img, img, 3, 17)
