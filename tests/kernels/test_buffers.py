"""``stereonet.kernels.empty_array``: the kernels' large buffers come from torch's allocator, not numpy's.

numpy asks the kernel for transparent huge pages (``MADV_HUGEPAGE``) on every array of 4 MiB or more; with the usual
``defrag=madvise`` setting a first touch of such memory may compact memory synchronously (``bp``'s first call on a
KITTI pair: 0.94 s, 0.6 s of it system time, against 0.38 s for the next calls). The test reads the flags of the
memory mapping that holds each buffer (``hg`` = ``MADV_HUGEPAGE``) in ``/proc/self/smaps``.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from stereonet.kernels import empty_array

SMAPS = Path("/proc/self/smaps")


def _vm_flags(array: np.ndarray) -> list[str]:
    """The VmFlags of the mapping holding the byte 1 MiB into ``array``."""
    addr = array.__array_interface__["data"][0] + (1 << 20)
    inside = False
    for line in SMAPS.read_text().splitlines():
        head = line.split(maxsplit=1)[0]
        if "-" in head and not head.endswith(":"):
            lo, hi = (int(x, 16) for x in head.split("-"))
            inside = lo <= addr < hi
        elif inside and line.startswith("VmFlags:"):
            return line.split()[1:]
    raise AssertionError("no mapping holds the array")


def test_empty_array_shape_dtype_and_zeros():
    a = empty_array((3, 4, 5), np.int16)
    assert a.shape == (3, 4, 5) and a.dtype == np.int16 and a.flags.c_contiguous and a.flags.writeable
    z = empty_array([2, 7], np.float32, zero=True)
    assert z.dtype == np.float32 and not z.any()
    a[:] = 7  # the array owns its memory for as long as it lives
    assert int(a.sum()) == 7 * 60


@pytest.mark.skipif(not sys.platform.startswith("linux") or not SMAPS.exists(),
                    reason="reads the memory mappings' flags from /proc/self/smaps (Linux only)")
def test_large_buffers_do_not_ask_for_huge_pages():
    ours = empty_array((64 << 20,), np.uint8)
    assert "hg" not in _vm_flags(ours)


HEAP_CODE = """
import sys
import numpy as np
sys.path.insert(0, sys.argv[1])
from test_buffers import _vm_flags
from stereonet.kernels import empty_array
from stereonet.measure import reuse_freed_memory
assert reuse_freed_memory()
theirs = np.ones(64 << 20, np.uint8)  # numpy: marked "hg"
print("hg" in _vm_flags(theirs))
del theirs
for zero in (False, True):
    ours = empty_array((64 << 20,), np.uint8, zero=zero)
    flags = _vm_flags(ours)
    print("hg" not in flags and "nh" in flags and (not zero or not ours.any()))
    del ours
"""


@pytest.mark.skipif(not sys.platform.startswith("linux") or not SMAPS.exists(),
                    reason="reads the memory mappings' flags from /proc/self/smaps (Linux only)")
def test_a_buffer_in_heap_memory_numpy_marked_for_huge_pages_is_unmarked():
    """With glibc serving every block from its heap (the programs' reuse_freed_memory), numpy's MADV_HUGEPAGE mark
    stays on the heap range after numpy frees it, and a torch buffer placed there later inherited it (the test above
    failed so, depending on what ran before it); empty_array marks its own pages MADV_NOHUGEPAGE. In a subprocess:
    the allocator setting is process-wide."""
    out = subprocess.run([sys.executable, "-c", HEAP_CODE, str(Path(__file__).parent)], capture_output=True,
                         text=True, check=True)
    assert out.stdout.split() == ["True", "True", "True"]
