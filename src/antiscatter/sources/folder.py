"""A folder of frames: ``<int>.png`` files in numeric order (the simulator's and the report's
frames), else every image file in natural order of name."""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np

from ..detection import check_frame_size
from ..errors import UsageError
from .base import Frame, FrameSource, quiet_opencv

__all__ = ["FolderSource", "list_frames", "frame_files", "read_frame", "IMAGE_SUFFIXES"]

_FRAME_NAME = re.compile(r"^(\d+)\.png$", re.IGNORECASE)
#: image files a frame folder may hold (any case)
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")


def list_frames(folder: Path) -> list[Path]:
    """The ``<int>.png`` files of ``folder`` sorted by their number (2 before 10)."""
    numbered = []
    for path in folder.iterdir():
        match = _FRAME_NAME.match(path.name)
        if match and path.is_file():
            numbered.append((int(match.group(1)), path))
    numbered.sort()
    return [path for _, path in numbered]


def _natural(name: str) -> list:
    """Sort key: runs of digits compare as numbers (frame_2.jpg before frame_10.jpg)."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", name.lower())]


def frame_files(folder: Path) -> list[tuple[int, Path]]:
    """The frames of ``folder`` as (frame number, path), in order.

    ``<int>.png`` files when there are any, numbered by their names (the simulator's output,
    the report's recordings; other files beside them are ignored); otherwise every image file
    (``IMAGE_SUFFIXES``) in natural order of name -- a camera's ``IMG_0001.JPG``..., an
    annotation tool's ``frame_000010.tif``... -- numbered 0, 1, 2, ... in that order."""
    numbered = list_frames(folder)
    if numbered:
        return [(int(path.stem), path) for path in numbered]
    images = sorted((p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file()),
                    key=lambda p: _natural(p.name))
    return list(enumerate(images))


def no_frames(folder: Path) -> UsageError:
    """The error for a folder without frames."""
    return UsageError(f"{folder}: no frames in this folder; allowed: <int>.png files, or images named in "
                      f"order ({', '.join(s[1:] for s in IMAGE_SUFFIXES)})")


def read_frame(path: Path, bits: int | None = None) -> tuple[np.ndarray, int]:
    """(BGR uint8 image, bit depth) of an image file.

    8-bit files are read as they are.  16-bit files (scientific cameras, raw converters) hold
    10-, 12-, 14- or 16-bit samples: ``bits`` -- the depth, found from the first frame of a
    sequence so every frame is scaled alike -- is the least of 10, 12, 14, 16 that holds the
    brightest sample when not given, and the samples are scaled to 8 bits by it (OpenCV's own
    conversion drops the low byte, leaving 12-bit data at 0-15).  Other sample types, and a file
    whose depth differs from ``bits`` (8 against 10-16), are refused."""
    with quiet_opencv(errors=True):
        image = cv2.imread(str(path), cv2.IMREAD_COLOR | cv2.IMREAD_ANYDEPTH)
    if image is None:
        raise UsageError(f"{path}: not a readable image")
    check_frame_size(image.shape[1], image.shape[0], what=f"{path}: image", error=UsageError)
    if image.dtype not in (np.uint8, np.uint16):
        raise UsageError(f"{path}: {image.dtype} samples; allowed 8- or 16-bit images")
    depth, first = (8 if image.dtype == np.uint8 else 16), (8 if bits == 8 else 16)
    if bits is not None and depth != first:  # scaled by the other depth, it would saturate or go black
        raise UsageError(f"{path}: a {depth}-bit image where the frames before it are {first}-bit; allowed "
                         "frames of one bit depth")
    if image.dtype == np.uint8:
        return image, 8
    if bits is None:
        peak = int(image.max())
        bits = next(b for b in (10, 12, 14, 16) if peak < 1 << b)
    return cv2.convertScaleAbs(image, alpha=255.0 / ((1 << bits) - 1)), bits


def _png_depth(path: Path) -> int | None:
    """8 or 16: the sample depth a PNG's header declares as OpenCV reads it (1-8 bits as 8); None for
    other files.  Read from 25 bytes, so a whole folder is checked before any frame is used."""
    if path.suffix.lower() != ".png":
        return None
    with path.open("rb") as handle:
        head = handle.read(25)
    if len(head) < 25 or head[:8] != b"\x89PNG\r\n\x1a\n" or head[12:16] != b"IHDR":
        return None
    return 16 if head[24] == 16 else 8


class FolderSource(FrameSource):
    """Frames read from the images of a folder (:func:`frame_files`), each numbered from 0 in order.

    loop: start again from the first frame after the last.
    """

    name = "folder"

    def __init__(self, folder: str | Path, *, loop: bool = False) -> None:
        self.folder = Path(folder)
        self.paths = [path for _, path in frame_files(self.folder)]
        if not self.paths:
            raise no_frames(self.folder)
        self.loop = loop
        self._next = 0
        self._count = 0
        self._bits: int | None = None  # the sample depth, from the first frame
        first = self._load(self.paths[0])
        self.size = (first.shape[1], first.shape[0])
        depth = 8 if self._bits == 8 else 16
        for path in self.paths[1:]:  # one depth throughout, checked before any frame is used
            other = _png_depth(path)
            if other is not None and other != depth:
                raise UsageError(f"{path}: a {other}-bit image where the frames before it are {depth}-bit; "
                                 "allowed frames of one bit depth")
        self._first = first

    def _load(self, path: Path):
        image, bits = read_frame(path, self._bits)
        self._bits = bits
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
