"""Output ``files``: patterns to a folder of PNGs or to a lossless FFV1 video.

``files:DIR`` writes ``DIR/<frame>.png``; ``files:NAME.mkv`` writes one FFV1
grey video (PyAV), complete after a clean stop, Ctrl-C or SIGTERM.
"""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import cv2
import numpy as np

from ..detections import Detections
from ..errors import UsageError
from ..sources.base import Frame
from .base import LightOutput

__all__ = ["PngFolderOutput", "Ffv1Output", "open_files_output"]


class PngFolderOutput(LightOutput):
    """One ``<frame>.png`` per pattern in ``folder`` (created if missing)."""

    name = "files"

    def __init__(self, folder: str | Path) -> None:
        self.folder = Path(folder)
        self._next = 0  # the frame after the last pattern written
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
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

    @staticmethod
    def _write(path: Path, image: np.ndarray) -> None:
        if not cv2.imwrite(str(path), image, [cv2.IMWRITE_PNG_COMPRESSION, 1]):
            raise OSError(f"{path}: could not be written")


class Ffv1Output(LightOutput):
    """Patterns encoded losslessly (FFV1, ``gray``) into a Matroska file."""

    name = "files"

    def __init__(self, path: str | Path, *, fps: float = 60.0) -> None:
        import av

        self.path = Path(path)
        if not self.path.parent.is_dir():
            raise UsageError(f"{self.path}: the folder {self.path.parent} does not exist")
        self._av = av
        self._container = av.open(str(self.path), mode="w", format="matroska")
        self._fps = Fraction(fps).limit_denominator(1001) if fps > 0 else Fraction(60)
        self._stream = None

    def show(self, pattern: np.ndarray, frame: Frame | None = None,
             detections: Detections | None = None) -> None:
        if self._stream is None:
            stream = self._container.add_stream("ffv1", rate=self._fps)
            stream.width = pattern.shape[1]
            stream.height = pattern.shape[0]
            stream.pix_fmt = "gray"
            self._stream = stream
        video_frame = self._av.VideoFrame.from_ndarray(np.ascontiguousarray(pattern), format="gray")
        for packet in self._stream.encode(video_frame):
            self._container.mux(packet)

    def close(self) -> None:
        if self._container is None:
            return
        try:
            if self._stream is not None:
                for packet in self._stream.encode(None):
                    self._container.mux(packet)
        finally:
            self._container.close()
            self._container = None


def open_files_output(target: str, *, fps: float = 60.0) -> LightOutput:
    """``target`` ending in .mkv -> FFV1 video, anything else -> a PNG folder."""
    if not target:
        raise UsageError("output 'files' needs a target: files:DIR or files:NAME.mkv")
    if target.lower().endswith(".mkv"):
        return Ffv1Output(target, fps=fps)
    return PngFolderOutput(target)
