"""Depth probing's work per frame for N tracked particles (the 12 cm housing's path after the tracker).

Usage: python scripts/bench_probe.py [--particles 300] [--frames 300]
Particles at random depths over 0.3-3 m in front of the twin's default camera and
projector (12 cm apart) drift at up to 200 px/s at 60 fps; each frame the probe judges
the last exposure (a particle under its probe, or another's, comes back at the dim level,
else lit; the verdicts read that exposure's pattern along each particle's line),
picks the next intervals (for the holes worth their light), and draws both patterns the pulse strategy shows (the whole
intervals dark between exposures, the probes lifted during the exposure), as
``antiscatter run`` does.  Median and p99 of each call are reported.
"""

from __future__ import annotations

import time

import numpy as np

from antiscatter.bench import machine_description, particle_bench_args
from antiscatter.detections import Detections
from antiscatter.probe import DepthProbe
from antiscatter.twin import TwinGeometry


def main() -> None:
    args = particle_bench_args(__doc__)
    rng = np.random.default_rng(0)
    geometry = TwinGeometry(baseline_m=0.12)
    n = args.particles
    w, h = geometry.camera_size
    start = rng.uniform((0, 0), (w, h), (n, 2))
    velocity = rng.uniform(-200, 200, (n, 2))
    depth = 1.0 / rng.uniform(1 / 3.0, 1 / 0.3, n)  # uniform in inverse depth, as the probe searches
    lit = 400.0 * depth ** -0.5  # brighter nearer (the prior learns the relation)
    ids = np.arange(n)
    probe = DepthProbe(geometry.plane_mapping, near_m=0.3, far_m=3.0, dim_level=0.1,
                       projector_size=geometry.projector_size)
    pattern = np.empty(geometry.projector_size[::-1], np.uint8)
    exposure = np.empty_like(pattern)
    times: dict[str, list[int]] = {"observe": [], "plan": [], "render": [], "frame": []}
    shown = probe.probes(Detections(start, np.full(n, 3.0), track_ids=ids))
    for f in range(args.frames):
        centres = (start + velocity * f / 60) % (w, h)
        a, b, given = shown.spans(ids, 0.0, 0.0)
        under = given & (a <= 1 / depth) & (1 / depth <= b)
        if f:  # or under another particle's probe: the light at its true place in the last exposure
            under |= probe.dark_at(exposure, probe.project(centres, 1 / depth))
        found = Detections(centres, np.full(n, 3.0), scores=lit * np.where(under, 0.1, 1.0), track_ids=ids)
        holes = Detections(centres, np.full(n, 3.0), track_ids=ids)
        t0 = time.perf_counter_ns()
        # judged against the light of the last exposure (its pattern, drawn at the end of the last frame)
        probe.observe(found, shown, np.empty(0, np.int64), exposure=exposure if f else None)
        t1 = time.perf_counter_ns()
        shown, between = probe.plan(holes)  # the holes worth their light
        t2 = time.perf_counter_ns()
        probe.render(holes, between, size=geometry.projector_size, out=pattern, given_only=True)
        probe.render(holes, shown, size=geometry.projector_size, out=exposure, hole=26, given_only=True)
        t3 = time.perf_counter_ns()
        for key, ns in (("observe", t1 - t0), ("plan", t2 - t1), ("render", (t3 - t2) // 2), ("frame", t3 - t0)):
            times[key].append(ns)
    print(f"machine: {machine_description()}")
    print(f"{n} particles, {args.frames} frames, projector {geometry.projector_size[0]}x{geometry.projector_size[1]}")
    for key, values in times.items():
        us = np.array(values[10:]) / 1e3
        name = "render (each of 2)" if key == "render" else key
        print(f"{name:>20s}: median {np.median(us):7.0f} us, p99 {np.percentile(us, 99):7.0f} us")
    print(f"settled depths learnt for the prior: {probe.prior_size()}")


if __name__ == "__main__":
    main()
