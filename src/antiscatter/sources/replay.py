"""Frames replayed from memory: a stand-in for a camera whose frames cost nothing to capture."""

from __future__ import annotations

import time
from typing import Sequence

import numpy as np

from .base import Frame, FrameSource

__all__ = ["ReplaySource"]


class ReplaySource(FrameSource):
    """Cycle through ``images`` (each (H, W, 3) or (H, W) uint8), ``frames`` times in all.

    fps = 0: frames are handed out at once, none is ever lost (like a file).
    fps > 0: behaves like a free-running camera with ``queue=False``: exposures
    complete every 1/fps seconds whether or not anyone reads, and ``read``
    blocks until the next one completes (the GIL is released while waiting);
    the frame's timestamp is that completion time.  Exposures nobody waited
    for are lost, as on the real camera.

    Used by ``bench --modes`` so that the modes are compared on the pipeline,
    not on how fast the simulator draws.
    """

    name = "replay"

    def __init__(self, images: Sequence[np.ndarray], *, frames: int, fps: float = 0.0) -> None:
        if not images:
            raise ValueError("images: got none, allowed one or more frames")
        self.images = list(images)
        self.frames = frames
        self.size = (self.images[0].shape[1], self.images[0].shape[0])
        self.fps = fps
        self.live = fps > 0
        self._period_ns = int(round(1e9 / fps)) if fps > 0 else 0
        self._start_ns: int | None = None
        self._count = 0

    def read(self) -> Frame | None:
        if self._count >= self.frames:
            return None
        stamp = self.now_ns()
        if self._period_ns:
            if self._start_ns is None:
                self._start_ns = stamp
            k = (stamp - self._start_ns) // self._period_ns + 1  # the next exposure to complete
            stamp = self._start_ns + k * self._period_ns
            delay = stamp - self.now_ns()
            if delay > 0:
                time.sleep(delay / 1e9)
        frame = Frame(self.images[self._count % len(self.images)], self._count, stamp,
                      media_time_ns=stamp if self.live else None)
        self._count += 1
        return frame
