"""``antiscatter record``: the report's lossless recorder, with the light as a plain lamp."""

from __future__ import annotations

import sys
import time
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

import numpy as np

from ..errors import UsageError
from ..outputs import open_output
from ..runtime import Pacer, StopFlag
from ..sources import open_source
from .keys import TerminalKeys
from .recorder import Recorder, RecorderFull

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
    exposure_ms, gain: a fixed camera exposure and analogue gain (None: automatic).
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


def record(request: RecordRequest, *, log: TextIO | None = None, out: TextIO | None = None) -> dict:
    """Record until the limit, ``e``, the panel's Stop, Ctrl-C/SIGTERM or the source's end."""
    log = log or sys.stderr
    out = out or sys.stdout
    if request.out.exists() and request.out.is_dir():
        raise UsageError(f"{request.out}: is a folder, expected a .mkv file path")
    with ExitStack() as stack:
        source = stack.enter_context(open_source(request.source, size=request.size, fps=request.fps or None,
                                                 colour=request.colour, exposure_ms=request.exposure_ms,
                                                 gain=request.gain))
        lamps = [stack.enter_context(open_output(spec, fps=request.fps or 60.0)) for spec in request.outputs]
        white = np.full((800, 1280), 255, np.uint8)
        black = np.zeros_like(white)
        recorder = Recorder(request.out, fps=request.fps or source.fps or 30.0,
                            buffer_bytes=int(request.buffer_mb * 2 ** 20), overflow=request.overflow)
        keys = TerminalKeys()
        stack.callback(keys.close)
        stop = stack.enter_context(StopFlag())
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
                        recorder.write(frame.image)
                        recorded += 1
                    except RecorderFull as exc:
                        message = str(exc)
                        print(message, file=log)
                        state["recording"] = False
                if panel is not None:
                    panel.publish(image=frame.image, stats={
                        "captured": captured, "recorded": recorded, "buffered": recorder.frames_in - recorder.frames_encoded,
                        "spilled": recorder.frames_spilled, "light": "on" if state["light"] else "off",
                        "recording": "yes" if state["recording"] else "no"})
        finally:
            summary = recorder.close()
        seconds = time.monotonic() - started
    summary.update(captured=captured, reason=reason, message=message, wall_seconds=seconds)
    print(f"recorded {summary['frames']} of {captured} captured frames to {request.out} ({reason}); dropped "
          f"{summary['dropped']}, spilled to disk {summary['spilled']}; {summary['bytes'] / 2 ** 20:.1f} MiB; "
          f"encoding {summary['encode_fps']:.0f} frames/s", file=out)
    return summary
