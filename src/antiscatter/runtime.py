"""The runtime loop: source -> detector stages -> pattern -> light outputs.

This is the one place that reads clocks around the stages
(``time.perf_counter_ns``); it writes the per-frame metrics CSV with the
report's columns, the detections CSV, and prints the report's table 1 summary.
"""

from __future__ import annotations

import csv
import os
import signal
import sys
import time
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, TextIO

import numpy as np

from .config import Config, parse_size
from .detection import Detector, make_detector
from .detections import Detections
from .errors import UsageError
from .outputs import LightOutput, open_output
from .pattern import render_pattern, scale_mapping
from .sources import FrameSource, open_source, parse_crop
from .stats import RunningStats

__all__ = ["REPORT_COLUMNS", "metrics_columns", "time_stages", "Pacer", "RunSummary", "run", "set_niceness"]

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
    "Capture Timestamp (ns)",
    "Tracking Duration (s)",
    "Pattern Rendering Duration (s)",
    "Output Duration (s)",
    "End-to-end Latency (s)",
)


def metrics_columns(detector: Detector) -> list[str]:
    """The metrics CSV header: the report's columns, then ours, then detector stages the report lacked."""
    extra_stages = [f"{s.label} Duration (s)" for s in detector.stages
                    if f"{s.label} Duration (s)" not in REPORT_COLUMNS]
    return [*REPORT_COLUMNS, *EXTRA_COLUMNS, *extra_stages]


def time_stages(detector: Detector, image: np.ndarray, *,
                clock: Callable[[], int] = time.perf_counter_ns) -> tuple[Detections, list[int]]:
    """Run the detector's stages on one frame, timing each: (detections, nanoseconds per stage).

    The one place stages are timed; ``run`` and ``bench`` both use it.
    """
    value = image
    durations = []
    t_prev = clock()
    for stage in detector.stages:
        value = stage.run(value)
        t_now = clock()
        durations.append(t_now - t_prev)
        t_prev = t_now
    return value, durations


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


class _StopFlag:
    """Set by SIGINT/SIGTERM; a second Ctrl-C raises KeyboardInterrupt at once."""

    def __init__(self) -> None:
        self.reason = ""
        self._previous: dict[int, object] = {}

    def __bool__(self) -> bool:
        return bool(self.reason)

    def _handle(self, signum: int, _frame: object) -> None:
        if self.reason and signum == signal.SIGINT:
            raise KeyboardInterrupt
        self.reason = signal.Signals(signum).name

    def __enter__(self) -> "_StopFlag":
        for signum in (signal.SIGINT, signal.SIGTERM):
            try:
                self._previous[signum] = signal.signal(signum, self._handle)
            except ValueError:  # not the main thread
                pass
        return self

    def __exit__(self, *exc: object) -> None:
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)  # type: ignore[arg-type]


def _open_csv(path: str, header: list[str]) -> tuple[TextIO, "csv._writer"]:
    target = Path(path)
    if target.is_dir():
        raise UsageError(f"{target}: is a folder, expected a CSV file path")
    try:
        handle = target.open("w", newline="")
    except FileNotFoundError:
        raise UsageError(f"{target}: the folder {target.parent} does not exist") from None
    except PermissionError:
        raise UsageError(f"{target}: permission denied") from None
    writer = csv.writer(handle)
    writer.writerow(header)
    return handle, writer


def _open_source(config: Config) -> FrameSource:
    sc = config.source
    crop = parse_crop(sc.crop) if sc.crop else None
    size = parse_size(sc.size) if sc.size else None
    return open_source(sc.spec, crop=crop, loop=sc.loop, sim_preset=sc.preset, seed=sc.seed,
                       size=size, fps=sc.camera_fps)


def run(config: Config, *, log: TextIO | None = None, out: TextIO | None = None) -> RunSummary:
    """Run the cancellation loop until the frame limit, the source's end, ``e`` or a signal.

    Every file is complete and valid however the run ends. Returns the summary
    (also printed to ``out``); bad input raises UsageError.
    """
    log = log or sys.stderr
    out = out or sys.stdout
    detector = make_detector(config.detector.name, config.detector_params)
    rc = config.run
    if rc.nice is not None:
        warning = set_niceness(rc.nice)
        print(warning or f"niceness set to {rc.nice}", file=log)

    columns = metrics_columns(detector)
    stage_columns = [f"{s.label} Duration (s)" for s in detector.stages]
    summary = RunSummary()
    timed = ["Capture Duration (s)", *stage_columns, "Total frame processing time (s)",
             "Tracking Duration (s)", "Pattern Rendering Duration (s)", "Output Duration (s)",
             "End-to-end Latency (s)"]
    tc = config.track
    tracker = None
    if tc.enabled:
        from .tracking import Tracker
        tracker = Tracker(confirm_hits=tc.confirm_hits, max_misses=tc.max_misses)
    if tracker is None:
        timed.remove("Tracking Duration (s)")
    summary.durations = {c: RunningStats() for c in timed}
    index_of = {c: i for i, c in enumerate(columns)}

    with ExitStack() as stack:
        source = stack.enter_context(_open_source(config))
        projector_size = (config.pattern.width, config.pattern.height)
        mapping = config.pattern.matrix()
        if mapping is None:
            mapping = scale_mapping(source.size, projector_size)
        outputs: list[LightOutput] = []
        for spec in config.output.outputs:
            output = stack.enter_context(open_output(spec, fps=rc.fps or source.fps or 60.0))
            outputs.append(output)
        names = ", ".join(o.name for o in outputs)
        metrics_writer = detections_writer = None
        if rc.metrics:
            handle, metrics_writer = _open_csv(rc.metrics, columns)
            stack.callback(handle.close)
        if rc.detections:
            header = ["frame", "x", "y", "radius"] + (["track_id"] if tracker is not None else [])
            handle, detections_writer = _open_csv(rc.detections, header)
            stack.callback(handle.close)
        tracking = ("" if tracker is None else
                    ", tracking" + (" with prediction" if tc.predict else "")
                    + (f" over {tc.latency_ms:g} ms" if tc.predict and tc.latency_ms >= 0 else ""))
        print(f"antiscatter run: source {config.source.spec} ({source.size[0]}x{source.size[1]}), "
              f"detector {detector.name}{tracking}, pattern {projector_size[0]}x{projector_size[1]}, "
              f"output {names}", file=log)
        latency_estimate = 0.0  # seconds, running mean of the measured capture-to-light time

        pattern_buffer = np.empty((projector_size[1], projector_size[0]), np.uint8)
        pacer = Pacer(rc.fps)
        stop = stack.enter_context(_StopFlag())
        clock = time.perf_counter_ns
        started = clock()
        row = [0.0] * len(columns)
        stage_index = [index_of[c] for c in stage_columns]
        while True:
            if stop:
                summary.stop_reason = f"stopped by {stop.reason}"
                break
            if rc.frames and summary.frames >= rc.frames:
                summary.stop_reason = f"frame limit {rc.frames}"
                break
            pacer.wait()
            t0 = clock()
            frame = source.read()
            t1 = clock()
            if frame is None:
                summary.stop_reason = "source ended"
                break
            detections, stage_ns = time_stages(detector, frame.image, clock=clock)
            t_prev = t1 + sum(stage_ns)
            holes, track_ns, track_ids = detections, 0, None
            if tracker is not None:
                t_track = clock()
                captured = frame.timestamp_ns / 1e9
                tracks = tracker.update(detections, captured)
                track_ids = tracks.detection_ids
                if tc.predict:
                    latency = tc.latency_ms / 1e3 if tc.latency_ms >= 0 else latency_estimate
                    holes = tracker.holes(captured + latency)
                else:
                    holes = tracker.holes(captured)
                track_ns = clock() - t_track
                t_prev = clock()
            pattern = render_pattern(holes, size=projector_size, mapping=mapping,
                                     margin=config.pattern.margin, out=pattern_buffer)
            t_pattern = clock()
            for output in outputs:
                output.show(pattern, frame, detections)
            t_out = clock()
            latency_ns = time.monotonic_ns() - frame.timestamp_ns
            # what the next frame's prediction should cover (a slow running mean)
            latency_estimate += (latency_ns / 1e9 - latency_estimate) * (0.1 if summary.frames else 1.0)

            capture_s = (t1 - t0) / 1e9
            total_s = (t_prev - t0) / 1e9
            values = {"Capture Duration (s)": capture_s, "Total frame processing time (s)": total_s,
                      "Pattern Rendering Duration (s)": (t_pattern - t_prev) / 1e9,
                      **({"Tracking Duration (s)": track_ns / 1e9} if tracker is not None else {}),
                      "Output Duration (s)": (t_out - t_pattern) / 1e9,
                      "End-to-end Latency (s)": latency_ns / 1e9}
            for column, ns in zip(stage_columns, stage_ns):
                values[column] = ns / 1e9
            for column, v in values.items():
                summary.durations[column].add(v)
            summary.particles.add(len(detections))
            summary.frames += 1

            if metrics_writer is not None:
                for i in range(len(row)):
                    row[i] = 0.0
                for column, v in values.items():
                    row[index_of[column]] = f"{v:.9f}"
                for i, ns in zip(stage_index, stage_ns):
                    row[i] = f"{ns / 1e9:.9f}"
                row[index_of["Number of MECs on screen"]] = len(detections)
                row[index_of["Frame"]] = frame.index
                row[index_of["Capture Timestamp (ns)"]] = frame.timestamp_ns
                metrics_writer.writerow(row)
            if detections_writer is not None and len(detections):
                if track_ids is None:
                    detections_writer.writerows(
                        (frame.index, f"{x:.3f}", f"{y:.3f}", f"{r:.3f}")
                        for (x, y), r in zip(detections.centres.tolist(), detections.radii.tolist()))
                else:
                    detections_writer.writerows(
                        (frame.index, f"{x:.3f}", f"{y:.3f}", f"{r:.3f}", i)
                        for (x, y), r, i in zip(detections.centres.tolist(), detections.radii.tolist(),
                                                track_ids.tolist()))
            if any(o.exit_requested for o in outputs):
                summary.stop_reason = "stopped from the window (e)"
                break
        summary.wall_s = (clock() - started) / 1e9
    _print_summary(summary, out)
    return summary


def _print_summary(summary: RunSummary, out: TextIO) -> None:
    p = summary.particles
    fps = summary.frames / summary.wall_s if summary.wall_s > 0 else 0.0
    print(f"frames: {summary.frames} ({summary.stop_reason})", file=out)
    if p.count:
        print(f"particles per frame: mean {p.mean:.1f}, min {p.min:.0f}, max {p.max:.0f}", file=out)
    print(summary.table(), file=out)
    print(f"frames per second: {fps:.1f} over {summary.wall_s:.2f} s", file=out)
