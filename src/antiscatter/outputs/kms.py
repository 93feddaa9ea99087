"""Output ``kms``: the projector on HDMI through DRM/KMS, double-buffered, flipped on vblank.

Uses kms++'s Python bindings (``pykms``; on Raspberry Pi OS the package
``python3-kms++``, seen from a venv made with ``--system-site-packages``),
imported lazily.  Two XRGB8888 dumb framebuffers alternate: each pattern is
converted into the back buffer, then an atomic commit flips the primary plane
to it on the next vertical blank.  The flip-complete event's time (the
``CLOCK_MONOTONIC`` clock of ``time.monotonic_ns()``) is kept as the moment
the previous pattern went out (``presented_ns``).  The framebuffer output
stays the simple fallback.
"""

from __future__ import annotations

import mmap
import select
import time
from typing import Any, Callable

import cv2
import numpy as np

from ..detections import Detections
from ..errors import UsageError
from ..sources.base import Frame
from .base import LightOutput
from .framebuffer import to_pixels

__all__ = ["KmsOutput", "load_pykms"]


def load_pykms() -> Any:
    try:
        import pykms  # type: ignore[import-not-found]
    except ImportError:
        raise UsageError("output 'kms' needs the pykms module (kms++) on the Raspberry Pi: sudo apt install "
                         "python3-kms++ and a venv made with --system-site-packages; or use "
                         "--output framebuffer") from None
    return pykms


class KmsOutput(LightOutput):
    """Double-buffered page flips on the first connected display.

    pykms: the module (tests pass a fake); loaded lazily when None.
    flip_timeout: seconds to wait for a flip to complete before giving up with an error.
    clock: the ``CLOCK_MONOTONIC`` clock in ns the flip events are on (tests pass a virtual one).
    """

    name = "kms"

    def __init__(self, *, pykms: Any = None, flip_timeout: float = 1.0,
                 clock: Callable[[], int] = time.monotonic_ns) -> None:
        self.clock = clock
        self.committed_ns = 0  # when the last flip was asked for
        self.kms = pykms or load_pykms()
        kms = self.kms
        try:
            self.card = kms.Card()
            resources = kms.ResourceManager(self.card)
            self.connector = resources.reserve_connector()
            self.crtc = resources.reserve_crtc(self.connector)
            self.plane = resources.reserve_primary_plane(self.crtc)
            self.mode = self.connector.get_default_mode()
        except (RuntimeError, OSError) as exc:
            raise UsageError(f"output 'kms': no display could be set up ({exc}); is the projector "
                             "connected, and is no desktop holding the display?") from None
        width, height = self.mode.hdisplay, self.mode.vdisplay
        self.size = (width, height)
        self.timeout = flip_timeout
        self.buffers = [kms.DumbFramebuffer(self.card, width, height, "XR24") for _ in range(2)]
        self._maps = []
        self.screens = []
        for fb in self.buffers:
            mapped = mmap.mmap(fb.fd(0), fb.size(0), mmap.MAP_SHARED, mmap.PROT_READ | mmap.PROT_WRITE,
                               offset=fb.offset(0))
            rows = np.ndarray((height, fb.stride(0)), np.uint8, buffer=mapped)
            self._maps.append(mapped)
            self.screens.append(rows[:, : width * 4].reshape(height, width, 4))
        self._pixels = np.empty((height, width, 4), np.uint8)
        self._scaled: np.ndarray | None = None
        self.front = 0
        self.pending = False
        self.presented_ns = 0
        self.flips = 0
        self.screens[0][...] = 0
        request = kms.AtomicReq(self.card)
        request.add(self.connector, "CRTC_ID", self.crtc.id)
        request.add(self.crtc, {"ACTIVE": 1, "MODE_ID": self.mode.to_blob(self.card).id})
        request.add(self.plane, {"FB_ID": self.buffers[0].id, "CRTC_ID": self.crtc.id,
                                 "SRC_X": 0, "SRC_Y": 0, "SRC_W": width << 16, "SRC_H": height << 16,
                                 "CRTC_X": 0, "CRTC_Y": 0, "CRTC_W": width, "CRTC_H": height})
        if request.commit_sync(allow_modeset=True) != 0:
            raise UsageError("output 'kms': the display refused the mode set (permission? another master?)")

    def _wait_flip(self, timeout: float | None = None) -> None:
        """Block until the pending flip completes (its time is when the last pattern went out);
        with ``timeout`` (seconds), give up after it and leave ``pending`` set."""
        while self.pending:
            ready, _, _ = select.select([self.card.fd], [], [], self.timeout if timeout is None else timeout)
            if not ready:
                if timeout is not None:
                    return
                raise RuntimeError(f"output 'kms': no flip completed within {self.timeout} s")
            for event in self.card.read_events():
                if event.type == self.kms.DrmEventType.FLIP_COMPLETE:
                    self.presented_ns = int(event.time * 1e9)
                    self.flips += 1
                    self.pending = False

    def restore(self, pattern: np.ndarray) -> None:
        """The exposure is over: the last pattern back -- if the display can take it now.  While the
        flash's (or pulse's) flip is still pending, a new flip would have to wait for it, and so
        would the next pattern after it (up to a refresh more latency): the flash stays on then."""
        self._wait_flip(timeout=0.0)
        if not self.pending:
            self.show(pattern)

    def show(self, pattern: np.ndarray, frame: Frame | None = None,
             detections: Detections | None = None) -> None:
        width, height = self.size
        if pattern.shape[:2] != (height, width):
            if self._scaled is None:
                self._scaled = np.empty((height, width), np.uint8)
            pattern = cv2.resize(pattern, (width, height), dst=self._scaled, interpolation=cv2.INTER_NEAREST)
        self._wait_flip()  # the back buffer may still be on screen until then
        back = 1 - self.front
        to_pixels(pattern, 32, out=self._pixels)
        self.screens[back][...] = self._pixels
        request = self.kms.AtomicReq(self.card)
        request.add(self.plane, "FB_ID", self.buffers[back].id)
        if request.commit(back, allow_modeset=False) != 0:
            raise RuntimeError("output 'kms': page flip refused")
        self.committed_ns = self.clock()
        self.pending = True
        self.front = back

    def next_flip_ns(self, refresh_ns: int) -> int:
        """When a flip asked for now would land (the display refreshing every ``refresh_ns``): the
        first vertical blank after now, or after the pending flip's; now while none has landed."""
        if self.pending:
            self._wait_flip(timeout=0.0)  # a flip that has landed says when the blanks are
        now = self.clock()
        if not self.presented_ns:
            return now

        def blank_after(t: int) -> int:
            return self.presented_ns + refresh_ns * ((t - self.presented_ns) // refresh_ns + 1)

        return blank_after(max(now, blank_after(self.committed_ns)) if self.pending else now)

    def close(self) -> None:
        if not self._maps:
            return
        try:
            self._wait_flip()
            self.show(np.zeros((self.size[1], self.size[0]), np.uint8))  # lamp off at the end
            self._wait_flip()
        finally:
            self.screens.clear()
            for mapped in self._maps:
                mapped.close()
            self._maps.clear()
