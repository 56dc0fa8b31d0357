"""Pieces shared by the command-line mains (eval, infer, bench, calibrate, export): one-line errors and the
argument parser that reports them. Measuring (:mod:`stereonet.measure`) and ``weights_available``
(:mod:`stereonet.matchers`) are library functions, re-exported here for the mains."""

from __future__ import annotations

import argparse
import sys
from typing import NoReturn

from stereonet.checks import StereoInputError
from stereonet.matchers import weights_available
from stereonet.measure import (
    PeakMemory,
    Stopwatch,
    max_rss_bytes,
    release_free_memory,
    reuse_freed_memory,
    rss_bytes,
)

__all__ = ["USER_ERRORS", "OneLineParser", "PeakMemory", "Stopwatch", "add_malloc_argument", "apply_malloc_argument",
           "check_output_path", "fail", "max_rss_bytes", "release_free_memory", "reuse_freed_memory", "rss_bytes", "weights_available"]

# Errors that come from the user's input: bad arguments, specs, names or file contents (StereoInputError,
# which every check of a public function raises) and file-system errors: one line, exit code 2. Anything else
# (a plain ValueError or TypeError included) is a bug and shows its traceback.
USER_ERRORS: tuple[type[BaseException], ...] = (StereoInputError, FileNotFoundError, NotADirectoryError,
                                                 IsADirectoryError, PermissionError, FileExistsError)


class OneLineParser(argparse.ArgumentParser):
    """argparse that reports a usage error as one line (``prog: error: ...``) instead of usage + error."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def add_malloc_argument(parser: argparse.ArgumentParser) -> None:
    """``--malloc reuse|default`` for the benchmarks: :func:`apply_malloc_argument` then sets glibc as infer.py and
    eval.py do (:func:`stereonet.measure.reuse_freed_memory`) or leaves glibc's own mmap/unmap per buffer."""
    parser.add_argument("--malloc", choices=("reuse", "default"), default="reuse",
                        help="'reuse': glibc keeps large freed buffers for reuse, as infer.py and eval.py set it "
                             "(stereonet.measure.reuse_freed_memory); 'default': glibc's own mmap/unmap per buffer")


def apply_malloc_argument(args: argparse.Namespace) -> None:
    """Act on :func:`add_malloc_argument`'s option."""
    if args.malloc == "reuse":
        reuse_freed_memory()


def check_output_path(path, arg: str, folder: bool) -> None:
    """Before any work: ``path`` (what option ``arg`` names) can be written as a file (``folder=False``) or a folder:
    it is not an existing entry of the other kind, and its nearest existing parent is a folder (the missing ones are
    created when the output is written). A one-line :class:`StereoInputError` naming ``arg`` otherwise."""
    from pathlib import Path

    path = Path(path)
    if path.exists() and path.is_dir() != folder:
        raise StereoInputError(f"{arg}: expected a {'folder' if folder else 'file'}, got the existing "
                               f"{'file' if folder else 'folder'} {path}")
    parent = path.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise StereoInputError(f"{arg}: {parent} is a file, so {path} cannot be written")


def fail(prog: str, message: object, code: int = 2) -> int:
    """Print ``prog: error: message`` on one line to stderr and return ``code`` (for ``return fail(...)``)."""
    text = " ".join(str(message).split()) or type(message).__name__
    print(f"{prog}: error: {text}", file=sys.stderr)
    return code
