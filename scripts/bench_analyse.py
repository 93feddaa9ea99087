"""``analyse`` on a local Dask cluster: throughput of 1 and 2 workers, chunking invariance, size spectra
against the simulator's truth.

Usage: python scripts/bench_analyse.py [--videos 8] [--frames 600] [--preset bubbles] [--folder DIR]

Writes --videos simulator videos of --frames frames (``antiscatter simulate --video``, seeds 1..N,
kept in --folder, default /tmp/antiscatter-bench-analyse, and reused when present), then analyses
them three times -- 1 worker with one chunk a file, 2 workers with one and with three -- each
into a fresh output folder, timing the analysis alone (the cluster is started before the clock).
Prints the throughput table (speed-up against 1 worker), whether every table (frames, particles,
bins, spectra) is identical across the runs, each stage's cost a frame on one core, and the whole
survey's size spectrum in UVP classes (in pixels: the same pixel size on both sides) against the
simulator's truth (particles counted as the scoreboard counts them: visibility >= 0.5, SNR >= 5).
Results: docs/decisions/006-analyse-and-mcap.md.
"""

from __future__ import annotations

import argparse
import csv
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from antiscatter.bench import at_least_one


def make_videos(folder: Path, count: int, frames: int, preset: str) -> list[Path]:
    """The simulator videos (each in its own folder with its truth.csv), made where missing."""
    videos = []
    for seed in range(1, count + 1):
        out = folder / f"v{seed}"
        video = out / f"v{seed}.mkv"
        if not (video.is_file() and (out / "truth.csv").is_file()):
            subprocess.run([sys.executable, "-m", "antiscatter", "simulate", str(out), "--preset", preset,
                            "--frames", str(frames), "--seed", str(seed), "--video", str(video), "--overwrite"],
                           check=True, stdout=subprocess.DEVNULL)
        videos.append(video)
    return videos


def timed_run(videos: list[Path], out: Path, workers: int, chunk_frames: int) -> tuple[float, dict]:
    """(seconds, tables) of one analysis on a fresh local cluster of ``workers`` processes."""
    import logging

    from dask.distributed import Client, LocalCluster

    from antiscatter.analyse import AnalyseRequest, analyse

    request = AnalyseRequest(tuple(map(str, videos)), out, workers=workers, chunk_frames=chunk_frames,
                             progress=False, plots=False)
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0",
                      silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
        client.run(lambda: None)  # every worker up before the clock starts
        start = time.perf_counter()
        result = analyse(request, client=client, log=open(os.devnull, "w"), out=open(os.devnull, "w"))
        seconds = time.perf_counter() - start
    return seconds, result["tables"]


def same_tables(a: dict, b: dict) -> bool:
    return all(set(a[name]) == set(b[name]) and all(np.array_equal(a[name][c], b[name][c]) for c in a[name])
               for name in a)


def stage_costs(video: Path, frames: int = 200) -> None:
    """Per-frame cost of each stage on one core: decoding, the detector single-frame and learning, sizing."""
    import cv2

    from antiscatter.analyse.inputs import plan_chunks, probe, read_chunk
    from antiscatter.analyse.work import detector_params, equivalent_diameters, measure_frame
    from antiscatter.detection import make_detector
    from antiscatter.detection.contrast.params import ContrastParams

    cv2.setNumThreads(1)
    source = probe(video, fps=60)
    chunk = plan_chunks(source, frames)[0]
    start = time.perf_counter()
    images = [image for _, image in read_chunk(chunk)]
    timings = {"decode (PyAV, one thread)": time.perf_counter() - start}
    for name, params in (("detect, single-frame (memory=0)", detector_params()),
                         ("detect, learning (memory=40, run's default)", ContrastParams())):
        detector = make_detector("contrast", params)
        start = time.perf_counter()
        found = [detector.detect(image) for image in images]
        timings[name] = time.perf_counter() - start
    greys = [cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) for image in images]
    single = make_detector("contrast", detector_params())
    found = [single.detect(image) for image in images]
    start = time.perf_counter()
    for grey, f in zip(greys, found):
        equivalent_diameters(grey, f.centres, f.radii)
    timings["sizing (equivalent diameters)"] = time.perf_counter() - start
    start = time.perf_counter()
    for image in images:
        measure_frame(image)
    timings["brightness and background"] = time.perf_counter() - start
    print(f"per-frame cost on one core ({len(images)} frames of {video.name}):")
    print("| stage | ms a frame | frames/s |")
    print("|---|---|---|")
    for name, seconds in timings.items():
        print(f"| {name} | {seconds / len(images) * 1e3:.1f} | {len(images) / seconds:.0f} |")


def truth_diameters(folders: list[Path]) -> np.ndarray:
    """Equivalent diameters, px, of the simulator's counted particles in every frame."""
    values = []
    for folder in folders:
        with (folder / "truth.csv").open() as handle:
            for row in csv.DictReader(handle):
                if float(row["Visibility"]) >= 0.5 and float(row["SNR"]) >= 5:
                    values.append(2 * float(row["Radius"]))
    return np.asarray(values)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--videos", type=at_least_one, default=8, help="simulator videos (default 8)")
    parser.add_argument("--frames", type=at_least_one, default=600, help="frames a video, a multiple of 3 (default 600)")
    parser.add_argument("--preset", default="bubbles", help="simulator preset (default bubbles: the detector's "
                        "recall there is 0.98, docs/scoreboard.md)")
    parser.add_argument("--folder", type=Path, default=Path("/tmp/antiscatter-bench-analyse"),
                        help="where the videos and outputs go (default /tmp/antiscatter-bench-analyse)")
    args = parser.parse_args()
    from antiscatter.bench import machine_description

    args.folder.mkdir(parents=True, exist_ok=True)
    videos = make_videos(args.folder, args.videos, args.frames, args.preset)
    total = args.videos * args.frames
    print(f"machine: {machine_description()}; load average before: {os.getloadavg()[0]:.2f}")
    print(f"{args.videos} videos of {args.frames} frames, preset {args.preset}, 800x600")
    print("| workers | chunks a file | seconds | frames/s | speed-up |")
    print("|---|---|---|---|---|")
    runs = {}
    for workers, chunks in ((1, 1), (2, 1), (2, 3)):
        out = args.folder / f"out-w{workers}-c{chunks}"
        subprocess.run(["rm", "-rf", str(out)], check=True)
        seconds, tables = timed_run(videos, out, workers, args.frames // chunks)
        runs[(workers, chunks)] = (seconds, tables)
        base = runs[(1, 1)][0]
        print(f"| {workers} | {chunks} | {seconds:.1f} | {total / seconds:.1f} | {base / seconds:.2f}x |")
    reference = runs[(1, 1)][1]
    for key, (_, tables) in runs.items():
        print(f"tables of {key[0]} worker(s), {key[1]} chunk(s) a file identical to 1 worker, 1 chunk: "
              f"{same_tables(tables, reference)}")
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    stage_costs(videos[0], min(args.frames, 200))
    found = reference["particles"]["diameter_px"]
    truth = truth_diameters([v.parent for v in videos])
    bounds = 2 ** (np.arange(0, 22) / 3)  # UVP classes in pixels (the same pixel size on both sides)
    counted_t, _ = np.histogram(truth, bounds)
    counted_f, _ = np.histogram(found, bounds)
    print(f"size spectrum, all frames: {len(truth)} counted truth particles, {len(found)} detections")
    print("| class (px) | truth | found | found / truth |")
    print("|---|---|---|---|")
    for low, high, t, f in zip(bounds[:-1], bounds[1:], counted_t, counted_f):
        if t or f:
            ratio = f"{f / t:.3f}" if t else "-"
            print(f"| {low:.2f}-{high:.2f} | {t} | {f} | {ratio} |")


if __name__ == "__main__":
    main()
