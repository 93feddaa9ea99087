"""The runtime loop: source -> detector stages -> pattern -> light outputs.

This is the one place that reads clocks around the stages
(``time.perf_counter_ns``); it writes the per-frame metrics CSV with the
report's columns, the detections CSV, and prints the report's table 1 summary.
"""

from __future__ import annotations

import array
import collections
import math
import os
import signal
import sys
import threading
import time
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator, TextIO

import cv2
import numpy as np

from .config import Config, light_ahead_reaches, parse_size
from .detection import Detector, check_frame_size, make_detector
from .detections import Detections
from .errors import SIGTERM_RECEIVED, UsageError, check_output_path
from .writing import CsvFile
from .levels import HoleLevels
from .lock import FLIP_MARGIN_S
from .outputs import LightOutput, check_output, open_output
from .pattern import scale_mapping
from .sources import FrameSource, open_source, parse_crop
from .sources.base import FrameClock, seconds_text
from .stats import RunningStats
from .strategies import strategy_entry
from .system import Exposure, LoopSettings, Step, System, finish_stages, make_tracker, time_stages

__all__ = ["REPORT_COLUMNS", "metrics_columns", "time_stages", "finish_stages", "Pacer", "RunSummary", "run",
           "set_niceness", "StopFlag", "LatestSlot", "apply_process_controls", "MODES"]

#: Execution modes of ``antiscatter run``.
MODES = ("single", "threads", "processes", "processes-pickle")

#: The report's metrics CSV columns, in its order (SPEC section 3).
REPORT_COLUMNS = (
    "Capture Duration (s)",
    "Greyscale Conversion Duration (s)",
    "Gaussian Blur Duration (s)",
    "Histogram Equalisation Duration (s)",
    "Binary Thresholding Duration (s)",
    "Canny Algorithm Duration (s)",
    "CV2 findContours() Duration (s)",
    "CV2 minEnclosingCircle() Duration (s)",
    "Number of MECs on screen",
    "Total frame processing time (s)",
)
#: Columns this product adds after the report's.
EXTRA_COLUMNS = (
    "Frame",
    "Frame Time (s)",
    "Capture Timestamp (ns)",
    "Tracking Duration (s)",
    "Pattern Rendering Duration (s)",
    "Output Duration (s)",
    "End-to-end Latency (s)",
    "Dropped Frames",
    "Exposure Phase Error (s)",
    "Candidates Cut",
)


def metrics_columns(detector: Detector) -> list[str]:
    """The metrics CSV header: the report's columns, then ours, then detector stages the report lacked."""
    extra_stages = [f"{s.label} Duration (s)" for s in detector.stages
                    if f"{s.label} Duration (s)" not in REPORT_COLUMNS]
    return [*REPORT_COLUMNS, *EXTRA_COLUMNS, *extra_stages]


@contextmanager
def _opencv_threads(threads: int) -> Iterator[None]:
    """OpenCV's own functions on ``threads`` threads while the block runs (``run --threads``; the
    process's setting before, OpenCV's default one a core, is put back after)."""
    previous = cv2.getNumThreads()
    cv2.setNumThreads(threads)
    try:
        yield
    finally:
        cv2.setNumThreads(previous)


class Pacer:
    """Drift-free pacing at ``fps``: frame k is released at ``start + k / fps``.

    A frame that is already late is released at once; when the loop falls more
    than one period behind, the schedule restarts from now instead of bursting.
    ``clock`` returns nanoseconds and ``sleep`` takes seconds (injectable for tests).
    """

    def __init__(self, fps: float, *, clock: Callable[[], int] = time.monotonic_ns,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        self.period_ns = int(round(1e9 / fps)) if fps > 0 else 0
        self._clock = clock
        self._sleep = sleep
        self._next: int | None = None

    def wait(self) -> None:
        if not self.period_ns:
            return
        now = self._clock()
        if self._next is None:
            self._next = now
        delay = self._next - now
        if delay > 0:
            self._sleep(delay / 1e9)
        elif -delay > self.period_ns:
            self._next = now
        self._next += self.period_ns


def apply_process_controls(rc: Any) -> list[str]:
    """Niceness, real-time priority, CPU affinity, memory locking: each reports whether it took effect."""
    notes = []
    if rc.nice is not None:
        notes.append(set_niceness(rc.nice) or f"niceness set to {rc.nice}")
    if rc.rt_priority is not None:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(rc.rt_priority))
            notes.append(f"real-time priority SCHED_FIFO {rc.rt_priority} set")
        except (PermissionError, OSError) as exc:
            notes.append(f"warning: --rt-priority {rc.rt_priority} not applied ({exc.strerror or exc}); "
                         "needs root or CAP_SYS_NICE")
    if rc.cpus:
        cpus = {int(c) for c in rc.cpus.split(",")}
        try:
            os.sched_setaffinity(0, cpus)
            notes.append(f"running on CPUs {sorted(os.sched_getaffinity(0))}")
        except OSError as exc:
            notes.append(f"warning: --cpus {rc.cpus} not applied ({exc.strerror or exc})")
    if rc.mlock:
        notes.append(lock_memory())
    return notes


def lock_memory() -> str:
    """mlockall(MCL_CURRENT | MCL_FUTURE): no page faults to swap in the real-time loop."""
    import ctypes
    import ctypes.util

    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        if libc.mlockall(1 | 2) != 0:
            return f"warning: --mlock not applied ({os.strerror(ctypes.get_errno())}); raise ulimit -l or run as root"
    except (OSError, AttributeError) as exc:
        return f"warning: --mlock not applied ({exc})"
    return "memory locked (mlockall)"


def set_niceness(nice: int) -> str | None:
    """Ask for process niceness ``nice``; a warning text when not permitted, else None."""
    try:
        os.setpriority(os.PRIO_PROCESS, 0, nice)
    except PermissionError:
        return (f"warning: --nice {nice} needs more privilege (root or CAP_SYS_NICE); "
                f"running at niceness {os.getpriority(os.PRIO_PROCESS, 0)}")
    return None


@dataclass
class RunSummary:
    """What a run did: counts, why it stopped, per-column running statistics (seconds)."""

    frames: int = 0
    stop_reason: str = ""
    particles: RunningStats = field(default_factory=RunningStats)
    durations: dict[str, RunningStats] = field(default_factory=dict)
    wall_s: float = 0.0
    dropped: int = 0
    period_ns: int = 0
    notes: list = field(default_factory=list)  # what the run found worth saying at its end
    # the panel's recordings in the order started: {"path", "frames"} or {"path", "error"}
    recordings: list = field(default_factory=list)
    cut: int = 0  # candidates the detector's work bound left out, over the run
    cut_frames: int = 0  # frames where it left any out
    damaged: str = ""  # the source ended before its declared end (a file cut short): the warning, else ""
    synthetic: bool = False  # the source drew its frames (the simulator): that drawing is not counted as capture
    # per-frame times as compact int64 arrays (8 bytes a frame), for percentiles and pacing
    output_times: array.array = field(default_factory=lambda: array.array("q"))
    latencies_ns: array.array = field(default_factory=lambda: array.array("q"))

    def pacing(self) -> dict[str, float]:
        """Achieved output rate and frame-interval error (against the --fps period, or the mean interval)."""
        if len(self.output_times) < 3:
            return {}
        times = np.asarray(self.output_times, dtype=np.float64)
        intervals = np.diff(times)
        period = self.period_ns or float(np.mean(intervals))
        error = np.abs(intervals - period) / 1e6
        return {"rate": (len(times) - 1) / ((times[-1] - times[0]) / 1e9),
                "jitter_p50_ms": float(np.median(error)), "jitter_p99_ms": float(np.percentile(error, 99)),
                "jitter_max_ms": float(error.max())}

    def table(self) -> str:
        """The report's table 1 layout: stage, mean and standard deviation in microseconds."""
        lines = [f"{'stage':<34}{'mean (us)':>12}{'sd (us)':>12}{'max (us)':>12}"]
        for column, stats in self.durations.items():
            if stats.count == 0:
                continue
            label = column.replace(" Duration (s)", "").replace(" (s)", "")
            lines.append(f"{label:<34}{stats.mean * 1e6:>12.1f}{stats.std * 1e6:>12.1f}"
                         f"{stats.max * 1e6:>12.1f}")
        return "\n".join(lines)


class StopFlag:
    """Set by SIGINT/SIGTERM (or the panel's Stop, via ``reason``); a second Ctrl-C raises KeyboardInterrupt at once."""

    def __init__(self) -> None:
        self.reason = ""
        self._previous: dict[int, object] = {}

    def __bool__(self) -> bool:
        return bool(self.reason)

    def _handle(self, signum: int, _frame: object) -> None:
        if self.reason and signum == signal.SIGINT:
            raise KeyboardInterrupt
        self.reason = signal.Signals(signum).name

    def __enter__(self) -> "StopFlag":
        for signum in (signal.SIGINT, signal.SIGTERM):
            try:
                self._previous[signum] = signal.signal(signum, self._handle)
            except ValueError:  # not the main thread
                pass
        if SIGTERM_RECEIVED.is_set():  # asked to stop before, where the exception was swallowed
            self.reason = self.reason or "SIGTERM"
        return self

    def __exit__(self, *exc: object) -> None:
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)  # type: ignore[arg-type]


def _open_csv(path: str, header: list[str]) -> CsvFile:
    """A CSV written whole rows at a time (a full disk leaves it whole); its path was checked before any work."""
    try:
        return CsvFile(path, header)
    except OSError as exc:
        raise UsageError(f"{path}: cannot be written ({exc.strerror or exc})") from None


def _open_source(config: Config, detector: Detector) -> FrameSource:
    sc = config.source
    crop = parse_crop(sc.crop) if sc.crop else None
    size = parse_size(sc.size) if sc.size else None
    return open_source(sc.spec, crop=crop, loop=sc.loop, sim_preset=sc.preset, seed=sc.seed,
                       size=size, fps=sc.camera_fps, colour=sc.camera_colour,
                       exposure_ms=sc.camera_exposure_ms or None, gain=sc.camera_gain or None,
                       working_size=detector.working_size if sc.camera_lores else None)


def _make_system(config: Config, detector: Detector, tracker: Any, camera_size: tuple[int, int], calibration: Any,
                 *, buffers: int, defer: bool) -> System:
    """The run's :class:`~antiscatter.system.System`: its mapping (the configured matrix, else the
    calibration's, else the camera scaled to the projector), the light map's mapping (a calibration
    with a baseline: its plane at ``light.far_m``), levels and depth probe from ``config``."""
    light, pattern = config.light, config.pattern
    projector_size = (pattern.width, pattern.height)
    mapping = pattern.matrix()
    if mapping is None and calibration is not None:
        mapping = calibration.homography
    if mapping is None:
        mapping = scale_mapping(camera_size, projector_size)
    probe = None
    if light.depth == "probe":
        from .probe import DepthProbe

        if calibration is None or calibration.baseline_m is None:
            raise UsageError(f"{pattern.calibration}: light.depth probe needs a calibration with a "
                             "baseline (measured at two or more distances)")
        probe = DepthProbe(calibration.mapping_at, near_m=light.near_m, far_m=light.far_m,
                           dim_level=light.dim_level, projector_size=projector_size, min_worth=light.min_worth)
    # each hole's own light (dim, or pulse while the camera exposes): tracked, not probed
    strategy = strategy_entry(light.strategy)
    levels = (HoleLevels(light.dim_level, floor=min(light.min_level, light.dim_level),
                         rest=light.rest if probe is None else 0)
              if light.levels == "adaptive" and strategy.visible and tracker is not None else None)
    tc = config.track
    settings = LoopSettings(strategy=light.strategy, dim_level=light.dim_level, flash_level=light.flash_level,
                            predict=tc.predict, latency_s=tc.latency_ms / 1e3 if tc.latency_ms >= 0 else None,
                            display_lag_s=pattern.display_lag_ms / 1e3, refresh_s=1.0 / pattern.refresh_hz,
                            grow=pattern.grow, grow_from=pattern.grow_from, margin=pattern.margin,
                            compensate=bool(light.compensate) and strategy.exposure != "flash"
                            and config.run.mode == "single")
    # the light the detector is told of lands on the background, taken to be at the far working
    # distance: a calibration with a baseline gives that plane's mapping (the working plane's is
    # off by the parallax there; docs/decisions/011-one-system.md)
    far = (calibration.mapping_at(light.far_m) if pattern.matrix() is None and calibration is not None
           and calibration.baseline_m is not None else None)
    return System(detector, tracker, mapping=mapping, camera_size=camera_size, projector_size=projector_size,
                  settings=settings, levels=levels, probe=probe, defer=defer, buffers=buffers, light_mapping=far)


#: frames per second of a folder of images, which has no clock of its own, when the run is not
#: paced (``--fps``): the camera's default rate
FOLDER_FPS = 60.0


class _Pipeline:
    """Per-run state shared by the execution modes: the I/O around the :class:`~antiscatter.system.System`'s
    per-frame step (outputs and their light, CSVs, panel, recording, the locked loop's lights)."""

    def __init__(self, config: Config, detector: Detector, tracker: Any, source: FrameSource, calibration: Any,
                 outputs: list[LightOutput], metrics_writer: Any, detections_writer: Any,
                 columns: list[str], summary: RunSummary, buffers: int) -> None:
        self.config = config
        self.detector = detector
        if tracker is not None:
            tracker.set_frame_size(source.size)  # motion settings for 800 px wide frames; the view's edges
        self.outputs = outputs
        self.metrics_writer = metrics_writer
        self.detections_writer = detections_writer
        self.summary = summary
        # the tracker's clock: a camera's sensor time; a file's or the simulator's own frame times
        # (replays run faster or slower than they were taken, and velocities are per scene second):
        # a video's presentation times, a folder's index over this interval
        self.frame_interval = None
        if not getattr(source, "live", False):
            rate = source.fps or config.run.fps or FOLDER_FPS
            self.frame_interval = 1.0 / rate
        # the frame's true time: the tracker's, and in the CSVs and the MCAP log (a live source's as UNIX time)
        self.frame_clock = FrameClock(live=self.frame_interval is None, interval_s=self.frame_interval or 0.0)
        self.camera_fps = source.fps  # the source's nominal rate (the panel's recordings)
        # the detector's learning for the next frames (stages marked ``after``) runs once the
        # pattern is out: in single mode by emit, with threads by the process thread meanwhile
        # (a worker process runs its detector whole)
        self.system = _make_system(config, detector, tracker, source.size, calibration, buffers=buffers,
                                   defer=config.run.mode in ("single", "threads"))
        self.learn_on_emit = config.run.mode == "single"
        system = self.system
        width, height = system.projector_size
        self.exposing = system.flash_image is not None or system.pulse_level is not None
        # the camera locked to the projector: the exposure's light goes out with each new pattern,
        # the pattern itself once that light's refresh is over (run_locked)
        self.locked = config.source.camera_lock
        self.phase_error_ns: int | None = None  # locked: the last exposure's start against its target
        self.full_image = np.full((height, width), 255, np.uint8)
        self.last_pattern: np.ndarray | None = None  # the pattern the lamp shows between exposures
        self.pulse_image: np.ndarray | None = None  # the last pattern, lifted (pulse)
        self.refresh_s = 1.0 / config.pattern.refresh_hz
        self.display_lag_s = config.pattern.display_lag_ms / 1e3  # from a flip to its light on the scene
        self.refresh_ns = int(round(self.refresh_s * 1e9))
        self.display_lag_ns = int(round(self.display_lag_s * 1e9))
        # the output whose flips are timed (kms): the locked loop schedules its flips by it
        self.display = next((o for o in outputs if o.name == "kms"), None)
        self.lift_at_ns = 0  # locked: the flip the next exposure's light is to land at (run_locked)
        self.lit_frame = 0  # locked: the index of the frame it is for
        # locked, a display lagging about a refresh: the last frame's light went out before this
        # frame was processed (runtime.light_ahead); its pattern is then light from pattern_on_ns
        self.ahead = False
        self.pattern_on_ns: int | None = None
        # locked, a display lagging more: this frame's light goes out after its pattern, for the
        # exposure after the next (runtime.light_after)
        self.post = False
        self._pattern_before: Exposure | None = None  # locked: the pattern the last frame showed
        # (kept only where a light may go out after the pattern: a refresh of slack for the lock's error)
        self._pattern_copies = ([np.empty((height, width), np.uint8) for _ in range(2)]
                                if self.locked and not light_ahead_reaches(config.source, config.pattern,
                                                                           slack_s=self.refresh_s)
                                else [])
        self._made: Exposure | None = None  # the light the last frame made, for the exposure it reaches
        self._flashed: Exposure | None = None  # the light that went out ahead, for the next exposure
        self._ahead_buffers: list[np.ndarray] = []  # (two: the next one goes out before it is judged)
        self.columns = columns
        self.index_of = {c: i for i, c in enumerate(columns)}
        self.stage_columns = [f"{st.label} Duration (s)" for st in detector.stages]
        self.row = [0.0] * len(columns)
        self.clock = time.perf_counter_ns
        self.panel: Any = None
        self.bar: Any = None  # the progress bar on a terminal (console.progress), advanced a frame at a time
        self.mcap: Any = None  # the MCAP log (--mcap), set by run
        self.light_on = True
        self.record_wanted = False
        self.record_path: Path | None = None  # a recording claimed by the panel, for the loop to start
        self.recorder: Any = None
        self.recording: dict[str, Any] = {}  # the summary's entry of the recording under way
        self.log: TextIO = sys.stderr  # where a failed recording is reported at once
        self._closers: list[threading.Thread] = []
        self._dark: np.ndarray | None = None

    @property
    def tracker(self) -> Any:
        return self.system.tracker

    def process(self, frame: Any, t0: int, t1: int, found: Detections | None = None,
                stage_ns: list[int] | None = None) -> Step:
        """Detect (unless ``found`` came from a detector process), track, render the pattern."""
        return self.render(self.analyse(frame, t0, t1, found, stage_ns))

    def analyse(self, frame: Any, t0: int, t1: int, found: Detections | None = None,
                stage_ns: list[int] | None = None) -> Step:
        """Detect and track (:meth:`System.analyse`) at the frame's capture time: the camera's
        sensor time, or the file's or simulator's own frame time (``FrameClock.source_ns``)."""
        captured = self.frame_clock.source_ns(frame) / 1e9
        on_s = self.pattern_on_ns / 1e9 if self.pattern_on_ns is not None else None  # the locked loop knows
        # a frame the camera's ISP also scaled (Frame.pooled) goes to the detector as that
        image = frame.image if frame.pooled is None else frame.pooled
        return self.system.analyse(image, captured, exposure_s=frame.exposure_ns / 1e9, on_s=on_s,
                                   found=found, stage_ns=stage_ns, frame=frame, t0=t0, t1=t1)

    def learn(self, rec: Step) -> None:
        """Run the detector's deferred stages for ``rec`` (its learning for the next frames), timed
        into its stage times; always marks them done, so nothing waits on a failed one."""
        if rec.learned is None or rec.learned.is_set():
            return
        try:
            finish_stages(rec.detector or self.detector, rec.detections, rec.stage_ns, clock=self.clock)
        finally:
            rec.learned.set()

    def render(self, rec: Step) -> Step:
        """Draw the record's holes into the next pattern buffer."""
        return self.system.render(rec)

    def _expose(self, rec: Step, shown: np.ndarray) -> np.ndarray:
        """The light the next exposure is taken under: with pulse the pattern with its holes lifted
        (kept as ``pulse_image``), else the pattern ``shown``, which is kept as ``last_pattern``."""
        exposed = shown
        if self.exposing:
            # flash and pulse run in mode single: the next capture, and the restore after it, come
            # before the next pattern is drawn, so these buffers are still intact then (no copies)
            self.last_pattern = shown
            if self.system.pulse_level is not None:  # drawn lifted: probing's halves, levels, prediction
                self.pulse_image = exposed = self.system.lift(rec, shown, drawn=self.light_on)
        return exposed

    def after_exposure(self, rec: Step) -> None:
        """Locked camera: the pattern on every output once the exposure's light has had its refresh
        (``kms`` waits for that light's flip, so the pattern lands at the next one)."""
        image = self.last_pattern if self.last_pattern is not None else self.full_image
        if not self.light_on:
            image = np.zeros_like(image)
        for output in self.outputs:
            output.show(image, rec.frame, rec.detections)

    def flash(self) -> int:
        """Show the next exposure's light on every output -- the uniform detection flash, or the
        last pattern with its holes lifted (pulse); the time it went on (monotonic ns)."""
        if self.system.flash_image is not None:
            image = self.system.flash_image
        else:
            image = self.pulse_image if self.pulse_image is not None else self.full_image
        if not self.light_on:
            image = np.zeros_like(image)
        for output in self.outputs:
            output.flash(image)
        return time.monotonic_ns()

    def flash_ahead(self, before: int) -> None:
        """Locked, the light ahead: the exposure light the last frame made goes out on every output
        now (at the next flip), before frame ``before`` - 1 is processed; that frame's :meth:`emit`
        then shows its pattern, and the exposure after it is judged by this light."""
        made = self._made if self._made is not None else Exposure(self.full_image)
        image = made.light
        if image is not None:  # (its buffers are redrawn before it is judged)
            if len(self._ahead_buffers) < 2:
                self._ahead_buffers.append(np.empty_like(image))
            self._ahead_buffers.reverse()
            image = self._ahead_buffers[0]
            np.copyto(image, made.light)
            made = Exposure(image, made.unlit_ids, made.rested_ids, made.probes)
        self._flashed = made
        if self.system.flash_image is not None:
            image = self.system.flash_image
        if image is None or not self.light_on:
            image = np.zeros_like(self.full_image)
        for output in self.outputs:
            output.flash(image, before)

    def restore(self) -> None:
        """The exposure is over: the last pattern back on every output while the frame is processed."""
        image = self.last_pattern if self.last_pattern is not None else self.full_image
        if not self.light_on:
            image = np.zeros_like(image)
        for output in self.outputs:
            output.restore(image)

    def emit(self, rec: Step, dropped: int) -> bool:
        """Show the pattern, log the frame; True when an output asked to stop."""
        clock = self.clock
        t_show = clock()
        shown = rec.pattern
        if not self.light_on:  # the panel's Light off: the lamp goes dark, the loop goes on
            if self._dark is None or self._dark.shape != shown.shape:
                self._dark = np.zeros_like(shown)
            shown = self._dark
        if self.locked and not (self.ahead or self.post):  # the next exposure's light at its flip; the pattern once it
            exposed = self._expose(rec, shown)  # has been on (after_exposure)
            light = self.system.flash_image if self.system.flash_image is not None else exposed
            if not self.light_on:
                light = shown
            while self.display.next_flip_ns(self.refresh_ns) < self.lift_at_ns - self.refresh_ns // 2:  # spare flips:
                for output in self.outputs:  # the new pattern in them
                    output.show(shown, rec.frame, rec.detections)
            for output in self.outputs:
                output.flash(light, self.lit_frame)
        else:  # (ahead: the light went out before the frame was processed; post: it goes out after)
            for output in self.outputs:
                output.show(shown, rec.frame, rec.detections)
        t_out = clock()
        shown_ns = time.monotonic_ns()  # the pattern is out: what follows is off the latency path
        if rec.learned is not None:
            if self.learn_on_emit:
                self.learn(rec)
            else:  # the process thread is doing it (it always marks it done)
                rec.learned.wait()
        if not self.locked or self.ahead or self.post:
            exposed = self._expose(rec, shown)
        # the next exposure is taken under this pattern, or its light (its holes, none under a flash)
        made = self._made = self.system.made(rec, exposed if self.light_on else None)
        if self.ahead:  # ... unless the last frame's went out ahead of this one: the next exposure is under it
            made = self._flashed
        elif self.post:  # ... or none went out for it (the first light after a pattern): it is under the
            made = self._pattern_before or Exposure(self.full_image)  # pattern shown before this one
        if self._pattern_copies:  # (kept for that: mode single draws every pattern into one buffer)
            self._pattern_copies.reverse()  # (two: the last is judged by until the next frame is processed)
            np.copyto(self._pattern_copies[0], shown)
            self._pattern_before = self.system.made(  # (between exposures its holes are dark)
                rec, self._pattern_copies[0] if self.light_on else None, pattern=True)
        # (mode single: the buffer stays intact until the next frame is processed)
        self.system.expose(made)
        self._record(rec.frame)
        latency_ns = shown_ns - rec.frame.timestamp_ns
        summary = self.summary
        summary.output_times.append(shown_ns)
        summary.latencies_ns.append(latency_ns)
        summary.dropped += dropped
        self.system.observe_latency(latency_ns / 1e9)
        values = {"Capture Duration (s)": (rec.t1 - rec.t0) / 1e9,
                  "Total frame processing time (s)": (rec.t1 - rec.t0 + sum(rec.stage_ns)) / 1e9,
                  "Pattern Rendering Duration (s)": (rec.t_pattern - rec.t_processed) / 1e9,
                  "Output Duration (s)": (t_out - t_show) / 1e9,
                  "End-to-end Latency (s)": latency_ns / 1e9}
        if self.tracker is not None:
            values["Tracking Duration (s)"] = rec.track_ns / 1e9
        for column, ns in zip(self.stage_columns, rec.stage_ns):
            values[column] = ns / 1e9
        for column, v in values.items():
            summary.durations[column].add(v)
        summary.particles.add(len(rec.detections))
        summary.frames += 1
        if self.bar is not None:
            self.bar.update()
        if rec.detections.cut:
            summary.cut += rec.detections.cut
            summary.cut_frames += 1
        frame, detections = rec.frame, rec.detections
        stamp_ns = self.frame_clock.stamp_ns(frame)
        if self.metrics_writer is not None:
            row, index_of = self.row, self.index_of
            for i in range(len(row)):
                row[i] = 0.0
            for column, v in values.items():
                row[index_of[column]] = f"{v:.9f}"
            row[index_of["Number of MECs on screen"]] = len(detections)
            row[index_of["Frame"]] = frame.index
            row[index_of["Frame Time (s)"]] = seconds_text(stamp_ns)
            row[index_of["Capture Timestamp (ns)"]] = frame.timestamp_ns
            row[index_of["Dropped Frames"]] = dropped
            row[index_of["Candidates Cut"]] = detections.cut
            if self.phase_error_ns is not None:
                row[index_of["Exposure Phase Error (s)"]] = f"{self.phase_error_ns / 1e9:.9f}"
            self.metrics_writer.writerow(row)
        if self.detections_writer is not None and len(detections):
            when = seconds_text(stamp_ns)
            if rec.track_ids is None:
                self.detections_writer.writerows(
                    (frame.index, when, f"{x:.3f}", f"{y:.3f}", f"{r:.3f}")
                    for (x, y), r in zip(detections.centres.tolist(), detections.radii.tolist()))
            else:
                self.detections_writer.writerows(
                    (frame.index, when, f"{x:.3f}", f"{y:.3f}", f"{r:.3f}", i)
                    for (x, y), r, i in zip(detections.centres.tolist(), detections.radii.tolist(),
                                            rec.track_ids.tolist()))
        if self.mcap is not None:  # the frame's ROS 2 messages (off the latency path: the pattern is out)
            self.mcap.write(stamp_ns, image=frame.image, detections=detections,
                            track_ids=rec.track_ids, pattern=shown,
                            metrics={**values, "Frame": frame.index, "Particles": len(detections),
                                     "Dropped Frames": dropped, "Candidates Cut": detections.cut})
        if self.panel is not None:
            self._publish(rec, latency_ns, dropped)
        return any(o.exit_requested for o in self.outputs)

    def _record(self, frame: Any) -> None:
        """Start, feed or stop the panel's recording of the input frames, each at its true time.

        A recording that fails (its file cannot be opened or written) stops with a message in the
        log and the summary; the run and its light go on.
        """
        if self.recorder is not None and (not self.record_wanted or self.record_path is not None):
            self.stop_recording()
        if self.record_wanted and self.record_path is not None:
            path, self.record_path = self.record_path, None
            entry = {"path": str(path)}
            self.summary.recordings.append(entry)
            try:
                from .record import Recorder

                clock = self.frame_clock
                self.recorder = Recorder(path, fps=self.config.run.fps or self.camera_fps or 30.0,
                                         unix_offset_ns=clock.offset_ns if clock.live else None)
            except Exception as exc:  # noqa: BLE001 - no recording may stop the light
                self.record_wanted = False
                self._recording_failed(entry, exc)
                return
            self.recording = entry
        if self.recorder is not None:
            try:
                self.recorder.write(frame.image, time_ns=self.frame_clock.source_ns(frame),
                                    exposure_ns=frame.exposure_ns, analogue_gain=frame.analogue_gain)
            except Exception as exc:  # noqa: BLE001 - no recording may stop the light
                self.record_wanted = False
                self._recording_failed(self.recording, exc)
                self.stop_recording()

    def _recording_state(self) -> str:
        """The panel's figure: the file being recorded, ``no``, or why the last recording failed."""
        if self.recorder is not None:
            return str(self.recorder.path)
        last = self.summary.recordings[-1] if self.summary.recordings else {}
        return f"failed: {last['path']}: {last['error']}" if "error" in last else "no"

    def _recording_failed(self, entry: dict[str, Any], exc: BaseException) -> None:
        """Note a failed recording in its summary entry and the log (once)."""
        if "error" in entry:
            return
        entry["error"] = str(exc) or type(exc).__name__
        print(f"panel recording {entry['path']} failed: {entry['error']}; the run goes on", file=self.log)

    def stop_recording(self, *, wait: bool = False) -> None:
        """Finish the recording in the background (the loop must not wait for the encoder)."""
        if self.recorder is not None:
            recorder, self.recorder = self.recorder, None
            entry, self.recording = self.recording, {}

            def close() -> None:
                try:
                    figures = recorder.close()
                except Exception as exc:  # noqa: BLE001 - reported, the run goes on
                    self._recording_failed(entry, exc)
                    return
                entry.update(figures)

            closer = threading.Thread(target=close, name="antiscatter-recorder-close")
            closer.start()
            self._closers.append(closer)
        if wait:
            for closer in self._closers:
                closer.join()
            if self.record_path is not None:  # claimed by the panel, never started: leave no empty file
                path, self.record_path = self.record_path, None
                if path.is_file() and path.stat().st_size == 0:
                    path.unlink()

    def _publish(self, rec: Step, latency_ns: int, dropped: int) -> None:
        summary = self.summary
        sample = {"t": time.monotonic(), "latency_ms": latency_ns / 1e6, "particles": float(len(rec.detections))}
        stats = None
        if summary.frames % 10 == 1:
            recent = np.asarray(summary.latencies_ns[-120:], dtype=np.float64) / 1e6
            times = summary.output_times[-60:]
            fps = (len(times) - 1) / ((times[-1] - times[0]) / 1e9) if len(times) > 2 else 0.0
            stats = {"frames": summary.frames, "fps": fps, "latency_p50_ms": float(np.median(recent)),
                     "latency_p99_ms": float(np.percentile(recent, 99)), "particles": len(rec.detections),
                     "dropped": summary.dropped, "light": "on" if self.light_on else "off",
                     "recording": self._recording_state()}
        self.panel.publish(image=rec.frame.image, detections=rec.detections, pattern=rec.pattern,
                           stats=stats, sample=sample)


def run(config: Config, *, log: TextIO | None = None, out: TextIO | None = None,
        source: FrameSource | None = None) -> RunSummary:
    """Run the cancellation loop until the frame limit, the source's end, ``e`` or a signal.

    ``config.run.mode`` picks the execution: ``single`` (one thread, the
    report's design) or ``threads`` (capture, processing and output overlap in
    three threads joined by latest-frame slots).  Every file is complete and
    valid however the run ends; a write the disk refuses stops the run with
    WriteError (one line), each file whole up to its last row or frame.  Returns the summary (also printed to ``out``);
    bad input raises UsageError.  ``source`` replaces the configured source (benchmarks, tests).
    """
    log = log or sys.stderr
    out = out or sys.stdout
    rc = config.run
    detector = make_detector(config.detector.name, config.detector_params, threads=rc.threads)
    # every file this run writes, before any work: one line and nothing written when one cannot be
    for flag, value in (("run.metrics (--metrics)", rc.metrics), ("run.detections (--detections)", rc.detections)):
        if value:
            check_output_path(value, flag)
    for spec in config.output.outputs:
        check_output(spec)
    if rc.record_to:  # the panel's Record button would fail mid-run
        check_output_path(rc.record_to, "run.record_to (--record-to)")
    if rc.mcap:
        from .mcap_out import require_mcap

        require_mcap()
        check_output_path(rc.mcap, "run.mcap (--mcap)", suffixes=(".mcap",))
    for note in apply_process_controls(rc):
        print(note, file=log)

    columns = metrics_columns(detector)
    stage_columns = [f"{s.label} Duration (s)" for s in detector.stages]
    summary = RunSummary()
    timed = ["Capture Duration (s)", *stage_columns, "Total frame processing time (s)",
             "Tracking Duration (s)", "Pattern Rendering Duration (s)", "Output Duration (s)",
             "End-to-end Latency (s)"]
    tc = config.track
    # probing: a new hole spans its line, and a particle's light is not known
    tracker = make_tracker(tc, probing=config.light.depth == "probe") if tc.enabled else None
    if tracker is None:
        timed.remove("Tracking Duration (s)")
    summary.durations = {c: RunningStats() for c in timed}
    summary.period_ns = int(round(1e9 / rc.fps)) if rc.fps else 0

    with ExitStack() as stack:
        stop = stack.enter_context(StopFlag())  # first: a signal from here on stops the run with its files whole
        stack.enter_context(_opencv_threads(rc.threads))
        panel = None
        if rc.web:  # its port first: a bad or busy one fails before the source opens or a file is touched
            from .web import ControlPanel

            panel = stack.enter_context(ControlPanel(rc.web, title="run", start=False))
        source = stack.enter_context(source if source is not None else _open_source(config, detector))
        check_frame_size(*source.size, what=f"source {config.source.spec}: frames", error=UsageError)
        calibration = None
        if config.pattern.calibration:  # before any file is written
            from .calibration import load_calibration

            calibration = load_calibration(config.pattern.calibration,
                                           sizes=(source.size, (config.pattern.width, config.pattern.height)))
        outputs: list[LightOutput] = []
        for spec in config.output.outputs:
            outputs.append(stack.enter_context(open_output(spec, fps=rc.fps or source.fps or 60.0)))
        names = ", ".join(o.name for o in outputs)
        metrics_writer = detections_writer = None
        if rc.metrics:
            metrics_writer = stack.enter_context(_open_csv(rc.metrics, columns))
        if rc.detections:
            header = ["frame", "time", "x", "y", "radius"] + (["track_id"] if tracker is not None else [])
            detections_writer = stack.enter_context(_open_csv(rc.detections, header))
        tracking = ("" if tracker is None else
                    ", tracking" + (" with prediction" if tc.predict else "")
                    + (f" over {tc.latency_ms:g} ms" if tc.predict and tc.latency_ms >= 0 else ""))
        print(f"antiscatter run: source {config.source.spec} ({source.size[0]}x{source.size[1]}), "
              f"detector {detector.name}{tracking}, pattern {config.pattern.width}x{config.pattern.height}, "
              f"output {names}, mode {rc.mode}, light strategy {config.light.strategy}", file=log)
        for note in config.notes:
            print(f"note: {note}", file=log)
        if (strategy_entry(config.light.strategy).exposing and getattr(source, "live", False)
                and not config.source.camera_lock):
            print(f"note: {config.light.strategy} on a free-running camera reads every other frame, each exposure "
                  "begun once its light is on screen (in the twin, co-located, pulse removed 0.856 against dim's "
                  "0.940); --camera-lock times the exposures to the projector", file=log)
        pipeline = _Pipeline(config, detector, tracker, source, calibration, outputs, metrics_writer,
                             detections_writer, columns, summary, buffers=1 if rc.mode == "single" else 3)
        if rc.mcap:
            from .mcap_out import McapLog

            pipeline.mcap = stack.enter_context(McapLog(rc.mcap))
        stack.callback(pipeline.stop_recording, wait=True)  # a recording is finished however the run ends
        if rc.frames or not getattr(source, "live", False):  # a run with an end: its progress on a terminal
            from .console import progress

            pipeline.bar = stack.enter_context(progress(total=rc.frames or None, desc="run"))
        if panel is not None:
            pipeline.panel = _serve_panel(panel, pipeline, stop, log)
        started = time.perf_counter_ns()
        if rc.mode == "threads":
            _run_threads(pipeline, source, stop, rc)
        elif rc.mode.startswith("processes"):
            _run_processes(pipeline, source, stop, rc, config,
                           transport="pickle" if rc.mode == "processes-pickle" else "shm")
        elif pipeline.locked:
            _run_locked(pipeline, source, stop, rc)
        else:
            _run_single(pipeline, source, stop, rc)
        summary.wall_s = (time.perf_counter_ns() - started) / 1e9
        summary.damaged = source.damaged
        summary.synthetic = getattr(source, "synthetic", False)
    _print_summary(summary, out, config)
    if summary.damaged:
        print(f"warning: {summary.damaged}", file=log)
    return summary


def _serve_panel(panel: Any, pipeline: _Pipeline, stop: "StopFlag", log: TextIO) -> Any:
    """Give the bound web panel the report's three keys as buttons (flags the loop reads) and serve it."""

    def light() -> str:
        pipeline.light_on = not pipeline.light_on
        return f"light {'on' if pipeline.light_on else 'off'}"

    def record() -> str:
        if pipeline.record_wanted:
            pipeline.record_wanted = False
            return "recording stopped"
        base = Path(pipeline.config.run.record_to or time.strftime("antiscatter-%Y%m%d-%H%M%S.mkv"))
        try:
            pipeline.record_path = claim_recording_path(base)
        except OSError as exc:
            message = f"cannot record to {base}: {exc.strerror or exc}"
            pipeline.summary.recordings.append({"path": str(base), "error": exc.strerror or str(exc)})
            print(f"panel recording {base} failed: {exc.strerror or exc}; the run goes on", file=log)
            return message
        pipeline.record_wanted = True
        return "recording"

    def finish() -> str:
        stop.reason = stop.reason or "panel"
        return "stopping"

    pipeline.log = log
    config, (width, height) = pipeline.config, pipeline.system.camera_size
    rate = config.run.fps or (1 / pipeline.frame_interval if pipeline.frame_interval else None)
    panel.info.update({"source": config.source.spec, "detector": config.detector.name,
                       "strategy": config.light.strategy, "frame": f"{width} x {height} px",
                       "rate": f"{rate:g} frames/s" if rate else "the camera's",
                       "mode": config.run.mode})
    panel.actions.update(light=light, record=record, stop=finish)
    panel.controls.update(_panel_controls(pipeline))
    panel.start()
    print(f"control panel: {panel.url}", file=log)
    return panel


def _panel_controls(pipeline: _Pipeline) -> dict[str, Any]:
    """The settings the panel offers, applied at the next frame (:meth:`System.change`): the
    strategy's hole level where it has one, and the detector's sensitivity (its ``sweep``
    parameter, over the sweep's range) unless the detector runs in worker processes."""
    from .detection import DETECTORS, with_sensitivity
    from .web import Control

    system, config = pipeline.system, pipeline.config
    controls: dict[str, Any] = {}
    if system.level is not None:
        low = system.levels.floor if system.levels is not None else 0.0

        def set_level(value: float) -> str:
            system.change(level=value)
            return f"hole level {value:g} from the next frame"

        controls["level"] = Control("hole level", "of full light", low, 1.0, 0.01, lambda: system.level, set_level)
    name = config.detector.name
    key, values = DETECTORS[name].sweep
    if key and not config.run.mode.startswith("processes"):
        params = [config.detector_params if config.detector_params is not None else DETECTORS[name].params()]

        def set_sensitivity(value: float) -> str:
            try:
                changed = with_sensitivity(name, params[0], value)
            except ValueError as exc:
                return f"{key}: {exc}"
            system.change(detector=make_detector(name, changed, threads=config.run.threads))
            params[0] = changed
            return f"{name} {key} {getattr(changed, key):g} from the next frame (its background learnt afresh)"

        controls["sensitivity"] = Control(f"detector {key}", "", float(min(values)), float(max(values)),
                                          0.5 if isinstance(getattr(params[0], key), float) else 1.0,
                                          lambda: getattr(params[0], key), set_sensitivity)
    return controls


def claim_recording_path(base: Path, *, limit: int = 10000) -> Path:
    """The first of ``base``, ``base-2``, ``base-3``, ... (same suffix) that does not exist, nor its
    sidecar CSV (:func:`~antiscatter.record.recorder.sidecar_path`), created empty.

    Created exclusively (``O_EXCL``), so no recording ever overwrites a file, and its folder's
    writability is known before the loop starts it.  OSError when it cannot be created.
    """
    from .record.recorder import sidecar_path

    for n in range(1, limit + 1):
        path = base if n == 1 else base.with_name(f"{base.stem}-{n}{base.suffix}")
        if sidecar_path(path).exists():
            continue
        try:
            os.close(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644))
        except FileExistsError:
            continue
        return path
    raise FileExistsError(17, f"{base} and its {limit - 1} numbered variants exist", str(base))


def _timed_read(source: FrameSource) -> tuple[Any, int, int]:
    """(frame or None, clock before, clock after) of one ``source.read()``; for a source that draws its
    frames (``synthetic``: the simulator) both the time after, as drawing a frame is no capture: the
    vehicle's camera has it drawn by the world."""
    t0 = time.perf_counter_ns()
    frame = source.read()
    t1 = time.perf_counter_ns()
    return frame, t1 if getattr(source, "synthetic", False) else t0, t1


def _finished(summary: RunSummary, stop: "StopFlag", rc: Any) -> bool:
    """True (with the reason recorded) once a signal arrived or the frame limit is reached."""
    if stop:
        summary.stop_reason = f"stopped by {stop.reason}"
        return True
    if rc.frames and summary.frames >= rc.frames:
        summary.stop_reason = f"frame limit {rc.frames}"
        return True
    return False


#: frames a live source may deliver from before the flash went on (exposed under the last pattern)
MAX_STALE_FRAMES = 3
#: locked: a flip asked for later than this before a vertical blank is taken as missing it (ns)
FLIP_MARGIN_NS = round(FLIP_MARGIN_S * 1e9)


def light_ahead(next_flip: float, ready: float, light_by: float, refresh: float) -> bool:
    """Locked loop: whether the last frame's exposure light goes out at the next flip, before the
    frame just read is processed (and that frame's light a frame later).  So when the next flip is
    the last whose light covers the next exposure (it is on the scene by ``light_by``: the
    exposure's start less the display lag) and the frame cannot be ready (``ready``, margin
    included) before it.  Otherwise the frame's own light goes out after it is processed, at the
    flip that covers the first exposure it can still reach -- with a projector lagging a refresh,
    every other exposure.  Any one unit of time throughout (ns in run, seconds in the twin)."""
    tolerance = refresh * 1e-6
    return next_flip <= light_by + tolerance and light_by < next_flip + refresh - tolerance and ready > next_flip


def light_after(pattern_flip: float, exposure: float, lag: float, next_read: float, refresh: float) -> float | None:
    """Locked loop, a display lagging past what the light ahead reaches: the flip at which this
    frame's exposure light goes out after its pattern (at ``pattern_flip``), for the exposure after
    the next (starting at ``exposure``) -- the last flip whose light, ``lag`` after it, is on by
    then -- when that flip comes a refresh or more after the pattern's and before the next frame is
    read (``next_read``): then every frame is still taken, each under the light of the frame two
    before.  None otherwise (the light ahead, or the frame's own light after it is processed, does).
    Any one unit of time throughout (ns in run, seconds in the twin)."""
    tolerance = refresh * 1e-6
    flip = pattern_flip + math.floor((exposure - lag - pattern_flip) / refresh + 1e-6) * refresh
    if flip >= pattern_flip + refresh - tolerance and flip < next_read:
        return flip
    return None


def _first_flip(next_flip: int, t: int, refresh: int) -> int:
    """The first flip at or after ``t`` (ns), the flips ``refresh`` apart from ``next_flip`` on."""
    return next_flip + max(0, -(-(t - next_flip) // refresh)) * refresh


def _run_single(pipeline: _Pipeline, source: FrameSource, stop: "StopFlag", rc: Any) -> None:
    """One thread: pace, capture, process, show -- the report's design.

    With the ``flash`` and ``pulse`` strategies each turn starts with the exposure's
    light (the detection flash, or the last pattern with its holes lifted); a live
    source's frames whose exposure began before that light can have been on (the camera
    free-runs; the display takes it at its next refresh, up to one refresh period after
    it was handed over, and shows it ``pattern.display_lag_ms`` later) are skipped and counted as dropped, so the detector sees
    particles under that light; once the frame is in, the last pattern goes back on
    while it is processed.
    """
    summary = pipeline.summary
    pacer = Pacer(rc.fps)
    flashing = pipeline.exposing
    live = getattr(source, "live", False)
    refresh_ns, lag_ns = pipeline.refresh_ns, pipeline.display_lag_ns  # (lag: from a flip to its light)
    while True:
        if _finished(summary, stop, rc):
            return
        pacer.wait()
        flash_on = pipeline.flash() + refresh_ns + lag_ns if flashing else 0  # on by then at the latest
        frame, t0, t1 = _timed_read(source)
        stale = 0
        while flashing and live and frame is not None and frame.exposure_start_ns < flash_on \
                and stale < MAX_STALE_FRAMES:
            stale += 1
            frame, t0, t1 = _timed_read(source)
        if frame is None:
            summary.stop_reason = "source ended"
            summary.dropped += stale  # (skipped as stale just before)
            return
        if flashing:
            pipeline.restore()
        if pipeline.emit(pipeline.process(frame, t0, t1), stale):
            summary.stop_reason = "stopped from the window (e)"
            return


def _run_locked(pipeline: _Pipeline, source: FrameSource, stop: "StopFlag", rc: Any) -> None:
    """Mode single with the camera locked to the projector (``source.camera_lock``).

    Each frame read nudges the camera's next frame durations (:class:`~antiscatter.lock.PhaseLock`)
    so that exposures begin in the middle of a refresh's light (``pattern.display_lag_ms`` after
    its flip).  A frame is processed; its exposure light (the pattern with its holes lifted, or the
    flash) goes out at the flip whose light covers the first exposure that can still be reached
    (the flips before it show the new pattern), the pattern itself at the one after.  With no lag
    and 5 ms of processing that is the next flip and every frame is taken whole under its light
    (the twin's locked camera).  A projector lagging a refresh needs the next exposure's light at
    the flip right after the frame is read, before it can be processed: the last frame's light
    goes out there first (:func:`light_ahead`, decided by the processing time measured so far),
    then the frame is processed and its pattern follows -- every frame is still taken, under a
    light a frame older.  A projector lagging more (12 ms at 60 / 120 Hz) needs it before the
    frame is read: each frame's light goes out right after its pattern, for the exposure after the
    next (:func:`light_after`), the next frame's pattern replacing it a refresh later -- every
    frame is taken, under the light of the frame two before (the first time, under the pattern:
    taken all the same, for the chain to start).  Frames whose exposure began before the light was
    on are skipped and counted as dropped (at most ``MAX_STALE_FRAMES`` in a row: until the lock
    holds, or when a frame took too long).
    """
    from .lock import PhaseLock

    summary = pipeline.summary
    config = pipeline.config
    display = pipeline.display
    if display is None:
        raise UsageError("source.camera_lock: needs output kms (its flips say when the projector's refreshes are)")
    refresh_ns, lag_ns = pipeline.refresh_ns, pipeline.display_lag_ns
    period_ns = int(round(1e9 / config.source.camera_fps))
    exposure_ns = int(round(config.source.camera_exposure_ms * 1e6))
    lock = PhaseLock(refresh_ns, period_ns, ((refresh_ns - exposure_ns) // 2 + lag_ns) % refresh_ns,
                     shortest_ns=getattr(source, "shortest_frame_ns", 0))
    lit_ns = 0  # when the last exposure light went on (its flip + the lag); the full lamp until the first
    made, last_start = 0, 0  # the camera's frames since the first read, by their exposures' starts
    busy_ns = 0  # the longest of the last frames' processing (read to pattern drawn), for light_ahead
    posted, posted_lit = False, 0  # a light went out after the last frame's pattern, on from posted_lit
    recent: collections.deque[int] = collections.deque(maxlen=8)
    while True:
        if _finished(summary, stop, rc):
            return
        frame, t0, t1 = _timed_read(source)
        stale = 0
        while True:
            if frame is not None and display.presented_ns:  # every exposure measures the phase
                source.set_frame_duration_ns(lock.update(frame.exposure_start_ns, display.presented_ns))
                pipeline.phase_error_ns = lock.error_ns
            if frame is None or frame.exposure_start_ns >= lit_ns or stale >= MAX_STALE_FRAMES:
                break
            stale += 1
            frame, t0, t1 = _timed_read(source)
        if frame is None:
            summary.stop_reason = "source ended"
            summary.dropped += stale  # (skipped as stale just before)
            return
        started = display.clock()
        pipeline.ahead, pipeline.pattern_on_ns, pipeline.post = False, None, False
        # the exposure after the next, and when the next frame is read (light_after)
        after_next = frame.exposure_start_ns + 2 * period_ns
        next_read = frame.exposure_start_ns + period_ns + exposure_ns + FLIP_MARGIN_NS
        if lock.locked and display.presented_ns:
            now_flip = display.next_flip_ns(refresh_ns)
            ready = started + busy_ns + FLIP_MARGIN_NS
            pattern_flip = _first_flip(now_flip, ready, refresh_ns)  # the pattern's
            if posted:  # the next exposure's light went out after the last frame's pattern
                pipeline.ahead = True
                pipeline.pattern_on_ns = pattern_flip + lag_ns
            elif light_ahead(now_flip, ready, frame.exposure_start_ns + period_ns - lag_ns, refresh_ns):
                pipeline.flash_ahead(frame.index + 1)
                pipeline.ahead = True
                pipeline.pattern_on_ns = pattern_flip + lag_ns  # (after the light's flip: ready > now_flip)
            # this frame's light after its pattern, for the exposure after the next (a lag past the
            # light ahead), foreseen by the typical processing time: a frame slower than that misses
            # one light (the next but one frame is then taken under the pattern), where the longest
            # of the last 8 would leave the loop reading every other frame for 8 frames after it
            typical = started + sorted(recent)[len(recent) // 2] + FLIP_MARGIN_NS if recent else ready
            typical_flip = _first_flip(now_flip, typical, refresh_ns)
            pipeline.post = (light_after(typical_flip, after_next, lag_ns, next_read, refresh_ns) is not None
                             and not (pipeline.ahead and not posted))
            if pipeline.post:
                pipeline.pattern_on_ns = typical_flip + lag_ns
        rec = pipeline.process(frame, t0, t1)
        recent.append(display.clock() - started)
        busy_ns = max(recent)
        if not (pipeline.ahead or pipeline.post):
            # the light's flip: the last before the first exposure still to come that it can reach
            # (once the lock holds; until then, the next flip)
            reach = display.next_flip_ns(refresh_ns) + lag_ns
            coming = frame.exposure_start_ns + period_ns
            while coming < reach:
                coming += period_ns
            blank = display.presented_ns
            pipeline.lift_at_ns = (blank + (coming - lag_ns - blank) // refresh_ns * refresh_ns
                                   if lock.locked and blank else 0)
            pipeline.lit_frame = frame.index + round((coming - frame.exposure_start_ns) / period_ns)
        if pipeline.emit(rec, stale):
            summary.stop_reason = "stopped from the window (e)"
            return
        if not (pipeline.ahead or pipeline.post):
            pipeline.after_exposure(rec)
        if pipeline.post or posted:
            # the next frame: under the light put out after the last frame's pattern; the first
            # time, under this pattern (taken all the same: skipped, it would break the chain)
            lit_ns = posted_lit if posted else 0
        else:
            lit_ns = display.presented_ns + lag_ns  # (kms waited for the light's flip before the pattern's)
        posted = False
        if pipeline.post:
            # (the pattern's flip as it came: a frame processed later than foreseen may miss it)
            flip = light_after(display.next_flip_ns(refresh_ns) - refresh_ns, after_next, lag_ns, next_read,
                               refresh_ns)
            if flip is not None:
                while display.next_flip_ns(refresh_ns) < flip - refresh_ns // 2:  # spare flips: the pattern
                    pipeline.after_exposure(rec)
                pipeline.flash_ahead(frame.index + 2)
                posted, posted_lit = True, int(flip) + lag_ns
        # the camera's frames between two read (gone while the loop was busy, or skipped as stale)
        if last_start:
            made += max(1, round((frame.exposure_start_ns - last_start) / period_ns))
        last_start = frame.exposure_start_ns
        if made >= 60 and summary.frames <= 0.6 * made and not summary.notes:
            summary.notes.append(
                f"the locked loop processed {summary.frames} of the camera's {made + 1} frames: no exposure light "
                "could reach the next exposure, not even the last frame's put out ahead nor this frame's after "
                "its pattern (the display lag too long, or processing too long for the frame period); in the "
                "twin at a 14 ms lag pulse so removed 0.832 against dim holes' 0.906 -- --strategy dim, or a "
                "camera frame period of more refreshes")


def _run_threads(pipeline: _Pipeline, source: FrameSource, stop: "StopFlag", rc: Any) -> None:
    """Capture, process and output in their own threads, joined by latest-frame slots.

    OpenCV and numpy release the GIL, so the stages overlap without copying
    frames between processes.  A stage that falls behind takes the newest item
    and the skipped ones are counted as dropped; nothing queues up.  The output
    thread paces at ``--fps`` (drift-free).  A crash in any thread stops the
    run and is raised here; Ctrl-C stops all three within a frame.
    """
    summary = pipeline.summary
    # a live source (camera) must never wait: stages take the newest frame; a
    # file or the simulator is replayed whole: hand-over waits instead of dropping
    lossless = not getattr(source, "live", False)
    captured, processed = LatestSlot(lossless=lossless), LatestSlot(lossless=lossless)
    errors: list[BaseException] = []
    finished = threading.Event()

    def guarded(body: Callable[[], None]) -> Callable[[], None]:
        def target() -> None:
            try:
                body()
            except BaseException as exc:  # noqa: BLE001 - handed to the main thread
                errors.append(exc)
                if body is not capture_loop:
                    finished.set()  # a failed stage stops everything at once
                # a failed source: the frames already captured still go out
            finally:
                captured.close()
                if body is not capture_loop:
                    processed.close()
        return target

    def capture_loop() -> None:
        while not finished.is_set() and not stop:
            frame, t0, t1 = _timed_read(source)
            if frame is None:
                summary.stop_reason = summary.stop_reason or "source ended"
                return
            captured.put((frame, t0, t1))

    def process_loop() -> None:
        while True:
            item = captured.get(finished)
            if item is None:
                return
            rec = pipeline.analyse(*item)
            processed.put(rec)  # the output thread renders: the stages balance
            pipeline.learn(rec)  # the detector's learning for the next frames, while it does

    def output_loop() -> None:
        pacer = Pacer(rc.fps)
        while True:
            rec = processed.get(finished)
            if rec is None:
                return
            rec = pipeline.render(rec)
            pacer.wait()
            dropped = captured.take_dropped() + processed.take_dropped()
            if pipeline.emit(rec, dropped):
                summary.stop_reason = "stopped from the window (e)"
                finished.set()
                return
            if rc.frames and summary.frames >= rc.frames:
                summary.stop_reason = f"frame limit {rc.frames}"
                finished.set()
                return

    threads = [threading.Thread(target=guarded(loop), name=f"antiscatter-{name}", daemon=True)
               for name, loop in (("capture", capture_loop), ("process", process_loop), ("output", output_loop))]
    for thread in threads:
        thread.start()
    try:
        while any(t.is_alive() for t in threads):
            if stop and not finished.is_set():
                summary.stop_reason = f"stopped by {stop.reason}"
                finished.set()
            for t in threads:
                t.join(timeout=0.05)
    finally:
        finished.set()
        captured.close()
        processed.close()
        for t in threads:
            t.join(timeout=5)
    if errors:
        raise errors[0]
    if stop and not summary.stop_reason.startswith("stopped"):
        summary.stop_reason = f"stopped by {stop.reason}"


def _run_processes(pipeline: _Pipeline, source: FrameSource, stop: "StopFlag", rc: Any, config: Config,
                   *, transport: str) -> None:
    """Detection in a worker process fed through shared memory (or, for comparison, pickled frames).

    A source failing mid-run has its error raised once the frames already read are written, as in
    single mode; the worker dying raises RunError (one line) unless a stop signal reached it too.
    """
    from .errors import RunError
    from .parallel import DetectorProcess

    summary = pipeline.summary
    first, t0, t1 = _timed_read(source)
    if first is None:
        summary.stop_reason = "source ended"
        return
    worker = DetectorProcess(config.detector.name, config.detector_params, first.image, transport=transport,
                             threads=rc.threads)
    pending: dict[int, tuple[Any, int, int]] = {}
    pacer = Pacer(rc.fps)
    submitted = 0
    ended = False
    failure: Exception | None = None
    try:
        worker.submit(submitted, first.image)
        pending[submitted] = (first, t0, t1)
        submitted += 1
        while True:
            if _finished(summary, stop, rc):
                break
            while not ended and not worker.full and not (rc.frames and submitted >= rc.frames):
                try:
                    frame, t0, t1 = _timed_read(source)
                except Exception as exc:  # noqa: BLE001 - raised below, after the frames in flight
                    failure, ended = exc, True
                    break
                if frame is None:
                    ended = True
                    break
                worker.submit(submitted, frame.image)
                pending[submitted] = (frame, t0, t1)
                submitted += 1
            if not pending:
                summary.stop_reason = "source ended"
                break
            try:
                result = worker.receive()
            except RunError as exc:
                if stop:  # a stop signal sent to the whole group ended the worker too
                    summary.stop_reason = f"stopped by {stop.reason}"
                    return
                raise RunError(f"{exc}; {summary.frames} frames processed; files are complete") from None
            if result is None:
                continue
            index, found, stage_ns = result
            frame, t0, t1 = pending.pop(index)
            record = pipeline.process(frame, t0, t1, found, stage_ns)
            pacer.wait()
            if pipeline.emit(record, 0):
                summary.stop_reason = "stopped from the window (e)"
                break
    finally:
        worker.close()
    if failure is not None:
        raise failure


class LatestSlot:
    """A one-item hand-over with latest-frame semantics.

    ``put`` replaces an item not yet taken (counted in ``dropped``); with
    ``lossless=True`` it waits for the item to be taken instead.  ``get`` waits
    for a new item and returns None once the slot is closed and empty or
    ``cancel`` (an Event) is set.  Queues never grow.
    """

    def __init__(self, *, lossless: bool = False) -> None:
        self._item: Any = None
        self._full = False
        self._closed = False
        self._dropped = 0
        self.lossless = lossless
        self._cond = threading.Condition()

    def put(self, item: Any, *, poll: float = 0.05) -> None:
        with self._cond:
            if self.lossless:
                while self._full and not self._closed:
                    self._cond.wait(poll)
            elif self._full:
                self._dropped += 1
            self._item, self._full = item, True
            self._cond.notify_all()

    def get(self, cancel: threading.Event | None = None, *, poll: float = 0.05) -> Any:
        with self._cond:
            while not self._full:
                if self._closed or (cancel is not None and cancel.is_set()):
                    return None
                self._cond.wait(poll)
            item, self._item, self._full = self._item, None, False
            self._cond.notify_all()
            return item

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    def take_dropped(self) -> int:
        """Items replaced before being taken, since the last call."""
        with self._cond:
            dropped, self._dropped = self._dropped, 0
            return dropped


def written_files(config: Config) -> list[tuple[str, str]]:
    """(path, what it holds) of every file or folder a run with ``config`` writes, in flag order
    (the panel's recordings are named apart, as they are made)."""
    rc = config.run
    files = [(rc.metrics, "per-frame stage timings"), (rc.detections, "one row per particle"),
             (rc.mcap, "every frame as ROS 2 messages")]
    for spec in config.output.outputs:
        kind, _, arg = spec.partition(":")
        if kind == "files" and arg:
            files.append((arg, "the light patterns"))
    return [(path, what) for path, what in files if path]


def _print_summary(summary: RunSummary, out: TextIO, config: Config | None = None) -> None:
    p = summary.particles
    fps = summary.frames / summary.wall_s if summary.wall_s > 0 else 0.0
    print(f"frames: {summary.frames} ({summary.stop_reason}), dropped {summary.dropped}", file=out)
    for note in summary.notes:
        print(f"note: {note}", file=out)
    if summary.cut:
        print(f"note: the detector's bound on its work per frame left {summary.cut} candidates out in "
              f"{summary.cut_frames} frames (the metrics CSV's 'Candidates Cut'): the view held more "
              "than a frame can be given time for", file=out)
    if p.count:
        print(f"particles per frame: mean {p.mean:.1f}, min {p.min:.0f}, max {p.max:.0f}", file=out)
    print(summary.table(), file=out)
    if summary.synthetic:
        print("note: the simulator draws each frame as it is read; the drawing is not counted as Capture "
              "(0 here), and End-to-end Latency runs from the frame drawn to its light shown", file=out)
    print(f"frames per second: {fps:.1f} over {summary.wall_s:.2f} s", file=out)
    for entry in summary.recordings:
        outcome = f"failed ({entry['error']})" if "error" in entry else f"{entry.get('frames', 0)} frames"
        print(f"panel recording {entry['path']}: {outcome}", file=out)
    pacing = summary.pacing()
    if pacing and summary.period_ns:  # paced (--fps): how closely the frames kept its period
        print(f"output rate {pacing['rate']:.2f} frames/s; interval error against the --fps period: p50 "
              f"{pacing['jitter_p50_ms']:.3f} ms, p99 {pacing['jitter_p99_ms']:.3f} ms, max "
              f"{pacing['jitter_max_ms']:.3f} ms", file=out)
    elif pacing:
        print(f"output rate {pacing['rate']:.2f} frames/s (unpaced: --fps sets a rate)", file=out)
    if config is not None:
        files = written_files(config)
        print("files written: " + (", ".join(f"{path} ({what})" for path, what in files) if files else
                                   "none (--metrics, --detections, --mcap or --output files:DIR keep the run)"),
              file=out)
