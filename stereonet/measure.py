"""Measuring a call: extra resident memory (:class:`PeakMemory`) and wall time (:class:`Stopwatch`).

Peak memory: ``tracemalloc`` does not see torch's (or OpenCV's, or numba's) native allocations, so
:class:`PeakMemory` measures the *resident set size* of the process instead: a daemon thread samples
``/proc/self/statm`` every millisecond while the measured call runs, and ``resource.getrusage``'s
``ru_maxrss`` (the process-wide high-water mark) is read before and after, which catches a peak the
sampler missed (a kernel holding the GIL) whenever that peak is a new high for the process. The number
reported is the peak RSS during the call minus the RSS just before it: the extra memory the call needed.
Before each measurement glibc's ``malloc_trim(0)`` hands freed heap memory back to the system, so buffers
freed by an earlier call and reused by this one are counted again; allocators that cache on their own
(numba, OpenMP pools) can still make the figure a lower bound. Run a single method for an exact figure.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import resource
import threading
import time
from pathlib import Path

_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096
_STATM = Path("/proc/self/statm")


def _load_libc():
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        return libc if hasattr(libc, "malloc_trim") else None
    except OSError:
        return None


_LIBC = _load_libc()


def release_free_memory() -> None:
    """Return freed heap memory to the system (glibc ``malloc_trim``; a no-op elsewhere)."""
    if _LIBC is not None:
        _LIBC.malloc_trim(0)


_M_TRIM_THRESHOLD, _M_MMAP_MAX = -1, -4  # glibc's mallopt parameters (malloc.h)


def reuse_freed_memory() -> bool:
    """Have glibc serve every allocation from its heap and keep freed heap memory for the next allocation
    (``mallopt``: no ``mmap`` allocations, no automatic trimming); True where applied (glibc), else False.

    By default glibc maps each block over 32 MiB (a cost volume, a feature map) afresh and unmaps it when
    freed, so every such buffer is paid again in page faults and in the kernel zeroing its pages: on Cones
    that was a third of ``siamese-census-sgm``'s CPU time (the model card, thirteenth session).
    Process-wide and not undone, so the library leaves it to its programs: ``infer.py``, ``eval.py`` and
    the benchmarks call it first. The price: freed memory stays resident until reused, so a call's peak can
    be higher (a freed block too small for a later request is kept beside it; ``siamese-census-sgm`` on
    Cones 101 -> 165 MiB). :func:`release_free_memory` hands it back: :class:`PeakMemory` does so first, and
    the strips of :func:`stereonet.tiling.match_with_budget` do so one by one.
    """
    if _LIBC is None or not hasattr(_LIBC, "mallopt"):
        return False
    return bool(_LIBC.mallopt(_M_MMAP_MAX, 0)) and bool(_LIBC.mallopt(_M_TRIM_THRESHOLD, 2 ** 31 - 1))


def rss_bytes() -> int:
    """Current resident set size of this process in bytes (0 where /proc is missing)."""
    try:
        return int(_STATM.read_text().split()[1]) * _PAGE
    except (OSError, IndexError, ValueError):
        return 0


def max_rss_bytes() -> int:
    """Process-wide peak resident set size so far (``ru_maxrss``, KiB on Linux) in bytes."""
    return int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss) * 1024


class PeakMemory:
    """Context manager: ``peak_mib`` = peak RSS during the block minus RSS at entry, in MiB (see module doc)."""

    def __init__(self, interval: float = 0.001) -> None:
        self.interval = interval
        self.peak_mib = 0.0
        self._stop = threading.Event()

    def _sample(self) -> None:
        while not self._stop.wait(self.interval):
            self._peak = max(self._peak, rss_bytes())

    def __enter__(self) -> PeakMemory:
        release_free_memory()
        self._base = rss_bytes()
        self._peak = self._base
        self._maxrss_before = max_rss_bytes()
        self._stop.clear()
        self._thread = threading.Thread(target=self._sample, daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()
        peak = max(self._peak, rss_bytes())
        maxrss_after = max_rss_bytes()
        if maxrss_after > self._maxrss_before:  # a new process-wide high was set inside the block
            peak = max(peak, maxrss_after)
        self.peak_mib = max(0.0, (peak - self._base) / 2 ** 20)


class Stopwatch:
    """Context manager: ``seconds`` of wall-clock time spent in the block."""

    def __enter__(self) -> Stopwatch:
        self._t0 = time.perf_counter()
        self.seconds = 0.0
        return self

    def __exit__(self, *exc) -> None:
        self.seconds = time.perf_counter() - self._t0
