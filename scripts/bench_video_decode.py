"""Decode speed of a video source: PyAV (the source since issue 50) against OpenCV (before), interleaved.

Writes test files from the simulator (FFV1 grey and BGR as ``record`` makes them, H.264 as a phone or
action camera does), then reads each whole, alternating the decoders, and prints the median ms per
frame of each.  docs/decisions/010-true-time.md holds the figures.

    python scripts/bench_video_decode.py --frames 200 --repeats 7
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from fractions import Fraction
from pathlib import Path

import av
import cv2
import numpy as np

from antiscatter.sources.simulated import SimulatorSource
from antiscatter.sources.video import VideoSource


def write(path: Path, frames: list[np.ndarray], codec: str, pix: str, options: dict[str, str]) -> None:
    """``frames`` (grey or BGR) to ``path`` at 60 frames a second, 1 ms ticks."""
    with av.open(str(path), "w") as container:
        stream = container.add_stream(codec, rate=60)
        stream.width, stream.height, stream.pix_fmt = frames[0].shape[1], frames[0].shape[0], pix
        stream.options = options
        stream.codec_context.time_base = Fraction(1, 1000)
        for i, image in enumerate(frames):
            frame = av.VideoFrame.from_ndarray(image, format="gray" if image.ndim == 2 else "bgr24")
            frame.pts, frame.time_base = round(i * 1000 / 60), Fraction(1, 1000)
            for packet in stream.encode(frame):
                container.mux(packet)
        for packet in stream.encode(None):
            container.mux(packet)


def opencv_ms(path: Path) -> float:
    """ms per frame of OpenCV's FFmpeg capture reading the file whole (BGR), its position read too."""
    capture = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
    count, start = 0, time.perf_counter()
    while True:
        ok, _ = capture.read()
        if not ok:
            break
        capture.get(cv2.CAP_PROP_POS_MSEC)
        count += 1
    seconds = time.perf_counter() - start
    capture.release()
    return seconds / count * 1e3


def source_ms(path: Path) -> float:
    """ms per frame of :class:`VideoSource` (PyAV, BGR, with each frame's presentation time)."""
    with VideoSource(path) as source:
        count, start = 0, time.perf_counter()
        while source.read() is not None:
            count += 1
        return (time.perf_counter() - start) / count * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        cases = []
        for size in ((728, 544), (1456, 1088)):
            sim = SimulatorSource(preset="seed", seed=1, size=size)
            colour = [sim.read().image.copy() for _ in range(args.frames)]
            grey = [cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) for image in colour]
            tag = f"{size[0]}x{size[1]}"
            for name, frames, codec, pix, options in (
                    ("FFV1 grey (record, camera Y)", grey, "ffv1", "gray", {"slices": "16", "level": "3"}),
                    ("FFV1 BGR (record --camera-colour)", colour, "ffv1", "bgr0", {"slices": "16", "level": "3"}),
                    ("H.264 yuv420p crf 18", colour, "libx264", "yuv420p", {"crf": "18"})):
                path = Path(folder) / f"{tag}-{len(cases)}.mkv"
                write(path, frames, codec, pix, options)
                cases.append((f"{tag} {name}", path))
        for label, path in cases:
            times: dict[str, list[float]] = {"OpenCV": [], "PyAV": []}
            for _ in range(args.repeats):  # interleaved: a load change hits both alike
                times["OpenCV"].append(opencv_ms(path))
                times["PyAV"].append(source_ms(path))
            cv, pa = statistics.median(times["OpenCV"]), statistics.median(times["PyAV"])
            print(f"{label:48s} OpenCV {cv:6.2f} ms  PyAV source {pa:6.2f} ms  ratio {pa / cv:4.2f}")


if __name__ == "__main__":
    main()
