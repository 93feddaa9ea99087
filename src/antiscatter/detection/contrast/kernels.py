"""Structuring elements and filter kernels the stages share (uint8)."""

from __future__ import annotations

import functools

import cv2
import numpy as np

_K3 = np.ones((3, 3), np.uint8)
_K5 = np.ones((5, 5), np.uint8)
_AROUND = np.array([[1, 1, 1], [1, 0, 1], [1, 1, 1]], np.uint8)  # the 8 neighbours


@functools.lru_cache(maxsize=64)
def _disc(radius: int) -> np.ndarray:
    """(2 radius + 1, 2 radius + 1) uint8: a disc of ``radius`` pixels (OpenCV's ellipse element;
    made once per radius: read-only, shared)."""
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    disc.flags.writeable = False
    return disc
