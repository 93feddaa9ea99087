"""A video file decoded by OpenCV's FFmpeg backend (FFV1 .mkv included)."""

from __future__ import annotations

from pathlib import Path

import cv2

from ..detection import check_frame_size
from ..errors import UsageError
from .base import Frame, FrameSource, quiet_opencv

__all__ = ["VideoSource", "Crop", "parse_crop"]

Crop = tuple[int, int, int, int]  # x0, x1, y0, y1 (half-open, pixels)


def parse_crop(text: str) -> Crop:
    """``"X0:X1,Y0:Y1"`` -> (x0, x1, y0, y1); columns X0..X1-1, rows Y0..Y1-1."""
    try:
        xs, ys = text.split(",")
        x0, x1 = (int(v) for v in xs.split(":"))
        y0, y1 = (int(v) for v in ys.split(":"))
    except ValueError:
        raise UsageError(f"--crop {text!r}: expected X0:X1,Y0:Y1 with integers, e.g. 430:700,0:320") from None
    if x0 < 0 or y0 < 0 or x1 <= x0 or y1 <= y0:
        raise UsageError(f"--crop {text!r}: need 0 <= X0 < X1 and 0 <= Y0 < Y1")
    return x0, x1, y0, y1


class VideoSource(FrameSource):
    """Frames of a video file, optionally cropped and looped.

    crop: (x0, x1, y0, y1) region kept, must lie inside the frame.
    loop: reopen at the end and play again.
    A file that ends before the frame count its container declares sets ``damaged``.
    """

    name = "video"

    def __init__(self, path: str | Path, *, crop: Crop | None = None, loop: bool = False) -> None:
        self.path = Path(path)
        self.loop = loop
        self._cap = self._open()
        width = int(self._cap.get(cv2.CAP_PROP_FRAME_WIDTH))
        height = int(self._cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        self.fps = float(self._cap.get(cv2.CAP_PROP_FPS) or 0.0)
        if width <= 0 or height <= 0:
            self._cap.release()
            raise UsageError(f"{self.path}: cannot be decoded as a video")
        if crop is not None:
            x0, x1, y0, y1 = crop
            if x1 > width or y1 > height:
                self._cap.release()
                raise UsageError(f"--crop {x0}:{x1},{y0}:{y1}: outside the {width}x{height} frame of "
                                 f"{self.path} (allowed X1 <= {width}, Y1 <= {height})")
            self.size = (x1 - x0, y1 - y0)
        else:
            self.size = (width, height)
        try:
            check_frame_size(*self.size, what=f"{self.path}{' cropped by --crop' if crop is not None else ''}: frames",
                             error=UsageError)
        except UsageError:
            self._cap.release()
            raise
        self.crop = crop
        self._count = 0
        self._decoded_this_pass = 0
        self._declared = int(self._cap.get(cv2.CAP_PROP_FRAME_COUNT))  # the container's count; <= 0 unknown

    def _open(self) -> cv2.VideoCapture:
        with quiet_opencv():
            cap = cv2.VideoCapture(str(self.path), cv2.CAP_FFMPEG)
        if not cap.isOpened():
            raise UsageError(f"{self.path}: cannot be opened as a video")
        return cap

    def read(self) -> Frame | None:
        ok, image = self._cap.read()
        if not ok:
            # ended short of the container's count (one frame's rounding allowed): cut short or damaged
            if not self.damaged and self._count == self._decoded_this_pass < self._declared - 1:
                self.damaged = (f"{self.path}: ended after {self._decoded_this_pass} of the {self._declared} "
                                "frames its container declares (cut short or damaged); the frames read were used")
            if not self.loop or self._decoded_this_pass == 0:
                return None
            self._cap.release()
            self._cap = self._open()
            self._decoded_this_pass = 0
            ok, image = self._cap.read()
            if not ok:
                return None
        self._decoded_this_pass += 1
        if self.crop is not None:
            x0, x1, y0, y1 = self.crop
            image = image[y0:y1, x0:x1]
        frame = Frame(image, self._count, self.now_ns())
        self._count += 1
        return frame

    def close(self) -> None:
        self._cap.release()
