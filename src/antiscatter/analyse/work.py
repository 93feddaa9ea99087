"""One task of ``analyse``: every frame of a chunk through the default detector, measured.

The detector runs single-frame (``ContrastParams(memory=0)``): each frame's detections depend on
that frame alone, so a chunk's results are the same however the files are cut into chunks and
whichever worker runs them (docs/decisions/006-analyse-and-mcap.md: the measured cost, and why a
warm-up of the learning detector cannot give identical results).  The pure function
:func:`analyse_chunk` returns plain arrays; :func:`save_result` / :func:`load_result` keep them in
``DIR/chunks/`` so a rerun does not compute them again.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from .inputs import Chunk, read_chunk

__all__ = ["analyse_chunk", "measure_frame", "chunk_key", "save_result", "load_result", "detector_params",
           "equivalent_diameters", "FORMAT", "BACKGROUND_CELL", "SIZE_LEVEL"]

#: version of the chunk results' content: a change of what a chunk computes bumps it (old results unused)
FORMAT = 2
#: side, px, of the cells whose median-filtered means make a frame's background (turbidity index)
BACKGROUND_CELL = 16
#: share of a particle's peak over its background that bounds its area for the ESD: a quarter
#: matched the simulator's footprints best (half lost bubbles' dim insides; the measured table:
#: docs/decisions/006-analyse-and-mcap.md)
SIZE_LEVEL = 0.25
#: per-frame columns of a chunk result
FRAME_FIELDS = ("frame", "time_s", "particles", "brightness", "background")
#: per-particle columns of a chunk result
PARTICLE_FIELDS = ("frame", "x", "y", "diameter_px")


def detector_params() -> Any:
    """The default detector's parameters for analysis: its defaults, single-frame."""
    from ..detection.contrast.params import ContrastParams

    return ContrastParams(memory=0)


def chunk_key(chunk: Chunk) -> str:
    """Hex digest naming a chunk's result: its file (path, sizes, modification times), frame range
    and the detector's parameters, so the same inputs and settings find the result again."""
    source = chunk.source
    identity = {"format": FORMAT, "path": str(source.path.resolve()), "kind": source.kind, "stamp": source.stamp,
                "start": chunk.start, "stop": chunk.stop, "bits": source.bits,
                "detector": dataclasses.asdict(detector_params())}
    return hashlib.sha256(json.dumps(identity, sort_keys=True).encode()).hexdigest()[:32]


def measure_frame(image: np.ndarray) -> tuple[float, float]:
    """(brightness, background) of one frame, grey levels 0..255.

    brightness: the mean of its luma.  background: the median of its background, the means of
    ``BACKGROUND_CELL`` px cells median-filtered over 3x3 cells so particles do not lift it: the
    veiling light turbid water scatters back from the lamp raises it.
    """
    import cv2

    grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
    h, w = grey.shape
    cells = cv2.resize(grey.astype(np.float32), (max(w // BACKGROUND_CELL, 3), max(h // BACKGROUND_CELL, 3)),
                       interpolation=cv2.INTER_AREA)  # float: a fraction of a grey level still shows
    return float(grey.mean()), float(np.median(cv2.medianBlur(cells, 3)))


def equivalent_diameters(grey: np.ndarray, centres: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """(N,) equivalent diameters, px, of the particles at ``centres`` (N, 2) px: ``2 sqrt(A / pi)`` with A
    the pixels within each detected disc (``radii`` (N,) px, plus one) at or above ``SIZE_LEVEL`` of the
    particle's peak over its local background (the median of the square around the disc) -- an area-based
    ESD as the UVP's, not the detector's covering radius (quantised to working pixels, with a halo for holes).

    Vectorised over particles of similar size: windows of a few sizes (powers of two) gathered at once.
    A particle cut by the frame's edge counts the pixels inside the frame.
    """
    out = np.empty(len(radii))
    if not len(radii):
        return out
    reaches = np.ceil(radii).astype(np.int64) + 2
    buckets = 2 ** np.ceil(np.log2(np.maximum(reaches, 4))).astype(np.int64)
    pad = int(buckets.max()) + 1
    padded = np.pad(grey.astype(np.float32), pad, constant_values=np.nan)  # beyond the frame: no pixel
    for reach in np.unique(buckets).tolist():
        chosen = np.flatnonzero(buckets == reach)
        x, y, r = centres[chosen, 0], centres[chosen, 1], radii[chosen]
        ix, iy = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
        offsets = np.arange(-reach, reach + 1)
        rows = (iy + pad)[:, None, None] + offsets[None, :, None]
        cols = (ix + pad)[:, None, None] + offsets[None, None, :]
        windows = padded[rows, cols]  # (n, 2 reach + 1, 2 reach + 1)
        dx = (ix[:, None, None] + offsets[None, None, :] + 0.5) - x[:, None, None]
        dy = (iy[:, None, None] + offsets[None, :, None] + 0.5) - y[:, None, None]
        d2 = dx * dx + dy * dy
        inside = d2 <= ((r + 1) ** 2)[:, None, None]
        background = np.nanmedian(np.where(inside, np.nan, windows).reshape(len(chosen), -1), axis=1)
        core = d2 <= (np.maximum(r, 1.0) ** 2)[:, None, None]
        peak = np.where(core & ~np.isnan(windows), windows, -np.inf).reshape(len(chosen), -1).max(axis=1)
        level = (background + SIZE_LEVEL * (peak - background))[:, None, None]
        area = np.count_nonzero(inside & (windows >= level), axis=(1, 2))
        diameters = 2 * np.sqrt(np.maximum(area, 1) / math.pi)
        out[chosen] = np.where(peak > background, diameters, 2 * r)
    return out


def analyse_chunk(chunk: Chunk) -> dict[str, Any]:
    """Every frame of ``chunk`` through a fresh single-frame detector.

    Returns a dict of arrays: per frame (``FRAME_FIELDS``: index, seconds from the file's first
    frame, particles, brightness, background) and per particle (``PARTICLE_FIELDS``: frame, centre
    x, y and diameter, px), plus ``size`` (width, height px); on a frame that cannot be read,
    ``error`` (one line) with the frames read before it.
    """
    import cv2

    from ..detection import make_detector

    cv2.setNumThreads(1)  # one core a task: the scheduler runs a task per core
    detector = make_detector("contrast", detector_params())
    frames: dict[str, list] = {name: [] for name in FRAME_FIELDS}
    particles: list[np.ndarray] = []
    size = (0, 0)
    error = ""
    try:
        for index, image in read_chunk(chunk):
            size = (image.shape[1], image.shape[0])
            found = detector.detect(image)
            brightness, background = measure_frame(image)
            for name, value in zip(FRAME_FIELDS, (index, chunk.source.times_s[index], len(found), brightness,
                                                  background)):
                frames[name].append(value)
            if len(found):
                grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
                particles.append(np.column_stack([np.full(len(found), index, np.float64), found.centres,
                                                  equivalent_diameters(grey, found.centres, found.radii)]))
    except ValueError as exc:
        error = str(exc).splitlines()[0]
    result: dict[str, Any] = {name: np.asarray(values, np.float64) for name, values in frames.items()}
    table = np.concatenate(particles) if particles else np.empty((0, len(PARTICLE_FIELDS)))
    for column, name in enumerate(PARTICLE_FIELDS):
        result[f"p_{name}"] = table[:, column].copy()
    result["size"] = np.asarray(size, np.int64)
    result["error"] = np.asarray(error)
    return result


def save_result(folder: Path, key: str, result: dict[str, Any]) -> Path:
    """Write ``result`` as ``folder/<key>.npz`` atomically (a temporary file renamed): a result there is whole."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{key}.npz"
    handle, temporary = tempfile.mkstemp(prefix=f".{key}-", suffix=".npz", dir=folder)
    try:
        with os.fdopen(handle, "wb") as file:
            np.savez(file, **result)
            file.flush()
            os.fsync(file.fileno())
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise
    return path


def load_result(folder: Path, key: str) -> dict[str, Any] | None:
    """The result saved under ``key``, or None when there is none (or it cannot be read)."""
    path = folder / f"{key}.npz"
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            return {name: data[name] for name in data.files}
    except (OSError, ValueError, KeyError):
        return None
