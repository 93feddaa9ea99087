"""What every light output provides."""

from __future__ import annotations

import numpy as np

from ..detections import Detections
from ..sources.base import Frame

__all__ = ["LightOutput"]


class LightOutput:
    """Base of every light output.

    ``show(pattern, frame, detections)`` hands one projector pattern ((H, W)
    uint8, 255 = light) to the output; ``flash(image)`` the light shown for a
    capture (detection flash or pulse) and ``restore(pattern)`` the pattern
    put back after it; ``exit_requested`` turns true when the
    user asked to stop from the output (``e`` in a window); ``close()`` leaves
    files complete and devices released.  Outputs are context managers.
    """

    name: str = "output"
    exit_requested: bool = False

    def show(self, pattern: np.ndarray, frame: Frame | None = None,
             detections: Detections | None = None) -> None:
        raise NotImplementedError

    def flash(self, image: np.ndarray, before: int | None = None) -> None:
        """Show the light for the next exposure: the uniform detection flash (``light.strategy =
        "flash"``) or the last pattern with its holes lifted (``"pulse"``); by default like a pattern.
        before: the index of the frame it lights, when the caller knows it (a locked camera's loop
        shows it after the frame before is read); else the frame after the last pattern shown."""
        self.show(image)

    def restore(self, pattern: np.ndarray) -> None:
        """The exposure is over: show the last pattern again; by default like a pattern."""
        self.show(pattern)

    def close(self) -> None:
        pass

    def __enter__(self) -> "LightOutput":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class NullOutput(LightOutput):
    """Output ``none``: discards the pattern (benchmarks, headless runs)."""

    name = "none"

    def show(self, pattern: np.ndarray, frame: Frame | None = None,
             detections: Detections | None = None) -> None:
        return None
