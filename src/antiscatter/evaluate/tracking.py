"""Tracking metrics against the simulator's particle ids, and prediction error.

Per frame, counted truth is matched to tracked detections exactly as for
detection scores (gated optimal assignment).  From those matches:

* MOTA = 1 - (misses + false positives + identity switches) / counted truth;
* identity switches: a particle matched to a different track id than the last time it was matched;
* fragmentations: a particle's tracking interrupted (matched, unmatched, matched again);
* IDF1 = 2 IDTP / (counted truth + tracked detections), IDTP from the best
  one-to-one pairing of particle ids with track ids over the whole sequence
  (Ristani et al. 2016), pairs counting in frames where they were matched.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from ..assignment import gates, match

__all__ = ["TrackingScore", "tracking_summary", "PredictionError", "isolated"]


def isolated(centres: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """(N,) bool: particles whose footprint touches no other's (centre distance to every other
    particle above the sum of the two radii), pixels."""
    n = len(centres)
    if n < 2:
        return np.ones(n, bool)
    from scipy.spatial import cKDTree

    centres, radii = np.asarray(centres, np.float64), np.asarray(radii, np.float64)
    # every pair within twice the largest radius, then the touching ones among them, at once
    # (a loop over the pairs took 7.9 ms a frame of the dense scene's 1350 particles; 0.6 now)
    pairs = cKDTree(centres).query_pairs(float(2 * np.max(radii)), output_type="ndarray")
    i, j = pairs[:, 0], pairs[:, 1]
    touch = np.hypot(*(centres[i] - centres[j]).T) <= radii[i] + radii[j]
    alone = np.ones(n, bool)
    alone[i[touch]] = False
    alone[j[touch]] = False
    return alone


@dataclass
class TrackingScore:
    """Accumulates tracking figures frame by frame; ``summary()`` gives the totals."""

    min_gate: float = 2.0
    gate_scale: float = 1.0
    gt: int = 0
    fp: int = 0
    fn: int = 0
    switches: int = 0
    fragmentations: int = 0
    predicted: int = 0
    pairs: dict = field(default_factory=dict)
    _last_track: dict = field(default_factory=dict)
    _tracked_now: dict = field(default_factory=dict)

    def add(self, truth_ids: np.ndarray, truth_centres: np.ndarray, truth_radii: np.ndarray,
            counted: np.ndarray, det_centres: np.ndarray, det_track_ids: np.ndarray) -> None:
        """One frame: truth (ids, centres, radii, counted) and detections with their track ids."""
        counted = np.asarray(counted, bool)
        m, unmatched_truth, unmatched_dets = match(truth_centres, gates(truth_radii, min_gate=self.min_gate,
                                                                        scale=self.gate_scale), det_centres)
        keep = counted[m[:, 0]] if len(m) else np.empty(0, bool)
        good = m[keep]
        ignored = len(m) - len(good)  # detections on uncounted truth: neither
        self.gt += int(counted.sum())
        self.fn += int(counted[unmatched_truth].sum()) if len(unmatched_truth) else 0
        self.fp += len(unmatched_dets)
        self.predicted += len(det_centres) - ignored
        seen = set()
        for t, d in good.tolist():
            tid, kid = int(truth_ids[t]), int(det_track_ids[d])
            seen.add(tid)
            self.pairs[(tid, kid)] = self.pairs.get((tid, kid), 0) + 1
            last = self._last_track.get(tid)
            if last is not None and last != kid:
                self.switches += 1
            if tid in self._tracked_now and not self._tracked_now[tid]:
                self.fragmentations += 1
            self._last_track[tid] = kid
            self._tracked_now[tid] = True
        for t in np.flatnonzero(counted).tolist():
            tid = int(truth_ids[t])
            if tid not in seen and tid in self._tracked_now:
                self._tracked_now[tid] = False

    def summary(self) -> dict[str, float]:
        mota = 1.0 - (self.fn + self.fp + self.switches) / self.gt if self.gt else float("nan")
        idtp = 0
        if self.pairs:
            truth_ids = sorted({t for t, _ in self.pairs})
            track_ids = sorted({k for _, k in self.pairs})
            ti = {t: i for i, t in enumerate(truth_ids)}
            ki = {k: i for i, k in enumerate(track_ids)}
            weight = np.zeros((len(truth_ids), len(track_ids)))
            for (t, k), n in self.pairs.items():
                weight[ti[t], ki[k]] = n
            a, b = linear_sum_assignment(weight, maximize=True)
            idtp = int(weight[a, b].sum())
        denominator = self.gt + self.predicted
        return {"mota": mota, "idf1": 2 * idtp / denominator if denominator else float("nan"),
                "id_switches": self.switches, "fragmentations": self.fragmentations, "idtp": idtp,
                "tracked_truth": self.gt, "tracked_detections": self.predicted}


def tracking_summary(frames) -> dict[str, float]:
    """Tracking figures over an iterable of per-frame tuples for :meth:`TrackingScore.add`."""
    score = TrackingScore()
    for item in frames:
        score.add(*item)
    return score.summary()


@dataclass
class PredictionError:
    """Distance between where a confirmed track predicted its particle k frames ahead and where it was."""

    horizons: tuple[int, ...] = (1, 2, 3)
    errors: dict = field(default_factory=dict)
    _pending: list = field(default_factory=list)

    def add(self, frame: int, truth_ids: np.ndarray, truth_centres: np.ndarray,
            predictions: dict[int, list[tuple[int, np.ndarray]]]) -> None:
        """frame's truth, and predictions {truth id: [(k, predicted centre at frame + k)]} made at this frame."""
        by_id = {int(i): c for i, c in zip(truth_ids.tolist(), np.asarray(truth_centres))}
        still = []
        for due, tid, k, centre in self._pending:
            if due == frame:
                if tid in by_id:
                    self.errors.setdefault(k, []).append(float(np.hypot(*(by_id[tid] - centre))))
            elif due > frame:
                still.append((due, tid, k, centre))
        self._pending = still
        for tid, items in predictions.items():
            for k, centre in items:
                self._pending.append((frame + k, tid, k, centre))

    def summary(self) -> dict[str, dict[str, float]]:
        out = {}
        for k in self.horizons:
            e = np.asarray(self.errors.get(k, []))
            out[f"+{k}"] = {"mean_px": float(e.mean()) if len(e) else float("nan"),
                            "p95_px": float(np.percentile(e, 95)) if len(e) else float("nan"), "count": len(e)}
        return out
