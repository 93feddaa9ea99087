"""Scores: particle-level precision, recall, F1 and errors; pixel-level cancellation and light kept."""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from ..assignment import gates, match

__all__ = ["FrameScore", "score_frame", "hole_mask", "summarise", "prf"]


@dataclass
class FrameScore:
    """One frame's counts and errors.

    tp, fp, fn: matched, spurious and missed particles (truth that is not counted
        -- hidden, mostly outside the frame, or lost in the noise -- is neither).
    centre_errors: (tp,) distances in pixels; radius_errors: (tp,) detected minus true radius.
    particle_px, covered_px: counted particle pixels, and those inside a hole (-1 without masks).
    background_px, lit_px: non-particle pixels, and those left lit (-1 without masks).
    """

    frame: int
    tp: int = 0
    fp: int = 0
    fn: int = 0
    centre_errors: np.ndarray = field(default_factory=lambda: np.empty(0))
    radius_errors: np.ndarray = field(default_factory=lambda: np.empty(0))
    particle_px: int = -1
    covered_px: int = -1
    background_px: int = -1
    lit_px: int = -1

    def row(self) -> dict[str, float]:
        p, r, f = prf(self.tp, self.fp, self.fn)
        out = {"frame": self.frame, "tp": self.tp, "fp": self.fp, "fn": self.fn,
               "precision": p, "recall": r, "f1": f,
               "centre_error_mean": float(self.centre_errors.mean()) if self.tp else float("nan")}
        if self.particle_px >= 0:
            out["cancellation"] = self.covered_px / self.particle_px if self.particle_px else 1.0
            out["light_kept"] = self.lit_px / self.background_px if self.background_px else 1.0
        return out


def prf(tp: int, fp: int, fn: int) -> tuple[float, float, float]:
    """Precision, recall, F1; an empty side counts as perfect (no false claims, nothing to find)."""
    precision = tp / (tp + fp) if tp + fp else 1.0
    recall = tp / (tp + fn) if tp + fn else 1.0
    f1 = 2 * precision * recall / (precision + recall) if precision + recall else 0.0
    return precision, recall, f1


def hole_mask(shape: tuple[int, int], centres: np.ndarray, radii: np.ndarray, *,
              margin: float = 0.0) -> np.ndarray:
    """(H, W) bool: pixels inside any detection's disc (radius + margin), as the pattern draws it."""
    mask = np.zeros(shape, np.uint8)
    for (x, y), r in zip(np.asarray(centres).tolist(), np.asarray(radii).tolist()):
        rr = max(r + margin, 0.0)
        if abs(x) < 1e7 and abs(y) < 1e7 and rr < 1e7:
            cv2.circle(mask, (round(x * 16), round(y * 16)), round(rr * 16), 1, -1, cv2.LINE_8, 4)
    return mask.astype(bool)


def score_frame(frame: int, truth_centres: np.ndarray, truth_radii: np.ndarray, counted: np.ndarray,
                det_centres: np.ndarray, det_radii: np.ndarray, *, min_gate: float = 2.0,
                gate_scale: float = 1.0, particle_mask: np.ndarray | None = None,
                ignore_mask: np.ndarray | None = None, margin: float = 0.0) -> FrameScore:
    """Match one frame and score it.

    counted: (T,) bool, truth that must be found; matches to uncounted truth are ignored.
    particle_mask: (H, W) bool of counted particle pixels, for pixel metrics.
    ignore_mask: (H, W) bool of pixels that are neither particle nor background
        (uncounted particles); margin: pixels added to each hole's radius.
    """
    counted = np.asarray(counted, dtype=bool)
    matches, unmatched_truth, unmatched_dets = match(truth_centres, gates(truth_radii, min_gate=min_gate,
                                                                          scale=gate_scale), det_centres)
    keep = counted[matches[:, 0]] if len(matches) else np.empty(0, bool)
    good = matches[keep]
    score = FrameScore(frame, tp=len(good), fp=len(unmatched_dets),
                       fn=int(counted[unmatched_truth].sum()) if len(unmatched_truth) else 0)
    if len(good):
        t, d = good[:, 0], good[:, 1]
        tc, dc = np.asarray(truth_centres)[t], np.asarray(det_centres)[d]
        score.centre_errors = np.hypot(tc[:, 0] - dc[:, 0], tc[:, 1] - dc[:, 1])
        score.radius_errors = np.asarray(det_radii)[d] - np.asarray(truth_radii)[t]
    if particle_mask is not None:
        holes = hole_mask(particle_mask.shape, det_centres, det_radii, margin=margin)
        background = ~particle_mask if ignore_mask is None else ~(particle_mask | ignore_mask)
        score.particle_px = int(particle_mask.sum())
        score.covered_px = int((particle_mask & holes).sum())
        score.background_px = int(background.sum())
        score.lit_px = int((background & ~holes).sum())
    return score


def summarise(scores: list[FrameScore]) -> dict[str, float]:
    """Overall figures over frames: counts pooled, errors over all matched pairs."""
    tp = sum(s.tp for s in scores)
    fp = sum(s.fp for s in scores)
    fn = sum(s.fn for s in scores)
    precision, recall, f1 = prf(tp, fp, fn)
    centre = np.concatenate([s.centre_errors for s in scores]) if scores else np.empty(0)
    radius = np.concatenate([s.radius_errors for s in scores]) if scores else np.empty(0)
    out = {"frames": len(scores), "truth": tp + fn, "detections": tp + fp, "tp": tp, "fp": fp, "fn": fn,
           "precision": precision, "recall": recall, "f1": f1,
           "centre_error_mean": float(centre.mean()) if len(centre) else float("nan"),
           "centre_error_p95": float(np.percentile(centre, 95)) if len(centre) else float("nan"),
           "radius_error_mean_abs": float(np.abs(radius).mean()) if len(radius) else float("nan"),
           "radius_bias": float(radius.mean()) if len(radius) else float("nan")}
    with_masks = [s for s in scores if s.particle_px >= 0]
    if with_masks:
        particle = sum(s.particle_px for s in with_masks)
        background = sum(s.background_px for s in with_masks)
        out["cancellation"] = sum(s.covered_px for s in with_masks) / particle if particle else 1.0
        out["light_kept"] = sum(s.lit_px for s in with_masks) / background if background else 1.0
    return out
