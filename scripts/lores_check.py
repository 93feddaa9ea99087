"""On the Pi: what the ISP's ``lores`` stream is, against the detector's own pooling of the main stream.

Opens the camera with a lores stream at the detector's working size (as ``run --camera-lores``)
and, over N frames of whatever the camera sees, reports how far the lores Y plane is from each
emulated filter of the main Y plane (mean absolute difference, grey levels: the nearest is the
ISP's filter as far as these can tell), and how the detections from the lores plane agree with
those from the main frame (matched within 1.5 px: the share of each found by the other).  Point the
camera at particles (a tank, or dust in a lamp's beam) for the second figure to mean anything.

    python scripts/lores_check.py --size 1456x1088 --frames 120

History and what the figures decide: docs/decisions/009-lores.md.
"""

from __future__ import annotations

import argparse

import cv2
import numpy as np

from antiscatter.assignment import match
from antiscatter.config import parse_size
from antiscatter.detection import make_detector
from antiscatter.sources import open_source


def emulations(grey: np.ndarray, size: tuple[int, int]) -> dict[str, np.ndarray]:
    """The main Y plane scaled to ``size`` by each filter the accuracy figures were measured with."""
    area = cv2.resize(grey, size, interpolation=cv2.INTER_AREA)
    return {"area (2x2 mean)": area,
            "lanczos4": cv2.resize(grey, size, interpolation=cv2.INTER_LANCZOS4),
            "gauss1 + area": cv2.resize(cv2.GaussianBlur(grey, (0, 0), 1.0), size, interpolation=cv2.INTER_AREA)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", default="1456x1088", help="main stream WxH (default 1456x1088)")
    parser.add_argument("--fps", type=float, default=60.0)
    parser.add_argument("--frames", type=int, default=120)
    args = parser.parse_args()
    size = parse_size(args.size)
    on_lores, on_main = make_detector("contrast"), make_detector("contrast")
    distance: dict[str, list[float]] = {}
    found = {"lores": 0, "main": 0, "both": 0}
    with open_source("camera", size=size, fps=args.fps, working_size=on_lores.working_size) as source:
        for _ in range(args.frames):
            frame = source.read()
            pooled = frame.pooled
            for name, plane in emulations(frame.image, pooled.working.shape[::-1]).items():
                diff = cv2.absdiff(plane, pooled.working)
                distance.setdefault(name, []).append(float(cv2.mean(diff)[0]))
            a, b = on_main.detect(frame.image), on_lores.detect(pooled)
            pairs, _, _ = match(a.centres, np.full(len(a), 1.5), b.centres)
            found["main"] += len(a)
            found["lores"] += len(b)
            found["both"] += len(pairs)
    print(f"{args.frames} frames, main {size[0]}x{size[1]}, lores {pooled.working.shape[1]}x{pooled.working.shape[0]}")
    for name, values in distance.items():
        print(f"  lores against {name:<16} mean |difference| {np.mean(values):.2f} grey levels")
    print(f"  particles: main {found['main']}, lores {found['lores']}, both {found['both']} "
          f"({found['both'] / max(found['main'], 1):.3f} of main's, {found['both'] / max(found['lores'], 1):.3f} "
          "of lores')")


if __name__ == "__main__":
    main()
