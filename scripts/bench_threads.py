"""The default detector on 1 and more threads, interleaved frame by frame in one process.

Variants, each a fresh ``contrast`` detector warmed up over the pool: ``1`` (one thread, one
OpenCV thread: the reference), ``cvN`` (OpenCV's own N threads alone), ``bandsN`` (the detector's
bands on N threads, one OpenCV thread) and ``bothN`` (both).  Every variant sees the same frames
in a rotating order; the OpenCV thread count is set before each call.  Prints per source the
median, p90 and p99 of a frame's time (ms, every stage including the learning after the
detections), each variant's throughput over the reference's (ratio of medians), the median of
the frame-by-frame ratios, the median CPU time a frame took over all the process's threads (the
work threading adds, which the load does not hide), the per-stage medians, and the load average before and after (on a
shared machine the ratios are depressed by the other jobs).  Detections are checked equal to the
reference's on every frame.

``--share``: instead, the share of a frame's time (one thread) that threads can take on -- the
bands' work and the coarse scale beside the fine measure, run one after the other and timed --
and what that bounds N threads' throughput to (Amdahl); the machine's load hardly moves it.

    python scripts/bench_threads.py /tmp/h/test/pan-1456 sim:1456x1088:fullres --threads 2
    (material: antiscatter evaluate --heldout test --heldout-frames 12 --heldout-export /tmp/h)
"""

from __future__ import annotations

import argparse
import os
import time

import cv2
import numpy as np

from antiscatter.bench import at_least_one, machine_description, pool_index, simulator_pool, source_pool
from antiscatter.detection import make_detector
from antiscatter.runtime import time_stages


def _pool(spec: str, distinct: int) -> list[np.ndarray]:
    """``sim:WxH:preset`` (simulator frames) or any source ``run`` takes."""
    if spec.startswith("sim:"):
        _, size, preset = spec.split(":")
        width, height = (int(v) for v in size.split("x"))
        return simulator_pool(width, height, preset, distinct=distinct)
    return source_pool(spec, distinct=distinct)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sources", nargs="+", help="folders, videos or sim:WxH:preset")
    parser.add_argument("--threads", type=at_least_one, default=2)
    parser.add_argument("--frames", type=at_least_one, default=120, help="timed frames per source")
    parser.add_argument("--distinct", type=at_least_one, default=12)
    parser.add_argument("--input", choices=("bgr", "y"), default="bgr")
    parser.add_argument("--variants", default="1,cv,bands,both", help="of 1, cv, bands, both")
    parser.add_argument("--share", action="store_true", help="the parallel share of a frame's time instead")
    args = parser.parse_args()
    n = args.threads
    if args.share:
        share(args)
        return
    wanted = args.variants.split(",")
    print(f"machine: {machine_description()}")
    for spec in args.sources:
        pool = _pool(spec, args.distinct)
        if args.input == "y":
            pool = [cv2.cvtColor(f, cv2.COLOR_BGR2GRAY) if f.ndim == 3 else f for f in pool]
        # name: (detector threads, OpenCV threads)
        variants = {"1": (1, 1), f"cv{n}": (1, n), f"bands{n}": (n, 1), f"both{n}": (n, n)}
        variants = {k: v for k, v in variants.items() if k.rstrip("0123456789") in wanted or k in wanted}
        built = {k: make_detector("contrast", threads=t) for k, (t, _) in variants.items()}
        for k, d in built.items():
            cv2.setNumThreads(variants[k][1])
            for image in pool:
                d.detect(image)
        names = list(built)
        times = {k: [] for k in names}
        cpu = {k: [] for k in names}
        stages = {k: [] for k in names}
        load0 = os.getloadavg()
        for i in range(args.frames):
            image = pool[pool_index(len(pool) + i, len(pool))]
            found = {}
            for k in names[i % len(names):] + names[:i % len(names)]:
                cv2.setNumThreads(variants[k][1])
                c0, t0 = time.process_time_ns(), time.perf_counter_ns()
                found[k], durations = time_stages(built[k], image)
                times[k].append(time.perf_counter_ns() - t0)
                cpu[k].append(time.process_time_ns() - c0)
                stages[k].append(durations)
            ref = found["1"] if "1" in found else None
            for k, f in found.items():
                if ref is not None and not (np.array_equal(f.centres, ref.centres) and np.array_equal(f.radii, ref.radii)
                                            and np.array_equal(f.scores, ref.scores)):
                    raise SystemExit(f"{spec} frame {i}: {k} detections differ from 1 thread's")
        load1 = os.getloadavg()
        h, w = pool[0].shape[:2]
        print(f"\n{spec} ({w}x{h}, {args.input}, {args.frames} frames, {len(pool)} distinct); "
              f"load average before {load0[0]:.1f}, after {load1[0]:.1f}")
        print(f"{'variant':<9}{'median':>8}{'p90':>8}{'p99':>8}{'x 1':>7}{'x 1 paired':>12}{'cpu ms':>8}"
              "   per stage medians (ms)")
        base = np.asarray(times["1"], float) if "1" in times else None
        stage_names = [s.name for s in built[names[0]].stages]
        for k in names:
            t = np.asarray(times[k], float) / 1e6
            med = float(np.median(t))
            ratio = paired = float("nan")
            if base is not None:
                ratio = float(np.median(base)) / 1e6 / med
                paired = float(np.median(base / np.asarray(times[k], float)))
            per = np.median(np.asarray(stages[k], float), axis=0) / 1e6
            print(f"{k:<9}{med:8.2f}{np.percentile(t, 90):8.2f}{np.percentile(t, 99):8.2f}{ratio:7.2f}{paired:12.2f}"
                  f"{np.median(cpu[k]) / 1e6:8.2f}   "
                  + " ".join(f"{s}={v:.2f}" for s, v in zip(stage_names, per)))
    cv2.setNumThreads(1)


def share(args: argparse.Namespace) -> None:
    """Per source: a frame's median time on one thread with the pool's work run in the caller and
    timed, that work's share, and the throughput it bounds 2 and 4 threads to."""
    from antiscatter.detection.contrast.bands import BandPool

    spent = [0]

    def run(self, work, spans):  # the bands one after the other, timed
        t0 = time.perf_counter_ns()
        for r0, r1 in spans:
            work(r0, r1)
        spent[0] += time.perf_counter_ns() - t0

    def call(self, first, second):  # the second task (the coarse scale) is what runs beside the first
        done = first()
        t0 = time.perf_counter_ns()
        other = second()
        spent[0] += time.perf_counter_ns() - t0
        return done, other

    BandPool.run, BandPool.call = run, call
    cv2.setNumThreads(1)
    print(f"machine: {machine_description()}")
    print(f"{'source':<40}{'ms/frame':>9}{'share':>7}{'2 threads':>11}{'4 threads':>11}   load")
    for spec in args.sources:
        pool = _pool(spec, args.distinct)
        if args.input == "y":
            pool = [cv2.cvtColor(f, cv2.COLOR_BGR2GRAY) if f.ndim == 3 else f for f in pool]
        detector = make_detector("contrast", threads=2)
        for image in pool:
            detector.detect(image)
        spent[0], total = 0, []
        for i in range(args.frames):
            t0 = time.perf_counter_ns()
            detector.detect(pool[pool_index(len(pool) + i, len(pool))])
            total.append(time.perf_counter_ns() - t0)
        p = spent[0] / sum(total)
        print(f"{spec:<40}{np.median(total) / 1e6:9.2f}{p:7.2f}{1 / (1 - p / 2):10.2f}x{1 / (1 - 3 * p / 4):10.2f}x"
              f"   {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
