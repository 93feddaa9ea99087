"""Output ``framebuffer``: the projector on HDMI through the Linux framebuffer.

The device's real geometry is read from ``/sys/class/graphics/fbN/``:
``virtual_size`` ("W,H"), ``bits_per_pixel`` (16 = RGB565, 32 = XRGB8888) and
``stride`` (bytes per row).  The device is memory-mapped once; each pattern is
converted straight into the mapping (no per-frame reopen).
"""

from __future__ import annotations

import mmap
import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ..detections import Detections
from ..errors import UsageError
from ..sources.base import Frame
from .base import LightOutput

__all__ = ["FramebufferGeometry", "read_geometry", "FramebufferOutput", "to_pixels"]


@dataclass(frozen=True)
class FramebufferGeometry:
    """width, height: virtual size in pixels; bits_per_pixel: 16 or 32; stride: bytes per row."""

    width: int
    height: int
    bits_per_pixel: int
    stride: int


def _read_sysfs(folder: Path, name: str) -> str:
    path = folder / name
    try:
        return path.read_text().strip()
    except FileNotFoundError:
        raise UsageError(f"{path}: missing; is {folder.name} a framebuffer device?") from None
    except PermissionError:
        raise UsageError(f"{path}: permission denied") from None


def read_geometry(folder: str | Path) -> FramebufferGeometry:
    """Geometry of one framebuffer from its sysfs folder (e.g. /sys/class/graphics/fb0)."""
    folder = Path(folder)
    size_text = _read_sysfs(folder, "virtual_size")
    bpp_text = _read_sysfs(folder, "bits_per_pixel")
    stride_text = _read_sysfs(folder, "stride")
    try:
        width, height = (int(v) for v in size_text.split(","))
        bpp = int(bpp_text)
        stride = int(stride_text)
    except ValueError:
        raise UsageError(f"{folder}: unreadable geometry (virtual_size {size_text!r}, "
                         f"bits_per_pixel {bpp_text!r}, stride {stride_text!r})") from None
    if bpp not in (16, 32):
        raise UsageError(f"{folder / 'bits_per_pixel'}: {bpp} is not supported; allowed 16 (RGB565) "
                         "or 32 (XRGB8888); set the mode with fbset -depth 16 or 32")
    if width <= 0 or height <= 0 or stride < width * bpp // 8:
        raise UsageError(f"{folder}: inconsistent geometry {width}x{height}, stride {stride} "
                         f"(need stride >= {width * bpp // 8})")
    return FramebufferGeometry(width, height, bpp, stride)


def to_pixels(pattern: np.ndarray, bits_per_pixel: int, out: np.ndarray | None = None) -> np.ndarray:
    """Grey (H, W) uint8 -> framebuffer pixels, (H, W, 2) RGB565 or (H, W, 4) XRGB8888 bytes.

    RGB565 is little-endian 16-bit ``r5 << 11 | g6 << 5 | b5``; XRGB8888 is the
    byte sequence B, G, R, X with X = 255.
    """
    if bits_per_pixel == 16:
        return cv2.cvtColor(pattern, cv2.COLOR_GRAY2BGR565, dst=out)
    if bits_per_pixel == 32:
        return cv2.cvtColor(pattern, cv2.COLOR_GRAY2BGRA, dst=out)
    raise ValueError(f"bits_per_pixel: got {bits_per_pixel}, allowed 16 or 32")


class FramebufferOutput(LightOutput):
    """Write patterns to ``/dev/fbN``, scaled (nearest) to the framebuffer's size.

    device: the framebuffer device (an ordinary file works, for tests).
    sysfs: the folder holding its geometry; ``/sys/class/graphics/<device name>`` by default.
    blank_on_close: leave the lamp off (all black) when the run ends, as the report did.
    """

    name = "framebuffer"

    def __init__(self, device: str | Path = "/dev/fb0", *, sysfs: str | Path | None = None,
                 blank_on_close: bool = True) -> None:
        self.device = Path(device)
        self.geometry = read_geometry(sysfs or Path("/sys/class/graphics") / self.device.name)
        g = self.geometry
        length = g.stride * g.height
        try:
            fd = os.open(self.device, os.O_RDWR)
        except FileNotFoundError:
            raise UsageError(f"{self.device}: no such framebuffer device") from None
        except PermissionError:
            raise UsageError(f"{self.device}: permission denied (add the user to the 'video' group)") from None
        try:
            size = os.fstat(fd).st_size  # 0 for a device node; an ordinary file must be big enough
            if 0 < size < length:
                raise UsageError(f"{self.device}: {size} bytes, smaller than the {length} bytes its geometry needs")
            self._map = mmap.mmap(fd, length, mmap.MAP_SHARED, mmap.PROT_READ | mmap.PROT_WRITE)
        except (OSError, ValueError) as exc:
            raise UsageError(f"{self.device}: cannot be memory-mapped ({exc})") from None
        finally:
            os.close(fd)
        bytes_pp = g.bits_per_pixel // 8
        rows = np.ndarray((g.height, g.stride), np.uint8, buffer=self._map)
        self._screen = rows[:, : g.width * bytes_pp].reshape(g.height, g.width, bytes_pp)
        self._pixels = np.empty((g.height, g.width, bytes_pp), np.uint8)
        self._scaled: np.ndarray | None = None
        self.blank_on_close = blank_on_close

    def show(self, pattern: np.ndarray, frame: Frame | None = None,
             detections: Detections | None = None) -> None:
        g = self.geometry
        if pattern.shape[:2] != (g.height, g.width):
            if self._scaled is None:
                self._scaled = np.empty((g.height, g.width), np.uint8)
            pattern = cv2.resize(pattern, (g.width, g.height), dst=self._scaled,
                                 interpolation=cv2.INTER_NEAREST)
        to_pixels(pattern, g.bits_per_pixel, out=self._pixels)
        self._screen[...] = self._pixels

    def close(self) -> None:
        if self._map.closed:
            return
        if self.blank_on_close:
            self._screen[...] = 0
        del self._screen
        self._map.close()
