"""Make docs/pipeline.png: a simulator frame, its detections, and the projector pattern.

Usage: python scripts/make_figure.py [OUT.png]
"""

from __future__ import annotations

import sys

import cv2
import numpy as np

from antiscatter.detection import make_detector
from antiscatter.pattern import render_pattern, scale_mapping
from antiscatter.simulate import make_scene


def main(out: str = "docs/pipeline.png") -> None:
    scene = make_scene("seed", rng=np.random.default_rng(0))
    detector = make_detector("contrast")
    for _ in range(240):  # the detector sees the stream, as in a run
        detector.detect(scene.render())
        scene.step()
    frame = scene.render()
    found = detector.detect(frame)
    overlay = frame.copy()
    for (x, y), r in zip(found.centres.tolist(), found.radii.tolist()):
        cv2.circle(overlay, (round(x), round(y)), max(round(r), 1), (0, 0, 255), 2)
    pattern = render_pattern(found, size=(800, 600), mapping=scale_mapping(scene.size, (800, 600)),
                             margin=2)
    panels = [frame, overlay, cv2.cvtColor(pattern, cv2.COLOR_GRAY2BGR)]
    titles = ["camera frame (simulator)", "detections (contrast detector)", "projector pattern"]
    labelled = []
    for image, title in zip(panels, titles):
        image = cv2.resize(image, (400, 300), interpolation=cv2.INTER_AREA)
        bar = np.full((36, 400, 3), 40, np.uint8)
        cv2.putText(bar, title, (10, 25), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1, cv2.LINE_AA)
        labelled.append(np.vstack([bar, image]))
    gap = np.full((336, 8, 3), 40, np.uint8)
    figure = np.hstack([labelled[0], gap, labelled[1], gap, labelled[2]])
    cv2.imwrite(out, figure)
    print(f"wrote {out}")


if __name__ == "__main__":
    main(*sys.argv[1:])
