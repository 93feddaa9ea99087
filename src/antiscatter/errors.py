"""Errors that reach the user as one line and exit code 2."""

from __future__ import annotations

__all__ = ["UsageError"]


class UsageError(Exception):
    """Bad input (a file, a config key, a value): shown as one line, exit code 2.

    The message names the file, key or value and says what is allowed.
    """
