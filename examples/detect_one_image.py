"""Find the particles in one image with the library API and draw the projector pattern for them.

    python examples/detect_one_image.py [IMAGE] [--pattern PATTERN.png]

IMAGE: any photograph (PNG, JPEG); without one, a frame of the simulator's ``bubbles`` preset, whose
ground truth is printed beside the detections. The pattern is the projector's image: white, with a
black hole over each particle (1280x800, the camera-to-projector mapping taken as the identity).
"""

from __future__ import annotations

import argparse
import sys

import cv2
import numpy as np

from antiscatter.detection import detect
from antiscatter.pattern import render_pattern
from antiscatter.simulate import make_scene


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("image", nargs="?", help="an image file (default: a simulator frame)")
    parser.add_argument("--pattern", metavar="PATTERN.png", help="write the projector pattern here")
    args = parser.parse_args(argv)

    truth = None
    if args.image:
        image = cv2.imread(args.image, cv2.IMREAD_COLOR)
        if image is None:
            print(f"{args.image}: not an image file", file=sys.stderr)
            return 2
    else:
        scene = make_scene("bubbles", rng=np.random.default_rng(0))  # seeded: the same frame every time
        scene.step()
        image, truth = scene.render(), scene.truth()

    found = detect(image, "contrast")  # the default detector of `antiscatter run`, default parameters
    height, width = image.shape[:2]
    print(f"{len(found.radii)} particles in the {width}x{height} image")
    for (x, y), radius in zip(found.centres[:5], found.radii[:5]):
        print(f"  at x {x:7.1f} px, y {y:7.1f} px, radius {radius:4.1f} px")
    if truth is not None:
        print(f"the simulator drew {int(np.sum(truth.visibility > 0))} visible particles")

    if args.pattern:
        pattern = render_pattern(found, size=(1280, 800))  # (800, 1280) uint8: 255 lit, 0 in the holes
        if not cv2.imwrite(args.pattern, pattern):
            print(f"{args.pattern}: could not be written", file=sys.stderr)
            return 2
        print(f"pattern: {args.pattern} ({np.mean(pattern == 0):.1%} of the projector dark)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
