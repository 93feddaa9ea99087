"""Stages 4-5: :func:`label` (connected components of the candidate mask, as per-pixel arrays) and
:func:`measure` (split, reject, and measure each particle's centre, radius and flux).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, NotRequired, TypedDict

import cv2
import numpy as np

from ...detections import Detections
from .background import noise_at
from .groups import _gather, _group_max
from .split import _split_peaks, split_images

if TYPE_CHECKING:
    from .bands import BandPool


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
    return _measure(components, excess, noise, halo=halo, max_radius=max_radius, split=split,
                    frame_width=frame_width, factor=factor, lone_k=lone_k, seen=seen, core=core, full=full,
                    fine=fine, split_budget=split_budget)[0]


def _measure(components: Components, excess: np.ndarray, noise: np.ndarray, *,
             halo: float, max_radius: float, split: bool, frame_width: int, factor: int = 2,
             lone_k: float = 0.0, seen: np.ndarray | None = None, core: float = 0.0,
             full: tuple[np.ndarray, np.ndarray] | None = None, fine: bool = True,
             split_budget: int = 0, images: tuple | None = None) -> tuple[Detections, int, int]:
    """:func:`measure`'s (detections, how many of them come first, one a component in component
    order -- the rest are the further particles split components held, in component order --, the
    work the split would do unbounded, pixel-peak pairs).  images: the split's
    :func:`~.split.split_images` of ``excess``, when made already."""
    n = components["count"]
    if n == 0:
        return Detections.empty(), 0, 0
    lab, x, y = components["labels"], components["x"], components["y"]
    flat = components.get("flat")
    if flat is None:
        flat = y * excess.shape[1] + x
    weight = np.maximum(_gather(excess, flat).astype(np.float64), 1e-3)
    area = np.bincount(lab, minlength=n)
    (peak,) = _group_max(lab, n, weight)
    cut = work = 0
    components_n = n
    if split:
        unsplit = lab
        lab, n, cut, work = _split_peaks(lab, x, y, weight, excess, noise, n, full=full if factor == 2 else None,
                                         fine=fine, area=area, peak=peak, flat=flat, budget=split_budget,
                                         images=images)
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
    return (Detections(centres[keep], radii[keep], scores=wsum[keep], cut=cut), int(keep[:components_n].sum()),
            work)


#: fewest components a band of :func:`measure_in_bands` holds: fewer cost more to hand over than to measure
MIN_COMPONENTS = 16


def measure_in_bands(components: Components, excess: np.ndarray, noise: np.ndarray, pool: BandPool,
                     **settings: Any) -> Detections:
    """:func:`measure`'s detections, in its order, measured in bands of components on ``pool``'s threads.

    The components are labelled once over the whole frame, in the order of their first pixel
    (raster order), so consecutive labels make horizontal bands of the frame; each band holds
    whole components -- a particle on a seam belongs to the band of its first row -- and about
    the same number of pixels.  A component's split and measures depend on its own pixels alone,
    so each band's detections are the whole frame's for those components; they are put back in
    :func:`measure`'s order (each component's first particle by label, then the further particles
    of split components by label).  The split's budget bounds the whole frame's work: when the
    bands' work adds up to more than it, the frame is measured again whole (as :func:`measure`
    chooses which components to leave unsplit over the frame).  settings: :func:`measure`'s."""
    n = components["count"]
    count = min(pool.threads, n // MIN_COMPONENTS)
    if count < 2:
        return measure(components, excess, noise, **settings)
    lab = components["labels"]
    area = np.bincount(lab, minlength=n)
    pixels = np.cumsum(area)
    edges = np.searchsorted(pixels, pixels[-1] * np.arange(1, count) / count, side="right")
    edges = np.unique(np.concatenate([[0], np.minimum(edges, n), [n]]))
    spans = [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]
    flat = components.get("flat")
    parts: dict[int, tuple[Detections, int, int]] = {}
    images = None  # the split's frame-wide images, once for all bands (in bands)
    if settings.get("split") and area.max() >= 8:
        images = split_images(excess, settings.get("fine", True), pool)

    def work(a: int, b: int) -> None:
        sel = np.flatnonzero((lab >= a) & (lab < b))
        part: Components = {"labels": lab[sel] - a, "x": components["x"][sel], "y": components["y"][sel],
                            "count": b - a}
        if flat is not None:
            part["flat"] = flat[sel]
        parts[a] = _measure(part, excess, noise, images=images, **settings)

    pool.run(work, spans)
    found = [parts[a] for a, _ in spans]
    budget = settings.get("split_budget", 0)
    if budget and sum(w for _, _, w in found) > budget:
        return measure(components, excess, noise, **settings)
    order = [(d, slice(None, first)) for d, first, _ in found] + [(d, slice(first, None)) for d, first, _ in found]
    return Detections(np.concatenate([d.centres[s] for d, s in order]).reshape(-1, 2),
                      np.concatenate([d.radii[s] for d, s in order]),
                      scores=np.concatenate([d.scores[s] for d, s in order]), cut=sum(d.cut for d, _, _ in found))


def brightest(found: Detections, limit: int) -> Detections:
    """At most ``limit`` particles (0 = no ceiling): the brightest by score (flux), in their order;
    the rest are added to ``cut``."""
    if not limit or len(found) <= limit:
        return found
    keep = np.sort(np.argsort(-found.scores, kind="stable")[:limit])
    kept = found[keep]
    return Detections(kept.centres, kept.radii, kept.scores, kept.track_ids, found.cut + len(found) - limit)
