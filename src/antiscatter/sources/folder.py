"""A folder of ``<int>.png`` frames, in natural numeric order."""

from __future__ import annotations

import re
from pathlib import Path

import cv2

from ..errors import UsageError
from .base import Frame, FrameSource

__all__ = ["FolderSource", "list_frames"]

_FRAME_NAME = re.compile(r"^(\d+)\.png$", re.IGNORECASE)


def list_frames(folder: Path) -> list[Path]:
    """The ``<int>.png`` files of ``folder`` sorted by their number (2 before 10)."""
    numbered = []
    for path in folder.iterdir():
        match = _FRAME_NAME.match(path.name)
        if match and path.is_file():
            numbered.append((int(match.group(1)), path))
    numbered.sort()
    return [path for _, path in numbered]


class FolderSource(FrameSource):
    """Frames read from ``<int>.png`` files; other files are ignored.

    loop: start again from the first frame after the last.
    """

    name = "folder"

    def __init__(self, folder: str | Path, *, loop: bool = False) -> None:
        self.folder = Path(folder)
        self.paths = list_frames(self.folder)
        if not self.paths:
            raise UsageError(f"{self.folder}: no frames named <int>.png in this folder")
        self.loop = loop
        self._next = 0
        self._count = 0
        first = self._load(self.paths[0])
        self.size = (first.shape[1], first.shape[0])
        self._first = first

    def _load(self, path: Path):
        image = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if image is None:
            raise UsageError(f"{path}: not a readable PNG image")
        return image

    def read(self) -> Frame | None:
        if self._next >= len(self.paths):
            if not self.loop:
                return None
            self._next = 0
        path = self.paths[self._next]
        if self._first is not None:
            image, self._first = self._first, None
        else:
            image = self._load(path)
        if (image.shape[1], image.shape[0]) != self.size:
            raise UsageError(f"{path}: size {image.shape[1]}x{image.shape[0]} differs from the "
                             f"first frame's {self.size[0]}x{self.size[1]}")
        self._next += 1
        frame = Frame(image, self._count, self.now_ns())
        self._count += 1
        return frame
