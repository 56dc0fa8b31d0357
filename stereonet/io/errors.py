"""The error raised for unreadable files, and the shared file-existence check."""

from __future__ import annotations

import os
from pathlib import Path

from stereonet.checks import StereoInputError


class FileFormatError(StereoInputError):
    """A file exists but is truncated, corrupt or not in the expected format; the message names the file."""


def existing_file(path: str | os.PathLike) -> Path:
    """Return ``path`` as a Path, raising ``FileNotFoundError`` naming it when it is not a readable file."""
    p = Path(path)
    if not p.is_file():
        what = "is a directory, expected a file" if p.is_dir() else "no such file"
        raise FileNotFoundError(f"{p}: {what}")
    return p


def fail(path: str | os.PathLike, problem: str) -> FileFormatError:
    """Build the one-line error ``"<path>: <problem>"`` (callers ``raise fail(...)``)."""
    return FileFormatError(f"{path}: {problem}")
