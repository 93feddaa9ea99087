"""Make docs/gallery/<preset>.png: frame 30 of every simulator preset (seed 1).

Usage: python scripts/make_gallery.py [OUT_DIR]
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np

from antiscatter.simulate import PRESETS, make_scene


def main(out: str = "docs/gallery") -> None:
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    for name, entry in PRESETS.items():
        scene = make_scene(name, rng=np.random.default_rng(1))
        for _ in range(30):
            scene.step()
        image = scene.render()
        scale = 480 / image.shape[1]
        image = cv2.resize(image, (480, round(image.shape[0] * scale)), interpolation=cv2.INTER_AREA)
        label = f"{name}: {entry.summary}"
        cv2.putText(image, label, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(image, label, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
        cv2.imwrite(str(folder / f"{name}.png"), image)
        print(f"wrote {folder / f'{name}.png'}")


if __name__ == "__main__":
    main(*sys.argv[1:])
