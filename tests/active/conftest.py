"""Active-stereo tests run torch single-threaded: their tensors are small (a few thousand points, tiny
images), where OpenMP thread hand-offs cost more than they save — up to 30x on a busy 2-core machine."""

from __future__ import annotations

import pytest
import torch


@pytest.fixture(autouse=True)
def _single_thread():
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
