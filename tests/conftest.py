"""Shared helpers: frames with known particles, small videos, the CLI in-process."""

from __future__ import annotations

import io
import sys
from contextlib import redirect_stderr, redirect_stdout
from fractions import Fraction
from pathlib import Path
from typing import Iterable

import cv2
import numpy as np
import pytest


def draw_discs(size: tuple[int, int], discs: Iterable[tuple[float, float, float]], *,
               background: int = 0, value: int = 255) -> np.ndarray:
    """(H, W, 3) BGR frame with filled discs (x, y, r) drawn at sub-pixel precision."""
    width, height = size
    image = np.full((height, width, 3), background, np.uint8)
    for x, y, r in discs:
        cv2.circle(image, (round(x * 16), round(y * 16)), round(r * 16), (value,) * 3, -1, cv2.LINE_8, 4)
    return image


def write_ffv1(path: Path, frames: list[np.ndarray], fps: int = 30) -> None:
    """Write BGR frames losslessly (FFV1, bgr0) with PyAV."""
    import av

    with av.open(str(path), mode="w", format="matroska") as container:
        stream = container.add_stream("ffv1", rate=Fraction(fps))
        stream.width, stream.height = frames[0].shape[1], frames[0].shape[0]
        stream.pix_fmt = "bgr0"
        for image in frames:
            frame = av.VideoFrame.from_ndarray(image, format="bgr24")
            for packet in stream.encode(frame):
                container.mux(packet)
        for packet in stream.encode(None):
            container.mux(packet)


def csv_rows(path: Path) -> list[list[str]]:
    """The rows of a CSV that must be whole: ends in a line break, every row as wide as the header."""
    import csv

    text = Path(path).read_text()
    assert text.endswith("\n"), f"{path} ends in a partial row"
    rows = list(csv.reader(text.splitlines()))
    assert rows and all(len(r) == len(rows[0]) for r in rows), f"{path}: a row without the header's fields"
    return rows


def mkv_frames(path: Path) -> int:
    """Frames of a video decoded to its end (an error on the way fails the test)."""
    import av

    with av.open(str(path)) as container:
        return sum(1 for _ in container.decode(video=0))


def numbered_frames(count: int, size: tuple[int, int] = (64, 48)) -> list[np.ndarray]:
    """Frames whose pixels encode their index and position (exact round trips)."""
    width, height = size
    yy, xx = np.mgrid[0:height, 0:width]
    frames = []
    for i in range(count):
        image = np.empty((height, width, 3), np.uint8)
        image[..., 0] = (xx * 3 + i) % 256
        image[..., 1] = (yy * 5) % 256
        image[..., 2] = i * 10 % 256
        frames.append(image)
    return frames


class CliResult:
    def __init__(self, code: int, out: str, err: str) -> None:
        self.code, self.out, self.err = code, out, err


def run_cli(*args: str) -> CliResult:
    """Call ``antiscatter`` in-process; returns exit code, stdout and stderr."""
    from antiscatter.cli import main

    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        try:
            code = main(list(args))
        except SystemExit as exc:
            code = int(exc.code or 0)
    return CliResult(code, out.getvalue(), err.getvalue())


@pytest.fixture
def cli():
    return run_cli


@pytest.fixture
def python() -> str:
    return sys.executable


class PanelProcess:
    """``antiscatter ARGS --web 127.0.0.1:0`` in a subprocess; ``url`` is its panel, read from stderr.

    A context manager: the process is killed on exit if it is still running.
    """

    def __init__(self, args: list[str], cwd) -> None:
        import subprocess

        self.proc = subprocess.Popen([sys.executable, "-m", "antiscatter", *args, "--web", "127.0.0.1:0"], cwd=cwd,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.url = None
        while self.url is None:
            line = self.proc.stderr.readline()
            assert line, f"antiscatter {args[0]} ended before serving the panel"
            if line.startswith("control panel: "):
                self.url = line.split(": ", 1)[1].strip()

    def post(self, action: str) -> str:
        """Press a button, with the run's token read from the page as the page does; returns the panel's message."""
        import json
        import re
        import urllib.request

        page = urllib.request.urlopen(self.url, timeout=5).read().decode()
        token = re.search(r'name="antiscatter-token" content="([^"]+)"', page).group(1)
        request = urllib.request.Request(self.url + "action/" + action, method="POST",
                                         headers={"X-Antiscatter-Token": token})
        return json.loads(urllib.request.urlopen(request, timeout=5).read())["message"]

    def stats(self) -> dict:
        import json
        import urllib.request

        return json.loads(urllib.request.urlopen(self.url + "stats", timeout=5).read())

    def __enter__(self) -> "PanelProcess":
        return self

    def __exit__(self, *exc: object) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.communicate()


def write_vfr(path: Path, frames: list[np.ndarray], pts: list[int], time_base: Fraction = Fraction(1, 1000),
              codec: str = "ffv1") -> None:
    """Write BGR frames with PyAV at the given presentation times (ticks of ``time_base``): a
    variable-frame-rate file, as a camera that drops frames or a phone makes."""
    import av

    with av.open(str(path), mode="w") as container:
        stream = container.add_stream(codec, rate=30)
        stream.width, stream.height = frames[0].shape[1], frames[0].shape[0]
        stream.pix_fmt = "bgr0" if codec == "ffv1" else "yuv444p"
        stream.codec_context.time_base = time_base
        if codec != "ffv1":
            stream.options = {"qp": "0"}  # lossless
        for image, ticks in zip(frames, pts):
            frame = av.VideoFrame.from_ndarray(image, format="bgr24")
            frame.pts, frame.time_base = ticks, time_base
            for packet in stream.encode(frame):
                container.mux(packet)
        for packet in stream.encode(None):
            container.mux(packet)
