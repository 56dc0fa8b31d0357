"""Shared test fixtures and per-dtype tolerances."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"

# One per-dtype tolerance table for numerical comparisons.
TOL = {torch.float32: dict(rtol=1e-4, atol=1e-5), torch.float64: dict(rtol=1e-9, atol=1e-10)}

torch.set_num_threads(2)


@pytest.fixture
def one_thread():
    """Torch on one thread for the test: many tiny tensor ops (RANSAC batches, 3x3 solves, small networks)
    run faster than with OpenMP hand-offs between two busy cores."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture
def shared_data() -> Path:
    """../shared/data, or skip when the optional real data is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"optional real data not present at {SHARED_DATA}")
    return SHARED_DATA


@pytest.fixture
def textured_pair():
    """A random-texture fronto-parallel pair with constant disparity 5 (left reference), 1x1x48x96."""
    g = torch.Generator().manual_seed(0)
    big = torch.rand(1, 1, 48, 120, generator=g)
    d = 5
    left = big[..., 10:106]
    right = big[..., 10 + d:106 + d]
    return left.contiguous(), right.contiguous(), d
