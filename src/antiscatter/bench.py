"""``antiscatter bench``: per-stage latency of every detector on the same frames.

Frames come from the simulator (``mixed`` at 800x600 and ``fullres`` at
1456x1088 by default).  Every detector first runs once over the frames, so
what is timed is the steady state (a learning detector's first frames, before
its background settles, cost up to several times more).  Detectors run interleaved -- frame by frame, in a
rotating order -- so that machine noise and drift hit all of them alike.  The
time of one plain copy of a frame is measured the same way and reported as the
memory floor, and so is :func:`minimal_chain`, the least any detector of the
``contrast`` design does (one channel, one pooling, a background, one
threshold, one labelling pass): the chain floor.
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from .console import progress
from .detection import DETECTORS, Pooled, make_detector
from .detection.contrast import downsample, label
from .system import time_stages
from .simulate import make_scene

__all__ = ["BenchResult", "bench", "format_bench", "machine_description", "bench_modes", "format_modes",
           "particle_bench_args", "minimal_chain"]

DEFAULT_SIZES = ((800, 600, "mixed"), (1456, 1088, "fullres"))


def at_least_one(text: str) -> int:
    """An integer >= 1 from the command line (argparse turns the error into its one line, exit 2)."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"got {text!r}, allowed an integer >= 1")
    return value


def particle_bench_args(description: str | None, *, particles: int = 300, frames: int = 300,
                        preset: bool = False) -> argparse.Namespace:
    """``--particles`` and ``--frames`` (each an integer >= 1; else argparse's error, exit 2) of the
    scripts that time one part of the chain for N particles over a number of frames; with
    ``preset``, also ``--preset NAME`` (a simulator preset, else argparse's error; default none)."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--particles", type=at_least_one, default=particles)
    parser.add_argument("--frames", type=at_least_one, default=frames)
    if preset:
        from .simulate import PRESETS

        parser.add_argument("--preset", choices=sorted(PRESETS), default=None,
                            help="also time it on the default detector's detections in this simulator scene")
    return parser.parse_args()


def machine_description() -> str:
    """CPU model, core count, Python and OpenCV versions."""
    model = platform.processor() or platform.machine()
    info: dict[str, str] = {}
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                key, sep, value = line.partition(":")
                if sep:
                    info.setdefault(key.strip().lower(), value.strip())
    except OSError:
        pass
    for key in ("model name", "model", "hardware"):  # x86 / Raspberry Pi / other ARM
        if info.get(key) and not info[key].isdigit():
            model = info[key]
            break
    return (f"{model}, {os.cpu_count()} cores, {platform.system()} {platform.machine()}, "
            f"Python {platform.python_version()}, OpenCV {cv2.__version__}")


def _stats(ns: list[int]) -> dict[str, float]:
    us = np.asarray(ns, dtype=np.float64) / 1e3
    return {"mean_us": float(us.mean()), "sd_us": float(us.std(ddof=1)) if len(us) > 1 else 0.0,
            "median_us": float(np.median(us)), "p99_us": float(np.percentile(us, 99)),
            "max_us": float(us.max())}


@dataclass
class BenchResult:
    """Everything ``bench`` measured, ready for JSON."""

    machine: str
    threads: int
    frames: int
    sizes: list[dict[str, Any]]
    input: str = "bgr"

    def as_dict(self) -> dict[str, Any]:
        sizes = [{k: v for k, v in entry.items() if not k.startswith("_")} for entry in self.sizes]
        return {"machine": self.machine, "opencv_threads": self.threads, "frames": self.frames,
                "input": self.input, "sizes": sizes}


#: the background cell of :func:`minimal_chain` (working pixels) and its fixed threshold (grey levels)
CHAIN_CELL = 16
CHAIN_LEVEL = 8


def minimal_chain(image: np.ndarray | Pooled) -> tuple[np.ndarray, np.ndarray]:
    """The least a local-contrast detector does, as a floor for ``bench`` to time (not a detector:
    no noise estimate, no learnt background, no splitting, no rejection): one channel ((H, W, 3)
    BGR -> luma; a grey or Y frame as it is), 2x2 block means, a background from the means of
    ``CHAIN_CELL``-pixel cells brought back up linearly, one threshold ``CHAIN_LEVEL`` grey levels
    above it, one labelling pass, and each component's centroid and equivalent radius.

    Returns (centres (N, 2), radii (N,)) in full-resolution pixels.  What a detector costs beyond
    this is its own logic; what this costs, no detector of that design can save.  A
    :class:`~antiscatter.detection.Pooled` frame at factor 2 (the ISP's lores plane) skips the pooling."""
    half = image.working if isinstance(image, Pooled) else downsample(image, factor=2)  # luma, 2x2 block means
    h, w = half.shape
    cw, ch = max(w // CHAIN_CELL, 1), max(h // CHAIN_CELL, 1)
    cells = cv2.resize(half[: ch * CHAIN_CELL, : cw * CHAIN_CELL], (cw, ch), interpolation=cv2.INTER_AREA)
    background = cv2.resize(cells, (w, h), interpolation=cv2.INTER_LINEAR)
    components = label(cv2.compare(cv2.subtract(half, background), CHAIN_LEVEL, cv2.CMP_GT))
    lab, n = components["labels"], components["count"]
    area = np.bincount(lab, minlength=n)
    safe = np.maximum(area, 1)
    centres = np.column_stack([np.bincount(lab, components["x"], n) / safe, np.bincount(lab, components["y"], n) / safe])
    return 2 * centres + 0.5, 2 * np.sqrt(area / np.pi)


def pool_index(k: int, distinct: int) -> int:
    """Frame k of the bench's sequence: the pool played forwards, then back, and so on (0, 1, ..,
    n - 1, n - 2, .., 1, 0, 1, ..), so the camera holds still and particles only ever move a
    step.  Played round in a cycle, every particle jumped at once each ``distinct`` frames: the
    contrast detector took that for the view turning and followed a still view from then on
    (at 800x600 it looked for turns every frame, 0.55 ms a frame on average, where a still
    view's looks come every 6th frame, 0.09 ms a frame)."""
    if distinct < 2:
        return 0
    k %= 2 * distinct - 2
    return k if k < distinct else 2 * distinct - 2 - k


def simulator_pool(width: int, height: int, preset: str, *, distinct: int = 20, seed: int = 0) -> list[np.ndarray]:
    """``distinct`` BGR frames of the simulator's ``preset`` at ``width`` x ``height``, 3 steps apart."""
    scene = make_scene(preset, rng=np.random.default_rng(seed), size=(width, height))
    pool = []
    for i in progress(range(distinct), desc=f"render {preset} {width}x{height}", leave=False):
        if i:
            for _ in range(3):
                scene.step()
        pool.append(scene.render())
    return pool


def source_pool(spec: str, *, distinct: int = 20) -> list[np.ndarray]:
    """The first ``distinct`` frames of any source ``run`` takes (a folder, a video file, ``sim``),
    as the source delivers them (BGR or grey); a one-line UsageError when it gives none."""
    from .errors import UsageError
    from .sources import open_source

    pool = []
    with open_source(spec) as source:
        while len(pool) < distinct:
            frame = source.read()
            if frame is None:
                break
            pool.append(np.ascontiguousarray(frame.image))
    if not pool:
        raise UsageError(f"bench {spec}: the source gave no frame")
    if len({image.shape for image in pool}) > 1:
        raise UsageError(f"bench {spec}: frames of different sizes ({pool[0].shape[1]}x{pool[0].shape[0]} and "
                         "others); bench takes one size a source")
    return pool


def bench(*, detectors: list[str] | None = None, frames: int = 200, threads: int = 1,
          sizes: tuple[tuple[int, int, str], ...] = DEFAULT_SIZES, distinct: int = 20,
          seed: int = 0, input: str = "bgr", source: str | None = None) -> BenchResult:
    """Time every detector's stages on ``frames`` frames per size (``distinct`` different ones, played
    forwards and back: :func:`pool_index`).

    sizes: (width, height, simulator preset) of each pool when ``source`` is None.
    source: a source ``run`` takes (a folder, a video file, ``sim``): its first ``distinct`` frames
        are the one pool instead, so speed is measured on the frames that matter.
    input: "bgr" (video files, the simulator, webcams) or "y" (the luma plane alone, as the
        Pi camera's YUV420 stream delivers it; computed before timing).
    threads: threads detection runs on, as ``run --threads``: a threaded detector's bands and
        OpenCV's own functions (default 1, as one Pi core).
    """
    if input not in ("bgr", "y"):
        raise ValueError(f"input: got {input!r}, allowed bgr or y")
    names = detectors or list(DETECTORS)
    if source is not None:
        pools = [(source, source_pool(source, distinct=distinct))]
    else:
        pools = [(preset, simulator_pool(w, h, preset, distinct=distinct, seed=seed)) for w, h, preset in sizes]
    previous = cv2.getNumThreads()
    cv2.setNumThreads(threads)
    try:
        results = []
        for title, pool in pools:
            if input == "y":
                pool = [cv2.cvtColor(f, cv2.COLOR_BGR2GRAY) if f.ndim == 3 else f for f in pool]
            else:
                pool = [cv2.cvtColor(f, cv2.COLOR_GRAY2BGR) if f.ndim == 2 else f for f in pool]
            results.append(_bench_pool({name: make_detector(name, threads=threads) for name in names}, pool, title,
                                       frames))
    finally:
        cv2.setNumThreads(previous)
    return BenchResult(machine_description(), threads, frames, results, input)


def _bench_pool(built: dict[str, Any], pool: list[np.ndarray], title: str, frames: int) -> dict[str, Any]:
    """One pool's entry of :func:`bench`: every detector (fresh, warmed up over the pool) and the
    copy and chain floors, interleaved frame by frame in a rotating order."""
    distinct = len(pool)
    height, width = pool[0].shape[:2]
    copy_target = np.empty_like(pool[0])
    for image in pool:
        minimal_chain(image)
    per_stage: dict[str, dict[str, list[int]]] = {n: {s.name: [] for s in d.stages} for n, d in built.items()}
    totals: dict[str, list[int]] = {n: [] for n in built}
    counts: dict[str, list[int]] = {n: [] for n in built}
    copies: list[int] = []
    chains: list[int] = []
    order = list(built)
    for name in order:  # warm-up: first calls allocate, learnt backgrounds settle (steady state)
        for image in pool:
            built[name].detect(image)
    for k in progress(range(frames), desc=f"bench {title} {width}x{height}"):  # (drawn between frames, untimed)
        image = pool[pool_index(distinct + k, distinct)]
        t0 = time.perf_counter_ns()
        np.copyto(copy_target, image)
        copies.append(time.perf_counter_ns() - t0)
        t0 = time.perf_counter_ns()
        minimal_chain(image)
        chains.append(time.perf_counter_ns() - t0)
        rotated = order[k % len(order):] + order[:k % len(order)]
        for name in rotated:
            detections, durations = time_stages(built[name], image)
            for stage, ns in zip(built[name].stages, durations):
                per_stage[name][stage.name].append(ns)
            totals[name].append(sum(durations))
            counts[name].append(len(detections))
    floor = float(np.median(copies)) / 1e3
    chain = float(np.median(chains)) / 1e3
    seed_median = float(np.median(totals["seed"])) / 1e3 if "seed" in totals else None
    entry: dict[str, Any] = {"size": f"{width}x{height}", "preset": title, "copy_floor_us": _stats(copies),
                             "chain_floor_us": _stats(chains),
                             "chain_speedup_vs_seed": (seed_median / chain) if seed_median else None,
                             "detectors": {}, "_samples": {}}
    for name, d in built.items():
        total = _stats(totals[name])
        entry["detectors"][name] = {
            "stages": {s.name: {"label": s.label, **_stats(per_stage[name][s.name])} for s in d.stages},
            "total": total,
            "particles_per_frame": float(np.mean(counts[name])),
            "fps": 1e6 / total["median_us"] if total["median_us"] else float("inf"),
            "speedup_vs_seed": (seed_median / total["median_us"]) if seed_median else None,
            "x_floor": total["median_us"] / floor if floor else None,
            "x_chain": total["median_us"] / chain if chain else None,
        }
        for stage in d.stages:
            entry["_samples"][f"{name}: {stage.label}"] = np.asarray(per_stage[name][stage.name]) / 1e3
        entry["_samples"][f"{name}: total"] = np.asarray(totals[name]) / 1e3
    return entry


def bench_modes(*, frames: int = 300, sizes: tuple[tuple[int, int, str], ...] = DEFAULT_SIZES,
                detector: str = "contrast", fps: float = 0.0, camera_fps: float = 1000.0,
                vehicle: bool = False) -> list[dict[str, Any]]:
    """The same frames through every execution mode of ``run``, one after the other.

    Frames are simulator frames rendered beforehand and served by an emulated
    free-running camera at ``camera_fps`` (faster than any mode can process, so
    the pipeline is what is measured; a read blocks until the next exposure
    completes, as Picamera2's does with ``queue=False``).  Returns per size and
    mode: frames per second, end-to-end latency (exposure complete to pattern
    handed to the output) p50/p99/max in ms, and frames dropped between stages.
    vehicle: run as ``auto`` does with the camera -- tracking with prediction, dim holes at each
    particle's own level -- instead of ``run``'s default for files and the simulator (holes from
    each frame's detections, no tracking): the latency the lamp's light really waits for.
    """
    import io

    from .config import HARDWARE_STRATEGY, load_config
    from .runtime import MODES, run
    from .sources.replay import ReplaySource

    results = []
    for width, height, preset in sizes:
        scene = make_scene(preset, rng=np.random.default_rng(0), size=(width, height))
        pool = []
        for _ in range(30):
            pool.append(scene.render())
            scene.step()
        # played forwards and back (:func:`pool_index`): round in a cycle every particle jumped at once
        # each 30 frames -- the detector took it for the view turning and the tracker lost every track
        pool += pool[-2:0:-1]
        for mode in progress(MODES, desc=f"bench modes {width}x{height}", unit="mode"):
            overrides: dict[str, Any] = {"detector": {"name": detector}, "output": {"outputs": ("none",)},
                                         "run": {"frames": frames, "mode": mode, "fps": fps}}
            if vehicle:
                overrides.update(track={"enabled": True}, light={"strategy": HARDWARE_STRATEGY, "levels": "adaptive"})
            config = load_config(overrides=overrides)
            summary = run(config, log=io.StringIO(), out=io.StringIO(),
                          source=ReplaySource(pool, frames=10 ** 9, fps=camera_fps))
            latency = np.asarray(summary.latencies_ns, dtype=np.float64) / 1e6
            pacing = summary.pacing()
            tracking = summary.durations.get("Tracking Duration (s)")
            results.append({"size": f"{width}x{height}", "mode": mode, "frames": summary.frames,
                            # the tracker's share of the latency (its stage's mean; None without tracking)
                            "tracking_mean_ms": tracking.mean * 1e3 if tracking is not None and tracking.count else None,
                            "fps": summary.frames / summary.wall_s if summary.wall_s else 0.0,
                            "latency_p50_ms": float(np.median(latency)),
                            "latency_p99_ms": float(np.percentile(latency, 99)),
                            "latency_max_ms": float(latency.max()), "dropped": summary.dropped,
                            **({"jitter_p99_ms": pacing["jitter_p99_ms"], "rate": pacing["rate"]} if fps else {})})
    return results


def format_modes(results: list[dict[str, Any]]) -> str:
    tracked = any(r.get("tracking_mean_ms") is not None for r in results)
    lines = [f"machine: {machine_description()}", "frames from an emulated camera running at 1000 frames/s"
             + ("; as on the vehicle: tracking with prediction, dim holes at their own levels" if tracked else ""),
             f"{'size':<11}{'mode':<17}{'frames/s':>10}{'latency p50':>13}{'p99':>9}{'max':>9}{'dropped':>9}"
             + (f"{'tracking':>10}" if tracked else "") + "  (ms)"]
    for r in results:
        line = (f"{r['size']:<11}{r['mode']:<17}{r['fps']:>10.1f}{r['latency_p50_ms']:>13.2f}"
                f"{r['latency_p99_ms']:>9.2f}{r['latency_max_ms']:>9.2f}{r['dropped']:>9}")
        if tracked:
            line += f"{r['tracking_mean_ms']:>10.2f}" if r.get("tracking_mean_ms") is not None else f"{'-':>10}"
        lines.append(line)
    return "\n".join(lines)


def format_bench(result: BenchResult) -> str:
    """The report's table 1 layout per size: stage mean and sd, plus median, p99 and max (us)."""
    lines = [f"machine: {result.machine}",
             f"threads: {result.threads} (the detectors' bands and OpenCV's); {result.frames} frames per size, "
             f"detectors interleaved; input {'BGR frames' if result.input == 'bgr' else 'the Y (luma) plane'}"]
    for entry in result.sizes:
        floor = entry["copy_floor_us"]["median_us"]
        lines.append("")
        chain = entry["chain_floor_us"]["median_us"]
        lines.append(f"{entry['size']} ({entry['preset']}); memory floor (one frame copy): "
                     f"median {floor:.1f} us; chain floor (minimal_chain: channel, pooling, background, "
                     f"threshold, labels): median {chain:.1f} us"
                     + (f", {entry['chain_speedup_vs_seed']:.2f}x seed's throughput"
                        if entry.get("chain_speedup_vs_seed") else ""))
        for name, d in entry["detectors"].items():
            lines.append(f"  detector {name}: {d['particles_per_frame']:.1f} particles/frame")
            lines.append(f"    {'stage':<28}{'mean':>9}{'sd':>9}{'median':>9}{'p99':>9}{'max':>9}  (us)")
            for stage in d["stages"].values():
                lines.append(f"    {stage['label']:<28}{stage['mean_us']:>9.1f}{stage['sd_us']:>9.1f}"
                             f"{stage['median_us']:>9.1f}{stage['p99_us']:>9.1f}{stage['max_us']:>9.1f}")
            t = d["total"]
            lines.append(f"    {'total':<28}{t['mean_us']:>9.1f}{t['sd_us']:>9.1f}{t['median_us']:>9.1f}"
                         f"{t['p99_us']:>9.1f}{t['max_us']:>9.1f}")
            ratio = f", {d['speedup_vs_seed']:.2f}x seed's throughput" if d["speedup_vs_seed"] else ""
            lines.append(f"    {d['fps']:.0f} frames/s{ratio}, {d['x_floor']:.1f}x the memory floor, "
                         f"{d['x_chain']:.1f}x the chain floor")
    return "\n".join(lines)


def plot_bench(result: BenchResult, path: str) -> None:
    """Per-stage box plots (whiskers at p1 and p99), one panel per frame size (needs matplotlib)."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(result.sizes), figsize=(7 * len(result.sizes), 6), squeeze=False)
    for ax, entry in zip(axes[0], result.sizes):
        labels = list(entry["_samples"])
        data = [entry["_samples"][k] for k in labels]
        try:  # matplotlib >= 3.10
            ax.boxplot(data, orientation="horizontal", whis=(1, 99), showfliers=False)
        except TypeError:
            ax.boxplot(data, vert=False, whis=(1, 99), showfliers=False)
        ax.set_yticks(range(1, len(labels) + 1), labels, fontsize=8)
        ax.invert_yaxis()
        ax.set_xscale("log")
        ax.axvline(entry["copy_floor_us"]["median_us"], color="tab:red", linestyle="--",
                   label="memory floor (one frame copy)")
        ax.axvline(entry["chain_floor_us"]["median_us"], color="tab:purple", linestyle=":",
                   label="chain floor (minimal_chain)")
        ax.set_xlabel("microseconds per frame (log)")
        ax.set_title(f"{entry['size']} ({entry['preset']})")
        ax.legend(fontsize=8)
    fig.suptitle(f"antiscatter bench: {result.threads} thread(s), {result.frames} frames")
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def save_figure(fig: object, path: str | Path) -> None:
    """Write a matplotlib figure (format from the ending, 100 dpi) whole or not at all: a full disk
    raises WriteError and leaves no part of it."""
    import io

    from .writing import write_whole

    buffer = io.BytesIO()
    fig.savefig(buffer, format=Path(path).suffix[1:].lower() or "png", dpi=100)  # type: ignore[attr-defined]
    write_whole(path, buffer.getvalue())


def plot_suffixes() -> tuple[str, ...]:
    """The file endings ``--plot`` can write (matplotlib's formats: ``.png``, ``.pdf``, ``.svg``, ...),
    so a plot path is checked before the work it shows; UsageError without matplotlib."""
    _pyplot()
    from matplotlib.backend_bases import FigureCanvasBase

    return tuple(sorted(f".{suffix}" for suffix in FigureCanvasBase.get_supported_filetypes()))


def _pyplot():
    from .errors import UsageError

    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise UsageError("--plot needs matplotlib: pip install 'antiscatter[plot]'") from None
    return plt
