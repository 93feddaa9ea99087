"""Frames per second of generation into memory, per preset, on one core.

Usage: python scripts/bench_simulator.py [--frames N] [--json]
Renders each preset at its own size (step + render + truth), OpenCV on one
thread, and reports the median and p90 frame time and the median rate.
"""

from __future__ import annotations

import argparse
import json
import platform
import time

import cv2
import numpy as np

from antiscatter.simulate import PRESETS, make_scene


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--frames", type=int, default=100)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    results = {}
    for name in PRESETS:
        scene = make_scene(name, rng=np.random.default_rng(1))
        scene.render()  # first frame builds lazy tables
        times = []
        for _ in range(args.frames):
            t0 = time.perf_counter_ns()
            scene.step()
            scene.render()
            scene.truth()
            times.append(time.perf_counter_ns() - t0)
        ms = np.array(times) / 1e6
        results[name] = {"size": f"{scene.size[0]}x{scene.size[1]}", "median_ms": float(np.median(ms)),
                         "p90_ms": float(np.percentile(ms, 90)), "fps": float(1000 / np.median(ms))}
    machine = f"{platform.machine()} {platform.processor() or ''} {platform.python_version()}".strip()
    if args.json:
        print(json.dumps({"machine": machine, "opencv_threads": 1, "presets": results}, indent=2))
        return
    print(f"simulator generation into memory, {args.frames} frames per preset, 1 OpenCV thread, {machine}")
    print(f"{'preset':<10}{'size':>11}{'median ms':>11}{'p90 ms':>9}{'frames/s':>10}")
    for name, r in results.items():
        print(f"{name:<10}{r['size']:>11}{r['median_ms']:>11.2f}{r['p90_ms']:>9.2f}{r['fps']:>10.0f}")


if __name__ == "__main__":
    main()
