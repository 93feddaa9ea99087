"""Frame sources, picked by the ``run`` argument.

``sim`` (or nothing) the built-in simulator; ``camera`` the Pi camera;
``webcam:N`` an OpenCV capture device; a folder of frames (``<int>.png``, or
images named in order: see :func:`~.folder.frame_files`); a video file.  A keyword that is
also the name of a file or folder here is refused as ambiguous (``sim:`` / ``camera:`` for the
source, ``./sim`` for the folder); an empty name is refused.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Callable

from ..detection import check_frame_size
from ..errors import UsageError
from .base import Frame, FrameSource, frame_time_ns
from .folder import FolderSource, frame_files, list_frames
from .video import VideoSource, parse_crop

__all__ = ["Frame", "FrameSource", "frame_time_ns", "FolderSource", "VideoSource", "open_source",
           "list_frames", "frame_files", "parse_crop", "SOURCE_KINDS"]

SOURCE_KINDS = ("sim", "camera", "webcam:N", "<folder of frames>", "<video file>")
#: sources named by a keyword; ``sim:`` and ``camera:`` name them even where a file or folder of
#: that name is in the current folder (``./sim`` names the folder)
KEYWORDS = {"sim": "the simulator", "camera": "the camera"}

_WEBCAM = re.compile(r"^webcam:(\d+)$")


def open_source(spec: str, *, crop: tuple[int, int, int, int] | None = None, loop: bool = False,
                sim_preset: str = "seed", seed: int = 0,
                size: tuple[int, int] | None = None, fps: float | None = None,
                colour: bool = False, exposure_ms: float | None = None,
                gain: float | None = None,
                working_size: Callable[[int, int], tuple[int, int] | None] | None = None) -> FrameSource:
    """Open the source named by ``spec`` (see the module docstring); ``size`` (width, height) px is
    checked against the frame-size limits, and the camera's exposure and gain against its rule,
    for every source and before anything is allocated.

    working_size: the detector's ``Detector.working_size``: the camera then asks its ISP for a
    ``lores`` stream of that size (``CameraSource``'s ``lores``); other sources ignore it.  None
    (default): no lores stream."""
    if not spec or not spec.strip():
        raise UsageError(f"source {spec!r}: empty; allowed: {', '.join(SOURCE_KINDS)}")
    if spec in KEYWORDS and Path(spec).exists():
        kind = "folder" if Path(spec).is_dir() else "file"
        raise UsageError(f"source {spec!r}: ambiguous, a {kind} named {spec} is in this folder; write ./{spec} "
                         f"for the {kind} or {spec}: for {KEYWORDS[spec]}")
    if spec.endswith(":") and spec[:-1] in KEYWORDS:
        spec = spec[:-1]
    if size is not None:
        check_frame_size(*size, what=f"source {spec}: frames", error=UsageError)
    if exposure_ms is not None or gain is not None:  # the camera's own rule, whatever the source
        from .camera import camera_controls

        camera_controls(fps or 60.0, exposure_ms, gain)
    if crop is not None and spec in ("sim", "camera") or (crop is not None and _WEBCAM.match(spec)):
        raise UsageError(f"--crop applies to video files only, not to source {spec!r}")
    if spec == "sim":
        from .simulated import SimulatorSource
        return SimulatorSource(preset=sim_preset, seed=seed, size=size)
    if spec == "camera":
        from .camera import DEFAULT_SIZE, CameraSource

        size = size or DEFAULT_SIZE
        lores = None
        if working_size is not None:
            lores = working_size(*size)
            if lores is None:
                raise UsageError(f"camera_lores: the detector works on whole {size[0]}x{size[1]} frames (no "
                                 "working resolution below the frame's to scale to); allowed with contrast at "
                                 "working factor 2")
        return CameraSource(size=size, fps=fps or 60.0, colour=colour, exposure_ms=exposure_ms,
                            gain=gain, lores=lores)
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
