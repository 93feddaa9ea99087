"""Time detector settings side by side on the held-out material (real photographs), interleaved.

Each case's frames go through every variant in turn (a fresh detector per case and variant, one
OpenCV thread), so the machine's noise falls on all alike.  Prints, per frame size, the median,
90th percentile and maximum time of a frame in ms and each variant's median over the first's, and
each variant's slowest frame over its median.

    python scripts/bench_heldout.py --split test --variants memory=0,coarse=false default memory=0
"""

from __future__ import annotations

import argparse
import time
from collections import defaultdict
from pathlib import Path

import cv2
import numpy as np

from antiscatter.config import parse_param
from antiscatter.detection import make_detector
from antiscatter.detection.contrast import ContrastParams
from antiscatter.evaluate.heldout import cases


def params(text: str) -> ContrastParams:
    """``default`` or ``key=value,key=value`` (as ``-p``) as ContrastParams."""
    if text == "default":
        return ContrastParams()
    return ContrastParams(**dict(parse_param(item, ContrastParams, detector="contrast") for item in text.split(",")))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--split", default="test", choices=("dev", "test"))
    parser.add_argument("--variants", nargs="+", default=["memory=0,coarse=false", "default", "memory=0"])
    parser.add_argument("--data", default="../shared/data", help="folder holding msrb/")
    parser.add_argument("--repeat", type=int, default=2, help="passes over the material")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    times: dict[tuple[int, str], list[float]] = defaultdict(list)
    material = [(case.name, [image for _, image, _ in case.frames()]) for case in
                cases(args.split, data=Path(args.data))]
    for _ in range(args.repeat):
        for name, frames in material:
            detectors = {v: make_detector("contrast", params(v)) for v in args.variants}
            for image in frames:
                for variant, detector in detectors.items():
                    t0 = time.perf_counter_ns()
                    detector.detect(image)
                    times[(image.shape[1], variant)].append((time.perf_counter_ns() - t0) / 1e6)
    first = args.variants[0]
    for width in sorted({w for w, _ in times}):
        reference = float(np.median(times[(width, first)]))
        print(f"frames {width} px wide ({len(times[(width, first)])} a variant), ms a frame:")
        for variant in args.variants:
            t = np.asarray(times[(width, variant)])
            print(f"  {variant:<28} median {np.median(t):7.2f}  p90 {np.percentile(t, 90):7.2f}  "
                  f"max {t.max():7.2f}  median/first {np.median(t) / reference:5.2f}  "
                  f"max/median {t.max() / np.median(t):5.2f}")


if __name__ == "__main__":
    main()
