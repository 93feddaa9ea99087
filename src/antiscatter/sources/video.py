"""A video file decoded by PyAV (FFmpeg; FFV1 .mkv included), each frame with its presentation time.

PyAV rather than OpenCV: it gives each frame's own timestamp (a variable-rate file keeps its
times) and decoded as fast or faster (docs/decisions/010-true-time.md).
"""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path
from typing import Any, Iterator

from ..detection import check_frame_size
from ..errors import UsageError
from .base import Frame, FrameSource

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
    """Frames of a video file (BGR), optionally cropped and looped, each with its time in the file.

    crop: (x0, x1, y0, y1) region kept, must lie inside the frame.
    loop: reopen at the end and play again; the times go on from the last pass's end (one frame
        period after its last frame), so they never run backwards.
    A frame's ``media_time_ns`` is its presentation time, pts times the stream's time base, ns
    (a variable-rate file keeps its own spacing); a frame without a pts is placed one nominal frame
    period after the last.  A file that ends before the frame count its container declares, short
    of its declared duration too, sets ``damaged``.
    """

    name = "video"

    def __init__(self, path: str | Path, *, crop: Crop | None = None, loop: bool = False) -> None:
        self.path = Path(path)
        self.loop = loop
        self._container = self._open()
        stream = self._container.streams.video[0]
        width, height = stream.codec_context.width, stream.codec_context.height
        rate = stream.average_rate or stream.guessed_rate
        self.fps = float(rate) if rate else 0.0
        if width <= 0 or height <= 0:
            self._container.close()
            raise UsageError(f"{self.path}: cannot be decoded as a video")
        if crop is not None:
            x0, x1, y0, y1 = crop
            if x1 > width or y1 > height:
                self._container.close()
                raise UsageError(f"--crop {x0}:{x1},{y0}:{y1}: outside the {width}x{height} frame of "
                                 f"{self.path} (allowed X1 <= {width}, Y1 <= {height})")
            self.size = (x1 - x0, y1 - y0)
        else:
            self.size = (width, height)
        try:
            check_frame_size(*self.size, what=f"{self.path}{' cropped by --crop' if crop is not None else ''}: frames",
                             error=UsageError)
        except UsageError:
            self._container.close()
            raise
        self.crop = crop
        self._count = 0
        self._decoded_this_pass = 0
        # the container's frame count (<= 0 unknown), else its duration at the nominal rate, as OpenCV counts
        duration = self._container.duration  # microseconds, None when unknown
        self._duration_ns = int(duration) * 1000 if duration else 0
        self._declared = stream.frames or (round(duration / 1e6 * self.fps) if duration and self.fps else 0)
        self._period_ns = int(round(1e9 / self.fps)) if self.fps else 0
        self._offset_ns = 0  # added to the file's times: the passes before this one (loop)
        self._last_ns: int | None = None  # the last frame's time in this pass, file clock
        self._first_ns: int | None = None  # the first frame's time in the file
        self._frames = self._decode()

    def _open(self) -> Any:
        import av

        try:
            container = av.open(str(self.path))
        except (av.FFmpegError, OSError):
            raise UsageError(f"{self.path}: cannot be opened as a video") from None
        if not container.streams.video:
            container.close()
            raise UsageError(f"{self.path}: cannot be decoded as a video")
        return container

    def _decode(self) -> Iterator[Any]:
        """The file's frames in presentation order; a decoding error ends them (a damaged file)."""
        import av

        stream = self._container.streams.video[0]
        try:
            yield from self._container.decode(stream)
        except av.FFmpegError:
            return

    def _next(self) -> Any:
        return next(self._frames, None)

    def read(self) -> Frame | None:
        decoded = self._next()
        if decoded is None:
            # ended short of the container's count (one frame's rounding allowed) and of its duration
            # (a variable-rate file's count is an estimate): cut short or damaged
            if (not self.damaged and self._count == self._decoded_this_pass < self._declared - 1
                    and (not self._duration_ns or self._last_ns is None or self._first_ns is None
                         or self._last_ns - self._first_ns < self._duration_ns - 2 * self._period_ns)):
                self.damaged = (f"{self.path}: ended after {self._decoded_this_pass} of the {self._declared} "
                                "frames its container declares (cut short or damaged); the frames read were used")
            if not self.loop or self._decoded_this_pass == 0:
                return None
            self._container.close()
            self._container = self._open()
            self._frames = self._decode()
            if self._last_ns is not None:
                self._offset_ns += self._last_ns + (self._period_ns or 1) - (self._first_ns or 0)
            self._decoded_this_pass = 0
            self._last_ns = None
            decoded = self._next()
            if decoded is None:
                return None
        self._decoded_this_pass += 1
        if decoded.pts is not None and decoded.time_base is not None:
            file_ns = round(decoded.pts * Fraction(decoded.time_base) * 1_000_000_000)
        else:  # no timestamp: a nominal period after the last frame
            file_ns = 0 if self._last_ns is None else self._last_ns + self._period_ns
        if self._first_ns is None:
            self._first_ns = file_ns
        self._last_ns = file_ns
        image = decoded.to_ndarray(format="bgr24")
        if self.crop is not None:
            x0, x1, y0, y1 = self.crop
            image = image[y0:y1, x0:x1]
        frame = Frame(image, self._count, self.now_ns(), media_time_ns=self._offset_ns + file_ns)
        self._count += 1
        return frame

    def close(self) -> None:
        self._container.close()
