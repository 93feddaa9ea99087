"""Ground truth of one simulated frame."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Truth"]


@dataclass(frozen=True, eq=False)
class Truth:
    """Every particle in one frame, as parallel arrays.

    ids: (N,) int64 stable particle ids (>= 1).
    centres: (N, 2) float64, (x, y) in pixels.
    radii: (N,) float64, pixels.
    visibility: (N,) float64, share of the particle's disc inside the frame, 0..1.
    """

    ids: np.ndarray
    centres: np.ndarray
    radii: np.ndarray
    visibility: np.ndarray

    def __len__(self) -> int:
        return len(self.ids)
