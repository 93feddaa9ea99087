"""``antiscatter simulate``: frames, truth.csv and label masks on disk.

Everything is written to a staging folder inside OUT and moved into place at
the end, so an interrupted or failed run leaves nothing that looks complete.
"""

from __future__ import annotations

import csv
import os
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import TextIO

import cv2
import numpy as np

from ..errors import UsageError, check_output_path
from ..sources.folder import list_frames
from . import make_scene
from .truth import TRUTH_COLUMNS

__all__ = ["SimulationRequest", "simulate", "Progress"]


@dataclass(frozen=True)
class SimulationRequest:
    """What to simulate and where.

    out: output folder (``<frame>.png``, ``truth.csv``, ``masks/<frame>.png``).
    preset, frames, seed, size: the scene; size None = the preset's own.
    background: image or video replacing a realistic preset's background.
    masks: also write 16-bit label masks.
    video: write the frames as this lossless FFV1 .mkv instead of PNGs.
    overwrite: replace frames already in ``out``.
    """

    out: Path
    preset: str = "seed"
    frames: int = 120
    seed: int = 0
    size: tuple[int, int] | None = None
    background: str | None = None
    masks: bool = False
    video: Path | None = None
    overwrite: bool = False


class Progress:
    """A one-line progress bar on a terminal; silent otherwise."""

    def __init__(self, total: int, stream: TextIO = sys.stderr) -> None:
        self.total = total
        self.stream = stream
        self.enabled = stream.isatty()
        self.start = time.perf_counter()

    def update(self, done: int) -> None:
        if not self.enabled or (done % 5 and done != self.total):
            return
        width = 30
        filled = int(width * done / self.total)
        rate = done / max(time.perf_counter() - self.start, 1e-9)
        self.stream.write(f"\r[{'#' * filled}{'.' * (width - filled)}] {done}/{self.total} frames "
                          f"{rate:.0f} frames/s")
        if done == self.total:
            self.stream.write("\n")
        self.stream.flush()


def _check(request: SimulationRequest) -> None:
    if request.frames <= 0:
        raise UsageError(f"--frames {request.frames}: allowed a positive number of frames")
    if request.seed < 0:
        raise UsageError(f"--seed {request.seed}: allowed >= 0")
    out = request.out
    if out.exists() and not out.is_dir():
        raise UsageError(f"{out}: exists and is not a folder")
    if request.video is not None:
        if request.video.parent.resolve() != out.resolve():  # OUT itself is created by the run
            check_output_path(request.video, "--video")
        if request.video.suffix.lower() != ".mkv":
            raise UsageError(f"--video {request.video}: allowed a .mkv file (FFV1 in Matroska)")
        if request.video.exists() and not request.overwrite:
            raise UsageError(f"--video {request.video}: already exists; use --overwrite to replace it")
    if out.is_dir() and not request.overwrite:
        if list_frames(out) or (out / "truth.csv").exists():
            raise UsageError(f"{out}: already holds frames or truth.csv; use --overwrite to replace them")


def simulate(request: SimulationRequest, *, log: TextIO = sys.stderr) -> dict[str, float]:
    """Write the scene; returns {"frames": n, "particles": rows, "seconds": s, "fps": rate}."""
    _check(request)
    scene = make_scene(request.preset, rng=np.random.default_rng(request.seed), size=request.size,
                       background=request.background)
    width, height = scene.size
    out = request.out
    out.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=".partial-", dir=out))
    video_partial = None
    container = stream = None
    try:
        if request.masks:
            (staging / "masks").mkdir()
        if request.video is not None:
            import av

            video_partial = request.video.with_name(request.video.name + ".partial")
            container = av.open(str(video_partial), mode="w", format="matroska",
                                options={"fflags": "+bitexact"})  # same seed, same bytes
            stream = container.add_stream("ffv1", rate=Fraction(scene.fps).limit_denominator(1001))
            stream.width, stream.height, stream.pix_fmt = width, height, "bgr0"
            stream.thread_type = "AUTO"
        labels = np.zeros((height, width), np.uint16) if request.masks else None
        rows = 0
        progress = Progress(request.frames)
        started = time.perf_counter()
        with (staging / "truth.csv").open("w", newline="") as handle:
            writer = csv.writer(handle)
            writer.writerow(TRUTH_COLUMNS)
            for index in range(request.frames):
                if index:
                    scene.step()
                image = scene.render(labels=labels)
                truth = scene.truth()
                writer.writerows(truth.rows(index))
                rows += len(truth)
                if container is not None:
                    frame = av.VideoFrame.from_ndarray(image, format="bgr24")
                    for packet in stream.encode(frame):
                        container.mux(packet)
                elif not cv2.imwrite(str(staging / f"{index}.png"), image):
                    raise OSError(f"{staging / f'{index}.png'}: could not be written")
                if labels is not None:
                    cv2.imwrite(str(staging / "masks" / f"{index}.png"), labels)
                progress.update(index + 1)
        if container is not None:
            for packet in stream.encode(None):
                container.mux(packet)
            container.close()
            container = None
        seconds = time.perf_counter() - started
        _move_into_place(staging, out, overwrite=request.overwrite)
        if video_partial is not None:
            os.replace(video_partial, request.video)
    except BaseException:
        if container is not None:
            container.close()
        if video_partial is not None and video_partial.exists():
            video_partial.unlink()
        raise
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return {"frames": request.frames, "particles": rows, "seconds": seconds,
            "fps": request.frames / seconds if seconds > 0 else 0.0}


def _move_into_place(staging: Path, out: Path, *, overwrite: bool) -> None:
    if overwrite:
        for old in list_frames(out):
            old.unlink()
        if (out / "masks").is_dir():
            shutil.rmtree(out / "masks")
    for item in staging.iterdir():
        if item.name == "truth.csv":
            continue
        os.replace(item, out / item.name)
    os.replace(staging / "truth.csv", out / "truth.csv")  # last: its presence marks completion
