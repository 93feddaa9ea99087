"""The tables of ``analyse``: per frame, per particle, per time bin and size spectra, per file and over all.

Plain numpy in, columns (dicts of arrays) out; :func:`write_tables` writes them as Parquet with
pyarrow.  Over all, the files are laid end to end in input order (a survey's files one after the
other), each file's times offset by the durations before it.
"""

from __future__ import annotations

import csv
import io
import math
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .volume import VolumeModel, esd_classes

__all__ = ["FileResult", "combine_chunks", "frame_table", "particle_table", "bin_table", "spectrum_table",
           "summary_rows", "default_classes", "write_tables", "write_summary", "ALL"]

#: the ``file`` value of the rows over all files
ALL = "ALL"
#: a particle this many pixels across is the largest the default classes hold (the default
#: detector's largest radius, 48 px, plus its halo, on both sides)
LARGEST_PX = 100.0


@dataclass
class FileResult:
    """One input's measurements, its chunks joined in frame order.

    name: the path as given; frames: per-frame columns (frame, time_s, particles, brightness,
    background); particles: per-particle columns (frame, x, y, diameter_px); size: (width, height)
    px; fps: frames a second over the file; status: ok, damaged (some frames unreadable) or
    skipped (nothing read); reason: why, one line.
    """

    name: str
    frames: dict[str, np.ndarray]
    particles: dict[str, np.ndarray]
    size: tuple[int, int]
    fps: float
    status: str = "ok"
    reason: str = ""


def combine_chunks(name: str, results: list[dict[str, Any]], fps: float) -> FileResult:
    """Join one file's chunk results (in frame order) into a :class:`FileResult`."""
    frames = {f: np.concatenate([r[f] for r in results]) for f in ("frame", "time_s", "particles", "brightness",
                                                                   "background")}
    particles = {f: np.concatenate([r[f"p_{f}"] for r in results]) for f in ("frame", "x", "y", "diameter_px")}
    sizes = [tuple(int(v) for v in r["size"]) for r in results if int(r["size"][0])]
    errors = [str(r["error"]) for r in results if str(r["error"])]
    status = "ok" if not errors else ("damaged" if len(frames["frame"]) else "skipped")
    return FileResult(name, frames, particles, sizes[0] if sizes else (0, 0), fps, status, "; ".join(errors))


def default_classes(results: list[FileResult], model: VolumeModel) -> np.ndarray:
    """UVP class bounds, mm, from one pixel to ``LARGEST_PX`` pixels across at the files' pixel sizes."""
    scales = [model.mm_per_pixel(r.size[0]) for r in results if r.size[0]]
    if not scales:
        return esd_classes(1.0, 100.0)
    return esd_classes(min(scales), max(scales) * LARGEST_PX)


def _offsets(results: list[FileResult]) -> list[float]:
    """Seconds each file starts at when the files are laid end to end."""
    offsets, at = [], 0.0
    for r in results:
        offsets.append(at)
        if len(r.frames["time_s"]):
            at += float(r.frames["time_s"][-1]) + (1.0 / r.fps if r.fps > 0 else 0.0)
    return offsets


def frame_table(results: list[FileResult]) -> dict[str, np.ndarray]:
    """One row a frame: file, frame, time_s, particles, brightness, background (grey levels),
    turbidity_index (background / 255: the veiling light's share of full scale, comparable within
    a survey taken with the same camera settings)."""
    columns: dict[str, list] = {"file": [], "frame": [], "time_s": [], "particles": [], "brightness": [],
                                "background": [], "turbidity_index": []}
    for r in results:
        n = len(r.frames["frame"])
        columns["file"].append(np.full(n, r.name, dtype=object))
        columns["frame"].append(r.frames["frame"].astype(np.int64))
        columns["time_s"].append(r.frames["time_s"])
        columns["particles"].append(r.frames["particles"].astype(np.int64))
        columns["brightness"].append(r.frames["brightness"])
        columns["background"].append(r.frames["background"])
        columns["turbidity_index"].append(r.frames["background"] / 255.0)
    return {k: (np.concatenate(v) if v else np.empty(0)) for k, v in columns.items()}


def particle_times(result: FileResult) -> np.ndarray:
    """(P,) seconds of each particle's frame (the file's frames are in ascending order)."""
    at = np.searchsorted(result.frames["frame"], result.particles["frame"])
    return result.frames["time_s"][at] if len(at) else np.empty(0)


def particle_table(results: list[FileResult], model: VolumeModel) -> dict[str, np.ndarray]:
    """One row a particle: file, frame, time_s, x, y, diameter_px (px) and esd_mm (at the reference distance)."""
    columns: dict[str, list] = {k: [] for k in ("file", "frame", "time_s", "x", "y", "diameter_px", "esd_mm")}
    for r in results:
        p = r.particles
        n = len(p["frame"])
        frame = p["frame"].astype(np.int64)
        columns["file"].append(np.full(n, r.name, dtype=object))
        columns["frame"].append(frame)
        columns["time_s"].append(particle_times(r))
        columns["x"].append(p["x"])
        columns["y"].append(p["y"])
        columns["diameter_px"].append(p["diameter_px"])
        columns["esd_mm"].append(p["diameter_px"] * (model.mm_per_pixel(r.size[0]) if r.size[0] else math.nan))
    return {k: (np.concatenate(v) if v else np.empty(0)) for k, v in columns.items()}


def _rows_for(results: list[FileResult]) -> list[tuple[str, list[FileResult], list[float]]]:
    """(name, files, time offsets) for each file alone and for all of them end to end."""
    rows = [(r.name, [r], [0.0]) for r in results if len(r.frames["frame"])]
    readable = [r for r in results if len(r.frames["frame"])]
    if readable:
        rows.append((ALL, readable, _offsets(readable)))
    return rows


def bin_table(results: list[FileResult], model: VolumeModel, bin_s: float) -> dict[str, np.ndarray]:
    """One row per time bin of ``bin_s`` seconds, per file and over all (``ALL``).

    Columns: file, bin, start_s, end_s, frames, particles, per_frame, per_second (particles over the
    footage's seconds, frames / fps), per_litre (particles over the litres imaged, frames x the
    frame's volume), brightness, background, turbidity_index (means over the bin's frames).
    """
    out: dict[str, list] = {k: [] for k in ("file", "bin", "start_s", "end_s", "frames", "particles", "per_frame",
                                            "per_second", "per_litre", "brightness", "background",
                                            "turbidity_index")}
    for name, files, offsets in _rows_for(results):
        times = np.concatenate([f.frames["time_s"] + o for f, o in zip(files, offsets)])
        counts = np.concatenate([f.frames["particles"] for f in files])
        seconds = np.concatenate([np.full(len(f.frames["frame"]), 1.0 / f.fps if f.fps > 0 else math.nan)
                                  for f in files])
        litres = np.concatenate([np.full(len(f.frames["frame"]), model.litres(*f.size)) for f in files])
        brightness = np.concatenate([f.frames["brightness"] for f in files])
        background = np.concatenate([f.frames["background"] for f in files])
        bins = np.floor(times / bin_s + 1e-9).astype(np.int64)
        for b in np.unique(bins).tolist():
            at = bins == b
            n, total = int(at.sum()), float(counts[at].sum())
            out["file"].append(name)
            out["bin"].append(b)
            out["start_s"].append(b * bin_s)
            out["end_s"].append((b + 1) * bin_s)
            out["frames"].append(n)
            out["particles"].append(int(total))
            out["per_frame"].append(total / n)
            out["per_second"].append(total / float(seconds[at].sum()))
            out["per_litre"].append(total / float(litres[at].sum()))
            out["brightness"].append(float(brightness[at].mean()))
            out["background"].append(float(background[at].mean()))
            out["turbidity_index"].append(float(background[at].mean()) / 255.0)
    return {k: np.asarray(v, dtype=object if k == "file" else None) for k, v in out.items()}


def spectrum_table(results: list[FileResult], model: VolumeModel, bounds: np.ndarray,
                   bin_s: float) -> dict[str, np.ndarray]:
    """Size spectra: one row per ESD class per time bin (bin -1: the whole file), per file and over all.

    Columns: file, bin, class_low_mm, class_high_mm, count, per_litre (count over the litres the
    bin's frames imaged), per_litre_per_mm (per_litre over the class's width: the normalised spectrum).
    """
    out: dict[str, list] = {k: [] for k in ("file", "bin", "class_low_mm", "class_high_mm", "count", "per_litre",
                                            "per_litre_per_mm")}
    low, high = bounds[:-1], bounds[1:]
    for name, files, offsets in _rows_for(results):
        frame_times = np.concatenate([f.frames["time_s"] + o for f, o in zip(files, offsets)])
        frame_litres = np.concatenate([np.full(len(f.frames["frame"]), model.litres(*f.size)) for f in files])
        esd, times = [], []
        for f, o in zip(files, offsets):
            esd.append(f.particles["diameter_px"] * model.mm_per_pixel(f.size[0]))
            times.append(particle_times(f) + o)
        esd_all, times_all = np.concatenate(esd), np.concatenate(times) if times else np.empty(0)
        frame_bins = np.floor(frame_times / bin_s + 1e-9).astype(np.int64)
        particle_bins = np.floor(times_all / bin_s + 1e-9).astype(np.int64)
        for b in [-1, *np.unique(frame_bins).tolist()]:
            chosen = esd_all if b < 0 else esd_all[particle_bins == b]
            litres = float(frame_litres.sum() if b < 0 else frame_litres[frame_bins == b].sum())
            counts, _ = np.histogram(chosen, bins=bounds)
            for lo, hi, c in zip(low.tolist(), high.tolist(), counts.tolist()):
                out["file"].append(name)
                out["bin"].append(b)
                out["class_low_mm"].append(lo)
                out["class_high_mm"].append(hi)
                out["count"].append(c)
                out["per_litre"].append(c / litres)
                out["per_litre_per_mm"].append(c / litres / (hi - lo))
    return {k: np.asarray(v, dtype=object if k == "file" else None) for k, v in out.items()}


def summary_rows(results: list[FileResult], skipped: list[tuple[str, str]], model: VolumeModel) -> list[dict]:
    """One row per input (and ``ALL``): status, reason and the whole file's figures."""
    rows = []
    readable = [r for r in results if len(r.frames["frame"])]
    groups = [(r.name, [r], r.status, r.reason) for r in results]
    if readable:
        bad = len(skipped) + sum(r.status != "ok" for r in results)
        groups.append((ALL, readable, "ok" if not bad else "incomplete",
                       f"{bad} input(s) skipped or damaged" if bad else ""))
    for name, files, status, reason in groups:
        frames = sum(len(f.frames["frame"]) for f in files)
        particles = float(sum(f.frames["particles"].sum() for f in files))
        seconds = sum(len(f.frames["frame"]) / f.fps for f in files if f.fps > 0)
        litres = sum(len(f.frames["frame"]) * model.litres(*f.size) for f in files if f.size[0])
        brightness = (float(np.concatenate([f.frames["brightness"] for f in files]).mean()) if frames else math.nan)
        background = (float(np.concatenate([f.frames["background"] for f in files]).mean()) if frames else math.nan)
        one = files[0] if len(files) == 1 and files[0].size[0] else None
        rows.append({"file": name, "status": status, "reason": reason, "frames": frames,
                     "seconds": round(seconds, 6), "particles": int(particles),
                     "per_frame": particles / frames if frames else math.nan,
                     "per_second": particles / seconds if seconds else math.nan,
                     "per_litre": particles / litres if litres else math.nan,
                     "brightness": brightness, "turbidity_index": background / 255.0,
                     "litres_per_frame": model.litres(*one.size) if one else math.nan,
                     "mm_per_pixel": model.mm_per_pixel(one.size[0]) if one else math.nan})
    for name, reason in skipped:
        rows.insert(len(rows) - (1 if readable else 0), {"file": name, "status": "skipped", "reason": reason,
                                                          "frames": 0})
    return rows


def _atomic(path: Path, write) -> None:
    """Write ``path`` through a temporary file renamed into place, so it is whole or absent."""
    handle, temporary = tempfile.mkstemp(prefix=f".{path.name}-", dir=path.parent)
    os.close(handle)
    try:
        write(temporary)
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise


def write_tables(out: Path, tables: dict[str, dict[str, np.ndarray]]) -> list[Path]:
    """Each table as ``out/<name>.parquet`` (pyarrow); returns the paths."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    paths = []
    for name, columns in tables.items():
        table = pa.table({k: pa.array(v.tolist() if v.dtype == object else v) for k, v in columns.items()})
        path = out / f"{name}.parquet"
        _atomic(path, lambda p, t=table: pq.write_table(t, p))
        paths.append(path)
    return paths


SUMMARY_COLUMNS = ("file", "status", "reason", "frames", "seconds", "particles", "per_frame", "per_second",
                   "per_litre", "brightness", "turbidity_index", "litres_per_frame", "mm_per_pixel")


def write_summary(path: Path, rows: list[dict]) -> None:
    """The summary CSV, ``SUMMARY_COLUMNS``, one row per input and ``ALL``; numbers to 6 significant digits."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(SUMMARY_COLUMNS)
    for row in rows:
        writer.writerow([_cell(row.get(c, "")) for c in SUMMARY_COLUMNS])
    _atomic(path, lambda p: Path(p).write_text(buffer.getvalue()))


def _cell(value: Any) -> str:
    if isinstance(value, float):
        return "" if math.isnan(value) else f"{value:.6g}"
    return str(value)
