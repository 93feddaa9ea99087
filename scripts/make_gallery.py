"""Make docs/gallery/<preset>.png: frame 30 of every simulator preset (seed 1).

Usage: python scripts/make_gallery.py [OUT_DIR]
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np

from antiscatter.simulate import PRESETS, make_scene


def caption(text: str, width: int, *, scale: float = 0.45, line: int = 18) -> np.ndarray:
    """A dark band holding ``text`` in white, wrapped to ``width`` pixels (a band above the frame:
    nothing of the scene is covered, and no outline is drawn -- OpenCV 5's thick outline ran
    past the thin text and left a ghost of its last letters)."""
    font = cv2.FONT_HERSHEY_SIMPLEX
    lines, current = [], ""
    for word in text.split():
        trial = f"{current} {word}".strip()
        if current and cv2.getTextSize(trial, font, scale, 1)[0][0] > width - 16:
            lines.append(current)
            trial = word
        current = trial
    lines.append(current)
    band = np.full((line * len(lines) + 8, width, 3), 24, np.uint8)
    for i, words in enumerate(lines):
        cv2.putText(band, words, (8, line * (i + 1)), font, scale, (255, 255, 255), 1, cv2.LINE_AA)
    return band


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
        image = np.vstack([caption(f"{name}: {entry.summary}", image.shape[1]), image])
        cv2.imwrite(str(folder / f"{name}.png"), image)
        print(f"wrote {folder / f'{name}.png'}")


if __name__ == "__main__":
    main(*sys.argv[1:])
