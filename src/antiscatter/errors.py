"""Errors that reach the user as one line and exit code 2."""

from __future__ import annotations

from pathlib import Path

__all__ = ["UsageError", "check_output_path"]


class UsageError(Exception):
    """Bad input (a file, a config key, a value): shown as one line, exit code 2.

    The message names the file, key or value and says what is allowed.
    """


def check_output_path(path: str | Path, flag: str) -> Path:
    """A file we are about to write: its folder must exist and it must not be a folder itself.

    Checked before any work, so bad input fails at once with one line and nothing written.
    """
    path = Path(path)
    if path.is_dir():
        raise UsageError(f"{flag} {path}: is a folder, expected a file path")
    if not path.parent.is_dir():
        raise UsageError(f"{flag} {path}: the folder {path.parent} does not exist")
    return path
