"""Pieces shared by the command-line mains (eval, infer, bench): one-line errors, memory meter, timing.

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

import argparse
import ctypes
import ctypes.util
import os
import resource
import sys
import threading
import time
from pathlib import Path
from typing import NoReturn

from stereonet.checks import StereoInputError

_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096
_STATM = Path("/proc/self/statm")

# Errors that come from the user's input: bad arguments, specs, names or file contents (StereoInputError,
# which every check of a public function raises) and file-system errors: one line, exit code 2. Anything else
# (a plain ValueError or TypeError included) is a bug and shows its traceback.
USER_ERRORS: tuple[type[BaseException], ...] = (StereoInputError, FileNotFoundError, NotADirectoryError,
                                                 IsADirectoryError, PermissionError, FileExistsError)


class OneLineParser(argparse.ArgumentParser):
    """argparse that reports a usage error as one line (``prog: error: ...``) instead of usage + error."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def fail(prog: str, message: object, code: int = 2) -> int:
    """Print ``prog: error: message`` on one line to stderr and return ``code`` (for ``return fail(...)``)."""
    text = " ".join(str(message).split()) or type(message).__name__
    print(f"{prog}: error: {text}", file=sys.stderr)
    return code


def weights_available(name: str) -> bool:
    """Whether matcher ``name`` can run without an explicit checkpoint (always True when it needs none).

    Asks ``stereonet.models.registered.weights_available`` when the learned family provides it, else looks
    for the shipped file of the matcher's network (``siamese-sgm`` uses ``siamese``'s weights).
    """
    from stereonet import matchers

    if not matchers.spec(name).needs_weights:
        return True
    try:
        from stereonet.models import registered
        from stereonet.models.weights import default_weights_path
    except ImportError:
        return False
    probe = getattr(registered, "weights_available", None)
    if probe is not None:
        try:
            return bool(probe(name))
        except (KeyError, ValueError):  # a name the learned family does not know: look for the file
            pass
    return default_weights_path(name.split("-")[0]).is_file()


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
