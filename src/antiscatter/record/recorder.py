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

from ..errors import UsageError
from ..writing import video_frames, write_failed

__all__ = ["Recorder", "RecorderFull", "pixel_format"]


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
    """Record frames losslessly to ``path`` (.mkv).

    fps: nominal frame rate written to the file.
    buffer_bytes: RAM for frames waiting to be encoded.
    overflow: ``spill`` (to a temporary file on disk, in order) or ``stop``.
    slices: FFV1 slices (parallel encoding); threads: encoder threads (0 = automatic).
    """

    def __init__(self, path: str | Path, *, fps: float = 30.0, buffer_bytes: int = 512 * 2 ** 20,
                 overflow: str = "spill", slices: int = 16, threads: int = 0) -> None:
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
        # clusters of at most a second, each written out as it ends: a recording cut short (a full
        # disk, a crash) loses at most that
        self.container = av.open(str(self.path), mode="w", format="matroska",
                                 options={"cluster_time_limit": "1000", "flush_packets": "1"})
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
    def write(self, image: np.ndarray) -> None:
        """Take one frame (copied: the caller may reuse its buffer)."""
        if isinstance(self._error, OSError):
            raise write_failed(self.path, self._error, f"recording stopped after {self.frames_in} frames")
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
                self._queue.append(np.array(image, copy=True, order="C"))
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
                self._queue.append(("spill", offset))
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
    def _next(self) -> np.ndarray | None:
        with self._cond:
            while not self._queue:
                if self._closing:
                    return None
                self._cond.wait(0.1)
            item = self._queue.popleft()
            if isinstance(item, tuple):
                _, offset = item
                self._spill.seek(offset)
                data = self._spill.read(int(np.prod(self.shape)))
                self._spilled -= 1
                return np.frombuffer(data, np.uint8).reshape(self.shape)
            self._queued_bytes -= item.nbytes
            return item

    def _encode_loop(self) -> None:
        av = self._av
        try:
            while True:
                image = self._next()
                if image is None:
                    break
                t0 = time.perf_counter()
                if self.stream is None:
                    stream = self.container.add_stream("ffv1", rate=self.fps)
                    stream.width, stream.height = image.shape[1], image.shape[0]
                    stream.pix_fmt = self.format[1]
                    stream.options = {"slices": str(self.slices), "slicecrc": "1", "level": "3"}
                    stream.thread_type = "AUTO"
                    if self.threads:
                        stream.thread_count = self.threads
                    self.stream = stream
                frame = av.VideoFrame.from_ndarray(image, format=self.format[0])
                for packet in self.stream.encode(frame):
                    self.container.mux(packet)
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
        if self._error is not None and not isinstance(self._error, OSError):
            raise RuntimeError(f"{self.path}: encoder failed ({self._error})")
        seconds = time.perf_counter() - self.started
        # no frame encoded: no file of ours (an existing one is left as it was, not counted)
        size = self.path.stat().st_size if self.stream is not None and self.path.exists() else 0
        frames = self.frames_encoded
        figures: dict = {}
        if self._error is not None:
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
