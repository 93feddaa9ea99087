"""Locking the camera's exposures to the projector's refresh in software.

The Pi camera free-runs: each frame lasts its ``FrameDurationLimits``, on the
sensor's own clock.  The projector flips on its vertical blank, on the
display's.  A pulse or a flash can be timed to an exposure only if the exposure
begins at a known moment of the projector's refresh.  Without the sensor's
trigger input wired to the projector's vsync, the loop does what software
camera synchronisation does (Raspberry Pi's libcamera sync, rpicam-apps
``--sync``; the frame-rate "PLL" hacks before it): it measures where each
exposure began against the display's last vertical blank and lengthens or
shortens the camera's next frame to pull the exposures to ``target`` after a
blank.  The sensor applies a new frame duration a few frames late, so the
correction is a share (``gain``) of the error left once the corrections already
asked for have applied; it is also bounded by what the sensor can do (``shortest_ns``: its
shortest frame) and by ``step_ns`` a frame.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .errors import UsageError

__all__ = ["PhaseLock", "display_lag", "lock_check", "GAIN", "DELAY", "LOCKED_WITHIN"]

#: the locked loop's one timing margin (seconds): a frame is taken to be read this long after its
#: exposure ends, and a flip asked for later than this before its vertical blank misses it
#: (runtime's loop, config.locked_light_reaches and the twin's model of the loop all use it)
FLIP_MARGIN_S = 1e-3

#: the frames a new duration may take to apply: the corrections asked for that long ago or less
#: are taken as still to come (a Smith predictor), so the loop does not ask for them again
DELAY = 4
#: the share of the predicted phase error corrected a frame.  Simulated at 60 frames/s on a 120 Hz
#: display, from 17 phases across a refresh, with the IMX296's shortest frame (16.56 ms: it can
#: barely shorten one), a sensor clock 50 ppm off and durations applied 1 to 6 frames late: 0.3
#: locks within 29 frames (within LOCKED_WITHIN from then on) and holds 6-7 us from the target;
#: 0.4 within 33, 0.5 does not lock with 6 frames' delay; without the predictor 0.2 does not
#: lock with 5 or more
GAIN = 0.3
#: the exposures count as locked once they begin within this share of a refresh of the target
LOCKED_WITHIN = 0.05


@dataclass
class PhaseLock:
    """Frame durations that pull each exposure's start to ``target_ns`` after a vertical blank.

    refresh_ns: the display's refresh period; period_ns: the camera's nominal frame period (a
    whole number of refreshes); shortest_ns: the shortest frame the sensor can give (0: no limit);
    step_ns: the most a frame is lengthened or shortened (default a quarter refresh);
    delay: the frames a new duration may take to apply (``DELAY``).
    error_ns: the last exposure's start against the target (> 0: late), after :meth:`update`.
    """

    refresh_ns: int
    period_ns: int
    target_ns: int
    gain: float = GAIN
    shortest_ns: int = 0
    step_ns: int = 0
    delay: int = DELAY
    error_ns: int | None = field(default=None, init=False)
    _coming: deque = field(default_factory=deque, init=False, repr=False)  # the corrections still to apply

    def __post_init__(self) -> None:
        if self.refresh_ns <= 0 or self.period_ns <= 0:
            raise ValueError(f"refresh_ns, period_ns: got {self.refresh_ns}, {self.period_ns}, allowed > 0")
        turns = self.period_ns / self.refresh_ns
        if abs(turns - round(turns)) > 1e-3 or round(turns) < 1:
            raise ValueError(f"period_ns: got {self.period_ns}, allowed a whole number of refreshes "
                             f"({self.refresh_ns} ns)")
        if not 0 <= self.target_ns < self.refresh_ns:
            raise ValueError(f"target_ns: got {self.target_ns}, allowed 0 <= target < one refresh ({self.refresh_ns} ns)")
        if not (math.isfinite(self.gain) and 0 < self.gain <= 1):
            raise ValueError(f"gain: got {self.gain}, allowed 0 < gain <= 1")
        self.step_ns = self.step_ns or self.refresh_ns // 4
        self._coming = deque([0] * self.delay, maxlen=self.delay)

    def update(self, exposure_start_ns: int, vblank_ns: int) -> int:
        """The next frame's duration (ns) after an exposure that began at ``exposure_start_ns``,
        with a vertical blank at ``vblank_ns`` (any one: they repeat every refresh)."""
        r = self.refresh_ns
        late = (exposure_start_ns - vblank_ns - self.target_ns) % r
        # late by `late`, or early by r - late: the nearer, unless the sensor would close a late error
        # sooner the long way round (it may barely shorten its frames: the IMX296 gives 60.4 frames/s
        # at most) -- never within a quarter refresh of the target, where the lock's own overshoot
        # would otherwise send it round again
        shorten = min(self.step_ns, self.period_ns - self.shortest_ns) if self.shortest_ns else self.step_ns
        long_way = late > r // 2 or (late > r // 4 and (r - late) * shorten < late * self.step_ns)
        self.error_ns = late - r if long_way else late
        predicted = self.error_ns - sum(self._coming)  # once the corrections on their way have applied
        correction = max(-self.step_ns, min(shorten, round(self.gain * predicted)))
        self._coming.append(correction)
        return self.period_ns - correction

    @property
    def locked(self) -> bool:
        """Whether the last exposure began within ``LOCKED_WITHIN`` of a refresh of the target."""
        return self.error_ns is not None and abs(self.error_ns) <= LOCKED_WITHIN * self.refresh_ns


def display_lag(source: Any, display: Any, *, refresh_ns: int, trials: int = 12, settle: int = 6) -> dict:
    """The projector's lag from a flip to its light on the scene, measured with the camera looking
    at what the projector lights (a fixed exposure, best near the frame period: then almost every
    onset falls inside one; ``display``: output ``kms``).

    Each trial shows black for ``settle`` frames, then white at a known flip (every other trial a
    refresh later, so the onset meets the camera's frames at two phases), and reads frames until
    ``settle`` more are lit.  The frame whose exposure the light came on in is lit by the
    share of it after the onset: onset = its exposure's end - that share of its exposure.  The lag
    is the onset less the flip's time; a trial whose onset fell between two exposures tells
    nothing and is left out.  Returns the median over the trials that told (ms), their spread
    and values.  A view the white does not brighten, or no onset inside an exposure, is an error.
    Lags up to about ``settle`` frame periods less the exposure and a period are measured (6:
    75 ms at 60 Hz with 15 ms exposures, simulated; with 3 it was 25 ms -- a longer lag left the
    black's level lit by the trial before's white, and a projector's lag can be several frames).
    """
    width, height = display.size
    black, white = np.zeros((height, width), np.uint8), np.full((height, width), 255, np.uint8)

    def frames(n: int) -> list:
        out = []
        for _ in range(n):
            frame = source.read()
            if frame is None:
                raise UsageError("display lag: the camera stopped delivering frames")
            out.append(frame)
        return out

    def level(frame: Any) -> float:
        return float(np.mean(frame.image))

    lags: list[float] = []
    for trial in range(trials):
        display.show(black)
        dark = level(frames(settle)[-1])
        if trial % 2:  # every other trial a refresh later against the camera's frames (its phase holds)
            display.show(black)
        flip = display.next_flip_ns(refresh_ns)  # where the white lands (the black's flip has landed)
        display.show(white)
        seen = frames(settle + 1)
        bright = level(seen[-1])
        if bright - dark < 8:
            raise UsageError(f"display lag: the projector's white brightened the camera's view by {bright - dark:.1f} "
                             "grey levels (allowed >= 8): point the camera at what the projector lights, with a "
                             "fixed exposure")
        if not seen[-1].exposure_ns:
            raise UsageError("display lag: needs the camera's exposure times (source camera with a fixed "
                             "--camera-exposure-ms)")
        for frame in seen:
            share = (level(frame) - dark) / (bright - dark)
            if share > 0.05:
                if share < 0.95:  # the onset inside this exposure
                    end = frame.exposure_start_ns + frame.exposure_ns
                    lags.append((end - share * frame.exposure_ns - flip) / 1e6)
                break
    if not lags:
        raise UsageError(f"display lag: in {trials} trials no onset fell inside an exposure; use an exposure near "
                         "the frame period (--camera-exposure-ms)")
    lags.sort()
    return {"lag_ms": lags[len(lags) // 2], "spread_ms": (lags[0], lags[-1]), "trials_ms": lags}


#: lock check: an exposure counts as wholly under its light (or wholly outside it) within this share
WHOLE = 0.05


def lock_check(source: Any, display: Any, *, refresh_ns: int, period_ns: int, exposure_ns: int, lag_ns: int = 0,
               frames: int = 240, settle: int = 3) -> dict:
    """Whether the camera locks to the projector as ``run --camera-lock`` needs it to, checked
    with the camera looking at what the projector lights (``display``: output ``kms``).

    The loop is the locked loop's without the detector: each frame read steers the camera's next
    frame duration (:class:`PhaseLock`, exposures to the middle of a refresh's light, ``lag_ns``
    after its flip), and white goes out at the flip whose light covers the next exposure, black
    at the flip after.  Each frame's share of its exposure lit, (level - black's) / (white's -
    black's), is then 1 when the sensor's timestamps, its frame durations and the display lag are
    all right; an exposure across the light's edge is lit in part.  Returns the frames the lock
    took, the phase errors and the lit shares of the frames after it, and ``ok``: locked within
    half the frames, and every frame after it that the white was shown for lit whole.
    """
    width, height = display.size
    black, white = np.zeros((height, width), np.uint8), np.full((height, width), 255, np.uint8)

    def read() -> Any:
        frame = source.read()
        if frame is None:
            raise UsageError("lock check: the camera stopped delivering frames")
        return frame

    def level(frame: Any) -> float:
        return float(np.mean(frame.image))

    display.show(black)
    dark = level([read() for _ in range(settle)][-1])
    display.show(white)
    bright = level([read() for _ in range(settle)][-1])
    if bright - dark < 8:
        raise UsageError(f"lock check: the projector's white brightened the camera's view by {bright - dark:.1f} "
                         "grey levels (allowed >= 8): point the camera at what the projector lights")
    display.show(black)
    lock = PhaseLock(refresh_ns, period_ns, ((refresh_ns - exposure_ns) // 2 + lag_ns) % refresh_ns,
                     shortest_ns=getattr(source, "shortest_frame_ns", 0))
    errors: list[int] = []
    shares: list[float | None] = []  # each frame's lit share; None: no white was shown for it
    lit_for: int | None = None  # the exposure start the last white was shown for
    for _ in range(frames):
        frame = read()
        start = frame.exposure_start_ns
        if not frame.exposure_ns:
            raise UsageError("lock check: needs the camera's exposure times (a fixed --camera-exposure-ms)")
        if display.presented_ns:
            source.set_frame_duration_ns(lock.update(start, display.presented_ns))
        errors.append(lock.error_ns if lock.error_ns is not None else refresh_ns)
        aimed = lit_for is not None and abs(start - lit_for) < period_ns // 2
        shares.append(min(1.0, max(0.0, (level(frame) - dark) / (bright - dark))) if aimed else None)
        # the white for the first exposure still to come it can reach: at the last flip whose light
        # (lag_ns on) begins by its start
        first = display.next_flip_ns(refresh_ns)
        blank = display.presented_ns or first
        coming = start
        flip = first - refresh_ns
        while flip < first - refresh_ns // 2:
            coming += period_ns
            flip = blank + (coming - lag_ns - blank) // refresh_ns * refresh_ns
        while display.next_flip_ns(refresh_ns) < flip - refresh_ns // 2:
            display.show(black)  # the flips before it
        display.show(white)
        display.show(black)  # (waits for the white's flip to land)
        lit_for = coming
    within = [abs(e) <= LOCKED_WITHIN * refresh_ns for e in errors]
    locked_at = next((k for k in range(len(within)) if all(within[k:])), None)
    after = shares[locked_at:] if locked_at is not None else []
    told = [s for s in after if s is not None]
    whole = sum(s >= 1 - WHOLE for s in told)
    settled = errors[locked_at:] if locked_at is not None else []
    return {"locked_at": locked_at, "frames": frames, "lit_frames": len(told), "whole": whole,
            "least_lit": min(told) if told else None, "median_lit": float(np.median(told)) if told else None,
            "error_us": (float(np.median(np.abs(settled))) / 1e3, float(np.percentile(np.abs(settled), 99)) / 1e3)
            if settled else None,
            "ok": locked_at is not None and locked_at <= frames // 2 and bool(told) and whole == len(told)}
