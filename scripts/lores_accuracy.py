"""Accuracy of ``contrast`` on a plane the camera's ISP scaled (a ``lores`` stream) against the full frame.

The ISP scales with a filter, not the detector's pooling (2x2 mean plus ``point`` of the block's
maximum).  Emulated here on the held-out material: the frame's Y plane (luma, as the camera's)
resized to the working resolution by ``cv2.resize`` (INTER_AREA, INTER_LINEAR -- at an exact
factor of 2 both are the 2x2 mean, the same array; INTER_LANCZOS4 as a sharper, unfiltered bound; a
Gaussian of sigma 1 px before the 2x2 mean as a softer one), handed to the detector as a :class:`~antiscatter.detection.Pooled`
frame with the full Y plane (as the camera's main stream gives it) or without it.  Every variant
and ``seed`` see the same frames; F1 pooled over the split, as ``evaluate --heldout`` reports it.

    python scripts/lores_accuracy.py --split dev test [--frames N]
    python scripts/lores_accuracy.py --split --catalogue

History: docs/decisions/009-lores.md.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import cv2

from antiscatter.detection import Detector, Pooled, Stage, make_detector
from antiscatter.evaluate.heldout import evaluate_heldout
from antiscatter.evaluate.runs import Matching

def _resize(interpolation: int):
    return lambda plane, size: cv2.resize(plane, size, interpolation=interpolation)


def _soft(plane, size):
    return cv2.resize(cv2.GaussianBlur(plane, (0, 0), 1.0), size, interpolation=cv2.INTER_AREA)


#: the ISP's filter, emulated: (Y plane, (w, h)) -> the plane at (w, h)
FILTERS = {"area": _resize(cv2.INTER_AREA), "linear": _resize(cv2.INTER_LINEAR),
           "lanczos4": _resize(cv2.INTER_LANCZOS4), "gauss1": _soft}


def isp_scaled(detector: Detector, scaler, *, keep_full: bool, name: str) -> Detector:
    """``detector`` behind a first stage that does what the camera would: the Y plane of the BGR
    frame, and that plane scaled to the detector's working size by ``scaler``."""

    def scale(image):
        grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        h, w = grey.shape
        size = detector.working_size(w, h)
        factor = w // size[0]
        whole = grey[: size[1] * factor, : size[0] * factor]
        return Pooled(scaler(whole, size), factor, whole if keep_full else None)

    return dataclasses.replace(detector, name=name, stages=(Stage("isp", "ISP", scale), *detector.stages))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--split", nargs="*", default=["dev", "test"], choices=("dev", "test"))
    parser.add_argument("--catalogue", action="store_true", help="also the simulator's catalogued scenarios")
    parser.add_argument("--filters", nargs="+", default=list(FILTERS), choices=list(FILTERS))
    parser.add_argument("--frames", type=int, default=None, help="frames per case (default: each case's own)")
    parser.add_argument("--data", default="/work/shared/data", help="folder holding msrb/")
    parser.add_argument("--params", default="", help="contrast params key=value,... (default: the defaults)")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    from antiscatter.config import parse_param
    from antiscatter.detection.contrast import ContrastParams

    extra = dict(parse_param(p, ContrastParams, detector="contrast") for p in args.params.split(",") if p)

    def contrast() -> Detector:
        return make_detector("contrast", ContrastParams(**extra))

    def variants() -> dict[str, Detector]:
        detectors = {"full BGR": contrast(), "seed": make_detector("seed")}
        for label in args.filters:
            detectors[f"lores {label} + full Y"] = isp_scaled(contrast(), FILTERS[label], keep_full=True,
                                                             name=f"lores-{label}-full")
            detectors[f"lores {label}"] = isp_scaled(contrast(), FILTERS[label], keep_full=False,
                                                     name=f"lores-{label}")
        return detectors

    if args.catalogue:
        from antiscatter.evaluate.metrics import summarise
        from antiscatter.evaluate.runs import evaluate_scenario
        from antiscatter.simulate.catalogue import load_catalogue

        _, scenarios = load_catalogue(None)
        names = list(variants())
        print("catalogue F1 (" + ", ".join(scenarios) + ")")
        rows = {n: [] for n in names}
        for sc in scenarios.values():
            scores = evaluate_scenario(sc.preset, sc.size, sc.frames if args.frames is None else args.frames,
                                       sc.seed, variants(), Matching())
            for n in names:
                rows[n].append(summarise(scores[n])["f1"])
        for n in names:
            print(f"  {n:<26}" + " ".join(f"{f:.3f}" for f in rows[n])
                  + f"   worst dF1 {min(a - b for a, b in zip(rows[n], rows['full BGR'])):+.3f}")
    for split in args.split:
        detectors = variants()
        result = evaluate_heldout(split, detectors, Matching(), frames=args.frames, data=Path(args.data))
        base = result["overall"]["full BGR"]["f1"]
        print(f"held-out {split}: {result['frames']} frames, {result['counted']} counted particles")
        print(f"  {'variant':<26}{'F1':>7}{'P':>7}{'R':>7}{'dF1':>8}")
        for name, row in result["overall"].items():
            print(f"  {name:<26}{row['f1']:7.3f}{row['precision']:7.3f}{row['recall']:7.3f}{row['f1'] - base:+8.3f}")
        for case in result["cases"]:
            rows = case["detectors"]
            print(f"    {case['case']:<22}" + " ".join(f"{n.split(' +')[0][:12]}{'+' if '+' in n else ''}="
                                                       f"{r['f1']:.3f}" for n, r in rows.items()))


if __name__ == "__main__":
    main()
