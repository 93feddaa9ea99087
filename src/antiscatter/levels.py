"""How much light each dim hole leaves its particle: just enough for the camera to see it.

With ``dim`` and ``pulse`` holes a particle is darkened, not blacked out, so the next frame's
detector still finds it (the closed-loop catch, see ``antiscatter twin``); the light it is
left is backscatter the lamp still makes.  One level for every hole is set by the faintest
particle that must stay visible, and most of the backscatter comes from near, bright particles
that would be seen at a fraction of it.  :class:`HoleLevels` gives each tracked particle its
own level from what the detector measured of it under its hole: its flux (the detection's
score, the light it sends back) is proportional to the light it got, so the level that brings
it to ``target`` is its level times ``target`` over its flux.  The level falls to at most half
of itself a frame (a noisy flux does not black a hole out at once) and never below ``floor``;
a particle missed under its own hole gets twice its level back, and that level becomes the
least it is given from then on (a level it was lost at is not tried again).

A confirmed track just seen also rests (``rest`` frames; with ``run`` 1 for pulsed holes, 2 for
dim ones, :func:`rest_for`): its hole is left fully dark through the next exposure instead of
dimmed, the camera cannot see the particle then, and the tracker carries its hole along the
predicted path (an expected miss: it neither raises the level nor counts against the track); the
exposure after, it is dimmed and looked at again.  Between looks a particle sends back none of the light a dim hole leaves it.  In the twin
(co-located, 5 ms, prediction, scenes 1-6 each) dim holes removed 0.893 -> 0.899 (mixed; scenes
7-18 0.871 -> 0.886, at 20 ms 0.874 -> 0.888), textured 0.872 -> 0.885, survey 0.842 -> 0.865,
dense 0.805 -> 0.821, sand 0.776 -> 0.795, snow 0.922 -> 0.938, bubbles 0.932 -> 0.934, keeping
0.000-0.006 less of the scene light (the holes of coasting tracks grow with their uncertainty);
pulsed holes, which leave their particles light only while the camera exposes, -0.006..+0.012
(mixed 0.914 -> 0.912, scenes 7-18 0.895 -> 0.900, survey 0.867 -> 0.879, bubbles 0.949 ->
0.943; mean +0.004).  Two frames of rest after each look removed less than one (mixed, dim,
before the light map's fixes: 0.895 against 0.900).  Depth probing reads a particle vanished
under its probe as held by it, so a probed run does not rest.

Only confirmed tracks are turned down: a confirmed track's hole stays on its predicted path
through a miss (coasting), a tentative one's goes out, and the particle is lit in full until
it is found again.  In the twin (co-located, pulse, 5 ms, mixed) turning down every track --
a new particle at ``target`` over its lit flux at once -- lost its first frames: removed
0.64 against 0.77 with one level for all over frames 1-3 (8 scenes), and with a 480 Hz
projector over 60 frames 0.908 against 0.915 (9 scenes); turning down confirmed tracks alone
0.927 there, and at 120 Hz the same as every track (0.888 / 0.863 pulse / dim against 0.887 /
0.864, 12 scenes).  A confirmed track seen lit in full (not under its hole) goes to ``target``
over its flux; detectors whose scores are not a flux (NaN, the ``seed`` detector's) leave every
hole at ``ceiling``.  Ids are the tracker's; the levels of tracks the tracker no longer holds
are forgotten.

With depth probing (:class:`~antiscatter.probe.DepthProbe`) a track had its hole's light when
its verdict found it dimmed under its own probe or hole (or vanished under it): ``dimmed`` is
then the probe's ``dimmed``, and the probes and settled holes are drawn at the tracks' levels
(between exposures, pulsed intervals stay dark).  Twin, 12 cm, 5 ms, against one level: pulse
0.801 / 0.903 -> 0.814 / 0.900 removed / kept (seeds 1-12), 0.804 / 0.899 -> 0.814 / 0.899
(13-36); dim 0.712 / 0.927 -> 0.736 / 0.924, 0.716 / 0.925 -> 0.739 / 0.924.  (When every track
was turned down and the target was 40, probing lost scene light: pulse kept 0.895.)
"""

from __future__ import annotations

import numpy as np

from .detections import Detections, rows_in

__all__ = ["DIM_REST", "HoleLevels", "LEVELS", "MIN_LEVEL", "REST", "TARGET_FLUX", "rest_for"]

#: the light in dim and pulsed holes: each particle's own (:class:`HoleLevels`) or ``dim_level`` for all
LEVELS = ("adaptive", "fixed")

#: the least light a hole leaves its particle (a fraction of the lamp's): below it a particle's
#: image is lost in the noise the detector divides up where the lamp gave little
MIN_LEVEL = 0.02

#: the flux (the ``contrast`` detector's score: grey levels above the background summed over the
#: particle's working pixels) a dimmed particle is kept at -- a few times the faintest particles
#: the detector finds (a tenth of its detections score below 8).  Twin (co-located, 5 ms, mixed,
#: 12 + 12 scenes): 40 / 20 / 10 removed with pulsed holes 0.888 / 0.895 / - and 0.892 / 0.896 /
#: 0.896, with dim holes 0.863 / 0.871 / - and 0.866 / 0.872 / 0.872, scene light the same;
#: textured and sand +0.002..+0.006 for 20, a 480 Hz projector the same (0.927 / 0.926).  (40,
#: when every track was turned down, confirmed or not: 20-80 and a floor of 0.01-0.04 were within
#: 0.005 of each other then.)
TARGET_FLUX = 20.0

#: the most a level falls in one frame, and what a miss multiplies it by
FALL = 0.5
RISE = 2.0

#: frames a confirmed track's hole stays fully dark after each frame that found its particle, with
#: pulsed holes (dim ones: ``DIM_REST``, see :func:`rest_for`)
REST = 1

#: ... with dim holes, which leave their particle its level through the whole frame, not only while
#: the camera exposes: the looks cost twice a pulse's light, and resting two frames after each
#: withheld more than it lost to the particles the tracker's path then missed.  Twin (co-located,
#: prediction, 5 ms, scene seeds 1-6, 1 s), 2 against 1: mixed 0.9194 -> 0.9242 removed (seeds
#: 7-12 0.9086 -> 0.9141; over 5 s 0.9370 -> 0.9426), sand 0.8279 -> 0.8346, snow 0.9453 ->
#: 0.9497, survey 0.8919 -> 0.8966, textured 0.9067 -> 0.9110, dense 0.8586 -> 0.8662, bubbles
#: 0.9517 -> 0.9483; scene light 0.0001-0.0026 less (dense 0.006); 3: mixed 0.9185.  Pulsed holes
#: with 2: mixed 0.9334 -> 0.9344 keeping 0.0010 less, so they keep ``REST``.  (Measured once
#: before, before lost tracks found on their path kept their motion, 2 removed less than 1.)
DIM_REST = 2


def rest_for(strategy: str) -> int:
    """The default ``rest`` for holes of ``strategy`` (``dim``: ``DIM_REST``; else ``REST``)."""
    return DIM_REST if strategy == "dim" else REST


class HoleLevels:
    """Per-track hole levels (fractions of full light) between ``floor`` and ``ceiling``.

    Call :meth:`update` once a frame after the tracker, and :meth:`of` for the holes to draw.
    rest: frames a confirmed track's hole is left fully dark after each frame that found its
    particle (0 = never); :attr:`resting` holds the ids whose holes :meth:`of` gives 0 now.
    """

    def __init__(self, ceiling: float, *, floor: float = MIN_LEVEL, target: float = TARGET_FLUX,
                 fall: float = FALL, rise: float = RISE, rest: int = 0) -> None:
        if not (0 <= floor <= ceiling <= 1):
            raise ValueError(f"floor, ceiling: got {floor}, {ceiling}; allowed 0 <= floor <= ceiling <= 1")
        if not (isinstance(rest, (int, np.integer)) and rest >= 0):
            raise ValueError(f"rest: got {rest!r}, allowed a whole number of frames >= 0")
        if not (target > 0 and 0 < fall <= 1 and rise >= 1):
            raise ValueError(f"target, fall, rise: got {target}, {fall}, {rise}; allowed target > 0, "
                             "0 < fall <= 1, rise >= 1")
        self.ceiling, self.floor, self.target, self.fall, self.rise = ceiling, floor, target, fall, rise
        self.ids = np.empty(0, np.int64)  # sorted
        self.level = np.empty(0)
        self.least = np.empty(0)  # a level the track was lost at, doubled: the least it gets again
        self.rest = int(rest)
        self.since = np.empty(0, np.int64)  # frames since each track's particle was last found
        self.resting = np.empty(0, np.int64)  # ids whose holes stay dark through the next exposure

    def _lookup(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(level, least, since) of each of ``ids``; ``ceiling``, 0 and 0 for ids not known."""
        if len(self.ids) == 0:
            return np.full(len(ids), self.ceiling), np.zeros(len(ids)), np.zeros(len(ids), np.int64)
        pos, known = rows_in(self.ids, ids)
        return (np.where(known, self.level[pos], self.ceiling), np.where(known, self.least[pos], 0.0),
                np.where(known, self.since[pos], 0))

    def update(self, found: Detections, detection_ids: np.ndarray, dimmed: np.ndarray | None,
               alive: np.ndarray, confirmed: np.ndarray, rested: np.ndarray | None = None) -> None:
        """Learn from this frame.

        found: its detections (scores: flux, NaN when unknown); detection_ids: (D,) the track of
        each (-1 none); dimmed: ids of the tracks whose holes were on during its exposure (None:
        none, e.g. under a flash); alive: every id the tracker holds now; confirmed: those of
        them that are confirmed -- only they are turned down (below); rested: of ``dimmed``,
        those whose holes were fully dark (:attr:`resting` when that pattern was drawn): not
        being found is expected of them.
        """
        alive = np.sort(np.asarray(alive, np.int64))
        level, least, since = self._lookup(alive)
        since += 1
        ids = np.asarray(detection_ids, np.int64)
        tracked = ids >= 0
        resting = np.empty(0, np.int64)
        if len(alive):
            # every track by its row in ``alive`` (sorted), found once
            seen = _rows(alive, ids[tracked])
            under = _rows(alive, np.empty(0, np.int64) if dimmed is None else np.asarray(dimmed, np.int64))
            was_under = np.zeros(len(alive), bool)
            was_under[under[under >= 0]] = True
            dark = np.zeros(len(alive), bool)  # rested: left in the dark, not dimmed
            if rested is not None and len(rested):
                r = _rows(alive, np.asarray(rested, np.int64))
                dark[r[r >= 0]] = True
                was_under &= ~dark
            flux = found.scores[tracked]
            measured = (seen >= 0) & np.isfinite(flux) & (flux > 0)
            pos, flux = seen[measured], flux[measured]
            current = level[pos]
            wanted = np.where(was_under[pos], np.maximum(current * self.target / flux, current * self.fall),
                              self.target / flux)
            level[pos] = np.clip(np.maximum(wanted, least[pos]), self.floor, self.ceiling)
            missed = was_under.copy()
            missed[seen[seen >= 0]] = False
            level[missed] = least[missed] = np.minimum(level[missed] * self.rise, self.ceiling)
            tentative = np.ones(len(alive), bool)
            sure = _rows(alive, np.asarray(confirmed, np.int64))
            tentative[sure[sure >= 0]] = False
            level[tentative] = self.ceiling  # not yet confirmed
            since[seen[seen >= 0]] = 0
            if self.rest:
                # found lately; not one found although its hole was dark: that hole missed it
                resting = alive[~tentative & (since < self.rest) & ~(dark & (since == 0))]
        self.ids, self.level, self.least, self.since, self.resting = alive, level, least, since, resting

    def of(self, track_ids: np.ndarray) -> np.ndarray:
        """Levels of the holes of ``track_ids`` (-1, an untracked hole: ``ceiling``; resting: 0)."""
        ids = np.asarray(track_ids, np.int64)
        level = self._lookup(ids)[0]
        if len(self.resting):
            level = np.where(self._resting(ids), 0.0, level)
        return np.where(ids >= 0, level, self.ceiling)

    def _resting(self, ids: np.ndarray) -> np.ndarray:
        """(N,) bool: which of ``ids`` are resting."""
        return rows_in(self.resting, ids)[1]

    def rested(self, hole_ids: np.ndarray) -> np.ndarray:
        """Of a pattern's holes (their track ids), those drawn dark because they rest: what
        :meth:`update` takes as ``rested`` once an exposure has been taken under that pattern."""
        ids = np.asarray(hole_ids, np.int64)
        return ids[self._resting(ids)]

    def grey(self, track_ids: np.ndarray) -> np.ndarray:
        """:meth:`of` as the projector's grey levels, 0..255."""
        return np.rint(self.of(track_ids) * 255.0).astype(np.uint8)


def _rows(ordered: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """The row of each of ``ids`` in the ascending ``ordered`` (-1 where it is not there)."""
    at, found = rows_in(ordered, ids)
    return np.where(found, at, -1)
