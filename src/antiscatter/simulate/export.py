"""``antiscatter simulate``: frames, truth.csv and label masks on disk.

Everything is written to a staging folder inside OUT and moved into place at
the end, so an interrupted or failed run leaves nothing that looks complete.
The staging folder is removed however the run ends (a full disk, Ctrl-C,
SIGTERM); one left by a killed run is removed by the next run into OUT.
"""

from __future__ import annotations

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

from ..console import progress
from ..errors import UsageError, check_output_folder, check_output_path
from ..writing import CsvFile, write_whole
from ..sources.folder import list_frames
from . import make_scene
from .truth import TRUTH_COLUMNS

__all__ = ["SimulationRequest", "simulate"]


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


def _check(request: SimulationRequest) -> None:
    if request.frames <= 0:
        raise UsageError(f"--frames {request.frames}: allowed a positive number of frames")
    if request.seed < 0:
        raise UsageError(f"--seed {request.seed}: allowed >= 0")
    out = request.out
    if out.exists() and not out.is_dir():
        raise UsageError(f"{out}: exists and is not a folder")
    check_output_folder(out, "OUT")  # writable, or made here (one level: its own folder must exist)
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
    out.mkdir(exist_ok=True)
    _remove_stale_staging(out)
    staging = Path(tempfile.mkdtemp(prefix=STAGING_PREFIX, dir=out))
    video_partial = None
    container = stream = None
    try:
        (staging / STAGING_PID).write_text(str(os.getpid()))
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
        started = time.perf_counter()
        with CsvFile(staging / "truth.csv", TRUTH_COLUMNS) as writer:
            for index in progress(range(request.frames), desc="simulate"):
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
                else:  # (cv2.imwrite reports success for a file the disk cut short)
                    write_whole(staging / f"{index}.png", _png(image))
                if labels is not None:
                    write_whole(staging / "masks" / f"{index}.png", _png(labels))
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
            try:
                container.close()
            except OSError:
                pass  # (its file is removed next)
        if video_partial is not None and video_partial.exists():
            video_partial.unlink()
        raise
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return {"frames": request.frames, "particles": rows, "seconds": seconds,
            "fps": request.frames / seconds if seconds > 0 else 0.0}


#: the hidden staging folder's name prefix inside OUT, and the file in it naming the process writing it
STAGING_PREFIX = ".partial-"
STAGING_PID = "pid"
#: seconds after which a staging folder without a readable pid file is taken as a killed run's
STALE_SECONDS = 3600.0


def _remove_stale_staging(out: Path) -> None:
    """Remove staging folders in ``out`` that killed runs left: their process no longer exists
    (or, without a readable pid file, nothing was written in them for ``STALE_SECONDS``).  A
    concurrent run's folder stays."""
    for folder in out.glob(f"{STAGING_PREFIX}*"):
        if not folder.is_dir():
            continue
        try:
            pid = int((folder / STAGING_PID).read_text())
        except (OSError, ValueError):
            pid = 0
        if pid:
            try:
                os.kill(pid, 0)
                continue  # alive: a run writing into OUT now
            except ProcessLookupError:
                pass
            except PermissionError:
                continue  # alive, another user's
        elif time.time() - folder.stat().st_mtime < STALE_SECONDS:
            continue
        shutil.rmtree(folder, ignore_errors=True)


def _png(image: np.ndarray) -> bytes:
    """``image`` as PNG bytes (8-bit frames, 16-bit label masks)."""
    ok, data = cv2.imencode(".png", image)
    if not ok:
        raise ValueError(f"an image of shape {image.shape} could not be encoded as PNG")
    return data.tobytes()


def _move_into_place(staging: Path, out: Path, *, overwrite: bool) -> None:
    if overwrite:
        for old in list_frames(out):
            old.unlink()
        if (out / "masks").is_dir():
            shutil.rmtree(out / "masks")
    for item in staging.iterdir():
        if item.name in ("truth.csv", STAGING_PID):
            continue
        os.replace(item, out / item.name)
    os.replace(staging / "truth.csv", out / "truth.csv")  # last: its presence marks completion
