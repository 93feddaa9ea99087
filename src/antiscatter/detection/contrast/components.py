"""Stages 4-5: :func:`label` (connected components of the candidate mask, as per-pixel arrays) and
:func:`measure` (split, reject, and measure each particle's centre, radius and flux).
"""

from __future__ import annotations

from typing import NotRequired, TypedDict

import cv2
import numpy as np

from ...detections import Detections
from .background import noise_at
from .groups import _gather, _group_max
from .split import _split_peaks


class Components(TypedDict):
    """What :func:`label` returns: the non-zero pixels of a mask, P of them, with their component.

    A plain dict at run time (callers build one by hand: ``flat`` may be left out)."""

    labels: np.ndarray  #: (P,) intp, component index 0..count-1
    x: np.ndarray  #: (P,) column, working pixels
    y: np.ndarray  #: (P,) row, working pixels
    flat: NotRequired[np.ndarray]  #: (P,) index into the raveled image, y * width + x
    count: int  #: number of components


def label(mask: np.ndarray) -> Components:
    """Connected components (8-connected) of ``mask`` as per-pixel arrays of the non-zero pixels
    (:class:`Components`).

    The pixels are found with numpy's flatnonzero on a boolean view (a third of the time of
    cv2.findNonZero at 1456x1088) and labelled 16-bit whenever they are too few to need more.
    """
    flat = np.flatnonzero(np.greater(mask, 0))
    if len(flat) == 0:
        empty = np.empty(0, np.intp)
        return {"labels": empty, "x": empty, "y": empty, "flat": empty, "count": 0}
    ltype = cv2.CV_16U if len(flat) < 65535 else cv2.CV_32S  # no more components than pixels
    count, labels = cv2.connectedComponents(mask, connectivity=8, ltype=ltype)
    y, x = np.divmod(flat, mask.shape[1])
    return {"labels": labels.ravel()[flat].astype(np.intp) - 1, "x": x, "y": y, "flat": flat, "count": count - 1}


def measure(components: Components, excess: np.ndarray, noise: np.ndarray, *,
            halo: float, max_radius: float, split: bool, frame_width: int, factor: int = 2,
            lone_k: float = 0.0, seen: np.ndarray | None = None, core: float = 0.0,
            full: tuple[np.ndarray, np.ndarray] | None = None, fine: bool = True,
            split_budget: int = 0) -> Detections:
    """Centres (brightness-weighted), covering radii and scores of the components; centres and
    radii in full-resolution pixels.

    The radius reaches the farthest pixel whose excess is at least ``core`` of the component's
    peak (0: the farthest of all), plus ``halo``.  The score is the particle's flux: its excess
    summed over its pixels (grey levels x working pixels) -- the light it sends back.  Unlike its
    peak it falls with the light where a near particle is clipped at white, and it goes as the
    fourth power of the distance whether the camera resolves the particle or not.

    excess: uint8 light above the background; noise: the coarse noise map (for splitting and
    ``lone_k``: a component of one working pixel is kept only when its excess exceeds ``lone_k``
    noise units -- a noise spike is almost always alone, a particle's light spreads; 0 = off --
    or where ``seen`` (uint8 working-resolution mask, optional) is set: where the last frame was
    bright, so a faint particle that persists is kept).

    full: (the full-resolution frame, its working background) when the working image is its 2x2
    blocks: flat components are split by their shape at full resolution (:func:`_split_flat`).
    fine: components are split at the 3x3 maxima of the excess smoothed by the 3x3 binomial
    kernel, 2 px apart or more; otherwise (coarse) at the 5x5 maxima of the 3x3-summed excess,
    3 px apart (6 at full resolution), which took two particles that close for one.  The
    detector splits coarsely while its own pattern is on the scene: there the edge of a
    hole crossing a particle is a dip in its light.  Figures: docs/decisions/001-contrast-tuning.md.

    split_budget: the split's bound on its work (see :func:`_split_peaks`; 0 = none); the
    components it left whole are counted in the detections' ``cut``.
    """
    n = components["count"]
    if n == 0:
        return Detections.empty()
    lab, x, y = components["labels"], components["x"], components["y"]
    flat = components.get("flat")
    if flat is None:
        flat = y * excess.shape[1] + x
    weight = np.maximum(_gather(excess, flat).astype(np.float64), 1e-3)
    area = np.bincount(lab, minlength=n)
    (peak,) = _group_max(lab, n, weight)
    cut = 0
    if split:
        unsplit = lab
        lab, n, cut = _split_peaks(lab, x, y, weight, excess, noise, n, full=full if factor == 2 else None,
                                   fine=fine, area=area, peak=peak, flat=flat, budget=split_budget)
        if lab is not unsplit:
            area = np.bincount(lab, minlength=n)
            (peak,) = _group_max(lab, n, weight)
    wsum = np.bincount(lab, weights=weight, minlength=n)
    cx = np.bincount(lab, weights=weight * x, minlength=n) / wsum
    cy = np.bincount(lab, weights=weight * y, minlength=n) / wsum
    if core:  # the particle is where its light is at least `core` of its peak, not all its halo
        inner = np.flatnonzero(weight >= core * peak[lab])  # the peak itself is always in
        lab, x, y = lab[inner], x[inner], y[inner]
    (far2,) = _group_max(lab, n, (x - cx[lab]) ** 2 + (y - cy[lab]) ** 2)
    # working -> full resolution: pixel centres map as u = f x + (f - 1) / 2
    offset = (factor - 1) / 2.0
    centres = np.empty((n, 2))
    np.multiply(cx, factor, out=centres[:, 0])
    np.multiply(cy, factor, out=centres[:, 1])
    centres += offset
    far = np.sqrt(far2)
    radii = factor * (far + 0.5) + halo  # the farthest pixel's far edge, plus the blur halo
    keep = (radii <= max_radius * max(1.0, frame_width / 800.0)) & (wsum > 0)
    if lone_k > 0:
        lone = np.flatnonzero(area == 1)
        if len(lone):
            px, py = np.rint(cx[lone]).astype(np.intp), np.rint(cy[lone]).astype(np.intp)
            strong = peak[lone] > lone_k * noise_at(noise, px, py, excess.shape)
            if seen is not None:
                strong |= seen[py, px] > 0
            keep[lone] &= strong
    return Detections(centres[keep], radii[keep], scores=wsum[keep], cut=cut)


def brightest(found: Detections, limit: int) -> Detections:
    """At most ``limit`` particles (0 = no ceiling): the brightest by score (flux), in their order;
    the rest are added to ``cut``."""
    if not limit or len(found) <= limit:
        return found
    keep = np.sort(np.argsort(-found.scores, kind="stable")[:limit])
    kept = found[keep]
    return Detections(kept.centres, kept.radii, kept.scores, kept.track_ids, found.cut + len(found) - limit)
