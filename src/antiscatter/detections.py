"""The one record that flows detect -> track -> pattern -> evaluate."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["Detections", "rows_in"]


def rows_in(ordered: np.ndarray, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(at, found): where each of ``ids`` (track ids) is in the ascending ``ordered`` (valid where found)."""
    if len(ordered) == 0:
        return np.zeros(len(ids), np.intp), np.zeros(len(ids), bool)
    at = np.minimum(np.searchsorted(ordered, ids), len(ordered) - 1)
    return at, ordered[at] == ids


@dataclass(frozen=True, eq=False)
class Detections:
    """Particles found in one frame, as parallel arrays.

    Parameters
    ----------
    centres : (N, 2) float64 array
        Particle centres ``(x, y)`` in image pixels (x to the right, y down).
    radii : (N,) float64 array
        Radius of the disc that covers each particle, in pixels.
    scores : (N,) float64 array, optional
        Detector confidence or contrast; NaN where the detector has none.
    track_ids : (N,) int64 array, optional
        Track identity, -1 where untracked.
    cut : int, optional
        Candidates the detector's bound on its work per frame left out of this frame: particles
        beyond its ceiling, clusters measured whole instead of split (0: nothing cut).

    Zero particles is length-0 arrays of the same shapes, never ``None``.
    """

    centres: np.ndarray
    radii: np.ndarray
    scores: np.ndarray = field(default=None)  # type: ignore[assignment]
    track_ids: np.ndarray = field(default=None)  # type: ignore[assignment]
    cut: int = 0

    def __post_init__(self) -> None:
        centres = np.asarray(self.centres, dtype=np.float64).reshape(-1, 2)
        radii = np.asarray(self.radii, dtype=np.float64).reshape(-1)
        n = len(centres)
        if len(radii) != n:
            raise ValueError(f"radii: expected {n} values to match centres, got {len(radii)}")
        scores = (np.full(n, np.nan) if self.scores is None
                  else np.asarray(self.scores, dtype=np.float64).reshape(-1))
        track_ids = (np.full(n, -1, dtype=np.int64) if self.track_ids is None
                     else np.asarray(self.track_ids, dtype=np.int64).reshape(-1))
        if len(scores) != n:
            raise ValueError(f"scores: expected {n} values to match centres, got {len(scores)}")
        if len(track_ids) != n:
            raise ValueError(f"track_ids: expected {n} values to match centres, got {len(track_ids)}")
        object.__setattr__(self, "centres", centres)
        object.__setattr__(self, "radii", radii)
        object.__setattr__(self, "scores", scores)
        object.__setattr__(self, "track_ids", track_ids)

    @classmethod
    def empty(cls) -> "Detections":
        """No particles: arrays of shape (0, 2) and (0,)."""
        return cls(np.empty((0, 2)), np.empty(0))

    def __len__(self) -> int:
        return len(self.radii)

    def __getitem__(self, index) -> "Detections":
        """Select particles by boolean mask, index array or slice."""
        return Detections(self.centres[index], self.radii[index],
                          self.scores[index], self.track_ids[index], self.cut)
