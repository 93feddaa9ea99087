"""The coarse scale: particles too large and faint for the working resolution.

A defocused particle near the lens is a wide, faint disc (up to ~40 px radius at 1456x1088) whose
light per pixel sinks into the noise and texture that the working-resolution test measures
against, while it sends back the most light of all (inverse square).  Pooled ``COARSE`` x
``COARSE`` more, the same disc is a compact spot of a few pixels over four times less noise, and
the single-frame test (spatial background, rings it must outshine) finds it there.  What the
coarse scale finds is merged with the working-resolution detections (:func:`merge_scales`).
"""

from __future__ import annotations

import cv2
import numpy as np

from ...detections import Detections
from .background import NOISE_WINDOW, frame_alone, threshold_mask
from .components import label, measure

#: pooling of the working image for the coarse scale (a 40 px radius disc at 1456 px is 5 px there)
COARSE = 4
#: ring radii (coarse pixels) a coarse spot must outshine: larger patches are lit scene
COARSE_RINGS = (3, 6, 12)
#: the coarse threshold in units of the detector's ``k``
COARSE_K = 1.5
#: background cell and texture median window, coarse pixels
COARSE_CELL = 8
COARSE_WINDOW = 24
#: smallest radius (full-resolution pixels, for frames 800 px wide; scaled with the width) a coarse
#: detection may have: smaller particles are the working resolution's
COARSE_MIN_RADIUS = 6.0
#: a coarse detection holding this many working-resolution detections within ABSORB_REACH of its
#: radius is one wide particle the working resolution broke up (a ring, a textured flake, a
#: defocused disc whose noise looked like several peaks): it replaces them (three touching discs
#: stay three)
ABSORB = 4
ABSORB_REACH = 0.8


def coarse_particles(half: np.ndarray, learnt: np.ndarray | None, *, factor: int, width: int, k: float,
                     min_contrast: float, core: float, halo: float, max_radius: float) -> Detections:
    """Wide particles of the working image ``half`` (uint8) found at ``COARSE`` times less resolution,
    in full-resolution pixels: radius at least ``COARSE_MIN_RADIUS`` (scaled with ``width``).

    learnt: the learnt background at working resolution (uint8) when it fits a still view, else
    None: a coarse spot must then also stand out against it (static lit scene does not).  k,
    min_contrast: the detector's threshold; core, halo, max_radius: as :func:`measure`."""
    h, w = half.shape
    cw, ch = max(w // COARSE, 8), max(h // COARSE, 8)
    small = cv2.resize(half, (cw, ch), interpolation=cv2.INTER_AREA)
    mask, excess, noise, limit = frame_alone(small, cell=COARSE_CELL, window=COARSE_WINDOW, rings=COARSE_RINGS,
                                             noise_window=NOISE_WINDOW, k=COARSE_K * k, min_contrast=min_contrast)
    if learnt is not None:
        pooled = cv2.resize(learnt, (cw, ch), interpolation=cv2.INTER_AREA)
        cv2.bitwise_and(mask, threshold_mask(small, pooled, limit)[0], dst=mask)
    if not cv2.countNonZero(mask):
        return Detections.empty()
    pool = w // cw
    found = measure(label(mask), excess, noise, halo=halo, core=core, max_radius=max_radius, split=False,
                    frame_width=width, factor=factor * pool)
    found = found[found.radii >= COARSE_MIN_RADIUS * max(1.0, width / 800.0)]
    # flux in working pixels, as the working resolution's scores
    return Detections(found.centres, found.radii, found.scores * (pool * pool))


def merge_scales(fine: Detections, coarse: Detections) -> Detections:
    """The working resolution's detections with the coarse scale's: a coarse particle holding no
    fine detection within its radius is added; one holding ``ABSORB`` or more within
    ``ABSORB_REACH`` of its radius replaces them; otherwise the fine ones stand.  The fine
    detections' ``cut`` carries over."""
    if len(coarse) == 0:
        return fine
    if len(fine) == 0:
        return Detections(coarse.centres, coarse.radii, coarse.scores, cut=fine.cut)
    d2 = ((coarse.centres[:, None, :] - fine.centres[None, :, :]) ** 2).sum(-1)
    inside = d2 < (ABSORB_REACH * coarse.radii[:, None]) ** 2
    absorbs = inside.sum(1) >= ABSORB
    alone = ~(d2 < coarse.radii[:, None] ** 2).any(1)
    kept_fine = fine[~inside[absorbs].any(0)] if absorbs.any() else fine
    added = coarse[alone | absorbs]
    if len(added) == 0:
        return kept_fine
    return Detections(np.concatenate([kept_fine.centres, added.centres]),
                      np.concatenate([kept_fine.radii, added.radii]),
                      np.concatenate([kept_fine.scores, added.scores]), cut=fine.cut)
