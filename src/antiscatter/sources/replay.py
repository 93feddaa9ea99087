"""Frames replayed from memory: a stand-in for a camera whose frames cost nothing to capture."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from .base import Frame, FrameSource

__all__ = ["ReplaySource"]


class ReplaySource(FrameSource):
    """Cycle through ``images`` (each (H, W, 3) or (H, W) uint8), ``frames`` times in all.

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
        self._count = 0

    def read(self) -> Frame | None:
        if self._count >= self.frames:
            return None
        frame = Frame(self.images[self._count % len(self.images)], self._count, self.now_ns())
        self._count += 1
        return frame
