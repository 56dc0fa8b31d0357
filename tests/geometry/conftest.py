"""Fixtures of the geometry tests."""

from __future__ import annotations

import pytest
import torch


@pytest.fixture
def one_thread():
    """Many tiny tensor ops (RANSAC batches, 3x3 solves) run faster on one thread than on two busy ones."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
