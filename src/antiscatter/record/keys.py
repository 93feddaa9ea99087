"""Single keys from the terminal (the report's l / r / e), without Enter, restored on close."""

from __future__ import annotations

import os
import queue
import select
import sys
import threading

__all__ = ["TerminalKeys"]


class TerminalKeys:
    """Read keys from stdin in cbreak mode in a background thread; ``poll()`` returns them.

    Does nothing (and ``active`` is False) when stdin is not a terminal.
    """

    def __init__(self) -> None:
        self.active = sys.stdin.isatty()
        self._keys: queue.Queue[str] = queue.Queue()
        self._stop = threading.Event()
        self._saved = None
        if not self.active:
            return
        import termios
        import tty

        self._fd = sys.stdin.fileno()
        self._saved = termios.tcgetattr(self._fd)
        tty.setcbreak(self._fd)
        self._thread = threading.Thread(target=self._read, name="antiscatter-keys", daemon=True)
        self._thread.start()

    def _read(self) -> None:
        while not self._stop.is_set():
            ready, _, _ = select.select([self._fd], [], [], 0.1)
            if ready:
                data = os.read(self._fd, 16).decode(errors="ignore")
                for key in data:
                    self._keys.put(key)

    def poll(self) -> list[str]:
        keys = []
        while True:
            try:
                keys.append(self._keys.get_nowait())
            except queue.Empty:
                return keys

    def close(self) -> None:
        if self._saved is not None:
            import termios

            self._stop.set()
            self._thread.join(timeout=1)
            termios.tcsetattr(self._fd, termios.TCSADRAIN, self._saved)
            self._saved = None
