"""Backgrounds that are not black: water, seabed, tank padding, a user's image or video.

Each function returns a float32 (H, W) or (H, W, 3) reflectance-like image in
0..1, before the lamp cone and the water colour are applied by the scene.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from ..errors import UsageError

__all__ = ["fractal_noise", "seabed", "padding", "gradient", "load_background", "BACKGROUNDS"]

BACKGROUNDS = ("black", "water", "seabed", "padding")


def fractal_noise(size: tuple[int, int], rng: np.random.Generator, *, octaves: int = 6,
                  base: int = 4, persistence: float = 0.55) -> np.ndarray:
    """Sum of upsampled random grids (value noise), float32 (H, W) normalised to 0..1."""
    width, height = size
    total = np.zeros((height, width), np.float32)
    amplitude, norm = 1.0, 0.0
    for octave in range(octaves):
        cells = base * 2 ** octave
        gw = max(2, int(round(cells * width / max(width, height))) + 1)
        gh = max(2, int(round(cells * height / max(width, height))) + 1)
        grid = rng.random((gh, gw)).astype(np.float32)
        total += amplitude * cv2.resize(grid, (width, height), interpolation=cv2.INTER_CUBIC)
        norm += amplitude
        amplitude *= persistence
    total /= norm
    lo, hi = np.percentile(total, [1, 99])
    return np.clip((total - lo) / max(hi - lo, 1e-6), 0.0, 1.0)


def seabed(size: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    """Sand and rock: fractal texture with ripples and scattered bright pebbles, 0..1."""
    width, height = size
    texture = fractal_noise(size, rng)
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    wavelength = rng.uniform(0.04, 0.08) * width
    angle = rng.uniform(0, np.pi)
    ripples = 0.5 + 0.5 * np.sin((xx * np.cos(angle) + yy * np.sin(angle)) * 2 * np.pi / wavelength
                                 + 3.0 * fractal_noise(size, rng, octaves=3))
    bed = 0.75 * texture ** 1.5 + 0.12 * ripples
    pebbles = np.zeros((height, width), np.float32)
    count = int(width * height / 1500)
    for x, y, r, b in zip(rng.uniform(0, width, count), rng.uniform(0, height, count),
                          rng.uniform(1.5, 0.012 * width + 2, count), rng.uniform(0.1, 0.4, count)):
        cv2.circle(pebbles, (int(x * 16), int(y * 16)), int(r * 16), float(b), -1, cv2.LINE_AA, 4)
    bed += cv2.GaussianBlur(pebbles, (0, 0), 1.0)
    return np.clip(bed, 0.0, 1.0)


def padding(size: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    """Quilted tank padding: a grid of bright, shaded cushions with stitched seams, 0..1.

    Its bright cushion tops are what made the report's histogram-equalisation
    design light up.
    """
    width, height = size
    cell = rng.uniform(0.07, 0.11) * width
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    u = (xx + yy) / cell
    v = (xx - yy) / cell
    fu, fv = u - np.floor(u) - 0.5, v - np.floor(v) - 0.5
    cushion = np.cos(np.pi * fu) * np.cos(np.pi * fv)  # 1 at cushion centres, 0 at seams
    seams = np.exp(-(np.minimum(np.abs(np.abs(fu) - 0.5), np.abs(np.abs(fv) - 0.5)) * cell / 1.2) ** 2)
    fabric = fractal_noise(size, rng, octaves=4, base=32)
    pad = 0.35 + 0.6 * np.clip(cushion, 0.0, 1.0) ** 0.7 - 0.3 * seams + 0.12 * (fabric - 0.5)
    return np.clip(pad, 0.0, 1.0).astype(np.float32)


def gradient(size: tuple[int, int]) -> np.ndarray:
    """Open water: light scattered back by the water itself, brighter towards the top."""
    width, height = size
    ramp = np.linspace(1.0, 0.35, height, dtype=np.float32)[:, None]
    return np.repeat(ramp, width, axis=1)


def load_background(path: str | Path, size: tuple[int, int]) -> np.ndarray:
    """A user's image (or the first frame of a video), BGR float32 0..1 resized to ``size``."""
    path = Path(path)
    if not path.is_file():
        raise UsageError(f"--background {path}: no such file")
    from ..sources.base import quiet_opencv

    with quiet_opencv(errors=True):  # the one line below says what failed, without OpenCV's and FFmpeg's first
        image = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if image is None:
            cap = cv2.VideoCapture(str(path))
            ok, image = cap.read() if cap.isOpened() else (False, None)
            cap.release()
    if image is None:
        raise UsageError(f"--background {path}: not a readable image or video")
    image = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
    return image.astype(np.float32) / 255.0
