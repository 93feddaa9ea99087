"""``antiscatter analyse``: a footage archive through the default detector on Dask, into tables and plots.

Inputs are probed, cut into chunks at keyframes and analysed one task a chunk on a Dask cluster
(a local one of ``workers`` processes, or an existing one at ``scheduler``).  Each finished
chunk's result is saved in ``OUT/chunks/`` under a hash of its file and settings as it arrives,
so a run stopped partway resumes where it was.  Then the tables (Parquet), the summary CSV and the
plots are written.  An input that cannot be read is named in the summary and skipped; the exit
code is then ``EXIT_SKIPPED``.
"""

from __future__ import annotations

import logging
import math
import os
import sys
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

from ..errors import UsageError, check_output_folder
from .inputs import Chunk, Input, expand_inputs, frame_rate, plan_chunks, probe
from .tables import (FileResult, bin_table, combine_chunks, default_classes, frame_table, particle_table,
                     spectrum_table, summary_rows, write_summary, write_tables)
from .volume import VolumeModel, esd_classes
from .work import analyse_chunk, chunk_key, load_result, save_result

__all__ = ["AnalyseRequest", "analyse", "EXIT_SKIPPED", "INSTALL_HINT", "require_analysis"]

#: exit code when an input was skipped or partly unreadable (the rest analysed, the summary names it)
EXIT_SKIPPED = 3
#: what to install for ``analyse``
INSTALL_HINT = "pip install 'antiscatter[analysis]'"
#: frames a second of a frame folder when not given: the camera's default rate, as ``run`` assumes
FOLDER_FPS = 60.0


@dataclass(frozen=True)
class AnalyseRequest:
    """What ``antiscatter analyse`` does; a bad value raises ValueError naming the field.

    inputs: video files, frame folders, globs, ``@list.txt`` files, in order.
    out: the folder to write (made if absent; its ``chunks/`` holds the resumable results).
    workers: local Dask worker processes; 0 = one per core (default 0).
    scheduler: address of an existing Dask scheduler (``tcp://host:8786``); empty = a local cluster.
    chunk_frames: frames per task, about: chunks start at keyframes (default 300).
    fps: frame rate of frame folders, frames a second (default 60, as ``run``); videos use their timestamps.
    bin_s: length of the time bins, seconds (default 10).
    volume: the volume and pixel-size model (:class:`VolumeModel`).
    classes_mm: (low, high) ESD range of the size classes, mm; None = one pixel to 100 pixels across.
    progress: a progress bar on stderr where it is a terminal (default True; off with --quiet too).
    plots: write the PNG figures (default True).
    """

    inputs: tuple[str, ...]
    out: Path
    workers: int = 0
    scheduler: str = ""
    chunk_frames: int = 300
    fps: float = FOLDER_FPS
    bin_s: float = 10.0
    volume: VolumeModel = field(default_factory=VolumeModel)
    classes_mm: tuple[float, float] | None = None
    progress: bool = True
    plots: bool = True

    def __post_init__(self) -> None:
        if self.workers < 0:
            raise ValueError(f"workers: got {self.workers}, allowed >= 0 (0 = one per core)")
        if self.chunk_frames < 1:
            raise ValueError(f"chunk_frames: got {self.chunk_frames}, allowed >= 1")
        if not (math.isfinite(self.fps) and self.fps > 0):
            raise ValueError(f"fps: got {self.fps}, allowed a number > 0")
        if not (math.isfinite(self.bin_s) and self.bin_s > 0):
            raise ValueError(f"bin_s: got {self.bin_s}, allowed a number of seconds > 0")
        if self.classes_mm is not None:
            esd_classes(*self.classes_mm)


def require_analysis(plots: bool = True) -> None:
    """A one-line UsageError naming the install command when a package of the ``analysis`` extra is missing."""
    import importlib.util

    needed = ["dask", "distributed", "pyarrow"] + (["matplotlib"] if plots else [])
    missing = [name for name in needed if importlib.util.find_spec(name) is None]
    if missing:
        raise UsageError(f"analyse needs {', '.join(missing)}: {INSTALL_HINT}")


def _probe(path: Path, fps: float) -> Input | str:
    """The probed input, or why it cannot be read (one line); runs on a worker."""
    try:
        return probe(path, fps=fps)
    except ValueError as exc:
        return str(exc).splitlines()[0]
    except Exception as exc:  # noqa: BLE001 -- any failure of one input is reported, the run goes on
        return f"cannot be read ({type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''})"


def _run_chunk(chunk: Chunk) -> dict[str, Any]:
    """One task: the chunk's result; an exception becomes its ``error`` (one line)."""
    try:
        return analyse_chunk(chunk)
    except Exception as exc:  # noqa: BLE001 -- any failure of one file is reported, the run goes on
        return {"error": f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"}


def _client(request: AnalyseRequest, stack: ExitStack, log: TextIO) -> Any:
    from dask.distributed import Client, LocalCluster

    if request.scheduler:
        try:
            return stack.enter_context(Client(request.scheduler, timeout="15s"))
        except (OSError, TimeoutError, ValueError) as exc:
            raise UsageError(f"--scheduler {request.scheduler}: cannot reach it ({str(exc).splitlines()[0]})") from None
    workers = request.workers or os.cpu_count() or 1
    cluster = stack.enter_context(LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                               dashboard_address=":0", silence_logs=logging.ERROR))
    print(f"antiscatter analyse: local Dask cluster of {workers} worker process(es)", file=log)
    return stack.enter_context(Client(cluster))


def analyse(request: AnalyseRequest, *, client: Any = None, log: TextIO | None = None,
            out: TextIO | None = None) -> dict[str, Any]:
    """Analyse every input; returns the summary rows, the paths written and the exit code.

    client: a ``dask.distributed.Client`` to use instead of starting one (tests, notebooks).
    Bad input (a missing file, a glob matching nothing, an unwritable ``out``) raises UsageError
    before any work; an unreadable input is skipped and named.
    """
    log = log or sys.stderr
    out = out or sys.stdout
    require_analysis(request.plots)
    paths = expand_inputs(request.inputs)
    folder = check_output_folder(request.out, "--out")
    chunks_folder = folder / "chunks"
    from dask.distributed import as_completed
    from ..console import progress

    with ExitStack() as stack:
        if client is None:
            client = _client(request, stack, log)
        folder.mkdir(exist_ok=True)  # once the cluster is there: bad input leaves nothing behind
        probed = client.gather(client.map(_probe, paths, fps=request.fps, pure=False))
        sources: list[Input] = []
        skipped: list[tuple[str, str]] = []
        for path, item in zip(paths, probed):
            if isinstance(item, str):
                skipped.append((str(path), item))
                print(f"antiscatter analyse: skipped {path}: {item}", file=log)
            else:
                sources.append(item)
        plan = {s.path: plan_chunks(s, request.chunk_frames) for s in sources}
        results: dict[str, dict[str, Any]] = {}
        pending: dict[Any, str] = {}
        keys = {}
        for chunks in plan.values():
            for chunk in chunks:
                key = keys[(chunk.source.path, chunk.start)] = chunk_key(chunk)
                saved = load_result(chunks_folder, key)
                if saved is not None:
                    results[key] = saved
        todo = [c for cs in plan.values() for c in cs if keys[(c.source.path, c.start)] not in results]
        total = sum(len(cs) for cs in plan.values())
        print(f"antiscatter analyse: {len(sources)} input(s), {sum(s.frames for s in sources)} frames in {total} "
              f"chunk(s); {total - len(todo)} already done in {chunks_folder}", file=log)
        futures = []
        for chunk in todo:
            future = client.submit(_run_chunk, chunk, pure=False)
            pending[future] = keys[(chunk.source.path, chunk.start)]
            futures.append(future)
        with progress(total=len(futures), unit="chunk", desc="analyse", enabled=request.progress and bool(futures)) as bar:
            for future in as_completed(futures):
                key = pending[future]
                try:
                    result = future.result()
                except Exception as exc:  # noqa: BLE001 -- its worker died (KilledWorker): reported, not fatal
                    result = {"error": f"its task failed ({type(exc).__name__}: {str(exc).splitlines()[0]})"}
                results[key] = result
                if not str(result.get("error", "")):
                    save_result(chunks_folder, key, result)  # a failed chunk is tried again next time
                bar.update(1)
    files: list[FileResult] = []
    for source in sources:
        parts = [results[keys[(source.path, c.start)]] for c in plan[source.path]]
        parts = [p if "frame" in p else _failed(p) for p in parts]
        result = combine_chunks(str(source.path), parts, frame_rate(source) if source.kind == "video"
                                else request.fps)
        if source.damaged and result.status == "ok":
            result.status, result.reason = "damaged", source.damaged
        files.append(result)
    return _write(request, folder, files, skipped, out, log)


def _failed(result: dict[str, Any]) -> dict[str, Any]:
    """An empty chunk result carrying only its error (the task itself failed)."""
    import numpy as np

    empty = {name: np.empty(0) for name in ("frame", "time_s", "particles", "brightness", "background",
                                            "p_frame", "p_x", "p_y", "p_diameter_px")}
    return {**empty, "size": np.zeros(2, np.int64), "error": np.asarray(str(result.get("error", "failed")))}


def _write(request: AnalyseRequest, folder: Path, files: list[FileResult], skipped: list[tuple[str, str]],
           out: TextIO, log: TextIO) -> dict[str, Any]:
    model = request.volume
    bounds = esd_classes(*request.classes_mm) if request.classes_mm else default_classes(files, model)
    for f in files:
        if f.status == "skipped":
            skipped.append((f.name, f.reason))
    readable = [f for f in files if f.status != "skipped"]
    tables = {"frames": frame_table(readable), "particles": particle_table(readable, model),
              "bins": bin_table(readable, model, request.bin_s),
              "spectra": spectrum_table(readable, model, bounds, request.bin_s)}
    written = write_tables(folder, tables) if readable else []
    rows = summary_rows(readable, skipped, model)
    summary_path = folder / "summary.csv"
    write_summary(summary_path, rows)
    written.append(summary_path)
    if request.plots and readable:
        from .plots import plot_spectrum, plot_time_series

        plot_time_series(folder / "timeseries.png", tables["bins"])
        plot_spectrum(folder / "spectrum.png", tables["spectra"])
        written += [folder / "timeseries.png", folder / "spectrum.png"]
    for row in rows:
        if row["file"] == "ALL" or row["status"] == "skipped":
            continue
        note = f" ({row['status']}: {row['reason']})" if row["status"] != "ok" else ""
        print(f"{row['file']}: {row['frames']} frames, {row['per_frame']:.1f} particles a frame, "
              f"{row['per_litre']:.3g} a litre{note}", file=out)
    for name, reason in skipped:
        print(f"skipped {name}: {reason}", file=out)
    damaged = [f for f in readable if f.status != "ok"]
    exit_code = EXIT_SKIPPED if skipped or damaged else 0
    print(f"wrote {', '.join(p.name for p in written)} to {folder}"
          + (f"; {len(skipped)} input(s) skipped, {len(damaged)} damaged (exit code {EXIT_SKIPPED})"
             if exit_code else ""), file=out)
    return {"rows": rows, "written": written, "exit_code": exit_code, "tables": tables}
