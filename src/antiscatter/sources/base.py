"""What every frame source provides."""

from __future__ import annotations

import os
import time
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Iterator

import cv2
import numpy as np

__all__ = ["Frame", "FrameSource", "quiet_opencv"]


@contextmanager
def quiet_opencv(*, errors: bool = False) -> Iterator[None]:
    """Silence OpenCV's own warnings (device probing) so errors stay one line; ``errors``: its
    error messages too (a file it cannot decode: ours names the file and says so).  FFmpeg's log
    lines inside OpenCV (a damaged file's) are silenced for the process when this runs before its
    first video is opened: the source says what it found instead (set OPENCV_FFMPEG_LOGLEVEL to see them)."""
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")  # AV_LOG_QUIET, read once by OpenCV's FFmpeg
    # cv2.utils.logging where the wheel has it (5.x); else the top-level calls (4.11, for numpy 1.24)
    logging = getattr(cv2.utils, "logging", cv2)
    previous = logging.getLogLevel()
    logging.setLogLevel(0 if errors else 2)  # LOG_LEVEL_SILENT, LOG_LEVEL_ERROR
    try:
        yield
    finally:
        logging.setLogLevel(previous)


@dataclass(frozen=True, eq=False)
class Frame:
    """One captured frame.

    image: (H, W, 3) BGR or (H, W) grey, uint8 (may be a view into a larger buffer).
    index: frame number from 0 in the order the source delivered them.
    timestamp_ns: capture time on the ``time.monotonic_ns()`` clock: the middle of the
        exposure where the camera says when it exposed (the particles are seen where they were
        then), the time the frame was read otherwise.
    exposure_ns: how long the frame was exposed, 0 when unknown (a file, the simulator).
    """

    image: np.ndarray
    index: int
    timestamp_ns: int
    exposure_ns: int = 0

    @property
    def exposure_start_ns(self) -> int:
        """When the exposure began (``timestamp_ns`` when its length is unknown)."""
        return self.timestamp_ns - self.exposure_ns // 2


class FrameSource:
    """Base of every source: ``read()`` until it returns ``None`` (the source ended).

    Sources are context managers; ``close()`` releases devices and files.
    A source that fails mid-run raises :class:`~antiscatter.errors.UsageError`
    (bad data) or ``RuntimeError`` (device failure) naming the frame.
    """

    name: str = "source"
    size: tuple[int, int] = (0, 0)  # (width, height) of delivered frames
    fps: float = 0.0  # nominal rate, 0 when unknown
    live: bool = False  # frames come whether or not they are taken (a camera): may be dropped
    synthetic: bool = False  # frames are drawn when read (the simulator): their drawing is not timed as capture
    damaged: str = ""  # why the source ended before its declared end (a file cut short), "" when it did not

    def read(self) -> Frame | None:
        raise NotImplementedError

    def close(self) -> None:
        pass

    def __enter__(self) -> "FrameSource":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @staticmethod
    def now_ns() -> int:
        return time.monotonic_ns()
