"""stereonet.measure: the glibc allocator setting the programs use (reuse_freed_memory)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from stereonet import measure

CODE = """
import sys
import numpy as np
from stereonet.measure import release_free_memory, reuse_freed_memory, rss_bytes
applied = reuse_freed_memory() if sys.argv[1] == "reuse" else False
base = rss_bytes()
block = np.ones(96 << 17)  # 96 MiB, touched: above glibc's 32 MiB mmap threshold
del block
kept = rss_bytes() - base
release_free_memory()
print(applied, kept >> 20, (rss_bytes() - base) >> 20)
"""


@pytest.mark.skipif(measure._LIBC is None or not hasattr(measure._LIBC, "mallopt"), reason="not glibc")
def test_reuse_freed_memory_keeps_a_freed_block_until_trimmed():
    """With the setting, a freed 96 MiB block stays resident for reuse (and malloc_trim still returns it);
    without it, glibc unmaps it at once. Run in subprocesses: the setting is process-wide."""
    def run(mode):
        out = subprocess.run([sys.executable, "-c", CODE, mode], capture_output=True, text=True, check=True)
        applied, kept, trimmed = out.stdout.split()
        return applied == "True", int(kept), int(trimmed)

    applied, kept, trimmed = run("reuse")
    assert applied and kept >= 90 and trimmed < 16
    applied, kept, _ = run("default")
    assert not applied and kept < 16
