"""What every frame source provides."""

from __future__ import annotations

import math
import os
import time
from contextlib import contextmanager
from dataclasses import dataclass
from typing import TYPE_CHECKING, Iterator

import cv2
import numpy as np

if TYPE_CHECKING:
    from ..detection import Pooled

__all__ = ["Frame", "FrameSource", "quiet_opencv", "frame_time_ns", "FrameClock", "seconds_text"]


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
    """One captured frame, with its time on two clocks (docs/decisions/010-true-time.md).

    image: (H, W, 3) BGR or (H, W) grey, uint8 (may be a view into a larger buffer).
    index: frame number from 0 in the order the source delivered them.
    timestamp_ns: when the frame was taken or read, on the ``time.monotonic_ns()`` clock: the
        middle of the exposure where the camera says when it exposed (the particles are seen where
        they were then), the time the frame was read otherwise.  The latency clock: compared with
        when its light went out.
    exposure_ns: how long the frame was exposed, 0 when unknown (a file, the simulator).
    pooled: the frame at the detector's working resolution, made by the camera's ISP (a ``lores``
        stream), which the runtime hands the detector in place of ``image``; None (default): none.
    media_time_ns: when the scene in the frame happened, ns, on the source's own clock: the
        camera's sensor clock (``CLOCK_MONOTONIC``, mid-exposure: ``timestamp_ns`` itself), a video
        file's presentation time (pts times its time base), the simulator's scene time (index over
        its rate), a webcam's read time.  A live source's is on the monotonic clock.  None
        (default): the source has no clock of its own (a folder of images): it is timed by its
        index and a rate (:func:`frame_time_ns`).  The tracker's clock and the time written
        beside the frame's results.
    analogue_gain: the sensor's analogue gain for this frame, 0.0 when unknown (not a camera).
    """

    image: np.ndarray
    index: int
    timestamp_ns: int
    exposure_ns: int = 0
    pooled: Pooled | None = None
    media_time_ns: int | None = None
    analogue_gain: float = 0.0

    @property
    def exposure_start_ns(self) -> int:
        """When the exposure began (``timestamp_ns`` when its length is unknown)."""
        return self.timestamp_ns - self.exposure_ns // 2


def frame_time_ns(frame: Frame, period_ns: float) -> int:
    """The frame's true time, ns: its ``media_time_ns``, else (no clock of its own: a folder of
    images) its index times ``period_ns``, the frame period the run assumes for it."""
    return frame.media_time_ns if frame.media_time_ns is not None else round(frame.index * period_ns)


def seconds_text(ns: int) -> str:
    """``ns`` nanoseconds as exact decimal seconds (``1733621000.123456789``): a UNIX time in ns
    does not fit a float's 53 bits."""
    sign, ns = ("-", -ns) if ns < 0 else ("", ns)
    return f"{sign}{ns // 1_000_000_000}.{ns % 1_000_000_000:09d}"


class FrameClock:
    """A frame's true time, ns: what the run's CSVs and MCAP messages carry (one rule for all).

    live: the frames' times are on the monotonic clock (a camera's sensor time, mid-exposure):
        they are mapped to UNIX time by the offset between the two clocks, read once here, so they
        line up with other logs (a vehicle's navigation) kept on the system's clock.
    interval_s: for a source that is not live, the frame period assumed where a frame has no time
        of its own (a folder of images: frame ``i`` at ``i * interval_s``); files and the simulator
        keep their own times (a video's presentation time, the scene's time), from 0 on their clock.
    """

    def __init__(self, *, live: bool, interval_s: float) -> None:
        if not live and not (math.isfinite(interval_s) and interval_s > 0):
            raise ValueError(f"interval_s: got {interval_s}, allowed a number > 0 for a source that is not live")
        self.live = live
        self.interval_s = interval_s
        self.offset_ns = time.time_ns() - time.monotonic_ns() if live else 0

    def source_ns(self, frame: Frame) -> int:
        """The true time of ``frame`` on its source's clock, ns: the monotonic clock for a live source
        (its ``timestamp_ns``: a camera's mid-exposure), :func:`frame_time_ns` otherwise."""
        if self.live:
            return int(frame.timestamp_ns)
        return frame_time_ns(frame, self.interval_s * 1e9)

    def stamp_ns(self, frame: Frame) -> int:
        """The true time of ``frame`` as written, ns: UNIX time for a live source, its source's own otherwise."""
        return self.source_ns(frame) + self.offset_ns


class FrameSource:
    """Base of every source: ``read()`` until it returns ``None`` (the source ended).

    Sources are context managers; ``close()`` releases devices and files.
    A source that fails mid-run raises :class:`~antiscatter.errors.UsageError`
    (bad data) or ``RuntimeError`` (device failure) naming the frame.
    """

    name: str = "source"
    size: tuple[int, int] = (0, 0)  # (width, height) of delivered frames
    fps: float = 0.0  # nominal rate, 0 when unknown
    live: bool = False  # frames come whether or not they are taken (a camera): may be dropped; their
    # media_time_ns is then on the monotonic clock
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
