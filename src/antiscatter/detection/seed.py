"""The 2024 report's final pipeline, reproduced exactly (detector ``seed``).

greyscale -> Gaussian blur 5x5 -> binary threshold at 200 -> zero-parameter
Canny (thresholds from the median) -> external contours -> minimum enclosing
circle per contour.  ``equalise=True`` swaps the threshold for histogram
equalisation, the report's first design.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import cv2
import numpy as np

from ..detections import Detections
from . import Detector, Stage, register_detector

__all__ = ["SeedParams", "to_grey", "blur", "threshold", "equalise", "canny_auto",
           "find_contours", "enclosing_circles", "build_seed"]


@dataclass(frozen=True)
class SeedParams:
    """Settings of the ``seed`` detector.

    threshold: binary threshold level, 0..255 (report: 200).
    blur_kernel: Gaussian kernel size in pixels, odd, >= 1 (report: 5; sigma from the kernel).
    canny_sigma: s in lower = (1 - s) * median, upper = (1 + s) * median, 0..1 (report: 0).
    equalise: histogram equalisation instead of the threshold (the report's first design).
    """

    threshold: int = 200
    blur_kernel: int = 5
    canny_sigma: float = 0.0
    equalise: bool = False

    def __post_init__(self) -> None:
        if not 0 <= self.threshold <= 255:
            raise ValueError(f"threshold: got {self.threshold}, allowed 0..255")
        if self.blur_kernel < 1 or self.blur_kernel % 2 == 0:
            raise ValueError(f"blur_kernel: got {self.blur_kernel}, allowed an odd integer >= 1")
        if not 0.0 <= self.canny_sigma <= 1.0:
            raise ValueError(f"canny_sigma: got {self.canny_sigma}, allowed 0..1")


def to_grey(image: np.ndarray) -> np.ndarray:
    """(H, W, 3) BGR or (H, W, 4) BGRA -> (H, W) grey; a grey image passes through."""
    if image.ndim == 2:
        return image
    if image.shape[2] == 4:
        return cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY)
    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)


def blur(grey: np.ndarray, *, kernel: int = 5) -> np.ndarray:
    """Gaussian blur with a ``kernel`` x ``kernel`` window, sigma derived from the size."""
    return cv2.GaussianBlur(grey, (kernel, kernel), 0)


def threshold(grey: np.ndarray, *, level: int = 200) -> np.ndarray:
    """Binary image: 255 where ``grey > level``, else 0."""
    return cv2.threshold(grey, level, 255, cv2.THRESH_BINARY)[1]


def equalise(grey: np.ndarray) -> np.ndarray:
    """Global histogram equalisation (the report's first design)."""
    return cv2.equalizeHist(grey)


def canny_auto(image: np.ndarray, *, sigma: float = 0.0) -> np.ndarray:
    """Canny with "zero-parameter" thresholds from the image median.

    lower = max(0, (1 - sigma) * median), upper = min(255, (1 + sigma) * median).
    """
    median = float(np.median(image))
    lower = int(max(0.0, (1.0 - sigma) * median))
    upper = int(min(255.0, (1.0 + sigma) * median))
    return cv2.Canny(image, lower, upper)


def find_contours(edges: np.ndarray) -> Sequence[np.ndarray]:
    """External contours (RETR_EXTERNAL, CHAIN_APPROX_SIMPLE) of a binary edge image."""
    return cv2.findContours(edges, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)[0]


def enclosing_circles(contours: Sequence[np.ndarray]) -> Detections:
    """Minimum enclosing circle of each contour -> Detections (centres, radii in pixels)."""
    n = len(contours)
    if n == 0:
        return Detections.empty()
    centres = np.empty((n, 2))
    radii = np.empty(n)
    for i, contour in enumerate(contours):
        (x, y), r = cv2.minEnclosingCircle(contour)
        centres[i] = x, y
        radii[i] = r
    return Detections(centres, radii)


def build_seed(params: SeedParams) -> Detector:
    """The report's chain as timed stages."""
    k, level, sigma = params.blur_kernel, params.threshold, params.canny_sigma
    stages = [
        Stage("greyscale", "Greyscale Conversion", to_grey),
        Stage("blur", "Gaussian Blur", lambda g: blur(g, kernel=k)),
    ]
    if params.equalise:
        stages.append(Stage("equalise", "Histogram Equalisation", equalise))
    else:
        stages.append(Stage("threshold", "Binary Thresholding", lambda g: threshold(g, level=level)))
    stages += [
        Stage("canny", "Canny Algorithm", lambda b: canny_auto(b, sigma=sigma)),
        Stage("contours", "CV2 findContours()", find_contours),
        Stage("circles", "CV2 minEnclosingCircle()", enclosing_circles),
    ]
    return Detector("seed", tuple(stages), params)


register_detector("seed", SeedParams, build_seed,
                  "the 2024 report's pipeline: blur, threshold 200, Canny, contours, enclosing circles",
                  sweep=("threshold", (20, 40, 60, 80, 100, 120, 140, 160, 180, 200, 220, 240)))
