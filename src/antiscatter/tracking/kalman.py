"""A constant-velocity Kalman tracker, vectorised over all tracks in numpy.

State per track: x, y (px), vx, vy (px/s) and radius r (px).  Motion: constant
velocity with white acceleration noise, each track's matched to its own motion
(``accel_floor``); the radius is a random walk.  The two
axes and the radius are independent under this model (block-diagonal F, Q, H
and R), so each track's covariance is kept as two 2x2 position-velocity blocks
and one radius variance, and the filter runs as closed-form element-wise
array arithmetic -- exactly the full Kalman filter, without 5x5 matrix stacks.
Association: gated, optimal one-to-one assignment on the distance between each
track's predicted centre and each detection (:func:`antiscatter.assignment.match`,
sparse, so hundreds of particles cost little), the gate being ``gate_sigma``
standard deviations of the track's predicted position, clipped to
[min_gate, max_gate] pixels.  A new track starts with the velocity of the
particles around it (the median of its nearest confirmed tracks': the water
carries neighbours alike), so a fast particle is found again in its second
frame.  A track is confirmed after ``confirm_hits`` hits; a confirmed track
that is missed keeps its hole on its predicted path for up to ``max_misses``
frames (a particle that went dark under its own hole keeps its hole) and its
identity for up to ``keep_misses``; a tentative one survives
``tentative_misses`` misses without a hole.  Ids are never reused.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..assignment import match, pairs_within
from ..detections import Detections
from ..levels import MIN_LEVEL

__all__ = ["Tracker", "Tracks", "Prediction"]

#: frame width (px) the motion settings' defaults are for (see Tracker.set_frame_size)
REFERENCE_WIDTH = 800

#: share of the frame period after a pattern goes on that its predicted holes are drawn for
#: (default 0.5: the pattern stays on a frame, and a hole drawn for its middle is off by a quarter
#: of a frame's motion at either end; history: docs/decisions/004-tracking-tuning.md)
PREDICT_AHEAD = 0.5

#: frames a lost confirmed track keeps its identity by default (see Tracker's keep_misses)
KEEP_MISSES = 12

#: sightings after which a track's hole follows its velocity, confirmed or not (default 2: two
#: give a velocity; history: docs/decisions/004-tracking-tuning.md)
MOVING_HITS = 2

#: px: the predicted centres of a merge's tracks lie at least this far apart (the box around
#: them, corner to corner): two tracks on one particle are no merge (see Tracker's merge_reach)
MERGE_GAP = 1.0

#: px: a confirmed track matched farther than this from its prediction may be in a merge, matched
#: to a piece of it (see Tracker._merged)
MERGE_SUSPECT = 3.0

#: px (at 800 px wide): a track found again after its hole went (past ``max_misses``) this near
#: its prediction keeps its motion and confirmation (see Tracker's keep_misses)
REFOUND = 2.0

#: flux (the detector's score) a track's next detection may differ by beyond ``flux_ratio`` times
#: its last: the faintest particles' flux is noise near the threshold (see Tracker's flux_ratio)
FLUX_SLACK = 10.0

#: memory of a track's averaged normalised innovation squared (see Tracker's accel_floor): the
#: share of the last average kept at each sighting
NIS_MEMORY = 0.7

#: exponent of a track's noise correction per sighting by its NIS, (averaged NIS / 2) ** NIS_RATE
#: (see Tracker's accel_floor)
NIS_RATE = 0.25

#: memory of the averaged lag-1 correlation of a track's normalised innovations: the share of the
#: last average kept at each sighting (see Tracker's accel_floor; history:
#: docs/decisions/004-tracking-tuning.md)
WHITE_MEMORY = 0.8

#: a track's noise is multiplied by 2 ** (WHITE_GAIN x that correlation) per sighting (history:
#: docs/decisions/004-tracking-tuning.md)
WHITE_GAIN = 2.0

#: most a particle's flux may change between its first two detections, either way, for
#: :meth:`Tracker._far` to take them for one particle (history: docs/decisions/004-tracking-tuning.md)
FAR_RATIO = 1.5

#: a new track's innovation statistics (see Tracker._match_noise): the NIS of a consistent filter,
#: no correlation yet, no last innovation
_NEW_INNOVATION = np.array([2.0, 0.0, 0.0, 0.0, 0.0])



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

    The measured history of each default: ``docs/decisions/004-tracking-tuning.md``.

    Parameters
    ----------
    confirm_hits : hits before a track is confirmed (default 3).
    max_misses : frames a confirmed track keeps its hole without a detection (coasting; default 5).
    keep_misses : frames a confirmed track is kept without a detection, for its identity (at least
        ``max_misses``; from ``max_misses`` on it has no hole).  Default None: ``KEEP_MISSES``
        (12), or ``max_misses`` if that is more: a particle the detector loses for a while gets
        its id back.  Found again after more than ``max_misses``, a track keeps its id but starts
        again as a new track does (it may be another particle; its velocity is stale) unless it is
        within ``REFOUND`` (2) px of its prediction; lost tracks take only the detections the
        tracks with a hole leave (:meth:`_associate`).  History: decision 004.
    tentative_misses : misses a not yet confirmed track survives, without a hole (default 3: a
        faint new particle the detector misses keeps its identity; at most ``keep_misses``).
        History: decision 004.
    flow_neighbours : a new track's velocity starts as the median velocity of this many nearest
        confirmed tracks (when there are that many; 0 = at rest).  Default 5: a particle thrown
        across the view is not born again in every frame.  History: decision 004.
    max_dark : misses in a row a confirmed track survives while they are expected -- its
        particle was under its own hole during the exposure (``update(..., unlit=ids)``) -- its
        hole kept on the predicted path.  0 (default) counts them as ordinary misses: with the
        default detector it cost scene light for no removal.  History: decision 004.
    gate_sigma : gate in standard deviations of the predicted position (default 4).
    min_gate, max_gate : gate limits in pixels (defaults 3 and 80).
    frame_size : (width, height) of the frames in px (None: 800 wide, no edges): ``accel_noise``,
        ``initial_speed`` and ``max_gate`` are for 800 px wide frames and grow in proportion above
        that (:meth:`set_frame_size`), and a track whose predicted centre has left the view by more
        than its radius is deleted: its particle has gone out of sight (kept, it took the next
        particle to come in near where it was heading).  History: decision 004.
    accel_noise : process noise, px/s^2 of white acceleration: a new track's, and the most a
        track's becomes (``accel_floor``; default 1500: the simulator's particles change speed by
        up to 500-2400 px/s^2 -- a bubble's 3 Hz wobble 0.3-1.5 m away, the seed tank's discs
        turning to new headings).  History: decision 004.
    merge_reach : a detection whose disc holds the predicted centres of two or more confirmed
        tracks -- within ``merge_reach`` times its radius of its centre, and at least
        ``MERGE_GAP`` px apart from each other -- is taken for their particles merged in the image
        (overlapping, or touching with their halos joined): it moves none of them (each goes on
        along its own prediction, as a coasting track does) and is a miss for none; the track it is
        assigned to takes its id.  Its centre lies between the particles: taken as one of them, it
        swapped or lost identities.  0 = off.  Default 0.7.  History: decision 004.
    flux_ratio : a detection whose flux (its score: the light it sends back; NaN, as the ``seed``
        detector's, checks nothing) is more than ``flux_ratio`` times a track's last, or less than
        that over ``flux_ratio`` (give or take ``FLUX_SLACK``), is not that track's particle --
        unless the track's own hole explains it: under its hole this exposure (``update(...,
        unlit=ids)``) a particle may be any fainter, and one last seen under its hole may come
        back lit up to 1 / ``MIN_LEVEL`` (50) times brighter still.  0 = off.  Default 6: a
        distance gate alone let a faint track take a bright particle just come into the lamp.  Off
        where depth is probed (the runtime and the twin): a particle's light under the probes is
        not known until their verdict.  History: decision 004.
    far_bright : a particle seen once, in the last frame, whose flux is at least ``far_bright``
        times the frame's median detection's, and that no track takes, may be found again anywhere
        within ``max_gate``: its track and a detection no track took are paired when each is the
        other's only candidate there with a flux within ``FAR_RATIO`` (1.5) of its own (of the
        tentative tracks a particle born again frame after frame leaves behind, only the newest).
        A near particle is bright and fast: one moving farther in a frame than a new track's gate
        was born again in every frame and never had a hole where it was.  0 = off (and off with
        ``flux_ratio`` 0).  Default 6.  History: decision 004.
    radius_noise : radius random walk, px/sqrt(s) (default 4).
    position_noise : detected centre noise, px (default 0.7).
    radius_measurement_noise : detected radius noise, px (default 1).
    initial_speed : prior speed spread of a new track, px/s (default 400).
    flow_holes : a particle seen once has its hole moved along the velocity it was born with --
        its neighbours' flow (``flow_neighbours``; at rest while there are fewer) -- as a tracked
        one's is along its own, and grown by its uncertainty as theirs (:meth:`holes`).  Default
        True: a near particle new to the view moves several pixels before its hole goes on.  Off
        where depth is probed: a new track's hole there is the whole epipolar segment.  History:
        decision 004.
    accel_floor : the least acceleration noise a track's may fall to, a share of ``accel_noise``
        (default 0.1; 1 = every track's is ``accel_noise``).  Each track's noise is matched to
        its own motion by its innovations (covariance matching, Mehra 1972): a new track starts
        at ``accel_noise`` (its motion is not known), and at each sighting the noise is
        multiplied by (averaged NIS / 2) ** ``NIS_RATE`` x 2 ** (``WHITE_GAIN`` x the averaged
        lag-1 correlation of its normalised innovations), within [accel_floor, 1] x
        ``accel_noise``.  The NIS -- innovation^2 over its variance, summed over both axes --
        averages 2 when the filter's spread is right, and lower it pulls the noise down; the
        innovations of an optimal filter are white, and one that lags the motion sees them keep
        their sign from one sighting to the next, which pushes it up.  A particle drifting
        steadily gets tight gates and holes, a wobbling bubble or a particle speeding up keeps
        wide ones.  A track found again after its hole went, its motion started afresh, starts
        again at ``accel_noise``.  History: decision 004.
    miss_cost : pixels (for frames 800 px wide, scaled with the width as the motion settings) that
        a track left without a detection costs the assignment where tracks compete for
        detections: a rearrangement that matches one more track is made only where it lengthens
        the summed distance by less (and a contested pair longer than this is not made); 0 = the
        most matches first.  A pair that is the only candidate of both its ends is matched within
        its gate all the same.  Default 30: matching the most first let a track seen once, whose
        gate is wide, take a neighbour's detection -- a switch for both.  History: decision 004.
    flux_cost : pixels (at 800 px wide, scaled as ``miss_cost``) added to a pair's distance per unit
        of |log| of the ratio of the detection's flux to the track's last (both plus
        ``FLUX_SLACK``), where tracks compete for detections: of two particles near a prediction,
        the one alike in brightness is taken -- a particle's light changes little from frame to
        frame.  Default 16 (twice the flux costs 11 px).  Gates stay on distance; none for a track
        under its own hole now or at its last sighting, none where a flux is not known
        (``seed``'s NaN), off with ``flux_ratio`` (depth probing).  0 = distance alone.  History:
        decision 004.
    revive_frames : for this many frames after a track seen twice or more is deleted, a
        detection that no live track takes but that lies within the dead track's gate (its
        motion carried on) gets the dead track's id and state back instead of a new one; it
        starts over as a new track otherwise.  0 = off (default: identities help counting, not
        the light).  History: decision 004.
    """

    def __init__(self, *, confirm_hits: int = 3, max_misses: int = 5, keep_misses: int | None = None,
                 tentative_misses: int = 3, flow_neighbours: int = 5,
                 max_dark: int = 0, gate_sigma: float = 4.0,
                 min_gate: float = 3.0, max_gate: float = 80.0, accel_noise: float = 1500.0,
                 radius_noise: float = 4.0, position_noise: float = 0.7,
                 radius_measurement_noise: float = 1.0, initial_speed: float = 400.0,
                 revive_frames: int = 0, frame_size: tuple[int, int] | None = None,
                 flow_holes: bool = True, merge_reach: float = 0.7, flux_ratio: float = 6.0,
                 far_bright: float = 6.0, accel_floor: float = 0.1, miss_cost: float = 30.0,
                 flux_cost: float = 16.0) -> None:
        keep_misses = max(KEEP_MISSES, max_misses) if keep_misses is None else keep_misses
        checks = {"confirm_hits": confirm_hits >= 1, "max_misses": max_misses >= 0, "revive_frames": revive_frames >= 0,
                  "keep_misses": keep_misses >= max_misses, "flow_neighbours": flow_neighbours >= 0,
                  "tentative_misses": tentative_misses >= 0, "max_dark": max_dark >= 0,
                  "gate_sigma": gate_sigma > 0, "min_gate": min_gate > 0, "max_gate": max_gate >= min_gate,
                  "accel_noise": accel_noise >= 0, "radius_noise": radius_noise >= 0,
                  "position_noise": position_noise > 0, "radius_measurement_noise": radius_measurement_noise > 0,
                  "initial_speed": initial_speed >= 0, "merge_reach": merge_reach >= 0,
                  "flux_ratio": flux_ratio == 0 or flux_ratio >= 1, "far_bright": far_bright == 0 or far_bright >= 1,
                  "accel_floor": 0 < accel_floor <= 1, "miss_cost": miss_cost >= 0,
                  "flux_cost": flux_cost >= 0}
        for name, ok in checks.items():
            if not ok:
                raise ValueError(f"{name}: got {locals()[name]!r}, out of range")
        self.confirm_hits = confirm_hits
        self.max_misses = max_misses
        self.keep_misses = keep_misses
        self.flow_neighbours = flow_neighbours
        self.tentative_misses = min(tentative_misses, keep_misses)  # never longer than a confirmed track
        self.max_dark = max_dark
        self.gate_sigma = gate_sigma
        self.min_gate = min_gate
        self._motion = (accel_noise, initial_speed, max_gate)  # as given: for 800 px wide frames
        self.view: tuple[int, int] | None = None
        self.set_frame_size(frame_size)
        self.radius_noise = radius_noise
        self.measurement = np.diag([position_noise ** 2, position_noise ** 2, radius_measurement_noise ** 2])
        self.x = np.empty((0, 5))
        # covariance blocks per track: for axis a in (x, y): pp[a], pv[a], vv[a]; radius: rr
        self.pp = np.empty((0, 2))
        self.pv = np.empty((0, 2))
        self.vv = np.empty((0, 2))
        self.rr = np.empty(0)
        self.ids = np.empty(0, np.int64)
        self.hits = np.empty(0, np.int64)
        self.misses = np.empty(0, np.int64)
        self.dark = np.empty(0, np.int64)  # of the misses in a row, how many were expected (unlit)
        self.timestamp: float | None = None
        self._next_id = 1
        self.revive_frames = revive_frames
        self.flow_holes = bool(flow_holes)
        self.merge_reach = float(merge_reach)
        self.flux_ratio = float(flux_ratio)
        self.far_bright = float(far_bright)
        self.accel_floor = float(accel_floor)
        self.miss_cost = float(miss_cost)  # px at 800 px wide, scaled as the motion settings
        self.flux_cost = float(flux_cost)  # px at 800 px wide per unit of |log flux ratio|, scaled as those
        self.flux = np.empty(0)  # the flux of each track's last detection (NaN: not known)
        self.flux_dark = np.empty(0, bool)  # ... taken while its own hole was on it
        self.qa = np.empty(0)  # each track's acceleration noise, px/s^2
        # each track's innovation statistics (_match_noise), a row of five: its averaged NIS, the
        # averaged product of its successive normalised innovations and of their squares (to
        # normalise it), its last normalised innovation (x, y) -- one array: each array per track
        # costs its share of every deletion and birth
        self.innovation = np.empty((0, 5))
        # deleted tracks that may come back: the same arrays, carried forward in time, and
        # the updates each has left
        self._dead: dict[str, np.ndarray] = {}

    def set_frame_size(self, size: tuple[int, int] | None) -> None:
        """Frames of ``size`` (width, height) px: scale the motion settings -- ``accel_noise``,
        ``initial_speed``, ``max_gate``, given for frames 800 px wide -- to the width (wider frames
        see the same motion as more pixels; narrower ones keep them as given, as the detector's
        cell and radius do), and delete tracks that leave the view.  None: as given, no edges.
        The runtime, the twin and ``evaluate`` call it with the first frame's size."""
        self.view = (int(size[0]), int(size[1])) if size and min(size) > 0 else None  # (0, 0): not known
        width = self.view[0] if self.view else None
        scale = max(1.0, width / REFERENCE_WIDTH) if width else 1.0
        accel_noise, initial_speed, max_gate = self._motion
        self.scale = scale  # of the motion settings and REFOUND
        self.accel_noise, self.initial_speed, self.max_gate = (accel_noise * scale, initial_speed * scale,
                                                               max_gate * scale)

    # ------------------------------------------------------------- model
    def _predict(self, dt: float) -> None:
        if dt <= 0 or len(self.x) == 0:
            return
        self.x, self.pp, self.pv, self.vv, self.rr = self._advance(self.x, self.pp, self.pv, self.vv, self.rr,
                                                                   self.qa, dt)

    def _advance(self, x: np.ndarray, pp: np.ndarray, pv: np.ndarray, vv: np.ndarray, rr: np.ndarray,
                 qa: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """State (N, 5) and covariance blocks (N, 2) x 3 and (N,) carried ``dt`` seconds forward
        (new arrays); ``qa`` (N,): each track's acceleration noise, px/s^2."""
        q = np.square(qa)[:, None]
        x = x.copy()
        x[:, 0:2] += x[:, 2:4] * dt
        # P' = F P F^T + Q per axis, F = [[1, dt], [0, 1]], Q = q [[dt^4/4, dt^3/2], [dt^3/2, dt^2]]
        return (x, _position_variance(pp, pv, vv, q, dt), pv + dt * vv + q * dt ** 3 / 2,
                vv + q * dt * dt, rr + self.radius_noise ** 2 * dt)

    def _gates(self, pp: np.ndarray) -> np.ndarray:
        """(N,) association gate in pixels for position variances ``pp`` (N, 2)."""
        # (the larger axis by np.maximum of the two columns: a fifth of np.max(axis=1)'s time)
        spread = np.sqrt(np.maximum(pp[:, 0], pp[:, 1]) + self.measurement[0, 0]) if len(pp) else np.empty(0)
        return np.clip(self.gate_sigma * spread, self.min_gate, self.max_gate)

    def _correct(self, t: np.ndarray, k: np.ndarray, detections: Detections,
                 under: np.ndarray | None = None) -> None:
        """Kalman update of tracks ``t`` with detections ``k`` (index arrays), whose flux each
        track keeps; ``under``: (N,) bool, the tracks whose own hole was on this exposure (None:
        none)."""
        m_pos, m_rad = self.measurement[0, 0], self.measurement[2, 2]
        pp, pv, vv = self.pp[t], self.pv[t], self.vv[t]
        s_pos = pp + m_pos  # innovation variance per axis
        k_p, k_v = pp / s_pos, pv / s_pos  # Kalman gains for position and velocity
        x = self.x[t]  # the matched rows, gathered once and written back once
        innovation = detections.centres[k] - x[:, 0:2]
        if self.accel_floor < 1:
            self._match_noise(t, innovation, s_pos)
        x[:, 0:2] += k_p * innovation
        x[:, 2:4] += k_v * innovation
        self.pp[t] = (1 - k_p) * pp
        self.pv[t] = (1 - k_p) * pv
        self.vv[t] = vv - k_v * pv
        rr = self.rr[t]
        k_r = rr / (rr + m_rad)
        x[:, 4] += k_r * (detections.radii[k] - x[:, 4])
        self.x[t] = x
        self.rr[t] = (1 - k_r) * rr
        self.flux[t] = detections.scores[k]
        self.flux_dark[t] = False if under is None else under[t]
        self._seen(t)

    def _match_noise(self, t: np.ndarray, innovation: np.ndarray, s_pos: np.ndarray) -> None:
        """Correct the acceleration noise of tracks ``t`` (index array) towards what their
        ``innovation`` (K, 2) px, of variance ``s_pos`` (K, 2) px^2 per axis, shows (see
        ``accel_floor``)."""
        u = innovation / np.sqrt(s_pos)  # normalised, per axis
        uu = np.square(u).sum(axis=1)
        stats = self.innovation[t]
        average = NIS_MEMORY * stats[:, 0] + (1 - NIS_MEMORY) * uu
        # an optimal filter's innovations are white: correlated from one sighting to the next, the
        # filter lags the motion (its noise is too low); the lag-1 correlation of the normalised
        # innovations, averaged
        last = stats[:, 3:5]
        lag = WHITE_MEMORY * stats[:, 1] + (1 - WHITE_MEMORY) * (u * last).sum(axis=1)
        power = WHITE_MEMORY * stats[:, 2] + (1 - WHITE_MEMORY) * 0.5 * (uu + np.square(last).sum(axis=1))
        self.innovation[t] = np.column_stack([average, lag, power, u])
        correlation = lag / np.maximum(power, 1e-12)
        # a consistent filter's NIS averages 2 (chi-square, two degrees of freedom)
        factor = np.power(average / 2.0, NIS_RATE) * np.exp2(WHITE_GAIN * correlation)
        self.qa[t] = np.clip(self.qa[t] * factor, self.accel_floor * self.accel_noise, self.accel_noise)

    def _seen(self, t: np.ndarray) -> None:
        """Tracks ``t`` (index array) seen this frame without a measurement of their own: a hit,
        the state left as predicted."""
        self.hits[t] += 1
        self.misses[t] = 0
        self.dark[t] = 0

    def _merged(self, detections: Detections, is_lost: np.ndarray, matches: np.ndarray) -> np.ndarray:
        """(N,) bool: confirmed tracks whose predicted centre lies in a detection that holds two or
        more of them, ``MERGE_GAP`` px or more apart (see ``merge_reach``); ``matches`` (K, 2) of
        (track, detection) from this frame's association.

        Such a detection leaves one of its tracks unmatched, or matched to another detection (a
        piece of the merge) farther than ``MERGE_SUSPECT`` px from its prediction: only the
        detections holding such a suspect are looked at, with the track each was given -- a tenth
        of the tracks (history: docs/decisions/004-tracking-tuning.md)."""
        merged = np.zeros(len(self.x), bool)
        if not self.merge_reach or len(detections) == 0 or len(matches) == 0:
            return merged
        member = (self.hits >= self.confirm_hits) & ~is_lost
        suspect = member.copy()
        t, k = matches[:, 0], matches[:, 1]
        near = np.hypot(*(self.x[t, :2] - detections.centres[k]).T) <= MERGE_SUSPECT
        suspect[t[near]] = False
        suspects = np.flatnonzero(suspect)
        if len(suspects) == 0:
            return merged
        reach = self.merge_reach * detections.radii
        dets, rows = pairs_within(detections.centres, reach, self.x[suspects, :2])
        if len(dets) == 0:
            return merged
        rows = suspects[rows]
        # each such detection's other member: the track it was given, when confirmed and inside
        held = np.zeros(len(detections), bool)
        held[dets] = True
        owner = np.full(len(detections), -1)
        owner[k] = t
        mine = np.flatnonzero(held & (owner >= 0))
        mine = mine[member[owner[mine]] & ~suspect[owner[mine]]]
        mine = mine[np.hypot(*(self.x[owner[mine], :2] - detections.centres[mine]).T) <= reach[mine]]
        dets, rows = np.concatenate([dets, mine]), np.concatenate([rows, owner[mine]])
        several = (np.bincount(dets, minlength=len(detections)) >= 2)[dets]
        if not several.any():
            return merged
        order = np.argsort(dets[several], kind="stable")
        dets, rows = dets[several][order], rows[several][order]
        starts = np.flatnonzero(np.r_[True, dets[1:] != dets[:-1]])
        x, y = self.x[rows, 0], self.x[rows, 1]
        span = np.hypot(np.maximum.reduceat(x, starts) - np.minimum.reduceat(x, starts),
                        np.maximum.reduceat(y, starts) - np.minimum.reduceat(y, starts))
        merged[rows[np.repeat(span >= MERGE_GAP, np.diff(np.r_[starts, len(dets)]))]] = True
        return merged

    _FIELDS = ("x", "pp", "pv", "vv", "rr", "ids", "hits", "misses", "dark", "flux", "flux_dark", "qa",
               "innovation")

    # ------------------------------------------------------------ update
    def update(self, detections: Detections, timestamp: float, *, unlit: np.ndarray | None = None) -> Tracks:
        """Advance to ``timestamp`` (seconds), associate ``detections``, return the tracks.

        Call every frame, with an empty Detections when nothing was found.  ``unlit``: ids of
        tracks whose hole was on their particle during this exposure; a miss of theirs is
        expected (a particle in the dark cannot be seen) and counts against ``max_dark``
        instead of ``max_misses``.
        """
        dt = 0.0 if self.timestamp is None else timestamp - self.timestamp
        if dt < 0:
            raise ValueError(f"timestamp: got {timestamp}, earlier than the last update {self.timestamp}")
        self._predict(dt)
        self._drop_departed()
        if self._dead and dt > 0:
            dead = self._dead
            dead["x"], dead["pp"], dead["pv"], dead["vv"], dead["rr"] = self._advance(
                dead["x"], dead["pp"], dead["pv"], dead["vv"], dead["rr"], dead["qa"], dt)
        self.timestamp = timestamp
        d = len(detections)
        m_pos, m_rad = self.measurement[0, 0], self.measurement[2, 2]
        lost = self._lost()
        under = (np.isin(self.ids, unlit) if unlit is not None and len(unlit) and len(self.ids)
                 else np.zeros(len(self.ids), bool))
        matches, unmatched_tracks, unmatched_dets = self._associate(detections, lost, self._flux_bounds(under),
                                                                    self._flux_penalty(detections, under))
        if self.far_bright and self.flux_ratio and len(unmatched_tracks) and len(unmatched_dets):
            far = self._far(detections, unmatched_tracks, unmatched_dets)
            if len(far):
                matches = np.concatenate([matches, far])
                unmatched_tracks = np.setdiff1d(unmatched_tracks, far[:, 0], assume_unique=True)
                unmatched_dets = np.setdiff1d(unmatched_dets, far[:, 1], assume_unique=True)
        detection_ids = np.full(d, -1, np.int64)
        merged = self._merged(detections, lost, matches)
        if len(matches):
            t, k = matches[:, 0], matches[:, 1]
            found_again = lost[t]
            stale, stale_at = t[found_again], k[found_again]
            if len(stale):  # (but one found where its motion took it is the same particle, moving so)
                elsewhere = np.hypot(*(self.x[stale, :2] - detections.centres[stale_at]).T) > REFOUND * self.scale
                stale, stale_at = stale[elsewhere], stale_at[elsewhere]
            moved = ~merged[t]  # in a merge, no detection moves a track: the merge, or a piece of it
            self._correct(t[moved], k[moved], detections, under)
            self._seen(t[~moved])
            detection_ids[k] = self.ids[t]
            if len(stale):
                # found again after its hole had gone: the identity is kept, the motion is not
                # trusted -- it starts again as a new track's (where it was seen, the neighbours'
                # flow, unconfirmed, its motion not known)
                self.x[stale, :2] = detections.centres[stale_at]
                self.x[stale, 2:4] = self._flow(self.x[stale, :2])
                self.pp[stale] = m_pos
                self.pv[stale] = 0.0
                self.vv[stale] = self.initial_speed ** 2
                self.hits[stale] = 1
                self.qa[stale] = self.accel_noise
                # a new track's NIS and no last innovation (the correlation's averages kept; history:
                # docs/decisions/004-tracking-tuning.md)
                self.innovation[stale, 0] = _NEW_INNOVATION[0]
                self.innovation[stale, 3:5] = _NEW_INNOVATION[3:5]
        if len(unmatched_tracks):
            unmatched_tracks = unmatched_tracks[~merged[unmatched_tracks]]  # hidden in a merge: no miss
            self.misses[unmatched_tracks] += 1
            self.dark[unmatched_tracks[under[unmatched_tracks]]] += 1
        # delete: tentative tracks after tentative_misses (unproven: a false alarm darkened by its
        # own hole must not live on), confirmed ones after keep_misses not counting expected
        # misses -- up to max_dark of them
        confirmed = self.hits >= self.confirm_hits
        unexpected = self._unexpected(confirmed)
        alive = self.dark <= self.max_dark if self.max_dark else True
        keep = np.where(confirmed, unexpected <= self.keep_misses, unexpected <= self.tentative_misses) & alive
        if not keep.all():
            if self.revive_frames:
                self._bury(~keep & (self.hits >= MOVING_HITS))
            self._keep(keep)
        if self._dead:
            unmatched_dets = self._revive(detections, unmatched_dets, detection_ids)
        if len(unmatched_dets):
            k = unmatched_dets
            m = len(k)
            new_x = np.zeros((m, 5))
            new_x[:, :2] = detections.centres[k]
            new_x[:, 4] = detections.radii[k]
            new_x[:, 2:4] = self._flow(new_x[:, :2])
            new_ids = np.arange(self._next_id, self._next_id + m, dtype=np.int64)
            self._next_id += m
            self._append({"x": new_x, "pp": np.full((m, 2), m_pos), "pv": np.zeros((m, 2)),
                          "vv": np.full((m, 2), self.initial_speed ** 2), "rr": np.full(m, m_rad), "ids": new_ids,
                          "hits": np.ones(m, np.int64), "misses": np.zeros(m, np.int64),
                          "dark": np.zeros(m, np.int64), "flux": detections.scores[k],
                          "flux_dark": np.zeros(m, bool), "qa": np.full(m, self.accel_noise),
                          "innovation": np.tile(_NEW_INNOVATION, (m, 1))})
            detection_ids[k] = new_ids
        return Tracks(self.ids.copy(), self.x[:, :2].copy(), self.x[:, 2:4].copy(), self.x[:, 4].copy(),
                      self.hits >= self.confirm_hits, self.misses.copy(), timestamp, detection_ids)

    def _drop_departed(self) -> None:
        """Delete the tracks whose predicted centre lies outside the view by more than their
        radius: their particles have left it."""
        if self.view is None or len(self.x) == 0:
            return
        width, height = self.view
        x, y, r = self.x[:, 0], self.x[:, 1], np.maximum(self.x[:, 4], 0.0)
        inside = (x >= -r) & (x <= width - 1 + r) & (y >= -r) & (y <= height - 1 + r)
        if not inside.all():
            self._keep(inside)

    def _associate(self, detections: Detections, is_lost: np.ndarray,
                   flux: tuple[np.ndarray, np.ndarray] | None = None,
                   penalty: tuple[np.ndarray, np.ndarray] | None = None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(matches (K, 2) of (track, detection), unmatched tracks, unmatched detections).

        flux: (low, high) per track, the detections' flux each may take (:meth:`_flux_bounds`),
        or None.  penalty: (per track, per detection) pixels whose difference a pair costs
        (:meth:`_flux_penalty`), or None.

        Tracks with a hole are matched first; the lost ones (``is_lost``, :meth:`_lost`)
        kept for their identity only take what is left.  A lost track's gate has grown wide over
        its misses: matched together with the rest, it competed for its neighbours' detections
        and made the assignment problems large (history: docs/decisions/004-tracking-tuning.md)."""
        gates = self._gates(self.pp)
        scores = detections.scores
        miss = self.miss_cost * self.scale

        def bounds(rows, values):  # the flux check of tracks ``rows`` on detections of ``values``
            return None if flux is None else (flux[0][rows], flux[1][rows], values)

        def cost(rows, dets):  # the penalty of tracks ``rows`` against detections ``dets``
            return None if penalty is None else (penalty[0][rows], penalty[1][dets])

        if not is_lost.any():
            return match(self.x[:, :2], gates, detections.centres, bounds=bounds(slice(None), scores), miss_cost=miss,
                         penalty=penalty)
        live, lost = np.flatnonzero(~is_lost), np.flatnonzero(is_lost)
        first, free_live, free_dets = match(self.x[live, :2], gates[live], detections.centres,
                                            bounds=bounds(live, scores), miss_cost=miss,
                                            penalty=cost(live, slice(None)))
        second, free_lost, free_dets2 = match(self.x[lost, :2], gates[lost], detections.centres[free_dets],
                                              bounds=bounds(lost, scores[free_dets]), miss_cost=miss,
                                              penalty=cost(lost, free_dets))
        matches = np.concatenate([np.column_stack([live[first[:, 0]], first[:, 1]]),
                                  np.column_stack([lost[second[:, 0]], free_dets[second[:, 1]]])]).astype(np.int64)
        return matches, np.sort(np.concatenate([live[free_live], lost[free_lost]])), free_dets[free_dets2]

    def _far(self, detections: Detections, tracks: np.ndarray, dets: np.ndarray) -> np.ndarray:
        """(K, 2) (track, detection) pairs found far apart (see ``far_bright``) among the unmatched
        ``tracks`` and ``dets`` (index arrays)."""
        none = np.empty((0, 2), np.int64)
        # seen once, in the last frame: a particle born again in every frame leaves a trail of such
        # tracks, and only the newest is where its next sighting is a frame's move away
        t = tracks[(self.hits[tracks] == 1) & (self.misses[tracks] == 0)]
        if len(t) == 0:
            return none
        scores = detections.scores
        known = scores[np.isfinite(scores)]
        if len(known) == 0:
            return none
        median = np.partition(known, len(known) // 2)[len(known) // 2]  # (np.median: 7x the time)
        t = t[self.flux[t] >= self.far_bright * median]  # (a NaN flux: False)
        k = dets[np.isfinite(scores[dets])]
        if len(t) == 0 or len(k) == 0:
            return none
        rows, cols = pairs_within(self.x[t, :2], np.full(len(t), self.max_gate), detections.centres[k])
        mine, theirs = self.flux[t[rows]], detections.scores[k[cols]]
        alike = (theirs <= mine * FAR_RATIO) & (mine <= theirs * FAR_RATIO)
        rows, cols = rows[alike], cols[alike]
        if len(rows) == 0:
            return none
        # only where neither end has another candidate: no guessing in a crowd
        alone = (np.bincount(rows, minlength=len(t))[rows] == 1) & (np.bincount(cols, minlength=len(k))[cols] == 1)
        return np.column_stack([t[rows[alone]], k[cols[alone]]]).astype(np.int64)

    def _flux_penalty(self, detections: Detections, under: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """(per track, per detection) for :meth:`_associate`: ``flux_cost`` (scaled) times the log
        of each flux plus ``FLUX_SLACK``, so a pair costs ``flux_cost`` pixels per unit of |log| of
        their ratio where tracks compete; NaN (no cost) for a track whose own hole is on its
        particle now or was at its last sighting (its light is not its particle's) and where a
        flux is not known.  None when off or no flux is known (``seed``'s NaN scores)."""
        if not self.flux_cost or not self.flux_ratio or len(self.flux) == 0 or len(detections) == 0:
            return None
        scores = detections.scores
        if not np.isfinite(scores).any():
            return None
        weight = self.flux_cost * self.scale
        with np.errstate(invalid="ignore", divide="ignore"):
            # the logs once per track and detection, not per pair; the slack as in the flux check
            mine = weight * np.log(np.where(under | self.flux_dark, np.nan, self.flux) + FLUX_SLACK)
            theirs = weight * np.log(scores + FLUX_SLACK)
        return (mine, theirs) if np.isfinite(mine).any() else None

    def _flux_bounds(self, under: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """(low, high) per track: the flux its detection may have this frame (``flux_ratio``);
        ``under``: (N,) bool, the tracks whose own hole was on their particle during this
        exposure.  None when off."""
        if not self.flux_ratio or len(self.flux) == 0:
            return None
        f = self.flux
        # under its own hole a particle sends back less than it did lit (no least), and one seen
        # last under its hole may come back lit with up to 1 / MIN_LEVEL times more: no hole a
        # particle is seen under leaves it less of the lamp
        low = np.where(under, -np.inf, f / self.flux_ratio - FLUX_SLACK)
        high = f * np.where(self.flux_dark & ~under, self.flux_ratio / MIN_LEVEL, self.flux_ratio) + FLUX_SLACK
        return low, high

    def _lost(self) -> np.ndarray:
        """(N,) bool: tracks missed more than ``max_misses`` times in a row, kept for their id only --
        not counting a confirmed track's misses in the dark of its own hole (``max_dark``), as for
        its hole (:meth:`snapshot`): a track whose hole is still on is not lost."""
        return self._unexpected(self.hits >= self.confirm_hits) > self.max_misses

    def _keep(self, keep: np.ndarray) -> None:
        """Keep the tracks ``keep`` (bool), delete the rest."""
        for name in self._FIELDS:
            setattr(self, name, getattr(self, name)[keep])

    def _append(self, rows: dict[str, np.ndarray]) -> None:
        """Add tracks: one array per name in ``_FIELDS``, rows in the same order."""
        for name in self._FIELDS:
            setattr(self, name, np.concatenate([getattr(self, name), rows[name]]))

    def _unexpected(self, confirmed: np.ndarray) -> np.ndarray:
        """(N,) misses in a row that were not expected: a confirmed track's misses under its own
        hole count against ``max_dark`` instead (when that is on)."""
        return self.misses - np.where(confirmed, self.dark, 0) if self.max_dark else self.misses

    def _flow(self, centres: np.ndarray) -> np.ndarray:
        """(M, 2) starting velocities of new tracks at ``centres``: the median velocity of the
        ``flow_neighbours`` nearest confirmed tracks, or rest when there are fewer."""
        k = self.flow_neighbours
        confirmed = np.flatnonzero(self.hits >= self.confirm_hits)
        if k == 0 or len(confirmed) < k or len(centres) == 0:
            return np.zeros((len(centres), 2))
        # a few births a frame among hundreds of tracks: all distances at once beat building a tree
        d2 = np.square(centres[:, 0, None] - self.x[confirmed, 0])  # (M, C)
        d2 += np.square(centres[:, 1, None] - self.x[confirmed, 1])
        nearest = np.argpartition(d2, k - 1, axis=1)[:, :k]
        velocities = np.sort(self.x[confirmed, 2:4][nearest], axis=1)  # (M, k, 2), per axis
        middle = k // 2
        return velocities[:, middle] if k % 2 else (velocities[:, middle - 1] + velocities[:, middle]) / 2

    # ------------------------------------------------------------ revival
    def _bury(self, dead: np.ndarray) -> None:
        """Keep the deleted tracks ``dead`` (bool) for ``revive_frames`` updates."""
        if not dead.any():
            return
        rows = {name: getattr(self, name)[dead] for name in self._FIELDS}
        rows["left"] = np.full(int(dead.sum()), self.revive_frames, np.int64)
        self._dead = rows if not self._dead else {name: np.concatenate([self._dead[name], rows[name]])
                                                  for name in rows}

    def _revive(self, detections: Detections, unmatched: np.ndarray, detection_ids: np.ndarray) -> np.ndarray:
        """Give dead tracks whose gate holds a detection no live track took their id and state back;
        age the rest.  Returns the detections still unmatched."""
        dead = self._dead
        if len(unmatched):
            pairs, _, _ = match(dead["x"][:, :2], self._gates(dead["pp"]), detections.centres[unmatched])
            if len(pairs):
                g, k = pairs[:, 0], unmatched[pairs[:, 1]]
                start = len(self.x)
                self._append({name: dead[name][g] for name in self._FIELDS})
                rows = np.arange(start, len(self.x))
                self.misses[rows] = 0
                self.dark[rows] = 0
                self.hits[rows] = 0  # back as new: its hole does not follow a velocity from before the gap
                self._correct(rows, k, detections)
                detection_ids[k] = self.ids[rows]
                unmatched = np.setdiff1d(unmatched, k)
                gone = np.zeros(len(dead["ids"]), bool)
                gone[g] = True
                dead = {name: value[~gone] for name, value in dead.items()}
        dead["left"] = dead["left"] - 1
        alive = dead["left"] > 0
        self._dead = {name: value[alive] for name, value in dead.items()} if alive.any() else {}
        return unmatched

    # ------------------------------------------------------------- holes
    def holes(self, at: float, *, uncertainty_sigma: float = 1.3, max_growth: float = 1.25) -> Detections:
        """Where every particle will be at time ``at`` (seconds): the holes to draw.

        Tracks seen at least twice (``MOVING_HITS``: they have a velocity), confirmed
        or not, also while coasting, are moved along their velocity; each radius
        grows by ``uncertainty_sigma`` standard deviations of the predicted
        position, at most ``max_growth`` pixels.  New particles, seen once, are
        moved along their neighbours' flow (``flow_holes``; without it they get a
        hole where they were seen).  The defaults (1.3 sd, at most 1.25 px) are the
        twin's best balance of backscatter removed and scene light kept (history:
        docs/decisions/004-tracking-tuning.md).
        """
        return self.snapshot().holes(at, uncertainty_sigma=uncertainty_sigma, max_growth=max_growth)

    def snapshot(self) -> "Prediction":
        """The tracks as they are now, frozen: holes for any later time, from another thread."""
        confirmed = self.hits >= self.confirm_hits
        # a tentative track that was just missed has no hole, a confirmed one for max_misses
        shown = (confirmed & (self._unexpected(confirmed) <= self.max_misses)) | (self.misses == 0)
        moving = confirmed | (self.hits >= (1 if self.flow_holes else MOVING_HITS))
        return Prediction(self.x[shown], self.pp[shown], self.pv[shown], self.vv[shown], self.ids[shown],
                          moving[shown], self.timestamp, self.qa[shown])


@dataclass(frozen=True, eq=False)
class Prediction:
    """A frozen copy of the tracks after one update, to draw holes for any time after it
    (``PREDICT_AHEAD``: the time ``run`` draws them for), while the tracker goes on with later
    frames."""

    x: np.ndarray
    pp: np.ndarray
    pv: np.ndarray
    vv: np.ndarray
    ids: np.ndarray
    moving: np.ndarray  # (N,) bool: the hole follows the velocity (seen MOVING_HITS times or more)
    timestamp: float | None
    accel_noise: np.ndarray  # (N,) px/s^2, each track's

    def holes(self, at: float, *, uncertainty_sigma: float = 1.3, max_growth: float = 1.25) -> Detections:
        """Where every particle will be at time ``at`` (seconds); see :meth:`Tracker.holes`."""
        n = len(self.x)
        if n == 0 or self.timestamp is None:
            return Detections.empty()
        dt = max(0.0, at - self.timestamp)
        moving = self.moving
        centres = self.x[:, :2] + np.where(moving[:, None], self.x[:, 2:4] * dt, 0.0)
        variance = _position_variance(self.pp, self.pv, self.vv, np.square(self.accel_noise)[:, None], dt)
        sd = np.sqrt(np.maximum(variance[:, 0], variance[:, 1]))
        growth = np.minimum(uncertainty_sigma * sd, max_growth)
        radii = np.maximum(self.x[:, 4], 0.5) + np.where(moving, growth, 0.0)
        return Detections(centres, radii, track_ids=self.ids.copy())


def _position_variance(pp: np.ndarray, pv: np.ndarray, vv: np.ndarray, q: float, dt: float) -> np.ndarray:
    """Position variance per axis ``dt`` seconds ahead under constant velocity with white
    acceleration of spectral density ``q`` (the (0, 0) entry of F P F^T + Q)."""
    return pp + 2 * dt * pv + dt * dt * vv + q * dt ** 4 / 4
