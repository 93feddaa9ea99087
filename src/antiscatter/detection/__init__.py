"""Particle detectors, picked by name.

A detector is a chain of named stages; each stage is a pure function of the
previous stage's output, the first takes the camera frame and the last returns
:class:`~antiscatter.detections.Detections`.  The runtime loop times every stage
(the detector itself never reads a clock).  Stages marked ``after`` come last,
take the detections and return them unchanged: they learn from this frame for
the next ones, and the runtime runs them once the pattern is out.
"""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass, fields, is_dataclass, replace
from typing import Any, Callable

import numpy as np

from ..detections import Detections

__all__ = ["Stage", "Detector", "Pooled", "DETECTORS", "register_detector", "detector_entry", "make_detector", "detect",
           "with_sensitivity", "MIN_FRAME_SIDE", "MAX_FRAME_PIXELS", "check_frame_size", "MAX_THREADS", "check_threads"]

#: the fewest pixels a frame may have either way: no background cell, ring or half-resolution
#: working image fits in less (the ``contrast`` detector's at 2x2 blocks must be 3 px or more;
#: smaller frames crashed OpenCV's resize, and some the interpreter itself)
MIN_FRAME_SIDE = 8
#: the most pixels a frame may have, 8192x8192 (64 Mpx, 192 MB as BGR): beyond any camera the
#: vehicle carries; a typo such as 100000x100000 ran out of memory deep inside a command
MAX_FRAME_PIXELS = 8192 * 8192
#: frame-sized buffers a command may hold at once (sources, pipeline, working images, the
#: twin's pixel grids), counted as BGR bytes: a frame larger than physical memory over this is refused
FRAME_BUFFERS = 64
#: the most threads a detector (``run --threads``, ``bench --threads``) takes: four per CPU, more
#: only measure contention
MAX_THREADS = 4 * (os.cpu_count() or 1)


@functools.cache
def _physical_memory() -> int | None:
    """Bytes of physical memory, None where the system does not say."""
    import os

    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def check_frame_size(width: int, height: int, what: str = "frame", *, error: type[Exception] = ValueError) -> None:
    """``error`` (ValueError, or the caller's: a UsageError for input from the command line) naming
    ``what`` when a frame of ``width`` x ``height`` px is too small to detect in or too large to hold:
    more than ``MAX_FRAME_PIXELS``, or ``FRAME_BUFFERS`` BGR copies beyond physical memory.
    The one limit every command checks before it allocates a frame."""
    if width < MIN_FRAME_SIDE or height < MIN_FRAME_SIDE:
        raise error(f"{what} of {width}x{height} px: too small, allowed at least "
                         f"{MIN_FRAME_SIDE}x{MIN_FRAME_SIDE}")
    memory = _physical_memory()
    limit = MAX_FRAME_PIXELS if memory is None else min(MAX_FRAME_PIXELS, memory // (3 * FRAME_BUFFERS))
    if width * height > limit:
        why = "" if limit == MAX_FRAME_PIXELS else f" ({memory / 2 ** 30:.1f} GB of memory)"
        raise error(f"{what} of {width}x{height} px: too large, allowed at most {limit / 1e6:.1f} million pixels"
                    f"{why}")


def check_threads(threads: int, what: str | None = None, *, error: type[Exception] = ValueError) -> int:
    """``threads`` when it is an integer 1..``MAX_THREADS``; else ``error``, its message led by
    ``what`` (default ``threads: got <value>``)."""
    if isinstance(threads, bool) or not isinstance(threads, int) or not 1 <= threads <= MAX_THREADS:
        allowed = f"allowed 1..{MAX_THREADS} ({MAX_THREADS // 4} CPUs here, four threads each)"
        raise error(f"{what}: {allowed}" if what else f"threads: got {threads!r}, {allowed}")
    return threads


@dataclass(frozen=True)
class Stage:
    """One timed step of a detector.

    name: short key (``"greyscale"``); label: the words used in the metrics
    CSV column ``"<label> Duration (s)"``; run: the pure function.
    after: the detections are known before this stage: it takes them, learns from
    the frame for the next ones and returns them unchanged, so the runtime may run it
    after this frame's pattern has gone out (off the latency path).
    """

    name: str
    label: str
    run: Callable[[Any], Any]
    after: bool = False


@dataclass(frozen=True, eq=False)
class Pooled:
    """A frame whose working-resolution plane was made before the detector: the camera's ISP
    scaled it (a ``lores`` stream), so the CPU never pools the full frame.  A detector whose
    ``working_size`` says which plane it wants takes this in place of the frame.

    working: (H // factor, W // factor) uint8, the frame's Y (luma) plane at the detector's
        working resolution.
    factor: full-resolution pixels per working pixel, each way (>= 2): the detections come back in
        full-resolution pixels, centres and radii, as from the full frame.
    full: the full frame's own Y plane, (H, W) uint8, when the source has it (the camera's main
        stream): the detector reads a few of its pixels for the shape of flat particles; None: it
        works from ``working`` alone.
    """

    working: np.ndarray
    factor: int
    full: np.ndarray | None = None

    @property
    def size(self) -> tuple[int, int]:
        """(W, H): the full frame's size, pixels."""
        return self.working.shape[1] * self.factor, self.working.shape[0] * self.factor


def _no_state() -> None:
    return None


def _full_frames_only(width: int, height: int) -> None:
    return None


def _no_light(light: Any) -> None:
    return None


@dataclass(frozen=True)
class Detector:
    """A named chain of stages; ``detect(frame)`` runs them untimed.

    reset: forget what was learnt from earlier frames (call between unrelated images).
    set_light: tell the detector the light the lamp gives the scene during the next frame's
        exposure -- an (H, W) map in camera pixels, 1 = full lamp (any size; None = full
        everywhere) -- so the pattern's own imprint on the background is not taken for
        particles; detectors that cannot use it ignore it.  The map may be a buffer the caller
        fills again for the frame after (``run`` does): read it in that frame's detection only.
    expect: where known particles should be in the next frame (Detections, camera pixels; for
        that frame only): a detector may accept fainter light there -- a tracked particle
        dimmed under its own hole -- than it would anywhere else.
    working_size: (width, height) of frames -> the (width, height) of the working plane a
        :class:`Pooled` frame of that size must carry, or None when the detector takes only whole
        frames (the default; ``contrast`` at factor 1).  Its first stage then takes either.
    """

    name: str
    stages: tuple[Stage, ...]
    params: Any = None
    reset: Callable[[], None] = _no_state
    set_light: Callable[[Any], None] = _no_light
    expect: Callable[[Any], None] = _no_light
    working_size: Callable[[int, int], tuple[int, int] | None] = _full_frames_only

    def detect(self, image: np.ndarray | Pooled) -> Detections:
        """Run every stage on one frame, (H, W, 3) BGR or (H, W) grey uint8, at least
        ``MIN_FRAME_SIDE`` px either way (ValueError otherwise: 16-bit frames are scaled to 8 bits
        first, as :func:`antiscatter.sources.folder.read_frame` does), or a :class:`Pooled` frame
        whose plane has the ``working_size`` of its full size (ValueError otherwise)."""
        if isinstance(image, Pooled):
            self.check_pooled(image)
        else:
            if image.dtype != np.uint8 or image.ndim not in (2, 3):
                raise ValueError(f"frame of {image.dtype} with shape {image.shape}: allowed uint8, "
                                 "(H, W) grey or (H, W, 3) BGR")
            check_frame_size(image.shape[1], image.shape[0])
        value: Any = image
        for stage in self.stages:
            value = stage.run(value)
        return value

    def check_pooled(self, pooled: Pooled) -> None:
        """ValueError unless this detector takes ``pooled``: a uint8 (h, w) plane of its
        ``working_size`` for the full size, and a full plane, if any, of that size."""
        plane = pooled.working
        if plane.dtype != np.uint8 or plane.ndim != 2:
            raise ValueError(f"pooled plane of {plane.dtype} with shape {plane.shape}: allowed uint8, (h, w)")
        width, height = pooled.size
        check_frame_size(width, height)
        wanted = self.working_size(width, height)
        if wanted != (plane.shape[1], plane.shape[0]):
            raise ValueError(f"pooled plane of {plane.shape[1]}x{plane.shape[0]} px at factor {pooled.factor}: "
                             f"detector {self.name!r} works on "
                             + ("whole frames only" if wanted is None else f"{wanted[0]}x{wanted[1]} px")
                             + f" for {width}x{height} px frames")
        if pooled.full is not None and pooled.full.shape != (height, width):
            raise ValueError(f"pooled full plane of shape {pooled.full.shape}: allowed ({height}, {width})")


@dataclass(frozen=True)
class _Entry:
    params: type
    build: Callable[[Any], Detector]
    summary: str
    sweep: tuple[str, tuple] = ("", ())  # sensitivity parameter and values for PR curves
    sweep_scaled: tuple[str, ...] = ()  # parameters that scale with it
    threaded: bool = False  # build takes ``threads`` (its frame-wide filters run in bands on them)


DETECTORS: dict[str, _Entry] = {}


def register_detector(name: str, params: type, build: Callable[[Any], Detector],
                      summary: str, *, sweep: tuple[str, tuple] = ("", ()),
                      sweep_scaled: tuple[str, ...] = (), threaded: bool = False) -> None:
    """Add a detector under ``name``; ``params`` is its frozen config dataclass.

    sweep: (parameter name, values from most to least sensitive) used to draw
    precision-recall curves; sweep_scaled: parameters moved in proportion with it
    (a second threshold bound to the first).  threaded: ``build`` takes a keyword ``threads``
    (the number of threads it detects on, >= 1), and gives the same detections on any number.
    """
    if not is_dataclass(params):
        raise TypeError("params must be a dataclass type")
    DETECTORS[name] = _Entry(params, build, summary, sweep, sweep_scaled, threaded)


def detector_entry(name: str) -> _Entry:
    """The registry entry of ``name``; an unknown name is a UsageError listing the known ones."""
    from ..errors import UsageError

    try:
        return DETECTORS[name]
    except KeyError:
        raise UsageError(f"unknown detector {name!r}; allowed: {', '.join(sorted(DETECTORS))}") from None


def make_detector(name: str, params: Any = None, *, threads: int = 1) -> Detector:
    """Build the detector registered as ``name`` with its params dataclass (or defaults).

    threads: threads a ``threaded`` detector detects on (default 1; the same detections on any
    number); a detector that is not threaded runs on one whatever is asked."""
    entry = detector_entry(name)
    if params is None:
        params = entry.params()
    elif not isinstance(params, entry.params):
        raise TypeError(f"detector {name!r} takes {entry.params.__name__}, got {type(params).__name__}")
    return entry.build(params, threads=threads) if entry.threaded else entry.build(params)


def with_sensitivity(name: str, params: Any, value: float) -> Any:
    """``params`` of detector ``name`` with its sensitivity parameter (``sweep``) at ``value`` and
    the parameters tied to it (``sweep_scaled``) moved in proportion; ValueError from the params'
    own check when the result is not allowed."""
    entry = detector_entry(name)
    key = entry.sweep[0]
    if not key:
        raise ValueError(f"detector {name!r} has no sensitivity parameter")
    old = getattr(params, key)
    value = type(old)(value)
    scale = value / old if old else 1.0
    changes = {key: value, **{tied: getattr(params, tied) * scale for tied in entry.sweep_scaled}}
    return replace(params, **changes)


def detect(image: np.ndarray, detector: str = "seed", **params: Any) -> Detections:
    """Convenience: find particles in one frame with the named detector and keyword params."""
    entry = detector_entry(detector)
    known = {f.name for f in fields(entry.params)}
    unknown = set(params) - known
    if unknown:
        raise ValueError(f"detector {detector!r} has no parameter {sorted(unknown)[0]!r}; allowed: {', '.join(sorted(known))}")
    return make_detector(detector, entry.params(**params)).detect(image)


from . import seed as _seed  # noqa: E402,F401  (registers "seed")
from . import contrast as _contrast  # noqa: E402,F401  (registers "contrast")
