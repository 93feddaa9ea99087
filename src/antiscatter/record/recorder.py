"""A lossless FFV1 recorder that never drops a frame silently.

Frames go into a bounded RAM buffer; a worker thread encodes them with PyAV
(FFV1 in Matroska, in-process, sliced so libavcodec uses several cores).  The
pixel format keeps what the source gives: ``gray`` for a grey / Y-plane frame,
``bgr0`` for BGR (FFV1 has no ``bgr24``).  When the buffer is full, the
``overflow`` policy decides: ``spill`` keeps frames in order in a temporary
file on disk until the encoder catches up, ``stop`` stops recording with a
message (``RecorderFull``).  ``close()`` encodes every frame taken and closes
the container, so a run stopped by Ctrl-C or SIGTERM leaves a valid file.  A full disk
(the file's, or the spill file's in ``TMPDIR``) stops the recording: ``write`` raises
:class:`~antiscatter.errors.WriteError`, and ``close()`` still closes the file and counts the
frames it holds.

Each frame keeps its true time: the caller gives it (a camera's sensor time, a file's presentation
time, the simulator's scene time; constant-rate when not given) and it becomes the frame's
Matroska timestamp, from the first frame, in the stream's time base (1 ms: FFmpeg's Matroska
muxer), and a row of the sidecar CSV beside the recording (:func:`sidecar_path`) with the time to
the nanosecond, the exposure and the gain (docs/decisions/010-true-time.md).
"""

from __future__ import annotations

import collections
import tempfile
import threading
import time
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import UsageError, WriteError
from ..writing import CsvFile, video_frames, write_failed

__all__ = ["Recorder", "RecorderFull", "pixel_format", "sidecar_path", "SIDECAR_COLUMNS", "TIME_BASE"]

#: the recording's stream time base, seconds per tick: FFmpeg's Matroska muxer keeps 1 ms whatever it is given
TIME_BASE = Fraction(1, 1000)

#: the sidecar CSV's columns: the frame's number in the recording; its Matroska timestamp (ticks of
#: ``TIME_BASE`` from the first frame); its true time, ns, on its source's clock; that time as UNIX
#: time, ns (a live source's monotonic clock mapped when the recording began; empty otherwise); the
#: exposure, microseconds, and the analogue gain (empty when unknown)
SIDECAR_COLUMNS = ("frame", "pts", "time_ns", "unix_time_ns", "exposure_us", "analogue_gain")


def sidecar_path(path: str | Path) -> Path:
    """The sidecar CSV of recording ``path``: ``clip.mkv`` -> ``clip.frames.csv`` beside it."""
    path = Path(path)
    return path.with_name(f"{path.stem}.frames.csv")


class RecorderFull(RuntimeError):
    """The RAM buffer is full and the overflow policy is ``stop``."""


def pixel_format(image: np.ndarray) -> tuple[str, str]:
    """(numpy-side format, FFV1 pixel format) that keep what ``image`` holds."""
    if image.ndim == 2:
        return "gray", "gray"
    if image.ndim == 3 and image.shape[2] == 3:
        return "bgr24", "bgr0"
    raise ValueError(f"image: got shape {image.shape}, allowed (H, W) grey or (H, W, 3) BGR")


class Recorder:
    """Record frames losslessly to ``path`` (.mkv), with their times in a sidecar CSV.

    fps: nominal frame rate written to the file, and the frames' spacing when no time is given.
    buffer_bytes: RAM for frames waiting to be encoded.
    overflow: ``spill`` (to a temporary file on disk, in order) or ``stop``.
    slices: FFV1 slices (parallel encoding); threads: encoder threads (0 = automatic).
    unix_offset_ns: UNIX time less the frames' clock, ns, when that clock is the system's monotonic
        one (a live source: ``time.time_ns() - time.monotonic_ns()``), for the sidecar's
        ``unix_time_ns``; None (default): the frames' clock is their own (a file, the simulator).
    """

    def __init__(self, path: str | Path, *, fps: float = 30.0, buffer_bytes: int = 512 * 2 ** 20,
                 overflow: str = "spill", slices: int = 16, threads: int = 0,
                 unix_offset_ns: int | None = None) -> None:
        import av

        self.path = Path(path)
        if self.path.suffix.lower() != ".mkv":
            raise UsageError(f"{self.path}: allowed a .mkv file (FFV1 in Matroska)")
        if not self.path.parent.is_dir():
            raise UsageError(f"{self.path}: the folder {self.path.parent} does not exist")
        if overflow not in ("spill", "stop"):
            raise UsageError(f"--overflow {overflow!r}: allowed spill, stop")
        self._av = av
        self.fps = Fraction(fps).limit_denominator(1001) if fps > 0 else Fraction(30)
        self.buffer_bytes = buffer_bytes
        self.overflow = overflow
        self.slices, self.threads = slices, threads
        self.unix_offset_ns = unix_offset_ns
        self.sidecar = sidecar_path(self.path)
        self._first_ns: int | None = None  # the first frame's time: pts 0
        self._last_pts = -1
        # clusters of at most a second, each written out as it ends: a recording cut short (a full
        # disk, a crash) loses at most that
        self.container = av.open(str(self.path), mode="w", format="matroska",
                                 options={"cluster_time_limit": "1000", "flush_packets": "1"})
        try:
            self._times = CsvFile(self.sidecar, SIDECAR_COLUMNS)
        except OSError as exc:
            self.container.close()
            raise UsageError(f"{self.sidecar}: cannot be written ({exc.strerror or exc})") from None
        self.stream: Any = None
        self.shape: tuple[int, ...] | None = None
        self.format = ("", "")
        self._queue: collections.deque = collections.deque()  # arrays, or ("spill", offset) markers
        self._queued_bytes = 0
        self._spill: Any = None
        self._spilled = 0
        self._cond = threading.Condition()
        self._closing = False
        self._error: BaseException | None = None
        self.frames_in = 0
        self.frames_encoded = 0
        self.frames_spilled = 0
        self.started = time.perf_counter()
        self.encode_seconds = 0.0
        self._worker = threading.Thread(target=self._encode_loop, name="antiscatter-encoder", daemon=True)
        self._worker.start()

    # ------------------------------------------------------------ producer
    def write(self, image: np.ndarray, *, time_ns: int | None = None, exposure_ns: int = 0,
              analogue_gain: float = 0.0) -> None:
        """Take one frame (copied: the caller may reuse its buffer).

        time_ns: the frame's true time, ns, on its source's clock (``Frame.media_time_ns``); None:
        ``fps`` after the last.  exposure_ns: its exposure, ns (0 unknown); analogue_gain: its gain
        (0 unknown).  Both go to the sidecar.
        """
        if time_ns is None:
            time_ns = (self._first_ns or 0) + round(Fraction(self.frames_in * 1_000_000_000) / self.fps)
        if self._first_ns is None:
            self._first_ns = int(time_ns)
        meta = (int(time_ns), int(exposure_ns), float(analogue_gain))
        if isinstance(self._error, OSError):
            raise write_failed(self.path, self._error, f"recording stopped after {self.frames_in} frames")
        if isinstance(self._error, WriteError):  # the sidecar's disk is full
            error = WriteError(f"{self._error.what}; stopped, recording stopped after {self.frames_in} frames")
            error.what, error.reason = self._error.what, self._error.reason
            raise error
        if self._error is not None:
            raise RuntimeError(f"{self.path}: encoder failed ({self._error})")
        if self.shape is None:
            self.shape = image.shape
            self.format = pixel_format(image)
        elif image.shape != self.shape:
            raise ValueError(f"frame {self.frames_in}: shape {image.shape} differs from {self.shape}")
        with self._cond:
            spilling = self._spilled > 0
            if not spilling and self._queued_bytes + image.nbytes <= self.buffer_bytes:
                self._queue.append((np.array(image, copy=True, order="C"), meta))
                self._queued_bytes += image.nbytes
            elif self.overflow == "spill":
                if self._spill is None:
                    self._spill = tempfile.TemporaryFile(prefix="antiscatter-spill-")
                offset = self._spill.seek(0, 2)
                try:
                    self._spill.write(np.ascontiguousarray(image).tobytes())
                    self._spill.flush()
                except OSError as exc:  # TMPDIR is full: the frames taken so far are still encoded
                    self._spill_failed(offset)
                    raise write_failed(f"the spill file in {tempfile.gettempdir()}", exc,
                                       f"recording stopped after {self.frames_in} frames") from None
                self._queue.append((offset, meta))
                self._spilled += 1
                self.frames_spilled += 1
            else:
                raise RecorderFull(f"{self.path}: the {self.buffer_bytes / 2 ** 20:.0f} MiB frame buffer is full "
                                   f"(the encoder is slower than the camera); recording stopped after "
                                   f"{self.frames_in} frames")
            self.frames_in += 1
            self._cond.notify()

    def _spill_failed(self, offset: int) -> None:
        """Cut the spill file back to its whole frames after a failed write (the caller holds the lock)."""
        try:
            self._spill.truncate(offset)
            self._spill.seek(offset)
        except (OSError, ValueError):
            pass

    # ------------------------------------------------------------ consumer
    def _next(self) -> tuple[np.ndarray, tuple[int, int, float]] | None:
        """The next frame to encode and its (time ns, exposure ns, gain); None once closing and empty."""
        with self._cond:
            while not self._queue:
                if self._closing:
                    return None
                self._cond.wait(0.1)
            item, meta = self._queue.popleft()
            if isinstance(item, int):  # an offset in the spill file
                self._spill.seek(item)
                data = self._spill.read(int(np.prod(self.shape)))
                self._spilled -= 1
                return np.frombuffer(data, np.uint8).reshape(self.shape), meta
            self._queued_bytes -= item.nbytes
            return item, meta

    def _pts(self, time_ns: int) -> int:
        """The Matroska timestamp of a frame at ``time_ns``: ``TIME_BASE`` ticks from the first frame,
        one tick after the last where the clock did not move on by one (a frame must follow the last)."""
        ticks = round(Fraction(time_ns - (self._first_ns or 0), 1_000_000_000) / TIME_BASE)
        self._last_pts = max(ticks, self._last_pts + 1)
        return self._last_pts

    def _encode_loop(self) -> None:
        av = self._av
        try:
            while True:
                item = self._next()
                if item is None:
                    break
                image, (time_ns, exposure_ns, gain) = item
                t0 = time.perf_counter()
                if self.stream is None:
                    stream = self.container.add_stream("ffv1", rate=self.fps)
                    stream.codec_context.time_base = TIME_BASE
                    stream.width, stream.height = image.shape[1], image.shape[0]
                    stream.pix_fmt = self.format[1]
                    stream.options = {"slices": str(self.slices), "slicecrc": "1", "level": "3"}
                    stream.thread_type = "AUTO"
                    if self.threads:
                        stream.thread_count = self.threads
                    self.stream = stream
                frame = av.VideoFrame.from_ndarray(image, format=self.format[0])
                frame.pts, frame.time_base = self._pts(time_ns), TIME_BASE
                for packet in self.stream.encode(frame):
                    self.container.mux(packet)
                unix = "" if self.unix_offset_ns is None else time_ns + self.unix_offset_ns
                self._times.writerow((self.frames_encoded, frame.pts, time_ns, unix,
                                      f"{exposure_ns / 1e3:g}" if exposure_ns else "",
                                      f"{gain:g}" if gain else ""))
                self.frames_encoded += 1
                self.encode_seconds += time.perf_counter() - t0
        except BaseException as exc:  # noqa: BLE001 - reported to the producer and at close
            self._error = exc

    def close(self) -> dict[str, float]:
        """Encode everything taken, finish the file; returns the summary figures.

        After a write the disk refused, the file is closed all the same and ``frames`` counts the
        frames it holds (readable up to there); ``error`` then says what failed.
        """
        with self._cond:
            self._closing = True
            self._cond.notify_all()
        self._worker.join()
        try:
            if self.stream is not None and self._error is None:
                for packet in self.stream.encode(None):
                    self.container.mux(packet)
        except OSError as exc:
            self._error = exc
        finally:
            try:
                self.container.close()  # (releases the file even when the trailer cannot be written)
            except OSError as exc:
                self._error = self._error or exc
            if self._spill is not None:
                self._spill.close()
            self._times.close()
            if self.frames_encoded == 0 and self._error is None:  # nothing recorded: no sidecar either
                self.sidecar.unlink(missing_ok=True)
        if self._error is not None and not isinstance(self._error, (OSError, WriteError)):
            raise RuntimeError(f"{self.path}: encoder failed ({self._error})")
        seconds = time.perf_counter() - self.started
        # no frame encoded: no file of ours (an existing one is left as it was, not counted)
        size = self.path.stat().st_size if self.stream is not None and self.path.exists() else 0
        frames = self.frames_encoded
        figures: dict = {}
        if isinstance(self._error, WriteError):  # the sidecar's disk filled: the video stopped with it
            frames = video_frames(self.path) if self.stream is not None else 0
            figures["error"] = getattr(self._error, "reason", str(self._error))
            figures["failed"] = str(self.sidecar)  # the file that failed (the video's otherwise)
        elif self._error is not None:
            frames = video_frames(self.path) if self.stream is not None else 0
            figures["error"] = f"{self._error.strerror or self._error}"
        figures = {"frames": frames, "dropped": self.frames_in - frames,
                   "spilled": self.frames_spilled, "bytes": size, "seconds": seconds,
                   "encode_fps": self.frames_encoded / self.encode_seconds if self.encode_seconds else 0.0,
                   **figures}
        return figures

    def __enter__(self) -> "Recorder":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
