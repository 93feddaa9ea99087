"""Writers that survive a full disk: every file complete up to its last whole row or frame.

A write that fails partway (``ENOSPC``, ``EIO``, ``EDQUOT``, ...) raises :class:`WriteError`
(one line, exit code 1) once the file has been cut back to what is whole: a CSV to its last whole
row, a single-file image removed, a Matroska video closed (its frames readable up to the last
one that reached the disk, counted by :func:`video_frames`).
"""

from __future__ import annotations

import csv
import io
import os
from pathlib import Path
from typing import Any, Iterable

from .errors import WriteError

__all__ = ["CsvFile", "write_whole", "video_frames", "write_failed"]


def write_failed(path: str | Path, exc: OSError, kept: str) -> WriteError:
    """The one-line error for a write to ``path`` that failed with ``exc``; ``kept`` says what the file holds."""
    reason = exc.strerror or str(exc) or type(exc).__name__
    error = WriteError(f"{path}: {reason}; stopped, {kept}")
    error.what, error.reason = f"{path}: {reason}", reason  # (for a caller that says itself what was kept)
    return error


class CsvFile:
    """A CSV file written a row (or a frame's rows) at a time, each in one unbuffered write.

    Nothing waits in a buffer, so however the program ends the file holds every row written;
    a write that fails (a full disk) is cut back to the last whole row before
    :class:`WriteError` is raised.  ``writerow`` / ``writerows`` as :func:`csv.writer`'s;
    ``rows`` counts the rows after the header.  A context manager.
    """

    def __init__(self, path: str | Path, header: Iterable[Any]) -> None:
        self.path = Path(path)
        self.rows = 0
        self._end = 0  # bytes of whole rows in the file
        self._text = io.StringIO()
        self._csv = csv.writer(self._text)
        self._fd: int | None = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o666)
        self._write([header], header=True)

    def writerow(self, row: Iterable[Any]) -> None:
        self._write([row])

    def writerows(self, rows: Iterable[Iterable[Any]]) -> None:
        self._write(rows)

    def _write(self, rows: Iterable[Iterable[Any]], *, header: bool = False) -> None:
        ends, parts, size = [], [], 0
        for row in rows:
            self._text.seek(0)
            self._text.truncate()
            self._csv.writerow(row)
            part = self._text.getvalue().encode()
            parts.append(part)
            size += len(part)
            ends.append(size)
        if not parts or self._fd is None:
            return
        data = memoryview(b"".join(parts))
        done = 0
        try:
            while done < len(data):
                done += os.write(self._fd, data[done:])
        except OSError as exc:
            whole = max((end for end in ends if end <= done), default=0)
            self._cut(self._end + whole)
            if not header:
                self.rows += ends.index(whole) + 1 if whole else 0
            raise write_failed(self.path, exc, f"the file holds the header and {self.rows} whole rows"
                               if self._end else "the file is empty") from None
        self._end += len(data)
        if not header:
            self.rows += len(parts)

    def _cut(self, size: int) -> None:
        """Truncate to ``size`` bytes (the whole rows) and close: nothing more is written."""
        try:
            os.ftruncate(self._fd, size)
        except OSError:
            pass
        self._end = size
        self.close()

    def close(self) -> None:
        if self._fd is not None:
            fd, self._fd = self._fd, None
            os.close(fd)

    def __enter__(self) -> "CsvFile":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def write_whole(path: str | Path, data: bytes) -> None:
    """Write ``data`` as the file ``path``, whole or not at all: a failed write removes the part
    written and raises :class:`WriteError`."""
    path = Path(path)
    try:
        with open(path, "wb") as handle:
            handle.write(data)
    except OSError as exc:
        try:
            path.unlink()
        except OSError:
            pass
        raise write_failed(path, exc, "not written (removed)") from None


def video_frames(path: str | Path) -> int:
    """Frames of the video ``path`` that can be read back whole: its first stream's packets, up to
    the first one cut short (a file the disk filled up).  0 for a file that cannot be opened."""
    import av

    count = 0
    try:
        with av.open(str(path)) as container:
            for packet in container.demux(video=0):
                if packet.size == 0:
                    continue
                if packet.is_corrupt:
                    break
                count += 1
    except (OSError, av.FFmpegError):
        pass
    return count
