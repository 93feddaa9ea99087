"""The default detector of this tree against the one of an earlier commit, interleaved frame by frame
in one process on the held-out material (real photographs), one OpenCV thread.

The earlier package is taken with ``git archive REV src/antiscatter`` and imported under another
name, so both run on the same frames with the same machine noise.  Prints, per frame width, each
side's median and 90th percentile time of a frame (ms) and new over old.

    python scripts/bench_ab.py b58d6d8 --old-params memory=0 --split test
"""

from __future__ import annotations

import argparse
import importlib
import subprocess
import sys
import tarfile
import tempfile
import time
from collections import defaultdict
from io import BytesIO
from pathlib import Path

import cv2
import numpy as np

from antiscatter.config import parse_param
from antiscatter.detection import make_detector
from antiscatter.detection.contrast import ContrastParams
from antiscatter.evaluate.heldout import cases

ROOT = Path(__file__).resolve().parent.parent


def _params(cls: type, text: str) -> object:
    """``default`` or ``key=value,...`` (as ``-p``, parsed by this tree's rules) as ``cls``."""
    if text == "default":
        return cls()
    values = {}
    for item in text.split(","):
        key, value = parse_param(item, ContrastParams, detector="contrast")
        values[key] = value
    return cls(**values)


def old_package(rev: str, folder: Path) -> object:
    """The ``antiscatter`` package of commit ``rev``, importable as ``antiscatter_old``."""
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev, "src/antiscatter"], check=True,
                             capture_output=True).stdout
    with tarfile.open(fileobj=BytesIO(archive)) as tar:
        tar.extractall(folder, filter="data")
    (folder / "src" / "antiscatter").rename(folder / "antiscatter_old")
    sys.path.insert(0, str(folder))
    return importlib.import_module("antiscatter_old.detection")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("rev", help="the earlier commit")
    parser.add_argument("--old-params", default="default", help="key=value,... for the old detector")
    parser.add_argument("--new-params", default="default", help="key=value,... for this tree's detector")
    parser.add_argument("--split", default="test", choices=("dev", "test"))
    parser.add_argument("--frames", type=int, default=None, help="frames a case (default: each case's own)")
    parser.add_argument("--data", default=str(ROOT.parent / "shared" / "data"), help="folder holding msrb/")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    with tempfile.TemporaryDirectory() as tmp:
        old = old_package(args.rev, Path(tmp))
        old_params = importlib.import_module("antiscatter_old.detection.contrast").ContrastParams
        times: dict[tuple[str, int], list[float]] = defaultdict(list)
        for case in cases(args.split, frames=args.frames, data=Path(args.data)):
            sides = {"old": old.make_detector("contrast", _params(old_params, args.old_params)),
                     "new": make_detector("contrast", _params(ContrastParams, args.new_params))}
            for k, (_, image, _) in enumerate(case.frames()):
                for name in (("old", "new") if k % 2 else ("new", "old")):
                    t0 = time.perf_counter_ns()
                    sides[name].detect(image)
                    times[(name, image.shape[1])].append((time.perf_counter_ns() - t0) / 1e6)
    for width in sorted({w for _, w in times}):
        o, n = np.asarray(times[("old", width)]), np.asarray(times[("new", width)])
        print(f"{width} px wide, {len(o)} frames: old median {np.median(o):.2f} ms p90 {np.percentile(o, 90):.2f} | "
              f"new median {np.median(n):.2f} ms p90 {np.percentile(n, 90):.2f} | new / old {np.median(n) / np.median(o):.3f}")


if __name__ == "__main__":
    main()
