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
exposure after, it is dimmed and looked at again.  Between looks a particle sends back none of
the light a dim hole leaves it.  Depth probing reads a particle vanished under its probe as held
by it, so a probed run does not rest.

Only confirmed tracks are turned down: a confirmed track's hole stays on its predicted path
through a miss (coasting), a tentative one's goes out, and the particle is lit in full until
it is found again (turning down every track lost a new particle's first frames).  A confirmed
track seen lit in full (not under its hole) goes to ``target`` over its flux; detectors whose
scores are not a flux (NaN, the ``seed`` detector's) leave every hole at ``ceiling``.  Ids are
the tracker's; the levels of tracks the tracker no longer holds are forgotten.

With depth probing (:class:`~antiscatter.probe.DepthProbe`) a track had its hole's light when
its verdict found it dimmed under its own probe or hole (or vanished under it): ``dimmed`` is
then the probe's ``dimmed``, and the probes and settled holes are drawn at the tracks' levels
(between exposures, pulsed intervals stay dark).

The measured history of these choices: ``docs/decisions/005-light-and-pattern-tuning.md``.
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
#: particle's working pixels) a dimmed particle is kept at (default 20: a few times the faintest
#: particles the detector finds; history: docs/decisions/005-light-and-pattern-tuning.md)
TARGET_FLUX = 20.0

#: the most a level falls in one frame, and what a miss multiplies it by
FALL = 0.5
RISE = 2.0

#: frames a confirmed track's hole stays fully dark after each frame that found its particle, with
#: pulsed holes (dim ones: ``DIM_REST``, see :func:`rest_for`)
REST = 1

#: ... with dim holes, which leave their particle its level through the whole frame, not only while
#: the camera exposes (default 2: the looks cost twice a pulse's light, and resting two frames
#: after each withheld more than it lost; history: docs/decisions/005-light-and-pattern-tuning.md)
DIM_REST = 2


def rest_for(strategy: str) -> int:
    """The default ``rest`` for holes of ``strategy`` (its :class:`~antiscatter.strategies.Strategy`'s:
    ``dim`` ``DIM_REST``, the others ``REST``)."""
    from .strategies import strategy_entry

    return strategy_entry(strategy).rest


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

    def set_ceiling(self, ceiling: float) -> None:
        """The most a hole gives from now on (0..1 of full light, at least ``floor``); every
        track's level is held under it."""
        self.ceiling = min(max(float(ceiling), self.floor), 1.0)
        np.minimum(self.level, self.ceiling, out=self.level)
        np.minimum(self.least, self.ceiling, out=self.least)

    def grey(self, track_ids: np.ndarray) -> np.ndarray:
        """:meth:`of` as the projector's grey levels, 0..255."""
        return np.rint(self.of(track_ids) * 255.0).astype(np.uint8)


def _rows(ordered: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """The row of each of ``ids`` in the ascending ``ordered`` (-1 where it is not there)."""
    at, found = rows_in(ordered, ids)
    return np.where(found, at, -1)
