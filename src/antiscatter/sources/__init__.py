"""Frame sources, picked by the ``run`` argument.

``sim`` (or nothing) the built-in simulator; ``camera`` the Pi camera;
``webcam:N`` an OpenCV capture device; a folder of frames (``<int>.png``, or
images named in order: see :func:`~.folder.frame_files`); a video file.
"""

from __future__ import annotations

import re
from pathlib import Path

from ..errors import UsageError
from .base import Frame, FrameSource
from .folder import FolderSource, frame_files, list_frames
from .video import VideoSource, parse_crop

__all__ = ["Frame", "FrameSource", "FolderSource", "VideoSource", "open_source",
           "list_frames", "frame_files", "parse_crop", "SOURCE_KINDS"]

SOURCE_KINDS = ("sim", "camera", "webcam:N", "<folder of frames>", "<video file>")

_WEBCAM = re.compile(r"^webcam:(\d+)$")


def open_source(spec: str, *, crop: tuple[int, int, int, int] | None = None, loop: bool = False,
                sim_preset: str = "seed", seed: int = 0,
                size: tuple[int, int] | None = None, fps: float | None = None,
                colour: bool = False, exposure_ms: float | None = None,
                gain: float | None = None) -> FrameSource:
    """Open the source named by ``spec`` (see the module docstring)."""
    spec = spec or "sim"
    if crop is not None and spec in ("sim", "camera") or (crop is not None and _WEBCAM.match(spec)):
        raise UsageError(f"--crop applies to video files only, not to source {spec!r}")
    if spec == "sim":
        from .simulated import SimulatorSource
        return SimulatorSource(preset=sim_preset, seed=seed, size=size)
    if spec == "camera":
        from .camera import CameraSource
        return CameraSource(size=size or (728, 544), fps=fps or 60.0, colour=colour, exposure_ms=exposure_ms,
                            gain=gain)
    match = _WEBCAM.match(spec)
    if match:
        from .webcam import WebcamSource
        return WebcamSource(int(match.group(1)), size=size)
    if spec.startswith("webcam"):
        raise UsageError(f"source {spec!r}: expected webcam:N with N a device number, e.g. webcam:0")
    path = Path(spec)
    if not path.exists():
        raise UsageError(f"source {spec!r}: no such file or folder; allowed: {', '.join(SOURCE_KINDS)}")
    if path.is_dir():
        if crop is not None:
            raise UsageError("--crop applies to video files only, not to a frame folder")
        return FolderSource(path, loop=loop)
    return VideoSource(path, crop=crop, loop=loop)
