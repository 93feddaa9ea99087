"""The closed loop's per-frame step, the one ``run`` and the twin both drive.

detect -> track -> predict -> the light strategy's levels and depth probes -> the pattern and the
light the next exposure gets.  No I/O and no clock of its own: the caller passes each frame's
capture time (seconds, the tracker's clock) and, when it knows it, when the pattern will be light
on the scene; stage times come from an injected clock.  ``run`` drives it in real time
(:mod:`antiscatter.runtime`), the twin in virtual time (:mod:`antiscatter.twin`); why:
docs/decisions/011-one-system.md.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, Mapping

import cv2
import numpy as np

from .detection import Detector
from .detections import Detections
from .levels import HoleLevels
from .pattern import GROW, GROW_FROM, camera_light, grow_holes, render_pattern
from .probe import DepthProbe, Intervals
from .strategies import strategy_entry
from .tracking import PREDICT_AHEAD, Tracker

if TYPE_CHECKING:
    from .config import TrackConfig

__all__ = ["System", "LoopSettings", "Step", "Exposure", "make_tracker", "time_stages", "finish_stages"]


def time_stages(detector: Detector, image: np.ndarray, *,
                clock: Callable[[], int] = time.perf_counter_ns, defer: bool = False) -> tuple[Detections, list[int]]:
    """Run the detector's stages on one frame, timing each: (detections, nanoseconds per stage).

    defer: stop before the stages marked ``after`` (learning for the next frames): the
    detections are known without them; :func:`finish_stages` runs them later and adds their
    times to the list.  The one place stages are timed; ``run`` and ``bench`` both use it.
    """
    value = image
    durations: list[int] = []
    t_prev = clock()
    for stage in detector.stages:
        if defer and stage.after:
            break
        value = stage.run(value)
        t_now = clock()
        durations.append(t_now - t_prev)
        t_prev = t_now
    return value, durations


def finish_stages(detector: Detector, detections: Detections, durations: list[int], *,
                  clock: Callable[[], int] = time.perf_counter_ns) -> None:
    """Run the stages :func:`time_stages` deferred (those after ``len(durations)``), timed, their
    nanoseconds appended to ``durations``."""
    value = detections
    for stage in detector.stages[len(durations):]:
        t_prev = clock()
        value = stage.run(value)
        durations.append(clock() - t_prev)


def make_tracker(settings: "TrackConfig | None" = None, *, probing: bool = False,
                 frame_size: tuple[int, int] | None = None) -> Tracker:
    """The tracker of ``run``, the twin and ``evaluate``, from a ``[track]`` section (its defaults when None).

    probing: depth probing draws a new track's hole along its whole line and knows a particle's
    light only from the probe's verdicts (no flow holes, no flux ratio).  frame_size: (width,
    height) px, for the motion settings and the view's edges (None: set later, ``set_frame_size``).
    """
    from .config import TrackConfig

    tc = settings if settings is not None else TrackConfig()
    return Tracker(confirm_hits=tc.confirm_hits, max_misses=tc.max_misses, keep_misses=tc.keep_misses,
                   max_dark=tc.max_dark, revive_frames=tc.revive_frames, merge_reach=tc.merge_reach,
                   flow_holes=not probing, flux_ratio=0.0 if probing else tc.flux_ratio,
                   far_bright=tc.far_bright, accel_floor=tc.accel_floor, miss_cost=tc.miss_cost,
                   flux_cost=tc.flux_cost, frame_size=frame_size)


@dataclass(frozen=True)
class LoopSettings:
    """How the system lights the scene: ``run``'s ``light``, ``pattern`` and ``track`` settings.

    strategy: none, dim, pulse, flash or coast (``LightConfig``); dim_level, flash_level: 0..1 of
    full light.  predict: holes where the particles will be while the pattern is on.  latency_s:
    capture to light, seconds, the prediction reaches over (None: measured, :meth:`System.observe_latency`).
    display_lag_s: from a flip to its light on the scene; refresh_s: the projector's refresh
    (seconds).  grow, grow_from, margin: the holes' growth and margin (:func:`~antiscatter.pattern.grow_holes`,
    projector px).  compensate: tell the detector the light each exposure got (``LightConfig.compensate``).
    """

    strategy: str = "none"
    dim_level: float = 0.1
    flash_level: float = 0.25
    predict: bool = False
    latency_s: float | None = None
    display_lag_s: float = 0.0
    refresh_s: float = 1 / 120
    grow: float = GROW
    grow_from: float = GROW_FROM
    margin: float = 0.0
    compensate: bool = False


@dataclass(frozen=True)
class Exposure:
    """The light one exposure is taken under, as the system made it, and what the next step needs of it."""

    light: np.ndarray | None  # (H, W) uint8 projector pixels, 255 = full; None: the lamp was off
    unlit_ids: Any = None  # the tracks whose holes it holds (none under a flash)
    rested_ids: Any = None  # of them, those fully dark (HoleLevels.rest)
    probes: Mapping = field(default_factory=dict)  # depth probing: each track's interval in it


@dataclass
class Step:
    """One frame on its way through the system (``frame``, ``t0``, ``t1``: the driver's, passed through)."""

    frame: Any
    t0: int  # clock before and after the capture (the driver's clock, ns)
    t1: int
    detections: Detections
    stage_ns: list[int]
    track_ns: int
    track_ids: np.ndarray | None
    pattern: Any  # the holes (Detections) until rendered, then the (H, W) uint8 pattern
    t_processed: int  # when rendering began
    t_pattern: int  # when rendering ended
    probes: Mapping = field(default_factory=dict)  # depth probing: each track's interval in this pattern
    hole_ids: Any = None  # the track ids of this pattern's holes
    intervals: Mapping | None = None  # depth probing with pulse: each track's whole remaining interval
    exposure: Any = None  # pulse with probing, levels or prediction: the pattern for the next exposure
    exposure_holes: Any = None  # pulse with prediction: its holes (Detections), for the time it is on
    rested_ids: Any = None  # the track ids of this pattern's holes left fully dark (HoleLevels.rest)
    learned: threading.Event | None = None  # the detector's deferred stages are done (None: none pending)
    detector: Detector | None = None  # the detector that made it (its deferred stages are that one's)


class _Timing:
    """When frames come and how long their light takes: running means (seconds)."""

    def __init__(self) -> None:
        self.last_capture: float | None = None  # the last frame's capture time
        self.frame_period: float | None = None  # running mean of the capture interval
        self.latency = 0.0  # running mean of the measured capture-to-light time
        self.samples = 0

    def captured(self, captured: float) -> float | None:
        """Note a capture at ``captured``; the frame period as now estimated (None: not yet known)."""
        if self.last_capture is not None and captured > self.last_capture:
            period = captured - self.last_capture
            self.frame_period = period if self.frame_period is None else 0.9 * self.frame_period + 0.1 * period
        self.last_capture = captured
        return self.frame_period


class System:
    """The per-frame step: :meth:`analyse` (detect, track, plan), :meth:`render` (the pattern and the
    pulse's exposure light), then, once the driver knows the light the next exposure is taken
    under, :meth:`expose`.

    Parameters
    ----------
    detector : the detector (its stages timed with ``clock``).
    tracker : None: holes from each frame's detections alone.
    mapping : (3, 3) camera to projector pixels at the working depth.
    camera_size, projector_size : (width, height) px.
    settings : :class:`LoopSettings`.
    levels : each hole's own light (dim, pulse), or None: one level for all.
    probe : depth probing (each track's interval found by bisection), or None.
    ranges : draw each hole over its particle's whole near..far epipolar segment (the twin's
        ``range`` mapping; ``run`` has none), or None.
    light_mapping : (3, 3) camera to projector pixels where the lamp's light is taken to land, for
        compensation (default ``mapping``).
    defer : leave the detector's ``after`` stages to the driver (:func:`finish_stages`).
    buffers : pattern buffers drawn into in turn (1: each step overwrites the last pattern).
    clock : nanoseconds, for the stage times only.
    """

    def __init__(self, detector: Detector, tracker: Tracker | None = None, *, mapping: np.ndarray,
                 camera_size: tuple[int, int], projector_size: tuple[int, int],
                 settings: LoopSettings = LoopSettings(), levels: HoleLevels | None = None,
                 probe: DepthProbe | None = None, ranges: DepthProbe | None = None,
                 light_mapping: np.ndarray | None = None, defer: bool = False, buffers: int = 1,
                 clock: Callable[[], int] = time.perf_counter_ns) -> None:
        self.detector, self.tracker, self.levels, self.probe, self.ranges = detector, tracker, levels, probe, ranges
        self.settings = settings
        self.mapping = mapping
        self.camera_size, self.projector_size = camera_size, projector_size
        width, height = projector_size
        self.strategy = strategy = strategy_entry(settings.strategy)
        self.hole_level = round(settings.dim_level * 255) if strategy.hole == "dim" else 0
        # pulse: while the camera exposes, the last pattern with its holes lifted to dim_level
        self.pulse_level = round(settings.dim_level * 255) if strategy.exposure == "lifted" else None
        self.flash_image = (np.full((height, width), round(settings.flash_level * 255), np.uint8)
                            if strategy.exposure == "flash" else None)
        self.buffers = [np.empty((height, width), np.uint8) for _ in range(buffers)]
        # pulse with probing, levels or prediction: the lifted pattern drawn for the exposure
        self.exposure_buffer = (np.empty((height, width), np.uint8)
                                if (probe is not None or levels is not None or (tracker is not None and settings.predict))
                                and self.pulse_level is not None else None)
        self._lifted: np.ndarray | None = None  # the buffer a pattern is lifted into (lift)
        # the light the next exposure gets, in camera pixels, into one buffer: the detector reads it
        # in the next frame's detection, before the next one is made
        self.camera_from_light = np.linalg.inv(mapping if light_mapping is None else light_mapping)
        self.light_buffer = np.empty(camera_size[::-1], np.uint8) if settings.compensate else None
        self.defer = defer
        self.clock = clock
        self.under = Exposure(None)  # the light the next exposure is taken under
        self.timing = _Timing()
        self._changes: dict[str, Any] = {}  # settings changed while running, for the next analyse
        self._changes_lock = threading.Lock()

    @property
    def level(self) -> float | None:
        """The strategy's hole level, 0..1 of full light (the most a hole gives with adaptive levels);
        None where the strategy has none (its holes dark, the exposure not lifted)."""
        if self.strategy.hole != "dim" and self.pulse_level is None:
            return None
        return self.levels.ceiling if self.levels is not None else (self.pulse_level or self.hole_level) / 255

    def change(self, *, level: float | None = None, detector: Detector | None = None) -> None:
        """Settings changed while the system runs (from another thread), applied as the next
        :meth:`analyse` begins: ``level`` the hole level (0..1 of full light; see :attr:`level`),
        ``detector`` a new detector in place of this one (it learns its background afresh)."""
        with self._changes_lock:
            if level is not None:
                self._changes["level"] = level
            if detector is not None:
                self._changes["detector"] = detector

    def _apply_changes(self) -> None:
        with self._changes_lock:
            changes, self._changes = self._changes, {}
        if "detector" in changes:
            self.detector = changes["detector"]
        if "level" in changes and self.level is not None:
            grey = round(changes["level"] * 255)
            if self.strategy.hole == "dim":
                self.hole_level = grey
            if self.pulse_level is not None:
                self.pulse_level = grey
            if self.levels is not None:
                self.levels.set_ceiling(changes["level"])

    def analyse(self, image: np.ndarray, captured_s: float, *, exposure_s: float = 0.0, on_s: float | None = None,
                found: Detections | None = None, stage_ns: list[int] | None = None,
                frame: Any = None, t0: int = 0, t1: int = 0) -> Step:
        """Detect (unless ``found`` came from a detector process, with its ``stage_ns``) and track;
        the holes to draw wait in ``step.pattern`` until :meth:`render`.

        captured_s: the frame's capture time (seconds, mid-exposure); exposure_s: its exposure
        time; on_s: when this step's pattern will be light on the scene, if the driver knows
        (else the latency setting or the measured one says).
        """
        if self._changes:
            self._apply_changes()
        learned = None
        if found is None:
            detections, stage_ns = time_stages(self.detector, image, clock=self.clock, defer=self.defer)
            if len(stage_ns) < len(self.detector.stages):
                learned = threading.Event()
        else:
            detections = found
        step = Step(frame, t0, t1, detections, stage_ns or [], 0, None, detections, t1 + sum(stage_ns or []), 0,
                    learned=learned, detector=self.detector)
        if self.tracker is not None:
            t_track = self.clock()
            self._track(step, captured_s, exposure_s, on_s)
            step.track_ns = self.clock() - t_track
            step.t_processed = self.clock()
        return step

    def _track(self, step: Step, captured: float, exposure_s: float, on_s: float | None) -> None:
        """Track ``step``'s detections, predict its holes, plan its probes and levels."""
        s, under, detections = self.settings, self.under, step.detections
        tracks = self.tracker.update(detections, captured, unlit=under.unlit_ids)
        step.track_ids = tracks.detection_ids
        prediction = self.tracker.snapshot()
        period = self.timing.captured(captured)
        latency = 0.0
        if s.predict:
            latency = (on_s - captured - s.display_lag_s if on_s is not None else
                       s.latency_s if s.latency_s is not None else self.timing.latency)
            # the pattern stays on until the next one, a frame period later: each hole where its
            # particle is halfway through that time (PREDICT_AHEAD), not where it is when it goes on
            step.pattern = prediction.holes(captured + latency + s.display_lag_s + PREDICT_AHEAD * (period or 0.0))
        else:
            step.pattern = prediction.holes(captured)
        if period is not None and s.compensate:
            # the camera sees our holes (and no flash): where the tracked particles should be in
            # the next frame, faint light is them, dimmed under their holes (open loop this only
            # adds noise; history: docs/decisions/005-light-and-pattern-tuning.md)
            self.detector.expect(prediction.holes(captured + period))
        if self.probe is not None:  # this exposure's verdicts, then the next intervals to try
            seen = Detections(detections.centres, detections.radii, detections.scores, tracks.detection_ids,
                              detections.cut)
            coasting = tracks.confirmed & (tracks.misses > 0)
            self.probe.observe(seen, under.probes, tracks.ids[coasting], exposure=under.light,
                               coasting_centres=tracks.centres[coasting])
            self.probe.forget(tracks.ids)
            step.probes, covers = self.probe.plan(step.pattern)
            if self.pulse_level is not None:
                step.intervals = covers
        if self.pulse_level is not None and s.predict:
            step.exposure_holes = prediction.holes(self._next_exposure(captured, exposure_s, latency, period))
        if self.levels is not None:  # how bright each came back under its own hole (or probe: its verdict)
            self.levels.update(detections, step.track_ids, under.unlit_ids if self.probe is None else self.probe.dimmed,
                               tracks.ids, tracks.ids[tracks.confirmed], rested=under.rested_ids)

    def _next_exposure(self, captured: float, exposure_s: float, latency: float, period: float | None) -> float:
        """Pulse: the time the lifted pattern is drawn for -- the first exposure to start after the
        pattern goes on, at its start (probing: the probes' halves it judges) or a refresh's middle
        from then (history: docs/decisions/005-light-and-pattern-tuning.md)."""
        started = captured - exposure_s / 2  # frames are stamped mid-exposure
        on = latency + self.settings.display_lag_s  # until the pattern is light on the scene
        first = started + (period * max(1, math.ceil(on / period - 1e-9)) if period else on)
        return first if self.probe is not None else first + self.settings.refresh_s / 2

    def render(self, step: Step) -> Step:
        """Draw the step's holes into the next pattern buffer (and, for pulse, its exposure light
        into ``step.exposure`` where it is drawn on its own)."""
        t_start = self.clock()
        buffer = self.buffers[0]
        self.buffers.append(self.buffers.pop(0))
        if self.probe is not None:
            self._render_probes(step, buffer)
        else:
            self._render_holes(step, buffer)
        step.t_pattern = self.clock()
        step.t_processed = t_start
        return step

    def _grown(self, holes: Detections) -> Detections:
        s = self.settings
        return grow_holes(holes, grow=s.grow, start=s.grow_from, frame_width=self.camera_size[0])

    def _draw(self, holes: Detections, out: np.ndarray, hole: int | np.ndarray) -> np.ndarray:
        """``holes`` (camera px) into ``out``: at the mapping, or over their whole depth range (``ranges``)."""
        if self.ranges is not None:
            return self.ranges.render(holes, {}, size=self.projector_size, margin=self.settings.margin, out=out,
                                      hole=hole)
        return render_pattern(holes, size=self.projector_size, mapping=self.mapping, margin=self.settings.margin,
                              out=out, hole=hole)

    def _render_probes(self, step: Step, buffer: np.ndarray) -> None:
        # a probe the camera sees is drawn as found: grown, its halves would overlap and its verdict
        # blur; the whole intervals dark between pulsed exposures grow
        holes, margin, size = step.pattern, self.settings.margin, self.projector_size
        step.hole_ids = Intervals.of(step.probes).ids  # the holes worth drawing (DepthProbe.min_worth)
        grey = self.levels.grey(holes.track_ids) if self.levels is not None else None
        # pulse: between exposures each track's whole interval is dark; the probe's half is
        # only needed while the camera looks, lifted to the dim level (or each track's own)
        step.pattern = self.probe.render(holes if step.intervals is None else self._grown(holes),
                                         step.probes if step.intervals is None else step.intervals,
                                         size=size, margin=margin, out=buffer,
                                         hole=grey if grey is not None and step.intervals is None
                                         else self.hole_level, given_only=True)
        if step.intervals is not None:
            # (holes of one prediction for another time: the same tracks in the same order, so the same levels)
            exposed = holes if step.exposure_holes is None else step.exposure_holes
            step.exposure = self.probe.render(exposed, step.probes, size=size, margin=margin,
                                              out=self.exposure_buffer,
                                              hole=self.pulse_level if grey is None else grey, given_only=True)

    def _render_holes(self, step: Step, buffer: np.ndarray) -> None:
        holes = self._grown(step.pattern)
        step.hole_ids = holes.track_ids
        grey = self.levels.grey(holes.track_ids) if self.levels is not None else None
        if self.levels is not None:
            step.rested_ids = self.levels.rested(holes.track_ids)
        if step.exposure_holes is not None:
            # pulse, predicted: the lifted pattern drawn for its own time (a second drawing), each
            # hole at its own level or at the pulse's (the same tracks as ``holes``, in the same
            # order: the same levels)
            step.exposure = self._draw(self._grown(step.exposure_holes), self.exposure_buffer,
                                       self.pulse_level if grey is None else grey)
            step.pattern = self._draw(holes, buffer, 0)
        elif grey is not None and self.pulse_level is not None:
            # pulse: each hole at its own level while the camera looks; between exposures the same
            # holes dark, wherever the lifted pattern is not full (not a second drawing)
            step.exposure = self._draw(holes, self.exposure_buffer, grey)
            step.pattern = (cv2.compare(step.exposure, 255, cv2.CMP_EQ, dst=buffer) if self.pulse_level < 255
                            else self._draw(holes, buffer, 0))
        else:  # dim holes at their own levels, or every hole at one
            step.pattern = self._draw(holes, buffer, self.hole_level if grey is None else grey)

    def lift(self, step: Step, shown: np.ndarray, *, drawn: bool = True) -> np.ndarray:
        """The light of the exposure that follows ``shown``: with pulse the step's own lifted
        pattern when it drew one (and ``drawn``), else ``shown`` with its holes lifted to the pulse
        level (into one buffer, valid until the next call); with other strategies ``shown``."""
        if self.pulse_level is None:
            return shown
        if step.exposure is not None and drawn:
            return step.exposure
        # cv2.max: a tenth of np.maximum's time against a scalar
        self._lifted = cv2.max(shown, self.pulse_level, dst=self._lifted)
        return self._lifted

    def made(self, step: Step, light: np.ndarray | None, *, pattern: bool = False) -> Exposure:
        """What an exposure under ``light`` (None: the lamp off) made from ``step`` is taken under:
        its holes' tracks unlit (none under a flash), its probes; ``pattern``: under the pattern
        itself, between exposures, where every hole is dark and no probe is judged."""
        if pattern:
            dark = step.hole_ids if light is not None else None
            return Exposure(light, dark, dark, {})
        unlit = step.hole_ids if light is not None and self.strategy.unlit else None
        return Exposure(light, unlit, step.rested_ids if unlit is not None else None,
                        step.probes if light is not None else {})

    def expose(self, under: Exposure) -> None:
        """The next exposure is taken under ``under``: the tracker, levels and probe read it, and
        with compensation the detector is told its light (in camera pixels)."""
        self.under = under
        if self.settings.compensate:
            self.detector.set_light(None if under.light is None else
                                    camera_light(under.light, self.camera_from_light, self.camera_size,
                                                 out=self.light_buffer))

    def observe_latency(self, seconds: float) -> None:
        """A measured capture-to-light time: the running mean the prediction reaches over when no
        latency is set (weight 0.1 after the first)."""
        timing = self.timing
        timing.latency += (seconds - timing.latency) * (0.1 if timing.samples else 1.0)
        timing.samples += 1
