"""What the commands show on the terminal besides their results: log records and progress bars.

Results (tables, JSON, summaries) are printed on stdout by the commands; everything here goes to
stderr.  The ``antiscatter`` logger carries diagnostics: :func:`configure_logging` (the CLI's
``--quiet`` / ``--verbose``) sets its level, and a progress bar shows only where that level lets
info through and stderr is a terminal, so piped or redirected output never holds bar fragments.
Used as a library, nothing is configured: the logger's level is Python's default (warnings), so
neither info nor bars appear unless the caller asks.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import os
import sys
from typing import Any, Iterable, Iterator, TypeVar

__all__ = ["LOGGER", "configure_logging", "progress", "progress_enabled", "write", "LogStream", "json_text"]

#: The package's logger; modules log to children of it (``antiscatter.run``, ...).
LOGGER = logging.getLogger("antiscatter")

#: Log levels of the CLI's verbosity: -1 ``--quiet`` (warnings and errors), 0 default (info), 1 ``--verbose``.
LEVELS = {-1: logging.WARNING, 0: logging.INFO, 1: logging.DEBUG}

T = TypeVar("T")


class _StderrHandler(logging.Handler):
    """Writes each record as one line to the current ``sys.stderr`` (looked up per record, so a
    test's capture sees it), above any progress bar, which is redrawn below it."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            text = self.format(record)
            from tqdm import tqdm

            tqdm.write(text, file=sys.stderr)
        except Exception:  # noqa: BLE001 -- logging must never break a command
            self.handleError(record)


class _Formatter(logging.Formatter):
    """The message as it is for info and errors (errors carry their own ``antiscatter CMD: error:``);
    ``warning:`` / ``debug:`` before warnings and debug records."""

    def format(self, record: logging.LogRecord) -> str:
        text = record.getMessage()
        if record.levelno == logging.WARNING:
            return f"warning: {text}"
        if record.levelno < logging.INFO:
            return f"debug: {record.name}: {text}"
        return text


@contextlib.contextmanager
def configure_logging(verbosity: int = 0) -> Iterator[logging.Handler]:
    """Send the ``antiscatter`` logger's records to stderr at the level of ``verbosity``, while the
    ``with`` block runs (the logger's level, handlers and propagation are restored after it).

    Parameters
    ----------
    verbosity : int
        -1 (``--quiet``: warnings and errors only, no progress bars), 0 (default: info too),
        1 (``--verbose``: debug too).

    Yields
    ------
    logging.Handler
        The handler installed; records do not also reach the root logger's handlers.
    """
    handler = _StderrHandler()
    handler.setFormatter(_Formatter())
    previous = LOGGER.level, LOGGER.propagate
    LOGGER.addHandler(handler)
    LOGGER.setLevel(LEVELS[max(-1, min(1, verbosity))])
    LOGGER.propagate = False
    try:
        yield handler
    finally:
        LOGGER.removeHandler(handler)
        LOGGER.setLevel(previous[0])
        LOGGER.propagate = previous[1]


def progress_enabled() -> bool:
    """Whether a progress bar shows: info records pass (not ``--quiet``) and stderr is a terminal."""
    try:
        tty = sys.stderr.isatty()
    except (AttributeError, ValueError):  # replaced by an object without it, or closed
        tty = False
    return tty and LOGGER.isEnabledFor(logging.INFO)


def progress(iterable: Iterable[T] | None = None, *, total: int | None = None, desc: str = "",
             unit: str = "frame", leave: bool = True, enabled: bool = True) -> Any:
    """A tqdm progress bar on stderr, drawn only where :func:`progress_enabled` says.

    Parameters
    ----------
    iterable : iterable, optional
        Items to count as they are taken; None for a bar advanced with ``update(n)``.
    total : int, optional
        Items expected (default: ``len(iterable)`` where it has one).
    desc : str
        The bar's label, e.g. the command or the stage.
    unit : str
        What one item is (default ``frame``).
    leave : bool
        Keep the finished bar on the terminal (default True; False for an inner bar of a nested loop).
    enabled : bool
        False turns the bar off whatever the terminal (e.g. ``analyse --no-progress``).

    Returns
    -------
    tqdm.tqdm
        Iterate it, or call ``update`` and ``close`` (or use it as a context manager).
    """
    from tqdm import tqdm

    show = enabled and progress_enabled()
    return tqdm(iterable, total=total, desc=desc, unit=unit, leave=leave, file=sys.stderr, disable=not show,
                **(_screen() if show else {}))


def _screen() -> dict[str, Any]:
    """tqdm's size settings: follow the terminal's size, or 80 x 20 where it reports none (a pty
    opened without a size, as ``script`` and some CI runners do: tqdm hides every bar at 0 rows)."""
    try:
        size = os.get_terminal_size(sys.stderr.fileno())
        columns, lines = size.columns, size.lines
    except (OSError, ValueError, AttributeError):
        columns = lines = 0
    if columns and lines:
        return {"dynamic_ncols": True}
    return {"ncols": columns or 80, "nrows": lines or 20}


def write(line: str) -> None:
    """Print a result line on stdout while a progress bar may be drawn: the bar is cleared, the line
    written, the bar drawn again below it (a plain print when no bar is shown)."""
    from tqdm import tqdm

    tqdm.write(line, file=sys.stdout)


class LogStream:
    """A text stream whose lines become log records: for library functions that take a ``log``
    stream (``runtime.run``, ``record``), so their notes go through the logger.

    A line beginning ``warning:`` becomes a warning (the prefix dropped: the formatter adds it),
    every other line an info record.
    """

    def __init__(self, logger: logging.Logger = LOGGER) -> None:
        self.logger = logger
        self._pending = ""

    def write(self, text: str) -> int:
        self._pending += text
        *lines, self._pending = self._pending.split("\n")
        for line in lines:
            if line.startswith("warning: "):
                self.logger.warning(line[len("warning: "):])
            elif line:
                self.logger.info(line)
        return len(text)

    def flush(self) -> None:
        pass

    def isatty(self) -> bool:
        return False


def _finite(value: Any) -> Any:
    """``value`` with every NaN or infinite float (also inside lists, tuples and dicts) as None."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    if hasattr(value, "item") and hasattr(value, "dtype") and getattr(value, "ndim", 1) == 0:  # numpy scalar
        return _finite(value.item())
    return value


def json_text(data: Any, *, indent: int | None = 2) -> str:
    """Strict JSON of ``data``: a figure without a value (NaN, e.g. the centre error of a frame
    with no match) is ``null``, as JSON has no NaN; numpy scalars as plain numbers."""
    return json.dumps(_finite(data), indent=indent, allow_nan=False)
