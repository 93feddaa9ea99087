"""The built-in simulator as a live source (frames in memory, no files)."""

from __future__ import annotations

import numpy as np

from ..simulate import make_scene
from .base import Frame, FrameSource

__all__ = ["SimulatorSource"]


class SimulatorSource(FrameSource):
    """Frames of a simulator preset, deterministic for a seed.

    preset: simulator preset name (``seed`` is the report's bubble model).
    seed: seed of the numpy Generator driving the scene.
    size: (width, height), the preset's own when None.
    Each frame's ``media_time_ns`` is the scene's own time (frame ``i`` at ``i / fps`` s), however
    fast the frames are drawn.
    """

    name = "sim"
    synthetic = True

    def __init__(self, *, preset: str = "seed", seed: int = 0,
                 size: tuple[int, int] | None = None) -> None:
        self.scene = make_scene(preset, rng=np.random.default_rng(seed), size=size)
        self.size = self.scene.size
        self.fps = self.scene.fps
        self._count = 0

    def read(self) -> Frame | None:
        if self._count > 0:
            self.scene.step()
        image = self.scene.render()
        frame = Frame(image, self._count, self.now_ns(), media_time_ns=round(self._count * 1e9 / self.fps))
        self._count += 1
        return frame
