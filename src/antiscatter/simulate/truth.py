"""Ground truth of one simulated frame."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["Truth", "KINDS", "TRUTH_COLUMNS"]

#: Particle kinds, indexed by the ``kinds`` array.
KINDS = ("bubble", "snow", "sand")

#: Columns of ``truth.csv``; the first five are the report's.
TRUTH_COLUMNS = ("Bubble ID", "Frame #", "X Position", "Y Position", "Radius",
                 "Depth (m)", "Kind", "Peak", "Visibility", "Label", "SNR")


@dataclass(frozen=True, eq=False)
class Truth:
    """Every particle in one frame, as parallel arrays.

    ids: (N,) int64 stable particle ids (>= 1); a respawned particle gets a new id.
    centres: (N, 2) float64, (x, y) in pixels at mid-exposure (sub-pixel).
    radii: (N,) float64, equivalent radius in pixels (sqrt(footprint area / pi)).
    visibility: (N,) float64, share of the footprint inside the frame and not
        hidden by a brighter particle, 0..1.
    depths: (N,) float64, distance from the camera in metres (NaN for 2-D presets).
    kinds: (N,) int8 index into :data:`KINDS`.
    peaks: (N,) float64, the particle's peak added brightness (grey levels, before clipping).
    labels: (N,) int32, the particle's value in this frame's label mask (0 = not visible).
    snr: (N,) float64, peak over the sensor noise at the particle (inf without noise);
        below about 3 a particle is lost in the noise.
    """

    ids: np.ndarray
    centres: np.ndarray
    radii: np.ndarray
    visibility: np.ndarray
    depths: np.ndarray = field(default=None)  # type: ignore[assignment]
    kinds: np.ndarray = field(default=None)  # type: ignore[assignment]
    peaks: np.ndarray = field(default=None)  # type: ignore[assignment]
    labels: np.ndarray = field(default=None)  # type: ignore[assignment]
    snr: np.ndarray = field(default=None)  # type: ignore[assignment]

    def __post_init__(self) -> None:
        n = len(self.ids)
        defaults = {"depths": np.full(n, np.nan), "kinds": np.zeros(n, np.int8),
                    "peaks": np.full(n, np.nan), "labels": np.arange(1, n + 1, dtype=np.int32),
                    "snr": np.full(n, np.inf)}
        for name, default in defaults.items():
            if getattr(self, name) is None:
                object.__setattr__(self, name, default)

    def __len__(self) -> int:
        return len(self.ids)

    def rows(self, frame: int) -> list[tuple]:
        """CSV rows in :data:`TRUTH_COLUMNS` order."""
        return [(int(i), frame, f"{x:.4f}", f"{y:.4f}", f"{r:.4f}",
                 "" if np.isnan(d) else f"{d:.4f}", KINDS[k], f"{p:.2f}", f"{v:.4f}", int(lab),
                 "inf" if np.isinf(q) else f"{q:.2f}")
                for i, (x, y), r, d, k, p, v, lab, q in zip(
                    self.ids.tolist(), self.centres.tolist(), self.radii.tolist(),
                    self.depths.tolist(), self.kinds.tolist(), self.peaks.tolist(),
                    self.visibility.tolist(), self.labels.tolist(), self.snr.tolist())]
