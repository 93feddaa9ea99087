"""Tracker update time for N particles, beside a full dense Hungarian assignment of the same size.

Usage: python scripts/bench_tracker.py [--particles 300] [--frames 300] [--preset NAME]
Particles move at up to 200 px/s with 0.5 px detection noise at 60 fps; the
median and p99 of Tracker.update are reported with the time of one dense
scipy linear_sum_assignment on the full N x N distance matrix (what a naive
tracker would pay per frame).  With --preset, the tracker is timed also on what
the default detector finds in that simulator scene (800x600, --frames frames,
at most 240): the births, deaths, misses and crowded gates of real detections,
which uniform synthetic motion lacks (on the mixed scene's 235 particles a frame
the update cost twice the synthetic 300's before the assignment's sweep).
"""

from __future__ import annotations

import time

import numpy as np
from scipy.optimize import linear_sum_assignment

from antiscatter.bench import machine_description, particle_bench_args
from antiscatter.detections import Detections
from antiscatter.tracking import Tracker


def main() -> None:
    args = particle_bench_args(__doc__, preset=True)
    rng = np.random.default_rng(0)
    n = args.particles
    start = rng.uniform(0, 800, (n, 2))
    velocity = rng.uniform(-200, 200, (n, 2))
    frames = [Detections((start + velocity * f / 60) % 800 + rng.normal(0, 0.5, (n, 2)), np.full(n, 3.0))
              for f in range(args.frames)]
    tracker = Tracker()
    update, dense = [], []
    for f, detections in enumerate(frames):
        t0 = time.perf_counter_ns()
        tracker.update(detections, f / 60)
        update.append(time.perf_counter_ns() - t0)
        if f % 10 == 0:
            cost = np.hypot(*(detections.centres[:, None, :] - frames[f - 1].centres[None, :, :]).transpose(2, 0, 1))
            t0 = time.perf_counter_ns()
            linear_sum_assignment(cost)
            dense.append(time.perf_counter_ns() - t0)
    u = np.array(update[10:]) / 1e6
    d = np.array(dense) / 1e6
    print(f"machine: {machine_description()}")
    print(f"{n} particles, {args.frames} frames")
    print(f"Tracker.update: median {np.median(u):.3f} ms, p99 {np.percentile(u, 99):.3f} ms")
    print(f"dense Hungarian alone ({n}x{n}): median {np.median(d):.3f} ms")
    if args.preset:
        scene_bench(args.preset, min(args.frames, 240))


def scene_bench(preset: str, frames: int) -> None:
    """Tracker.update on the default detector's detections in a simulator scene (found first, then timed)."""
    from antiscatter.detection import make_detector
    from antiscatter.simulate import make_scene

    size = (800, 600)
    scene = make_scene(preset, rng=np.random.default_rng(1), size=size)
    detector = make_detector("contrast")
    found = []
    for f in range(frames):
        if f:
            scene.step()
        found.append(detector.detect(scene.render()))
    tracker = Tracker(frame_size=size)
    update = []
    for f, detections in enumerate(found):
        t0 = time.perf_counter_ns()
        tracker.update(detections, f / scene.fps)
        update.append(time.perf_counter_ns() - t0)
    u = np.array(update[min(10, frames // 2):]) / 1e6
    counts = [len(d) for d in found]
    print(f"scene {preset} ({size[0]}x{size[1]}, {frames} frames, default detector): "
          f"median {np.median(counts):.0f} particles a frame")
    print(f"Tracker.update on its detections: median {np.median(u):.3f} ms, p99 {np.percentile(u, 99):.3f} ms")


if __name__ == "__main__":
    main()
