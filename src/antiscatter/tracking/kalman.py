"""A constant-velocity Kalman tracker, vectorised over all tracks in numpy.

State per track: x, y (px), vx, vy (px/s) and radius r (px).  Motion: constant
velocity with white acceleration noise; the radius is a random walk.
Association: gated, optimal one-to-one assignment on the distance between each
track's predicted centre and each detection (:func:`antiscatter.assignment.match`,
sparse, so hundreds of particles cost little), the gate being ``gate_sigma``
standard deviations of the track's predicted position, clipped to
[min_gate, max_gate] pixels.  A track is confirmed after ``confirm_hits`` hits;
a confirmed track that is missed coasts on its predicted path for up to
``max_misses`` frames (a particle that went dark under its own hole keeps its
hole), a tentative one is dropped at its first miss.  Ids are never reused.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..assignment import match
from ..detections import Detections

__all__ = ["Tracker", "Tracks"]

_H = np.array([[1, 0, 0, 0, 0], [0, 1, 0, 0, 0], [0, 0, 0, 0, 1]], dtype=np.float64)


@dataclass(frozen=True, eq=False)
class Tracks:
    """The tracks after one update, as parallel arrays.

    ids: (N,) int64; centres: (N, 2) px; velocities: (N, 2) px/s; radii: (N,) px;
    confirmed: (N,) bool; misses: (N,) int (0 = seen this frame); timestamp: s.
    detection_ids: (D,) int64, the track id given to each input detection.
    """

    ids: np.ndarray
    centres: np.ndarray
    velocities: np.ndarray
    radii: np.ndarray
    confirmed: np.ndarray
    misses: np.ndarray
    timestamp: float
    detection_ids: np.ndarray

    def __len__(self) -> int:
        return len(self.ids)


class Tracker:
    """Kalman tracker for particles (see the module docstring).

    Parameters
    ----------
    confirm_hits : hits before a track is confirmed (default 3).
    max_misses : frames a confirmed track coasts without a detection before deletion (default 5).
    gate_sigma : gate in standard deviations of the predicted position (default 4).
    min_gate, max_gate : gate limits in pixels (defaults 3 and 80).
    accel_noise : process noise, px/s^2 of white acceleration (default 3000).
    radius_noise : radius random walk, px/sqrt(s) (default 4).
    position_noise : detected centre noise, px (default 0.7).
    radius_measurement_noise : detected radius noise, px (default 1).
    initial_speed : prior speed spread of a new track, px/s (default 400).
    """

    def __init__(self, *, confirm_hits: int = 3, max_misses: int = 5, gate_sigma: float = 4.0,
                 min_gate: float = 3.0, max_gate: float = 80.0, accel_noise: float = 3000.0,
                 radius_noise: float = 4.0, position_noise: float = 0.7,
                 radius_measurement_noise: float = 1.0, initial_speed: float = 400.0) -> None:
        checks = {"confirm_hits": confirm_hits >= 1, "max_misses": max_misses >= 0,
                  "gate_sigma": gate_sigma > 0, "min_gate": min_gate > 0, "max_gate": max_gate >= min_gate,
                  "accel_noise": accel_noise >= 0, "radius_noise": radius_noise >= 0,
                  "position_noise": position_noise > 0, "radius_measurement_noise": radius_measurement_noise > 0,
                  "initial_speed": initial_speed >= 0}
        for name, ok in checks.items():
            if not ok:
                raise ValueError(f"{name}: got {locals()[name]!r}, out of range")
        self.confirm_hits = confirm_hits
        self.max_misses = max_misses
        self.gate_sigma = gate_sigma
        self.min_gate, self.max_gate = min_gate, max_gate
        self.accel_noise = accel_noise
        self.radius_noise = radius_noise
        self.measurement = np.diag([position_noise ** 2, position_noise ** 2, radius_measurement_noise ** 2])
        self.initial_speed = initial_speed
        self.x = np.empty((0, 5))
        self.P = np.empty((0, 5, 5))
        self.ids = np.empty(0, np.int64)
        self.hits = np.empty(0, np.int64)
        self.misses = np.empty(0, np.int64)
        self.timestamp: float | None = None
        self._next_id = 1

    # ------------------------------------------------------------- model
    def _transition(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        F = np.eye(5)
        F[0, 2] = F[1, 3] = dt
        q = self.accel_noise ** 2
        Q = np.zeros((5, 5))
        for p, v in ((0, 2), (1, 3)):
            Q[p, p] = q * dt ** 4 / 4
            Q[p, v] = Q[v, p] = q * dt ** 3 / 2
            Q[v, v] = q * dt ** 2
        Q[4, 4] = self.radius_noise ** 2 * dt
        return F, Q

    def _predict(self, dt: float) -> None:
        if dt <= 0 or len(self.x) == 0:
            return
        F, Q = self._transition(dt)
        self.x = self.x @ F.T
        self.P = F @ self.P @ F.T + Q

    # ------------------------------------------------------------ update
    def update(self, detections: Detections, timestamp: float) -> Tracks:
        """Advance to ``timestamp`` (seconds), associate ``detections``, return the tracks.

        Call every frame, with an empty Detections when nothing was found.
        """
        dt = 0.0 if self.timestamp is None else timestamp - self.timestamp
        if dt < 0:
            raise ValueError(f"timestamp: got {timestamp}, earlier than the last update {self.timestamp}")
        self._predict(dt)
        self.timestamp = timestamp
        n, d = len(self.x), len(detections)
        S_pos = self.P[:, :2, :2] + self.measurement[:2, :2]
        spread = np.sqrt(np.maximum(S_pos[:, 0, 0], S_pos[:, 1, 1])) if n else np.empty(0)
        gate = np.clip(self.gate_sigma * spread, self.min_gate, self.max_gate)
        matches, unmatched_tracks, unmatched_dets = match(self.x[:, :2], gate, detections.centres)
        detection_ids = np.full(d, -1, np.int64)
        if len(matches):
            t, k = matches[:, 0], matches[:, 1]
            z = np.column_stack([detections.centres[k], detections.radii[k]])
            P = self.P[t]
            S = _H @ P @ _H.T + self.measurement
            K = P @ _H.T @ np.linalg.inv(S)
            innovation = z - self.x[t] @ _H.T
            self.x[t] = self.x[t] + np.einsum("nij,nj->ni", K, innovation)
            self.P[t] = (np.eye(5) - K @ _H) @ P
            self.hits[t] += 1
            self.misses[t] = 0
            detection_ids[k] = self.ids[t]
        if len(unmatched_tracks):
            self.misses[unmatched_tracks] += 1
        # delete: tentative tracks at their first miss, confirmed ones after max_misses
        confirmed = self.hits >= self.confirm_hits
        keep = np.where(confirmed, self.misses <= self.max_misses, self.misses == 0)
        if not keep.all():
            self.x, self.P = self.x[keep], self.P[keep]
            self.ids, self.hits, self.misses = self.ids[keep], self.hits[keep], self.misses[keep]
        if len(unmatched_dets):
            k = unmatched_dets
            m = len(k)
            new_x = np.zeros((m, 5))
            new_x[:, :2] = detections.centres[k]
            new_x[:, 4] = detections.radii[k]
            new_P = np.zeros((m, 5, 5))
            new_P[:, 0, 0] = new_P[:, 1, 1] = self.measurement[0, 0]
            new_P[:, 2, 2] = new_P[:, 3, 3] = self.initial_speed ** 2
            new_P[:, 4, 4] = self.measurement[2, 2]
            new_ids = np.arange(self._next_id, self._next_id + m, dtype=np.int64)
            self._next_id += m
            self.x = np.concatenate([self.x, new_x])
            self.P = np.concatenate([self.P, new_P])
            self.ids = np.concatenate([self.ids, new_ids])
            self.hits = np.concatenate([self.hits, np.ones(m, np.int64)])
            self.misses = np.concatenate([self.misses, np.zeros(m, np.int64)])
            detection_ids[k] = new_ids
        return Tracks(self.ids.copy(), self.x[:, :2].copy(), self.x[:, 2:4].copy(), self.x[:, 4].copy(),
                      self.hits >= self.confirm_hits, self.misses.copy(), timestamp, detection_ids)

    # ------------------------------------------------------------- holes
    def holes(self, at: float, *, uncertainty_sigma: float = 2.0, max_growth: float = 6.0) -> Detections:
        """Where every particle will be at time ``at`` (seconds): the holes to draw.

        Confirmed tracks (also while coasting) are moved along their velocity;
        each radius grows by ``uncertainty_sigma`` standard deviations of the
        predicted position, at most ``max_growth`` pixels.  Tracks not yet
        confirmed -- new particles -- get a hole where they were seen.
        """
        n = len(self.x)
        if n == 0 or self.timestamp is None:
            return Detections.empty()
        dt = max(0.0, at - self.timestamp)
        confirmed = self.hits >= self.confirm_hits
        centres = self.x[:, :2] + np.where(confirmed[:, None], self.x[:, 2:4] * dt, 0.0)
        F, Q = self._transition(dt)
        P = F @ self.P @ F.T + Q if dt > 0 else self.P
        sd = np.sqrt(np.maximum(P[:, 0, 0], P[:, 1, 1]))
        growth = np.minimum(uncertainty_sigma * sd, max_growth)
        radii = np.maximum(self.x[:, 4], 0.5) + np.where(confirmed, growth, 0.0)
        return Detections(centres, radii, track_ids=self.ids.copy())
