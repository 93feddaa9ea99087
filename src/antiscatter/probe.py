"""Per-particle depth along the epipolar line, found by the light itself.

With the projector beside the camera (the housing's 12 cm), a particle seen at
camera pixel p may be anywhere on a segment of projector pixels: from where a
point at the far working distance would be lit to where a point at the near one
would be (hundreds of pixels).  Nothing in one image tells where on it -- but
the camera sees each particle under the light the pattern gives it.  With dim
holes (the ``dim`` strategy) a particle under its hole still shows, at
``dim_level`` of its brightness: so each frame the pattern can cover only part
of a particle's remaining segment and the next exposure says whether that part
held it (the particle dimmed, or vanished) or not (it stayed as bright as when
lit).  Bisection over a few frames pins the hole to the particle's depth; a
hole that stops working (the particle is lit again, twice in a row) reopens
the search.  A particle that came back dimmed may also have passed under another
track's hole or probe: each verdict is read against the pattern the exposure was
actually taken under, along the particle's whole line (:meth:`DepthProbe._widen`).
A new particle's search starts from the depths at which earlier
particles of its brightness settled (the lamp's inverse-square fall-off,
learnt as the dive goes: :meth:`DepthProbe.prior`).
With pulsed holes (the ``pulse`` strategy) the camera only looks during one
refresh: the probe's half is shown, lifted to the dim level, then, and the
whole remaining interval (:meth:`DepthProbe.covers`) is dark the rest of the
time, so a particle in the half not probed is not fully lit meanwhile.  A hole
is drawn only where the backscatter it withholds is worth the scene light it
takes (:attr:`DepthProbe.min_worth`): a faint particle whose depth is still
unknown would darken hundreds of pixels of line for little.

Depth is kept as inverse depth w = 1/Z in [1/far, 1/near]: for a
camera-projector pair the mapping of a plane at depth Z is linear in 1/Z, so
the projector position of p moves along a straight line as w grows.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Callable

import cv2
import numpy as np

from .detections import Detections, rows_in as _rows_in
from .pattern import blank_pattern, map_to_projector

__all__ = ["DepthProbe", "Intervals"]

_LO, _HI, _LIT, _HELD, _MISSED, _RESTARTED = range(6)  # columns of DepthProbe's track state
#: the least worth of a drawn hole (:attr:`DepthProbe.min_worth`)
MIN_WORTH = 0.2


class Intervals(Mapping):
    """Inverse-depth intervals of tracks, as arrays: ``ids`` (N,) int64 and ``lo``, ``hi`` (N,)
    float64; read as a mapping too (track id -> (lo, hi)).  What :meth:`DepthProbe.probes` and
    :meth:`DepthProbe.intervals` return and what :meth:`DepthProbe.observe` and
    :meth:`DepthProbe.render` take (a plain dict is converted)."""

    __slots__ = ("ids", "lo", "hi", "_order")

    def __init__(self, ids: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> None:
        self.ids = np.asarray(ids, np.int64).reshape(-1)
        self.lo = np.asarray(lo, np.float64).reshape(-1)
        self.hi = np.asarray(hi, np.float64).reshape(-1)
        self._order: np.ndarray | None = None

    @classmethod
    def of(cls, intervals: Mapping[int, tuple[float, float]]) -> "Intervals":
        if isinstance(intervals, Intervals):
            return intervals
        ids = list(intervals)
        spans = np.array([intervals[i] for i in ids], np.float64).reshape(-1, 2)
        return cls(np.array(ids, np.int64), spans[:, 0], spans[:, 1])

    def find(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(rows, found): the row of each of ``ids`` (valid where found)."""
        ids = np.asarray(ids, np.int64)
        if len(self.ids) == 0:
            return _rows_in(self.ids, ids)
        if self._order is None:
            self._order = np.argsort(self.ids, kind="stable")
        at, found = _rows_in(self.ids[self._order], ids)
        return self._order[at], found

    def spans(self, ids: np.ndarray, lo: float, hi: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(lo, hi, given) for each of ``ids``: its interval, or (lo, hi) where it has none."""
        rows, given = self.find(ids)
        if len(self.ids) == 0:
            return np.full(len(rows), lo), np.full(len(rows), hi), given
        return np.where(given, self.lo[rows], lo), np.where(given, self.hi[rows], hi), given

    def __getitem__(self, tid: int) -> tuple[float, float]:
        rows, found = self.find(np.array([tid]))
        if not found[0]:
            raise KeyError(tid)
        return float(self.lo[rows[0]]), float(self.hi[rows[0]])

    def __iter__(self) -> Iterator[int]:
        return iter(self.ids.tolist())

    def __len__(self) -> int:
        return len(self.ids)


@dataclass
class DepthProbe:
    """Bisection of each track's depth interval, judged by the next exposure.

    mapping_at: camera-to-projector homography of a plane at a depth in metres
        (a calibration's ``mapping_at``, or the twin's exact one).
    near_m, far_m: working distances.
    dim_level: light left in holes (0..1); a probed particle counts as hit when it
        comes back dimmer than (1 + dim_level) / 2 of its lit brightness -- what it
        gets with half of it under the probe, so it is judged under the probe when
        most of it is -- or not at all (the geometric middle, sqrt(dim_level), kept
        restarting the bisection of big near particles; history:
        docs/decisions/005-light-and-pattern-tuning.md).
    settle_px: stop halving once the interval spans this many projector pixels
        (about a hole's diameter).
    prior_samples: a new particle's search starts from the inverse depths that particles of its
        brightness were found at.  The lamp's light falls off with the square of the distance,
        so brightness says much about depth; how much -- albedos, sizes, defocus, the lamp, the
        camera's gain, the water -- is learnt from the probe's own results: a line (of the
        brightness law's slope, ``SLOPE``, until ``FIT_SLOPE`` tracks have settled, then fitted)
        through (log brightness, log inverse depth) of the last ``prior_samples`` tracks whose settled
        hole was seen to dim them ``HELD`` exposures in a row, widened to the central
        ``prior_coverage`` of the residuals plus a quarter each side.  The whole range before
        ``MIN_PRIOR`` such tracks, with ``prior_samples=0``, and for a track whose search
        already started again once.  Default 400: whole-range searches cost most of the light
        the pattern withholds from the scene.  Off sunlit or very clear water, where brightness
        says little about the distance to the lamp, the residuals are wide and so is the prior.
        History: docs/decisions/005-light-and-pattern-tuning.md.
    prior_coverage: share of the residuals the prior's interval covers (default 0.8).
    projector_size: (width, height) of the projector, for ``min_worth``; None: every hole drawn.
    min_worth: a hole is drawn only where it is worth its light: the share of the frame's
        backscatter it withholds (its particle's brightness when lit over that of all the holes'
        particles) at least ``min_worth`` times the share of the projector's field it darkens
        (its segment's area).  The two headline figures -- backscatter removed, scene light kept
        -- are such shares, so at 1 a hole stays when it removes at least as much of the one as
        it costs of the other.  Only segments long against their particle's worth fail: a faint
        far particle whose depth is still unknown (hundreds of pixels of line for a grain), or in
        a dense cloud, where each particle's share is small; a co-located or settled hole is a
        disc a few pixels across and always stays.  A probe not drawn gets no verdict; its
        whole interval is dark between pulses only if that is worth it too (:meth:`covers`).
    """

    mapping_at: Callable[[float], np.ndarray]
    near_m: float = 0.3
    far_m: float = 3.0
    dim_level: float = 0.1
    settle_px: float = 12.0
    prior_samples: int = 400
    prior_coverage: float = 0.8
    projector_size: tuple[int, int] | None = None
    min_worth: float = MIN_WORTH

    #: settled tracks needed before brightness narrows a new particle's search (default 4: the
    #: searches of a dive's first second are the costliest, so the prior starts early, and with the
    #: slope given only the level is learnt; history: docs/decisions/005-light-and-pattern-tuning.md)
    MIN_PRIOR = 4
    #: slope of log inverse depth against log brightness until ``FIT_SLOPE`` tracks have settled.
    #: The brightness is the detector's score: for the default detector a particle's flux, the
    #: light it sends back summed over its image, which goes as the fourth power of the distance
    #: (the lamp's inverse square, times the image's area for a particle the camera resolves or
    #: the camera's own inverse square for one it does not), so inverse depth goes as its fourth
    #: root: 0.25.  From ``FIT_SLOPE`` (40) settled tracks the data's own slope is kept: particles
    #: too small to resolve fade faster than the inverse square.  History:
    #: docs/decisions/005-light-and-pattern-tuning.md.
    SLOPE = 0.25
    FIT_SLOPE = 40
    #: while the slope is given, the prior's interval reaches at least this far either side of the
    #: line (log inverse depth: 0.3, a factor 1.35 in depth) -- the spread of a few settled tracks
    #: says little about the next particle's (history: docs/decisions/005-light-and-pattern-tuning.md)
    FEW_BAND = 0.3
    #: exposures in a row a settled hole must be seen to dim its particle before that depth is learnt
    HELD = 2
    #: exposures in a row a settled hole must miss its particle (it stays as bright as when lit)
    #: before the search starts again (default 2).  One verdict is noisy -- a particle half out of
    #: its hole after a jolt of the prediction, a neighbour's light, a flake turning -- and each
    #: restart spends frames of long searching holes on a depth that was right (history:
    #: docs/decisions/005-light-and-pattern-tuning.md).
    RESTART = 2

    def __post_init__(self) -> None:
        if not 0 < self.near_m < self.far_m:
            raise ValueError(f"near_m, far_m: got {self.near_m}, {self.far_m}; allowed 0 < near < far")
        if self.prior_samples < 0:
            raise ValueError(f"prior_samples: got {self.prior_samples}, allowed >= 0 (0 = no prior)")
        if not 0 < self.prior_coverage <= 1:
            raise ValueError(f"prior_coverage: got {self.prior_coverage}, allowed 0 < coverage <= 1")
        if not (math.isfinite(self.min_worth) and self.min_worth >= 0):
            raise ValueError(f"min_worth: got {self.min_worth}, allowed >= 0 (0 = every hole drawn)")
        # the settled tracks' (log brightness, log inverse depth), oldest first, at most prior_samples
        self._x = np.empty(0, np.float64)
        self._y = np.empty(0, np.float64)
        self._fit: tuple[float, float, float, float] | None = None  # slope, intercept, residual band
        self.w_far, self.w_near = 1.0 / self.far_m, 1.0 / self.near_m
        self._h_far = np.asarray(self.mapping_at(self.far_m), np.float64)
        self._h_near = np.asarray(self.mapping_at(self.near_m), np.float64)
        self._threshold = (1.0 + self.dim_level) / 2.0
        # each known track's state, one row per track in ascending id order (columns: _LO ..
        # _RESTARTED, counts and flags as floats, exact): its inverse-depth interval still holding
        # the particle (lo, hi); its brightness when fully lit (detector score, 0 = unknown);
        # exposures in a row its settled hole was seen to dim it (held) or failed to (missed);
        # whether its search has started again once (restarted)
        self._ids = np.empty(0, np.int64)
        self._state = np.empty((0, 6), np.float64)
        #: the tracks the last exposure found dimmed under their own probe or hole, or vanished
        #: under it: the ones whose particle had its hole's light (for HoleLevels)
        self.dimmed = np.empty(0, np.int64)

    # ----------------------------------------------------------------- geometry
    def span_px(self, centres: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Projector pixels between the positions of ``centres`` at inverse depths lo and hi."""
        step = _apply(self._h_near, centres) - _apply(self._h_far, centres)
        return np.hypot(*(step * (_t(hi, self) - _t(lo, self))[:, None]).T)

    def project(self, centres: np.ndarray, w: np.ndarray) -> np.ndarray:
        """Projector pixels where camera pixels ``centres`` (N, 2) at inverse depths ``w`` are lit:
        (N, 2) for w (N,), (N, S, 2) for w (N, S) -- S depths along each one's line."""
        far, near = _apply(self._h_far, centres), _apply(self._h_near, centres)
        t = _t(w, self)
        if t.ndim == 1:
            return far + t[:, None] * (near - far)
        return far[:, None, :] + t[..., None] * (near - far)[:, None, :]

    def dark_at(self, exposure: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Whether the ``exposure`` (projector pixels, uint8 with 255 = full or float with 1 = full)
        was dark at projector ``points`` (..., 2): below the verdicts' threshold, what dims a
        particle there as a probe would.  Outside the projector counts as lit (a particle seen lit
        is in its light)."""
        full = 255.0 if exposure.dtype == np.uint8 else 1.0
        u, v = np.moveaxis(np.rint(points).astype(np.intp), -1, 0)
        height, width = exposure.shape[:2]
        inside = (u >= 0) & (u < width) & (v >= 0) & (v < height)
        dark = np.zeros(u.shape, bool)
        dark[inside] = exposure[v[inside], u[inside]] < self._threshold * full
        return dark

    # ------------------------------------------------------------------ updates
    def observe(self, detections: Detections, shown: Mapping[int, tuple[float, float]],
                coasting: np.ndarray, *, exposure: np.ndarray | None = None,
                coasting_centres: np.ndarray | None = None) -> None:
        """One exposure's verdicts.

        detections: this frame's detections with their ``track_ids`` (scores = brightness, the
            default detector's flux -- its peak, clipped at white near the lamp, misled; a track
            has one detection at most, as the tracker assigns them);
        shown: the probe interval each track's hole covered during this exposure;
        coasting: ids of confirmed tracks not detected this frame (dark: under their hole);
        exposure: the pattern this exposure was taken under (projector pixels, uint8 or float,
            full = 255 or 1), so that a particle dimmed by another track's hole is not placed in
            its own probe (:meth:`_widen`); None: each verdict by the track's own probe alone;
        coasting_centres: (len(coasting), 2) their camera pixels at the exposure (predicted), for
            the same with ``exposure``.

        Every track's verdict at once; only what the prior is learnt from and asked for (a
        settled depth learnt, a new track's or a restarted search's interval) is taken in the
        detections' order, each prior from the depths learnt before it.
        """
        ids, scores = detections.track_ids, detections.scores
        use = (ids >= 0) & np.isfinite(scores)  # no track or no brightness from this detector: no verdict
        if not use.all():
            ids, scores = ids[use], scores[use]
        rows, known = self._find(ids)
        new = ~known
        if new.any():
            self._add(ids[new])
            rows = self._find(ids)[0]
        shown = Intervals.of(shown)
        a, b, probed = shown.spans(ids, 0.0, 0.0)
        lo, hi, lit, held, missed, restarted = self._state[rows].T
        judged = probed & (lit > 0)  # a probe was on it and its lit brightness is known
        dimmed = scores < self._threshold * lit
        hit, miss = judged & dimmed, judged & ~dimmed
        # dimmed: the particle is in the probed part, and a settled hole (the whole interval) holds it
        held = np.where(hit & (a == lo) & (b == hi), held + 1, np.where(judged, 0.0, held))
        learnt = hit & (held == self.HELD)  # seen dimmed under its settled hole: its depth is known
        inner, outer = np.maximum(lo, a), np.minimum(hi, b)
        overlap = inner < outer
        # dimmed: in the probed part of its interval (the probe itself when they do not overlap) --
        # or wherever else along its line the exposure was dark (another track's hole)
        dim_lo, dim_hi = np.where(overlap, inner, a), np.where(overlap, outer, b)
        if exposure is not None and hit.any():
            centres = detections.centres if use.all() else detections.centres[use]
            dim_lo, dim_hi = self._widen(exposure, centres, lo, hi, hit, dim_lo, dim_hi)
        # as bright as when lit: the particle is in the part not probed -- or, when the probe was
        # the whole settled interval, the hole missed: once may be the verdict's noise (the hole
        # stays), twice in a row and its search starts again
        from_lo, to_hi = a <= lo + 1e-12, b >= hi - 1e-12
        whole = miss & from_lo & to_hi
        again = whole & (missed + 1 >= self.RESTART)
        twice = again & (restarted > 0)  # the whole range; the first time, its brightness's prior (below)
        lo_now = np.where(hit, dim_lo,
                          np.where(miss & from_lo & ~to_hi, np.maximum(lo, b), np.where(twice, self.w_far, lo)))
        hi_now = np.where(hit, dim_hi,
                          np.where(miss & ~from_lo & to_hi, np.minimum(hi, a), np.where(twice, self.w_near, hi)))
        self.dimmed = ids[hit]
        lit_now = np.where(~judged & (lit <= 0), scores, np.where(hit, lit, 0.7 * lit + 0.3 * scores))
        missed_now = np.where(hit | again, 0.0, np.where(whole, missed + 1, missed))
        self._state[rows] = np.stack([lo_now, hi_now, lit_now, held, missed_now, np.maximum(restarted, again)], 1)
        # the prior, in the detections' order: learnt depths, then new and restarted searches from it
        asks = new | (again & ~twice)
        if learnt.any() or asks.any():
            wanted = np.where(new, scores, lit)  # a new track's brightness, a restarted one's when lit
            for i in np.flatnonzero(learnt | asks).tolist():
                if learnt[i]:
                    self._learn(float(lit[i]), float(lo[i]), float(hi[i]))
                else:
                    self._state[rows[i], :2] = self.prior(float(wanted[i]))
        # confirmed tracks not seen at all under their probe: vanished, so dimmed
        coasting = np.asarray(coasting, np.int64).reshape(-1)
        rows, known = self._find(coasting)
        a, b, probed = shown.spans(coasting, 0.0, 0.0)
        keep = known & probed
        if keep.any():
            rows, a, b = rows[keep], a[keep], b[keep]
            was_lo, was_hi = self._state[rows, _LO], self._state[rows, _HI]
            lo, hi = np.maximum(was_lo, a), np.minimum(was_hi, b)
            overlap = lo < hi
            lo, hi = np.where(overlap, lo, a), np.where(overlap, hi, b)
            if exposure is not None and coasting_centres is not None:
                centres = np.asarray(coasting_centres, np.float64).reshape(-1, 2)[keep]
                lo, hi = self._widen(exposure, centres, was_lo, was_hi, np.ones(len(rows), bool), lo, hi)
            self._state[rows, _LO] = lo
            self._state[rows, _HI] = hi
            self._state[rows, _MISSED] = 0.0
            self.dimmed = np.concatenate([self.dimmed, coasting[keep]])

    #: points along each interval at which the exposure's light is read (:meth:`_widen`)
    SAMPLES = 48
    #: a dimmed particle is placed in the part of its interval its own probe darkened only while it
    #: is at least this likely to be there, its depths along the line taken as equally likely (the
    #: part's share of the interval's dark points); below, the hull of them all (:meth:`_widen`).
    #: Default 0.8 (history: docs/decisions/005-light-and-pattern-tuning.md).
    SURE = 0.8

    def _widen(self, exposure: np.ndarray, centres: np.ndarray, lo: np.ndarray, hi: np.ndarray,
               dimmed: np.ndarray, inner: np.ndarray, outer: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(inner, outer): the intervals the ``dimmed`` particles' verdicts narrowed them to, widened
        to every depth of their interval [lo, hi] at which the exposure was dark -- another track's
        hole or probe crossed the particle's epipolar line there and would have dimmed it just as
        its own probe did -- where that makes the own probe's part doubtful (``SURE``).

        Judged by its own probe alone, a particle passing under a neighbour's hole was taken to be
        in its probed part, and the bisection went on in the wrong half, with nothing to tell.  The
        lines of particles on the same camera rows overlap in the projector, and in the first
        frames' whole-range searches half the view is dark (history:
        docs/decisions/005-light-and-pattern-tuning.md).
        exposure: the light on the scene during the exposure, in projector pixels (uint8, 255 =
        full, or float, 1 = full), read at SAMPLES points of each interval (:meth:`dark_at`).
        centres: the particles' camera pixels at the exposure."""
        # a settled hole's verdict covers its whole interval: nothing left to widen to
        rows = np.flatnonzero(dimmed & ((inner > lo) | (outer < hi)))
        if len(rows) == 0:
            return inner, outer
        w = lo[rows, None] + np.linspace(0.0, 1.0, self.SAMPLES) * (hi - lo)[rows, None]  # (R, S) inverse depths
        dark = self.dark_at(exposure, self.project(centres[rows], w))
        own = ((w >= inner[rows, None]) & (w <= outer[rows, None])).sum(axis=1)
        elsewhere = (dark & ((w < inner[rows, None]) | (w > outer[rows, None]))).sum(axis=1)
        doubtful = own < self.SURE * (own + elsewhere)
        dark &= doubtful[:, None]
        some = dark.any(axis=1)
        at = np.arange(len(rows))
        first = np.where(some, w[at, dark.argmax(axis=1)], np.inf)
        last = np.where(some, w[at, self.SAMPLES - 1 - dark[:, ::-1].argmax(axis=1)], -np.inf)
        inner, outer = inner.copy(), outer.copy()
        inner[rows] = np.minimum(inner[rows], first)
        outer[rows] = np.maximum(outer[rows], last)
        return inner, outer

    def prior(self, brightness: float) -> tuple[float, float]:
        """The inverse-depth interval a new particle of this brightness (lit) is searched over:
        what settled tracks of that brightness had (see ``prior_samples``), else near..far."""
        if len(self._x) < max(self.MIN_PRIOR, 1) or not brightness > 0:
            return self.w_far, self.w_near
        if self._fit is None:
            x, y = self._x, self._y
            if len(x) < self.FIT_SLOPE:  # the brightness law's slope; only the level is learnt
                slope = self.SLOPE
                intercept = _median(y - slope * x)
            else:
                slope, intercept = _line(x, y)
            tail = (1.0 - self.prior_coverage) / 2.0
            low, high = _quantiles(y - (slope * x + intercept), (tail, 1.0 - tail))
            pad = (high - low) / 4.0
            low, high = low - pad, high + pad
            if len(x) < self.FIT_SLOPE:  # a few samples' spread says little about the next particle's
                low, high = min(low, -self.FEW_BAND), max(high, self.FEW_BAND)
            self._fit = (float(slope), float(intercept), float(low), float(high))
        slope, intercept, low, high = self._fit
        middle = slope * math.log(brightness) + intercept
        lo, hi = max(self.w_far, math.exp(middle + low)), min(self.w_near, math.exp(middle + high))
        return (lo, hi) if lo < hi else (self.w_far, self.w_near)

    def prior_size(self) -> int:
        """Settled depths the prior has learnt from (at most ``prior_samples``)."""
        return len(self._x)

    def _learn(self, lit: float, lo: float, hi: float) -> None:
        """A settled track's (brightness, depth) for the prior."""
        if lit > 0 and self.prior_samples > 0:
            drop = max(len(self._x) + 1 - self.prior_samples, 0)  # the oldest beyond prior_samples
            self._x = np.append(self._x[drop:], math.log(lit))
            self._y = np.append(self._y[drop:], math.log((lo + hi) / 2))
            self._fit = None

    def _find(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(rows, known): each of ``ids``' row in the track state (valid where known)."""
        return _rows_in(self._ids, ids)

    def _add(self, ids: np.ndarray) -> None:
        """Rows for new tracks: the whole range, brightness unknown (observe sets their prior)."""
        ids = np.unique(ids)
        fresh = np.zeros((len(ids), 6))
        fresh[:, _LO], fresh[:, _HI] = self.w_far, self.w_near
        merged = np.concatenate([self._ids, ids])
        order = np.argsort(merged, kind="stable")
        self._ids = merged[order]
        self._state = np.concatenate([self._state, fresh])[order]

    def plan(self, holes: Detections) -> tuple[Intervals, Intervals]:
        """(probes, covers) of the next pattern, for the holes worth their light (``min_worth``;
        the others are not drawn and get no verdict):

        probes: the interval each hole covers while the camera exposes -- the lower half of its
            track's interval while that spans more than ``settle_px``, else all of it; a new
            particle the whole range;
        covers: each hole's whole interval, where its particle may be: what pulsed holes keep
            dark between exposures.
        """
        ids = holes.track_ids
        rows, known = self._find(ids)
        state = self._state[rows] if len(self._ids) else np.zeros((len(ids), 6))
        lo = np.where(known, state[:, _LO], self.w_far)
        hi = np.where(known, state[:, _HI], self.w_near)
        lit = np.where(known, state[:, _LIT], 0.0)  # 0: not known yet
        whole = self.span_px(holes.centres, lo, hi)  # projector px of each one's interval
        halve = (lit > 0) & (whole > self.settle_px)
        mid = np.where(halve, (lo + hi) / 2, hi)
        probed, covered = self._worth(holes, lit, (np.where(halve, whole / 2, whole), whole))
        return (Intervals(ids[probed], lo[probed], mid[probed]),
                Intervals(ids[covered], lo[covered], hi[covered]))

    def probes(self, holes: Detections) -> Intervals:
        """The probes of :meth:`plan`."""
        return self.plan(holes)[0]

    def covers(self, holes: Detections) -> Intervals:
        """The whole intervals of :meth:`plan`."""
        return self.plan(holes)[1]

    def _worth(self, holes: Detections, lit: np.ndarray, lengths: tuple[np.ndarray, ...]) -> list[np.ndarray]:
        """For each of ``lengths`` (projector px of each hole's segment): whether each hole drawn
        that long is worth its light (``min_worth``); holes whose particle's brightness is not
        known are always drawn."""
        total = float(lit[lit > 0].sum())
        if self.projector_size is None or self.min_worth <= 0 or total <= 0:
            return [np.ones(len(lit), bool) for _ in lengths]
        thickness = np.maximum(1.0, np.rint(2 * map_to_projector(holes, self._h_far)[1]))
        field = float(self.projector_size[0] * self.projector_size[1])
        per_px = self.min_worth * total / field  # lit / total >= min_worth * area / field
        return [(lit <= 0) | (lit >= per_px * thickness * (length + thickness)) for length in lengths]  # caps in

    def intervals(self) -> Intervals:
        """Each known track's whole remaining interval (inverse depths), where its particle may be."""
        return Intervals(self._ids.copy(), self._state[:, _LO].copy(), self._state[:, _HI].copy())

    def forget(self, alive: np.ndarray) -> None:
        """Drop the state of tracks that no longer exist."""
        keep = np.isin(self._ids, np.asarray(alive, np.int64))
        if not keep.all():
            self._ids, self._state = self._ids[keep], self._state[keep]

    # ---------------------------------------------------------------- rendering
    def render(self, holes: Detections, probes: Mapping[int, tuple[float, float]], *, size: tuple[int, int],
               margin: float = 0.0, out: np.ndarray | None = None, hole: int | np.ndarray = 0,
               given_only: bool = False) -> np.ndarray:
        """The pattern: each hole drawn as a thick segment over its probe interval (uint8, 255 = light).

        hole: the segments' grey level, or one per hole ((N,), :class:`~antiscatter.levels.HoleLevels`;
        where they cross, the brighter wins).
        given_only: draw only the holes ``probes`` has an interval for (:meth:`probes`,
        :meth:`covers`: the ones worth it); else the others over the whole near..far range.

        A thick line's round caps reach half its thickness past its ends.  A probe -- the part
        of its track's interval that the next exposure judges -- is drawn that much shorter at
        each end (down to a disc at its middle), so the light it withholds, caps included,
        spans its interval and no more: otherwise a particle just past the probe's end is
        dimmed by the cap, judged under it, and every such verdict pushes the bisection the
        same way.  A whole interval -- unknown depth, a settled one, or the one kept dark
        between pulses -- only has to cover the particle and is drawn in full, caps and all
        (history: docs/decisions/005-light-and-pattern-tuning.md).
        """
        out = blank_pattern(size, out)
        if len(holes) == 0:
            return out
        ids = holes.track_ids
        probes = Intervals.of(probes)
        lo, hi, given = probes.spans(ids, self.w_far, self.w_near)
        far, radii = map_to_projector(holes, self._h_far)
        near = _apply(self._h_near, holes.centres)
        a = far + _t(lo, self)[:, None] * (near - far)
        b = far + _t(hi, self)[:, None] * (near - far)
        thickness = np.maximum(1, np.rint(2 * (radii + margin))).astype(int)
        # a probe is a part of its track's interval that the next exposure judges; a whole interval
        # (settled, or kept dark between pulses) only has to cover the particle, caps and all
        rows, known = self._find(ids)
        probed = given & known
        if probed.any():
            probed &= (lo != self._state[rows, _LO]) | (hi != self._state[rows, _HI])
        if probed.any():
            length = np.hypot(*(b - a).T)
            inset = np.where(probed, np.minimum(thickness / 2.0, length / 2.0), 0.0)
            step = (b - a) * (inset / np.maximum(length, 1e-9))[:, None]
            a, b = a + step, b - step
        grey = np.broadcast_to(np.asarray(hole, np.int64), (len(holes),))
        # one level for all: drawn in order; one per hole: the brightest last
        order = np.arange(len(holes)) if np.ndim(hole) == 0 else np.argsort(grey, kind="stable")
        if given_only:
            order = order[given[order]]
        for (ax, ay), (bx, by), t, g in zip((a[order] * 16).round().astype(np.int64).tolist(),
                                            (b[order] * 16).round().astype(np.int64).tolist(),
                                            thickness[order].tolist(), grey[order].tolist()):
            cv2.line(out, (ax, ay), (bx, by), g, t, cv2.LINE_8, 4)
        return out


def _median(values: np.ndarray) -> float:
    """np.median's value (the middle order statistic, or the mean of the two), by one partition."""
    n = len(values)
    middle = np.partition(values, [(n - 1) // 2, n // 2])
    return float(middle[n // 2]) if n % 2 else float((middle[n // 2 - 1] + middle[n // 2]) / 2)


def _quantiles(values: np.ndarray, qs: tuple[float, ...]) -> np.ndarray:
    """np.quantile's default (linear) estimate of ``qs``, by one partition at the order
    statistics needed: the same numbers, half the time (this runs whenever a track settles)."""
    n = len(values)
    at = np.asarray(qs, np.float64) * (n - 1)
    below = np.floor(at).astype(np.intp)
    above = np.minimum(below + 1, n - 1)
    ordered = np.partition(values, np.unique(np.concatenate([below, above])))
    a, b, t = ordered[below], ordered[above], at - below
    step = b - a
    return np.where(t >= 0.5, b - step * (1 - t), a + step * t)  # numpy's own lerp, exactly


def _line(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Least-squares line y = slope x + intercept (slope 0 when x does not vary): the normal
    equations directly, a sixth of np.polyfit's time (this runs whenever a track settles)."""
    mx, my = float(x.mean()), float(y.mean())
    dx = x - mx
    spread = float(np.dot(dx, dx))
    if not spread > 0:
        return 0.0, my
    slope = float(np.dot(dx, y - my)) / spread
    return slope, my - slope * mx


def _t(w: np.ndarray, probe: DepthProbe) -> np.ndarray:
    return (np.asarray(w) - probe.w_far) / (probe.w_near - probe.w_far)


def _apply(h: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N, 2) points through the homography ``h``."""
    p = np.asarray(points, np.float64).reshape(-1, 1, 2)
    if len(p) == 0:  # OpenCV returns None for no points
        return np.empty((0, 2))
    return cv2.perspectiveTransform(p, np.asarray(h, np.float64)).reshape(-1, 2)
