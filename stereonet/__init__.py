"""stereonet: differentiable two-view stereo in PyTorch.

Conventions (see DESIGN.md): images are float ``(B, C, H, W)`` in [0, 1]; disparity is left-referenced,
``x_right = x_left - d``, ``(B, 1, H, W)`` with a bool ``valid`` mask; cost volumes are ``(B, D, H, W)``
with lower = better.
"""

from stereonet.checks import StereoInputError
from stereonet.types import Calibration, StereoOutput

__all__ = ["Calibration", "StereoInputError", "StereoOutput"]
__version__ = "0.1.0"
