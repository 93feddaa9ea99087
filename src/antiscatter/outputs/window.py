"""Output ``window``: OpenCV windows (input, segmentation, projector pattern).

Needs a display and an OpenCV build with GUI support; ``e`` (or Esc) in a
window stops the run.
"""

from __future__ import annotations

import os

import cv2
import numpy as np

from ..detections import Detections
from ..errors import UsageError
from ..sources.base import Frame
from .base import LightOutput

__all__ = ["WindowOutput", "display_available"]


def display_available() -> bool:
    """True when a display is reachable and OpenCV can open windows."""
    if os.name == "posix" and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        return False
    try:
        cv2.namedWindow("antiscatter-probe", cv2.WINDOW_NORMAL)
        cv2.destroyWindow("antiscatter-probe")
    except cv2.error:
        return False
    return True


class WindowOutput(LightOutput):
    """Three windows: the input, the segmentation (red circles) and the pattern."""

    name = "window"

    def __init__(self) -> None:
        if os.name == "posix" and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
            raise UsageError("output 'window' needs a display (DISPLAY is not set); "
                             "use --output none, files:PATH or framebuffer")
        try:
            for title in ("input", "segmentation", "pattern"):
                cv2.namedWindow(title, cv2.WINDOW_NORMAL)
        except cv2.error:
            raise UsageError("output 'window' needs OpenCV with GUI support "
                             "(pip install opencv-contrib-python instead of opencv-contrib-python-headless)") from None

    def show(self, pattern: np.ndarray, frame: Frame | None = None,
             detections: Detections | None = None) -> None:
        if frame is not None:
            image = frame.image if frame.image.ndim == 3 else cv2.cvtColor(frame.image, cv2.COLOR_GRAY2BGR)
            overlay = image.copy()
            if detections is not None:
                for (x, y), r in zip(detections.centres.tolist(), detections.radii.tolist()):
                    cv2.circle(overlay, (int(round(x)), int(round(y))), max(int(round(r)), 1), (0, 0, 255), 1)
            cv2.imshow("input", image)
            cv2.imshow("segmentation", overlay)
        cv2.imshow("pattern", pattern)
        key = cv2.waitKey(1) & 0xFF
        if key in (ord("e"), 27):
            self.exit_requested = True

    def close(self) -> None:
        try:
            cv2.destroyAllWindows()
        except cv2.error:
            pass
