"""Active-stereo tests run torch single-threaded: their tensors are small (a few thousand points, tiny
images), where OpenMP thread hand-offs cost more than they save — up to 30x on a busy 2-core machine."""

from __future__ import annotations

import pytest


@pytest.fixture(autouse=True)
def _single_thread(one_thread):
    yield
