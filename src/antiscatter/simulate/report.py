"""The 2024 report's bubble simulator (preset ``seed``), reproduced exactly.

Model (SPEC section 1), per particle: spawn at a uniform random x on the bottom
edge (y = height), integer radius uniform in 2..6, target velocity vx uniform in
-50..50 px/s and vy uniform in 50..200 px/s (upwards), current velocity = target.
Each frame (dt = 1/60 s), in this order:

1. with probability 0.01, every particle draws new target velocities;
2. ``x += vx * dt``, ``y -= vy * dt``;
3. ``vx += 0.1 * (target_vx - vx)``, ``vy += 0.1 * (target_vy - vy)``;
4. ``radius += 0.05 * (height - y) / height`` (bubbles grow as they rise);
5. particles with ``y <= -radius`` are removed;
6. new particles spawn so that 300 are alive.

Frame 0 is the state right after the first 300 spawn.  Random numbers are drawn
in this order from the given generator: the 0.01 coin, then (if it fires) the
new targets vx for all, then vy for all; spawning draws x, radius, vx, vy (each
an array over the new particles).  Particles are drawn as filled white circles
on black with sub-pixel centres and radii.
"""

from __future__ import annotations

import cv2
import numpy as np

from .truth import Truth

__all__ = ["ReportBubbles"]

_SHIFT = 4  # sub-pixel bits for cv2.circle
_ONE = 1 << _SHIFT


class ReportBubbles:
    """The report's white bubbles on black.

    Parameters
    ----------
    size : (width, height) in pixels, default (800, 600).
    rng : numpy Generator, the only source of randomness.
    fps : frame rate of the time step, default 60.
    count : particles kept alive, default 300.
    """

    def __init__(self, *, size: tuple[int, int] = (800, 600), rng: np.random.Generator,
                 fps: float = 60.0, count: int = 300) -> None:
        self.size = (int(size[0]), int(size[1]))
        self.fps = float(fps)
        self.count = int(count)
        self._rng = rng
        self._next_id = 1
        empty = np.empty(0)
        self.ids = np.empty(0, dtype=np.int64)
        self.x = self.y = self.vx = self.vy = self.tvx = self.tvy = self.r = empty
        self._spawn(self.count)

    def _spawn(self, k: int) -> None:
        if k <= 0:
            return
        width, height = self.size
        rng = self._rng
        x = rng.uniform(0.0, width, k)
        r = rng.integers(2, 7, k).astype(np.float64)
        tvx = rng.uniform(-50.0, 50.0, k)
        tvy = rng.uniform(50.0, 200.0, k)
        ids = np.arange(self._next_id, self._next_id + k, dtype=np.int64)
        self._next_id += k
        self.ids = np.concatenate([self.ids, ids])
        self.x = np.concatenate([self.x, x])
        self.y = np.concatenate([self.y, np.full(k, float(height))])
        self.r = np.concatenate([self.r, r])
        self.tvx = np.concatenate([self.tvx, tvx])
        self.tvy = np.concatenate([self.tvy, tvy])
        self.vx = np.concatenate([self.vx, tvx])
        self.vy = np.concatenate([self.vy, tvy])

    def step(self) -> None:
        """Advance one frame period (see the module docstring for the order)."""
        dt = 1.0 / self.fps
        height = self.size[1]
        n = len(self.ids)
        if self._rng.random() < 0.01:
            self.tvx = self._rng.uniform(-50.0, 50.0, n)
            self.tvy = self._rng.uniform(50.0, 200.0, n)
        self.x = self.x + self.vx * dt
        self.y = self.y - self.vy * dt
        self.vx = self.vx + 0.1 * (self.tvx - self.vx)
        self.vy = self.vy + 0.1 * (self.tvy - self.vy)
        self.r = self.r + 0.05 * (height - self.y) / height
        keep = self.y > -self.r
        if not keep.all():
            for name in ("ids", "x", "y", "vx", "vy", "tvx", "tvy", "r"):
                setattr(self, name, getattr(self, name)[keep])
        self._spawn(self.count - len(self.ids))

    def render(self, labels: np.ndarray | None = None) -> np.ndarray:
        """The frame: (H, W, 3) uint8, white filled circles on black.

        labels: optional (H, W) uint16 buffer filled with each particle's mask
            label (its row number in :meth:`truth` + 1; a later particle covers
            an earlier one where they overlap), 0 elsewhere.
        """
        width, height = self.size
        out = np.zeros((height, width, 3), np.uint8)
        cx = np.rint(self.x * _ONE).astype(np.int64).tolist()
        cy = np.rint(self.y * _ONE).astype(np.int64).tolist()
        cr = np.rint(self.r * _ONE).astype(np.int64).tolist()
        circle, white, line = cv2.circle, (255, 255, 255), cv2.LINE_8
        for x, y, r in zip(cx, cy, cr):
            circle(out, (x, y), r, white, -1, line, _SHIFT)
        if labels is not None:
            labels.fill(0)
            for label, (x, y, r) in enumerate(zip(cx, cy, cr), start=1):
                circle(labels, (x, y), r, label, -1, line, _SHIFT)
        return out

    def truth(self) -> Truth:
        """Ids, centres, radii and the share of each disc inside the frame."""
        n = len(self.ids)
        return Truth(self.ids.copy(), np.column_stack([self.x, self.y]), self.r.copy(),
                     disc_visibility(self.x, self.y, self.r, self.size),
                     peaks=np.full(n, 255.0))


def disc_visibility(x: np.ndarray, y: np.ndarray, r: np.ndarray,
                    size: tuple[int, int]) -> np.ndarray:
    """Approximate share of each disc's area inside the frame, 0..1.

    Uses the product of the visible fractions along x and y of the disc's
    circular-segment areas, exact for a disc cut by one edge.
    """

    def segment_inside(c: np.ndarray, lo: float, hi: float) -> np.ndarray:
        # fraction of a disc's area with coordinate in [lo, hi] along one axis
        def below(t: np.ndarray) -> np.ndarray:  # share of area with coordinate <= c + t*r
            t = np.clip(t, -1.0, 1.0)
            return (np.arcsin(t) + t * np.sqrt(1.0 - t * t)) / np.pi + 0.5
        safe = np.maximum(r, 1e-9)
        return np.clip(below((hi - c) / safe) - below((lo - c) / safe), 0.0, 1.0)

    width, height = size
    return segment_inside(x, 0.0, float(width)) * segment_inside(y, 0.0, float(height))
