"""Output ``files``: patterns to a folder of PNGs or to a lossless FFV1 video.

``files:DIR`` writes ``DIR/<frame>.png``; ``files:NAME.mkv`` writes one FFV1
grey video (PyAV), complete after a clean stop, Ctrl-C or SIGTERM.  A write that fails (a full
disk) stops the run with :class:`~antiscatter.errors.WriteError`, the folder holding whole PNGs
only and the video closed, readable up to its last frame on disk.
"""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import cv2
import numpy as np

from ..detections import Detections
from ..errors import UsageError, WriteError, check_output_folder, check_output_path
from ..sources.base import Frame
from ..writing import video_frames, write_failed, write_whole
from .base import LightOutput

__all__ = ["PngFolderOutput", "Ffv1Output", "open_files_output", "check_files_target"]


class PngFolderOutput(LightOutput):
    """One ``<frame>.png`` per pattern in ``folder`` (created if missing, when its own folder exists)."""

    name = "files"

    def __init__(self, folder: str | Path) -> None:
        self.folder = check_output_folder(folder, "output files:")
        self._next = 0  # the frame after the last pattern written
        self._written = 0  # images written whole
        try:
            self.folder.mkdir(exist_ok=True)
        except OSError as exc:
            raise UsageError(f"{self.folder}: cannot create the output folder ({exc.strerror})") from None

    def show(self, pattern: np.ndarray, frame: Frame | None = None,
             detections: Detections | None = None) -> None:
        index = frame.index if frame is not None else self._next
        self._next = index + 1
        self._write(self.folder / f"{index}.png", pattern)

    def flash(self, image: np.ndarray, before: int | None = None) -> None:
        """The light before frame N's capture (flash or pulse) goes to ``flash-N.png``."""
        self._write(self.folder / f"flash-{self._next if before is None else before}.png", image)

    def restore(self, pattern: np.ndarray) -> None:
        """The pattern put back after a capture is the last N.png already written: nothing new."""

    def _write(self, path: Path, image: np.ndarray) -> None:
        # encoded here and written whole: cv2.imwrite reports success for a file the disk cut short
        ok, data = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, 1])
        if not ok:
            raise ValueError(f"{path}: the pattern could not be encoded as PNG")
        try:
            write_whole(path, data.tobytes())
        except WriteError as exc:
            raise WriteError(f"{exc.what}; stopped, {self.folder} holds the {self._written} images before it, "
                             "whole") from None
        self._written += 1


class Ffv1Output(LightOutput):
    """Patterns encoded losslessly (FFV1, ``gray``) into a Matroska file."""

    name = "files"

    def __init__(self, path: str | Path, *, fps: float = 60.0) -> None:
        import av

        self.path = check_output_path(path, "output files:")
        self._av = av
        try:
            # clusters of at most a second, each written out as it ends: a run cut short (a full
            # disk, a crash) loses at most that
            self._container = av.open(str(self.path), mode="w", format="matroska",
                                      options={"cluster_time_limit": "1000", "flush_packets": "1"})
        except OSError as exc:
            raise UsageError(f"output files:{self.path}: cannot be written ({exc.strerror or exc})") from None
        self._fps = Fraction(fps).limit_denominator(1001) if fps > 0 else Fraction(60)
        self._stream = None
        self._frames = 0  # patterns handed to the encoder

    def show(self, pattern: np.ndarray, frame: Frame | None = None,
             detections: Detections | None = None) -> None:
        if self._container is None:  # closed after a failed write: the run is stopping
            return
        if self._stream is None:
            stream = self._container.add_stream("ffv1", rate=self._fps)
            stream.width = pattern.shape[1]
            stream.height = pattern.shape[0]
            stream.pix_fmt = "gray"
            self._stream = stream
        video_frame = self._av.VideoFrame.from_ndarray(np.ascontiguousarray(pattern), format="gray")
        try:
            for packet in self._stream.encode(video_frame):
                self._container.mux(packet)
        except OSError as exc:
            raise self._failed(exc) from None
        self._frames += 1

    def close(self) -> None:
        """Flush the encoder and finish the file; a write failing here raises WriteError, the file closed."""
        if self._container is None:
            return
        try:
            if self._stream is not None:
                for packet in self._stream.encode(None):
                    self._container.mux(packet)
            container, self._container = self._container, None
            container.close()  # the trailer; the file is released even when it cannot be written
        except OSError as exc:
            raise self._failed(exc) from None
        finally:
            self._release()

    def _release(self) -> None:
        """Close the container, whatever state a failed write left it in."""
        container, self._container = self._container, None
        if container is not None:
            try:
                container.close()
            except OSError:
                pass  # (the trailer could not be written: the file is read up to its last whole frame)

    def _failed(self, exc: OSError) -> Exception:
        """Close the file after a failed write; the one-line error with the frames it holds."""
        self._release()
        return write_failed(self.path, exc, f"the video holds {video_frames(self.path)} of "
                                            f"{self._frames} patterns")


def check_files_target(target: str) -> None:
    """Check ``files:`` output's target before any work: the video's folder exists and is writable,
    or the PNG folder is writable or can be made (one level: its own folder must exist)."""
    if not target:
        raise UsageError("output 'files' needs a target: files:DIR or files:NAME.mkv")
    if target.lower().endswith(".mkv"):
        check_output_path(target, "output files:")
    else:
        check_output_folder(target, "output files:")


def open_files_output(target: str, *, fps: float = 60.0) -> LightOutput:
    """``target`` ending in .mkv -> FFV1 video, anything else -> a PNG folder."""
    check_files_target(target)
    if target.lower().endswith(".mkv"):
        return Ffv1Output(target, fps=fps)
    return PngFolderOutput(target)
