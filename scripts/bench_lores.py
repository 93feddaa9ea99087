"""Time ``contrast`` on what the camera can hand it, beside ``seed``, interleaved in one process.

Per held-out case of 1456x1088 frames (real photographs; the test split by default), every
variant sees every frame in turn (a detector of its own per case and variant, one OpenCV thread,
the case's frames played forwards and back): ``contrast`` on the BGR frame, on its Y plane, on
the Y plane scaled to the working resolution as the ISP's ``lores`` stream would give it (a
:class:`~antiscatter.detection.Pooled` frame, with and without the full Y plane), ``seed`` on
the BGR frame, bench's chain floor on the Y plane and on the lores plane, and the copy of the Y
plane (the floor of any frame's handling).  Prints the median and 90th percentile of a frame's time (all stages, the learning
after the detections included), the Downsample stage's median, the throughput over seed's, and
the load average before and after.

    python scripts/bench_lores.py [--split test] [--frames 60]

History: docs/decisions/009-lores.md.
"""

from __future__ import annotations

import argparse
import os
import time
from collections import defaultdict
from pathlib import Path

import cv2
import numpy as np

from antiscatter.bench import minimal_chain
from antiscatter.detection import Pooled, make_detector
from antiscatter.evaluate.heldout import cases
from antiscatter.runtime import time_stages

VARIANTS = ("contrast BGR", "contrast Y", "contrast lores+full", "contrast lores", "seed BGR", "floor Y",
            "floor lores", "copy Y")
#: the floors: bench's minimal chain (pooling, cell background, one threshold, one labelling) on the
#: Y plane and on the lores plane; the copy of the Y plane (what the camera source does for main)
FLOORS = {"floor Y": minimal_chain, "floor lores": minimal_chain, "copy Y": np.copy}


def inputs(image: np.ndarray, size: tuple[int, int]) -> dict[str, object]:
    """What each variant is given for one BGR frame (made before any timing)."""
    grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    lores = cv2.resize(grey, size, interpolation=cv2.INTER_AREA)
    return {"contrast BGR": image, "contrast Y": grey, "contrast lores+full": Pooled(lores, 2, grey),
            "contrast lores": Pooled(lores, 2), "seed BGR": image, "floor Y": grey, "floor lores": Pooled(lores, 2),
            "copy Y": grey}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--split", default="test", choices=("dev", "test"))
    parser.add_argument("--frames", type=int, default=60, help="timed frames per case and variant")
    parser.add_argument("--data", default="/work/shared/data", help="folder holding msrb/")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    chosen = [c for c in cases(args.split, data=Path(args.data)) if c.size == (1456, 1088)]
    material = [(c.name, [image for _, image, _ in c.frames()]) for c in chosen]
    load_before = os.getloadavg()
    total: dict[str, list[float]] = defaultdict(list)
    pooling: dict[str, list[float]] = defaultdict(list)
    per_case: dict[tuple[str, str], list[float]] = defaultdict(list)
    for name, frames in material:
        detectors = {v: make_detector("seed" if v.startswith("seed") else "contrast") for v in VARIANTS
                     if v not in FLOORS}
        size = detectors["contrast BGR"].working_size(1456, 1088)
        fed = [inputs(image, size) for image in frames]
        order = list(range(len(fed))) + list(range(len(fed) - 2, 0, -1))  # forwards and back
        for k in range(args.frames):
            given = fed[order[k % len(order)]]
            variants = VARIANTS[k % len(VARIANTS):] + VARIANTS[: k % len(VARIANTS)]  # who goes first rotates
            for v in variants:
                if v in FLOORS:
                    start = time.perf_counter_ns()
                    FLOORS[v](given[v])
                    ns = [time.perf_counter_ns() - start]
                else:
                    _, ns = time_stages(detectors[v], given[v])
                total[v].append(sum(ns) / 1e6)
                per_case[(name, v)].append(sum(ns) / 1e6)
                pooling[v].append(ns[0] / 1e6)
    load_after = os.getloadavg()
    seed = float(np.median(total["seed BGR"]))
    print(f"held-out {args.split}, 1456x1088: {', '.join(n for n, _ in material)}; {args.frames} timed frames a "
          f"case and variant; OpenCV {cv2.__version__}, 1 thread; load average before "
          f"{' '.join(f'{x:.1f}' for x in load_before)}, after {' '.join(f'{x:.1f}' for x in load_after)}")
    print(f"| variant | median ms | p90 ms | first stage median ms | throughput / seed |")
    print("|---|---|---|---|---|")
    for v in VARIANTS:
        t = np.asarray(total[v])
        print(f"| {v} | {np.median(t):.2f} | {np.percentile(t, 90):.2f} | {np.median(pooling[v]):.2f} | "
              f"{seed / np.median(t):.2f}x |")
    print("per case, median ms (throughput / seed):")
    for name, _ in material:
        s = float(np.median(per_case[(name, "seed BGR")]))
        print(f"  {name:<18}" + "  ".join(f"{v}={np.median(per_case[(name, v)]):.2f} ({s / np.median(per_case[(name, v)]):.2f}x)"
                                          for v in VARIANTS))


if __name__ == "__main__":
    main()
