"""An OpenCV capture device (``webcam:N``), for laptops."""

from __future__ import annotations

import cv2

from ..errors import UsageError
from .base import Frame, FrameSource, quiet_opencv

__all__ = ["WebcamSource"]


class WebcamSource(FrameSource):
    """Frames from capture device ``index`` (``/dev/videoN`` on Linux)."""

    name = "webcam"
    live = True

    def __init__(self, index: int, *, size: tuple[int, int] | None = None) -> None:
        self.index = index
        with quiet_opencv(errors=True):  # OpenCV 4.x logs a missing device as an error: ours says it below
            self._cap = cv2.VideoCapture(index)
        if not self._cap.isOpened():
            raise UsageError(f"webcam:{index}: no capture device {index} could be opened")
        if size is not None:
            self._cap.set(cv2.CAP_PROP_FRAME_WIDTH, size[0])
            self._cap.set(cv2.CAP_PROP_FRAME_HEIGHT, size[1])
        self.size = (int(self._cap.get(cv2.CAP_PROP_FRAME_WIDTH)),
                     int(self._cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
        self.fps = float(self._cap.get(cv2.CAP_PROP_FPS) or 0.0)
        self._count = 0

    def read(self) -> Frame | None:
        ok, image = self._cap.read()
        if not ok:
            raise RuntimeError(f"webcam:{self.index}: the device stopped delivering frames")
        stamp = self.now_ns()  # read time: the device's own is not known here
        frame = Frame(image, self._count, stamp, media_time_ns=stamp)
        self._count += 1
        return frame

    def close(self) -> None:
        self._cap.release()
