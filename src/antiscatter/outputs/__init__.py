"""Light outputs, picked by name; several can run at once.

``framebuffer[:/dev/fbN]`` the projector through the Linux framebuffer;
``kms`` the projector through DRM/KMS with page flips on vblank (pykms);
``window`` OpenCV windows; ``files:DIR`` or ``files:NAME.mkv`` pattern frames
to disk; ``none`` nothing; ``auto`` a window where a display exists, else none.
"""

from __future__ import annotations

from ..errors import UsageError
from .base import LightOutput, NullOutput

__all__ = ["LightOutput", "NullOutput", "open_output", "check_output", "OUTPUT_KINDS"]

OUTPUT_KINDS = ("framebuffer[:/dev/fbN]", "kms", "window", "files:DIR", "files:NAME.mkv", "none", "auto")


def check_output(spec: str) -> None:
    """Check the file or folder of a ``files:`` output before any work (UsageError, one line);
    other outputs are devices, checked when opened."""
    kind, _, arg = spec.partition(":")
    if kind == "files":
        from .files import check_files_target
        check_files_target(arg)


def open_output(spec: str, *, fps: float = 60.0) -> LightOutput:
    """Open the light output named by ``spec`` (see the module docstring)."""
    kind, _, arg = spec.partition(":")
    if kind == "none" and not arg:
        return NullOutput()
    if kind == "auto" and not arg:
        from .window import WindowOutput, display_available
        return WindowOutput() if display_available() else NullOutput()
    if kind == "window" and not arg:
        from .window import WindowOutput
        return WindowOutput()
    if kind == "kms" and not arg:
        from .kms import KmsOutput
        return KmsOutput()
    if kind == "framebuffer":
        from .framebuffer import FramebufferOutput
        return FramebufferOutput(arg or "/dev/fb0")
    if kind == "files":
        from .files import open_files_output
        return open_files_output(arg, fps=fps)
    raise UsageError(f"unknown output {spec!r}; allowed: {', '.join(OUTPUT_KINDS)}")
