"""Errors that reach the user as one line: bad input (exit code 2), a run failing partway (exit code 1)."""

from __future__ import annotations

import os
import stat
import tempfile
import threading
from pathlib import Path
from typing import Iterable

__all__ = ["UsageError", "RunError", "WriteError", "Terminated", "SIGTERM_RECEIVED", "check_output_path", "check_output_folder"]


class UsageError(Exception):
    """Bad input (a file, a config key, a value): shown as one line, exit code 2.

    The message names the file, key or value and says what is allowed.
    """


class RunError(RuntimeError):
    """A run stopped partway by a failure outside the input (its detector process died): one line, exit code 1.

    The message says what failed and what was kept; the files written are complete up to it.
    """


class WriteError(RunError):
    """A file could not be written partway (a full disk, an I/O error, a quota): one line, exit code 1.

    Raised once the file is complete up to its last whole row or frame; the message says what it holds.
    """


class Terminated(BaseException):
    """SIGTERM where no stop flag is installed: the command unwinds as on Ctrl-C (files finished,
    staging removed) and exits with 143."""


#: set when a SIGTERM has been received: a :class:`Terminated` raised where Python swallows
#: exceptions (a finaliser the garbage collector ran, a callback) is not lost -- a stop flag
#: installed later finds the process already asked to stop
SIGTERM_RECEIVED = threading.Event()


def check_output_path(path: str | Path, flag: str, *, overwrite: bool = True,
                      suffixes: Iterable[str] = ()) -> Path:
    """A file we are about to write: checked before any work, so bad input fails at once with one line.

    Its folder must exist (none is created) and take a new file (a real probe: a temporary file is
    made and removed, which catches read-only mounts, ``/proc`` and the like); the path must not be a
    folder or a device (``/dev/full``); an existing file is refused unless ``overwrite``; with
    ``suffixes`` (lower case, with the dot) its extension must be one of them.
    """
    path = Path(path)
    if path.is_dir():
        raise UsageError(f"{flag} {path}: is a folder, expected a file path")
    suffixes = tuple(suffixes)
    if suffixes and path.suffix.lower() not in suffixes:
        raise UsageError(f"{flag} {path}: allowed a file ending in {', '.join(suffixes)}")
    if not path.parent.is_dir():
        raise UsageError(f"{flag} {path}: the folder {path.parent} {_missing(path.parent)}")
    if os.path.lexists(path):
        try:
            mode = path.stat().st_mode
        except OSError as exc:
            raise UsageError(f"{flag} {path}: cannot be read ({exc.strerror})") from None
        if not stat.S_ISREG(mode):
            raise UsageError(f"{flag} {path}: not a regular file (a device or a pipe); expected a file path")
        if not overwrite:
            raise UsageError(f"{flag} {path}: already exists; use --overwrite to replace it")
        if not os.access(path, os.W_OK):
            raise UsageError(f"{flag} {path}: not writable (permission denied)")
    _probe_folder(path.parent, f"{flag} {path}")
    return path


def check_output_folder(path: str | Path, flag: str) -> Path:
    """A folder we are about to write files into: an existing writable folder, or a new one whose
    own folder exists and is writable (the caller then creates that one level; no tree is made).

    Checked before any work, as :func:`check_output_path` (the same probe).
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise UsageError(f"{flag} {path}: exists and is not a folder")
    if path.is_dir():
        _probe_folder(path, f"{flag} {path}")
        return path
    if not path.parent.is_dir():
        raise UsageError(f"{flag} {path}: the folder {path.parent} {_missing(path.parent)}")
    _probe_folder(path.parent, f"{flag} {path}")
    return path


def _missing(folder: Path) -> str:
    """Why ``folder`` cannot hold files: it is a file, or it does not exist."""
    return "is a file, not a folder" if folder.exists() else "does not exist"


def _probe_folder(folder: Path, what: str) -> None:
    """Refuse ``folder`` unless a file can be created in it: permissions alone miss read-only
    mounts and pseudo file systems (``/proc``), and root passes every permission check."""
    if not os.access(folder, os.W_OK | os.X_OK):
        raise UsageError(f"{what}: cannot write in the folder {folder} (permission denied)")
    try:
        handle, probe = tempfile.mkstemp(prefix=".antiscatter-probe-", dir=folder)
    except OSError as exc:
        raise UsageError(f"{what}: cannot write in the folder {folder} ({exc.strerror or exc})") from None
    os.close(handle)
    try:
        os.unlink(probe)
    except OSError:
        pass
