"""``antiscatter record``: the report's lossless recorder, with the light as a plain lamp."""

from __future__ import annotations

import sys
import time
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

import numpy as np

from ..errors import UsageError, WriteError, check_output_path
from ..outputs import open_output
from ..runtime import Pacer, StopFlag
from ..sources import open_source
from ..sources.base import FrameClock
from .keys import TerminalKeys
from .recorder import Recorder, RecorderFull, sidecar_path

__all__ = ["RecordRequest", "record"]


@dataclass(frozen=True)
class RecordRequest:
    """What ``antiscatter record`` does.

    out: the .mkv to write; source: sim, camera, webcam:N or a video; size: (w, h) or None;
    fps: capture rate (camera, webcam) and pace for sim/video (0 = as fast as possible);
    seconds / frames: stop after (0 = until e, Ctrl-C or the source ends);
    light: the lamp on at the start; paused: start without recording (r starts);
    outputs: light outputs driven as a plain lamp (white / black);
    buffer_mb, overflow: RAM for frames waiting to be encoded, and what to do when full;
    web: control panel address, empty = none; colour: BGR from the camera instead of the Y plane;
    exposure_ms, gain: a fixed camera exposure and analogue gain (None: automatic);
    overwrite: replace an existing ``out`` (default False: a recording is never overwritten).
    mcap: also write each recorded frame as a ROS 2 CompressedImage (PNG) with the recorder's
        figures to this MCAP file (:mod:`antiscatter.mcap_out`); None = none.
    """

    out: Path
    source: str = "sim"
    size: tuple[int, int] | None = None
    fps: float = 30.0
    seconds: float = 0.0
    frames: int = 0
    light: bool = True
    paused: bool = False
    outputs: tuple[str, ...] = ("none",)
    buffer_mb: float = 512.0
    overflow: str = "spill"
    web: str = ""
    colour: bool = False
    exposure_ms: float | None = None
    gain: float | None = None
    overwrite: bool = False
    mcap: Path | None = None


def record(request: RecordRequest, *, log: TextIO | None = None, out: TextIO | None = None) -> dict:
    """Record until the limit, ``e``, the panel's Stop, Ctrl-C/SIGTERM or the source's end.

    A write the disk refuses (the file's or the spill file's) stops the recording: the summary is
    printed with the frames the file holds, then :class:`~antiscatter.errors.WriteError` is raised.
    """
    log = log or sys.stderr
    out = out or sys.stdout
    if request.out.suffix.lower() != ".mkv" and not request.out.is_dir():
        raise UsageError(f"{request.out}: allowed a .mkv file (FFV1 in Matroska)")
    check_output_path(request.out, "output", overwrite=request.overwrite)
    check_output_path(sidecar_path(request.out), "output's sidecar", overwrite=request.overwrite)
    if request.mcap is not None:
        from ..mcap_out import require_mcap

        require_mcap()
        check_output_path(request.mcap, "--mcap", suffixes=(".mcap",))
    buffer_bytes = int(request.buffer_mb * 2 ** 20)
    with ExitStack() as stack:
        stop = stack.enter_context(StopFlag())  # first: a signal from here on leaves a finished file
        source = stack.enter_context(open_source(request.source, size=request.size, fps=request.fps or None,
                                                 colour=request.colour, exposure_ms=request.exposure_ms,
                                                 gain=request.gain))
        lamps = [stack.enter_context(open_output(spec, fps=request.fps or 60.0)) for spec in request.outputs]
        if request.overflow == "stop" and buffer_bytes < source.size[0] * source.size[1]:
            _refuse_buffer(request, source.size[0] * source.size[1])
        white = np.full((800, 1280), 255, np.uint8)
        black = np.zeros_like(white)
        # the frames' true time: a live source's monotonic clock mapped to UNIX time (the sidecar's
        # unix_time_ns and the MCAP stamps, by one offset), a file's or the simulator's own
        live = getattr(source, "live", False)
        rate = request.fps or source.fps or 30.0
        clock = FrameClock(live=live, interval_s=0.0 if live else 1.0 / rate)
        recorder = Recorder(request.out, fps=rate, buffer_bytes=buffer_bytes, overflow=request.overflow,
                            unix_offset_ns=clock.offset_ns if live else None)
        log_mcap = None
        if request.mcap is not None:
            from ..mcap_out import McapLog

            log_mcap = stack.enter_context(McapLog(request.mcap))
        keys = TerminalKeys()
        stack.callback(keys.close)
        state = {"light": request.light, "recording": not request.paused, "lamp_shown": None}
        panel = None
        if request.web:
            from ..web import ControlPanel

            def toggle(name: str) -> str:
                state[name] = not state[name]
                return f"{name} {'on' if state[name] else 'off'}"

            def finish() -> str:
                stop.reason = stop.reason or "panel"
                return "stopping"

            panel = stack.enter_context(ControlPanel(
                request.web, title="record",
                actions={"light": lambda: toggle("light"), "record": lambda: toggle("recording"), "stop": finish}))
            print(f"control panel: {panel.url}", file=log)
        if keys.active:
            print("keys: l light on/off, r record/pause, e exit", file=log)
        print(f"antiscatter record: {request.source} ({source.size[0]}x{source.size[1]}) -> {request.out}", file=log)
        pacer = Pacer(request.fps if not getattr(source, "live", False) else 0.0)
        captured = recorded = 0
        reason = ""
        started = time.monotonic()
        message = ""
        failure: WriteError | None = None
        try:
            while True:
                for key in keys.poll():
                    if key == "l":
                        state["light"] = not state["light"]
                    elif key == "r":
                        state["recording"] = not state["recording"]
                        print("recording" if state["recording"] else "paused", file=log)
                    elif key == "e":
                        stop.reason = stop.reason or "e"
                if stop:
                    reason = f"stopped by {stop.reason}"
                    break
                if request.frames and captured >= request.frames:
                    reason = f"frame limit {request.frames}"
                    break
                if request.seconds and time.monotonic() - started >= request.seconds:
                    reason = f"time limit {request.seconds:g} s"
                    break
                if state["lamp_shown"] != state["light"]:
                    for lamp in lamps:
                        lamp.show(white if state["light"] else black)
                    state["lamp_shown"] = state["light"]
                pacer.wait()
                frame = source.read()
                if frame is None:
                    reason = "source ended"
                    break
                captured += 1
                if state["recording"]:
                    try:
                        recorder.write(frame.image, time_ns=clock.source_ns(frame),
                                       exposure_ns=frame.exposure_ns, analogue_gain=frame.analogue_gain)
                        recorded += 1
                        if log_mcap is not None:
                            log_mcap.write(clock.stamp_ns(frame), image=frame.image, metrics={
                                "Frame": frame.index, "Recorded": recorded, "Spilled": recorder.frames_spilled,
                                "Light": int(state["light"])})
                    except RecorderFull as exc:
                        if frame.image.nbytes > buffer_bytes:  # no frame ever fits: nothing was recorded
                            _refuse_buffer(request, frame.image.nbytes)
                        message = str(exc)
                        print(f"warning: {message}", file=log)
                        state["recording"] = False
                    except WriteError as exc:  # the disk is full: stop, with the frames the file holds
                        failure, message, reason = exc, str(exc), "write failed"
                        break
                if panel is not None:
                    panel.publish(image=frame.image, stats={
                        "captured": captured, "recorded": recorded, "buffered": recorder.frames_in - recorder.frames_encoded,
                        "spilled": recorder.frames_spilled, "light": "on" if state["light"] else "off",
                        "recording": "yes" if state["recording"] else "no"})
        finally:
            summary = recorder.close()
        seconds = time.monotonic() - started
    what = failure.what if failure is not None else f"{summary.get('failed', request.out)}: {summary.get('error', '')}"
    if "error" in summary:  # the file's disk filled (perhaps while the last frames were encoded)
        failure, reason = failure or WriteError(what), "write failed"
    summary.update(captured=captured, reason=reason, message=message, wall_seconds=seconds)
    print(f"recorded {summary['frames']} of {captured} captured frames to {request.out} ({reason}); dropped "
          f"{summary['dropped']}, spilled to disk {summary['spilled']}; {summary['bytes'] / 2 ** 20:.1f} MiB; "
          f"encoding {summary['encode_fps']:.0f} frames/s", file=out)
    if failure is not None:
        raise WriteError(f"{what}; stopped, the file holds {summary['frames']} of the {recorded} frames taken")
    return summary


def _refuse_buffer(request: RecordRequest, frame_bytes: int) -> None:
    """``--overflow stop`` with a buffer no frame fits in would record nothing: refused before recording."""
    raise UsageError(f"--buffer-mb {request.buffer_mb:g}: smaller than one frame ({frame_bytes / 2 ** 20:.2f} MiB) "
                     "with --overflow stop, nothing could be recorded; allowed at least one frame")
