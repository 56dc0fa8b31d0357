"""Noise floor for precision_validation.py: the float32 Siamese cost plus Gaussian noise of the size bfloat16
changes it by (std 0.001 in 1 - cos units, measured on val4 pairs 3 and 7), two seeds, on data_gen validation.
If these move val2/val4 bad-2 as much as bfloat16 does, bfloat16's change is indistinguishable from noise.

    python docs/experiments/precision_noise_floor.py [SPECS]     (default "val2;val4")
"""
import sys

import torch
from val_sets import compare

import stereonet.matchers.learned as learned
from stereonet.models.siamese import INVALID_COST

STD = 0.001
exact = learned._siamese_cost


def noisy_cost(seed):
    def cost(*args, **kwargs):
        vol = exact(*args, **kwargs)
        g = torch.Generator().manual_seed(seed)
        return vol + STD * torch.randn(vol.shape, generator=g, dtype=vol.dtype) * (vol < INVALID_COST)
    return cost


def with_cost(cost):
    def matcher(*args, **kwargs):
        learned._siamese_cost = cost
        try:
            return learned.siamese_census_sgm_matcher(*args, **kwargs)
        finally:
            learned._siamese_cost = exact
    return matcher


specs = sys.argv[1].split(";") if len(sys.argv) > 1 else ["val2", "val4"]
compare({f"census-sgm-noise-s{s}": (with_cost(noisy_cost(s)), {"precision": "float32"}) for s in (1, 2)}, specs)
