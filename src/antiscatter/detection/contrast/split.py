"""Stage 5's split: components that hold several particles (touching or overlapping) cut at
their intensity peaks (:func:`_split_peaks`) or, flat and saturated ones, at the necks of their
shape (:func:`_split_flat`); every pixel then goes to its nearest kept peak.
"""

from __future__ import annotations

from functools import partial
from typing import Callable

import cv2
import numpy as np

from .background import noise_at
from .bands import BandPool
from .groups import _FAST_AT, _gather, _group_max
from .kernels import _AROUND, _K3, _K5

#: where :func:`_nearest_peak`'s missing peaks lie, in 32-bit coordinates: for working images up
#: to a third of this a side, farther than any pixel is from its own peaks, with squared distances
#: that still fit 32 bits (larger ones are measured in 64)
_FAR = 30000
#: the spots of :func:`_spots` are looked for below this share of their component's peak: one as
#: bright as the peak is the bright particle itself -- or, in a flat one, a pixel of its plateau
#: that the 2x2 pooling cut
SPOT_SHARE = 0.9
#: smallest core (pixels above half the peak) that can hold two discs with a neck
_MIN_CORE = 20
#: a component with this many working pixels at ``_PLATEAU_SHARE`` of its peak or more is flat (a
#: saturated or uniform particle, or several): its shape is looked at even when its intensity had
#: maxima to split at -- they lie where the 2x2 pooling cut the plateau's edges, not at particles.
#: Only while no pattern of the lamp's is on the scene (as the fine split).
_PLATEAU = 8
_PLATEAU_SHARE = 0.97
#: a shape's two distance-transform peaks are two discs when the dip between them is at least this
#: share of the dip two overlapping discs of their radii, that far apart, make (see _disc_neck_dip)
DISC_DIP_SHARE = 0.25
#: ... and at least this many pixels: the distance transform's own steps are a few tenths of one
DISC_DIP_FLOOR = 0.2
#: ... in a core of which this share or more lies at the plateau (``_PLATEAU_SHARE`` of its peak)
DISC_PLATEAU = 0.7
#: a flat core is looked at for necks up to this compactness (others up to 0.8, see _necked)
FLAT_COMPACT = 0.94
#: a shape's two distance-transform peaks are two discs when the distance dips between them by at
#: least this many pixels (and ``DIP_SHARE`` of the smaller disc's radius)
NECK_FLOOR = 1.0
#: the shape test's distances are taken to this many steps a pixel (see :func:`_split_flat`)
_DISTANCE_STEPS = 1024.0
#: peaks this many working pixels apart or more (the smoothing's 3x3 no longer fills a neck
#: between them) are one particle when a path above the dip's level joins them (:func:`_joined`)
JOIN_REACH = 4
#: ... above this share of the dip that sets them apart below their height: a ring's or an arc's
#: peaks are joined along it at nearly their own height, a faint particle beside a bright one is
#: not (its saddle is the bright one's flank)
JOIN_SHARE = 0.5
#: ... the levels rounded up to this many steps an octave (9 % apart), so a component is labelled
#: at most this many times an octave of its peaks' levels
JOIN_LEVELS = 8
#: the shape test's levels of the distance transform are taken to this step (px) when two peaks
#: are looked for a path between them (:func:`_joined_in`)
_JOIN_STEP = 0.125
#: a peak is a particle of its own when the excess between it and its nearest higher peak dips
#: below its height by both this share of that height and DIP_NOISE noise units: a segment
#: samples many pixels, and at 3 units the grain of a textured flake or a ring's rim split it
DIP_SHARE = 0.25
DIP_NOISE = 5.0
_BINOMIAL = np.array([1.0, 2.0, 1.0], np.float32)
_BLOCK_X = np.array([0, 1, 0, 1])
_BLOCK_Y = np.array([0, 0, 1, 1])


#: rows of the excess around a pixel that :func:`split_images` reads: the 3x3 smoothing, then a
#: maximum over at most 5x5 of it
IMAGE_REACH = 3


def split_images(excess: np.ndarray, fine: bool = True,
                 pool: BandPool | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The frame-wide images the split reads its peaks from, (smoothed, its local maximum, strict):
    ``fine``: the excess (uint8 (h, w)) smoothed by the 3x3 binomial kernel (x16, int16) and its 3x3
    maximum, and where the excess is brighter than its 8 neighbours (uint8 mask); otherwise its
    3x3 sum (uint16), that sum's 5x5 maximum and None.  Exact sums, so equal neighbours tie
    exactly: the binomial's x16 in 16 bits (at most 4080; 30 % faster than in float32, the same
    values).  pool: threads they are made on in bands (None: the caller's alone; the same images)."""
    def images(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        if fine:
            smooth = cv2.sepFilter2D(rows, cv2.CV_16S, _BINOMIAL, _BINOMIAL)
            strict = cv2.compare(rows, cv2.dilate(rows, _AROUND), cv2.CMP_GT)
            return smooth, cv2.dilate(smooth, _K3), strict
        smooth = cv2.boxFilter(rows, cv2.CV_16U, (3, 3), normalize=False)
        return smooth, cv2.dilate(smooth, _K5), None

    if pool is None or pool.threads == 1:
        return images(excess)
    kind = np.int16 if fine else np.uint16
    out = (np.empty(excess.shape, kind), np.empty(excess.shape, kind), np.empty_like(excess) if fine else None)
    return pool.filter(images, excess, IMAGE_REACH, out)


def _split_peaks(lab: np.ndarray, x: np.ndarray, y: np.ndarray, weight: np.ndarray, excess: np.ndarray,
                 noise: np.ndarray, n: int, full: tuple[np.ndarray, np.ndarray] | None = None,
                 fine: bool = True, area: np.ndarray | None = None, peak: np.ndarray | None = None,
                 flat: np.ndarray | None = None, budget: int = 0,
                 images: tuple[np.ndarray, np.ndarray, np.ndarray | None] | None = None
                 ) -> tuple[np.ndarray, int, int, int]:
    """Split components that hold two or more particles (touching or overlapping).

    Within each component of 8 pixels or more, the local maxima (3x3) of the
    excess smoothed by the 3x3 binomial kernel are its candidate peaks, and with
    ``fine`` the compact spots of the unsmoothed excess (:func:`_spots`).  A peak
    other than the component's highest is a separate particle when its nearest
    higher peak is at least 2 px away and the excess on the segment between them
    dips below it by both ``DIP_SHARE`` of its height and ``DIP_NOISE`` noise units (so a
    narrow neck counts).  This runs on all components at once, without Python loops.
    ``fine=False``: the maxima (5x5) of the 3x3-summed excess, at least 3 px
    apart (see :func:`measure`).
    Flat or saturated particles have no intensity dip; for components without
    an intensity split -- and, with ``fine``, flat ones (``_PLATEAU``) -- whose core
    (the pixels above half the peak) has ``_MIN_CORE`` pixels or more, the same test
    runs on the distance transform of
    the core (a neck at least a quarter narrower than the smaller disc; at full
    resolution when ``full`` is given, see :func:`_split_flat`).  Pixels go to
    the nearest kept peak of their component.  ``area`` (pixels) and ``peak`` (highest weight) of
    each component, and ``flat`` (the pixels' raveled indices), when known; ``images``:
    :func:`split_images` of the excess, when made already.

    budget: the most work the split may do, in pixel-peak pairs (each component costs its pixels
    times its candidate peaks); 0 = no bound.  Over it, the components that cost least are split
    and the rest measured whole.  Returns (labels -- ``lab`` itself when nothing was split --,
    components, components left whole for the budget, the work all would have cost).
    """
    area = np.bincount(lab, minlength=n) if area is None else area
    inside = area[lab] >= 8
    if not inside.any():
        return lab, n, 0, 0
    idx = np.flatnonzero(inside)
    px, py, pl = x[idx], y[idx], lab[idx]
    pf = py * excess.shape[1] + px if flat is None else flat[idx]
    smooth_img, local_max, strict_img = split_images(excess, fine) if images is None else images
    weights, min_d2 = (16.0, 4) if fine else (9.0, 9)
    s = smooth_img.ravel().take(pf)
    is_max = s >= local_max.ravel().take(pf)
    pw = weight[idx]
    top = peak if peak is not None else _group_max(pl, n, pw)[0]
    if fine:  # and the spots the smoothing hid beside a brighter neighbour (inside the frame's rim)
        h, w = excess.shape
        strict = strict_img.ravel().take(pf)
        bump = np.flatnonzero((strict > 0) & ~is_max)  # strict maxima of the excess not yet peaks
        bx, by = px[bump], py[bump]
        bump = bump[(excess.ravel().take(pf[bump]) < SPOT_SHARE * top[pl[bump]])
                    & (bx > 0) & (bx < w - 1) & (by > 0) & (by < h - 1)]
        spot = bump[_spots(excess, pf[bump])]
        is_max[spot] = True
    maxima = np.bincount(pl[is_max], minlength=n)
    cost = np.where(maxima >= 2, area * maxima, 0)
    crowded = _over_budget(cost, budget)
    if crowded.any():  # measured whole: no peaks, no shape test
        maxima[crowded] = 0
    peaks = np.flatnonzero(is_max & (maxima[pl] >= 2))
    smoothed = np.ones(len(pl), bool)  # the peaks that are maxima of the smoothed excess, not spots
    if fine:
        smoothed[spot] = False
    kept_c, kept_y, kept_x = _separate(pl[peaks], py[peaks], px[peaks], s[peaks].astype(np.float64) / weights,
                                       excess, DIP_NOISE * noise_at(noise, px[peaks], py[peaks], excess.shape),
                                       min_d2=min_d2,
                                       join=partial(_joined, (pl, px, py, n), smooth_img, weights),
                                       joinable=smoothed[peaks])
    counts = np.bincount(kept_c, minlength=n)
    shaped = counts < 2  # the components whose shape is looked at: those the intensity did not split,
    if fine:  # and flat ones, whose intensity maxima are where pooling cut their plateau's edges
        shaped |= np.bincount(pl[pw >= _PLATEAU_SHARE * top[pl]], minlength=n) >= _PLATEAU
    shaped &= ~crowded
    necked, nearly = _necked(pl, px, py, pw, n, shaped, peak=top)
    if len(necked) or len(nearly):
        flat_c, flat_y, flat_x = _split_flat(pl, px, py, pw, n, np.concatenate([necked, nearly]), full,
                                             discs_only=nearly)
        if len(flat_c):
            replaced = np.zeros(n, bool)
            replaced[flat_c] = True
            keep = ~replaced[kept_c]
            kept_c = np.concatenate([kept_c[keep], flat_c])
            kept_y = np.concatenate([kept_y[keep], flat_y])
            kept_x = np.concatenate([kept_x[keep], flat_x])
    counts = np.bincount(kept_c, minlength=n)
    split = counts >= 2
    unsplit, work = int(crowded.sum()), int(cost.sum())
    if not split.any():
        return lab, n, unsplit, work
    sel = np.flatnonzero(split[kept_c])
    kc, ky, kx = kept_c[sel], kept_y[sel], kept_x[sel]
    order = np.argsort(kc, kind="stable")
    kc, ky, kx = kc[order], ky[order], kx[order]
    comps = np.flatnonzero(split)
    row = np.full(n, -1)
    row[comps] = np.arange(len(comps))
    width = int(counts[comps].max())
    first = np.searchsorted(kc, comps)
    rank = np.arange(len(kc)) - first[row[kc]]
    far, kind = (_FAR, np.int32) if max(excess.shape) <= _FAR // 3 else (1 << 40, np.int64)
    tx = np.full((len(comps), width), far, kind)
    ty = np.full((len(comps), width), far, kind)
    tx[row[kc], rank], ty[row[kc], rank] = kx, ky
    pixels = np.flatnonzero(split[lab])
    r = row[lab[pixels]]
    nearest = _nearest_peak(x.take(pixels), y.take(pixels), r, counts[comps][r], tx, ty)
    new_base = n + np.concatenate([[0], np.cumsum(counts[comps] - 1)[:-1]])  # first new label per component
    lab = lab.copy()
    lab[pixels] = np.where(nearest == 0, lab[pixels], new_base[r] + nearest - 1)
    return lab, n + int((counts[comps] - 1).sum()), unsplit, work


def _over_budget(cost: np.ndarray, budget: int) -> np.ndarray:
    """bool per component: left out of work of ``cost`` each (0 = none to do) so that what is done
    stays within ``budget`` (0 = no bound), the cheapest done first."""
    total = int(cost.sum())
    if not budget or total <= budget:
        return np.zeros(len(cost), bool)
    order = np.argsort(cost, kind="stable")
    out = np.zeros(len(cost), bool)
    out[order[np.cumsum(cost[order]) > budget]] = True
    return out & (cost > 0)


def _nearest_peak(x: np.ndarray, y: np.ndarray, row: np.ndarray, held: np.ndarray, tx: np.ndarray,
                  ty: np.ndarray) -> np.ndarray:
    """For each pixel (x, y), the rank of the nearest of its own component's peaks: ``row`` its
    component's row of ``tx``, ``ty`` ((C, W) integer peak coordinates, each row's first ``held``
    real and the rest far away), the first of equally near ones (the higher peak).

    Each pixel is measured against a row cut to the most peaks any component of its bucket holds,
    the components bucketed by powers of two of their peaks (2, 3-4, 5-8, ...), so a cluster of
    a dozen discs does not make every pixel of every pair measure a dozen distances.  One
    ``argmin`` a bucket, in 32-bit integers (exact), where pairing every pixel with each of its
    peaks and taking the first minimum of each run took the seed tank's clusters (4,200 pixels,
    35,000 pairs) ~0.9 ms, and this ~0.5."""
    x, y = x.astype(tx.dtype), y.astype(tx.dtype)
    if len(x) * tx.shape[1] <= 2 * int(held.sum()):  # one bucket is enough
        buckets = [slice(None)]
    else:
        bucket = np.frexp((held - 1).astype(np.float64))[1]  # 2 -> 1, 3-4 -> 2, 5-8 -> 3, ...
        order = np.argsort(bucket, kind="stable")
        buckets = np.split(order, np.flatnonzero(np.diff(bucket[order])) + 1)
    nearest = np.empty(len(x), np.intp)
    for sel in buckets:
        cut, rb = int(held[sel].max()), row[sel]
        dx, dy = x[sel, None] - tx[rb, :cut], y[sel, None] - ty[rb, :cut]
        nearest[sel] = np.argmin(dx * dx + dy * dy, axis=1)
    return nearest


def _spots(excess: np.ndarray, flat: np.ndarray) -> np.ndarray:
    """Which of the pixels at raveled indices ``flat`` of ``excess`` (uint8 (h, w); none on the
    frame's outermost rows and columns) are compact spots: brighter than all 8 neighbours, and
    on no ridge -- every line of 3 pixels through the pixel falls below half its height at one
    end or both.  Indices into ``flat``.

    The peaks of :func:`_split_peaks` are the maxima of the 3x3-smoothed excess, which a
    faint particle 2-4 working pixels from a bright one is not: the bright one's light, smoothed
    into the pixels between them, outweighs the faint one's.  Such a
    particle is a strict maximum of the unsmoothed excess; so is a noise bump on a bubble's
    rim or any bright edge, but the rim runs on through it (a ridge).  The caller takes its
    candidates from one 8-neighbour dilation of the frame (strict maxima already); the check here
    is repeated on those few so the function stands alone.
    """
    w = excess.shape[1]
    values = excess.ravel()
    centre = values.take(flat).astype(np.int16)
    brightest = np.zeros(len(flat), np.uint8)
    ridge = np.zeros(len(flat), np.uint8)
    for step in (1, w - 1, w, w + 1):  # the 4 lines through the pixel
        before, after = values.take(flat - step), values.take(flat + step)
        np.maximum(brightest, np.maximum(before, after), out=brightest)
        np.maximum(ridge, np.minimum(before, after), out=ridge)
    return np.flatnonzero((centre > brightest) & (2 * ridge.astype(np.int16) < centre))


def _necked(lab: np.ndarray, x: np.ndarray, y: np.ndarray, weight: np.ndarray, n: int,
            candidates: np.ndarray, peak: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Components (among ``candidates``, bool per label) whose core -- the pixels
    above half the peak -- has ``_MIN_CORE`` pixels or more and is not compact:
    area / (2 pi mean squared distance from its centroid) below 0.8, where a disc
    gives 1 and two touching equal discs 2/3; a whole component that is plainly a disc
    (0.95) has a disc for a core and is skipped.  ``lab`` holds every pixel of the
    components it names; ``peak``: their highest weights, when known.
    The cores are counted first, so the moments are taken of the few components with a
    core that large (most of a frame's are specks), the wholes' and the cores' in one pass
    (the cores as labels n..2n-1).  Returns those, and apart the components whose core is
    compact up to ``FLAT_COMPACT``: two white discs a radius apart make a core of 0.91-0.93
    (radius 6 and 8 px), split only at such discs' necks (:func:`_split_flat`)."""
    top, = _group_max(lab, n, weight) if peak is None else (peak,)
    core = weight >= 0.5 * top[lab]
    core_area = np.bincount(lab[core], minlength=n)
    wanted = candidates & (core_area >= _MIN_CORE)
    if not wanted.any():
        return np.empty(0, np.intp), np.empty(0, np.intp)
    sel = np.flatnonzero(wanted[lab])
    inner = sel[core[sel]]
    both = np.concatenate([lab[sel], lab[inner] + n])
    bx = np.concatenate([x[sel], x[inner]]).astype(np.float64)
    by = np.concatenate([y[sel], y[inner]]).astype(np.float64)
    area, msd = _moments(both, bx, by, 2 * n)
    disc = area[:n] >= 0.95 * 2 * np.pi * np.maximum(msd[:n], 1e-9)  # whole components
    compactness = area[n:] / (2 * np.pi * np.maximum(msd[n:], 1e-9))  # their cores'
    necked = wanted & ~disc & (compactness < 0.8)
    return np.flatnonzero(necked), np.flatnonzero(wanted & ~disc & ~necked & (compactness < FLAT_COMPACT))


def _moments(lab: np.ndarray, x: np.ndarray, y: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Per label: (pixel count, mean squared distance of its pixels from their centroid)."""
    area = np.bincount(lab, minlength=n)
    safe = np.maximum(area, 1)
    mx, my = np.bincount(lab, x, n) / safe, np.bincount(lab, y, n) / safe
    return area, np.bincount(lab, x * x + y * y, n) / safe - mx * mx - my * my


def _separate(comp: np.ndarray, py: np.ndarray, px: np.ndarray, value: np.ndarray, excess: np.ndarray,
              floor: np.ndarray, min_d2: int = 9, discs: np.ndarray | None = None,
              strict: np.ndarray | None = None, join: Callable[..., np.ndarray] | None = None,
              joinable: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The peaks that stand apart, for all components at once: (component, y, x) of each kept peak.

    The highest peak of each component is kept; another is kept when its
    nearest higher peak (same component) is at least sqrt(min_d2) px away and the
    excess on the segment between them dips below its own by max(``DIP_SHARE`` of its value, its
    ``floor``, in the excess's units) --
    or, where ``discs`` ((N,) bool per peak; ``excess`` a distance transform, values the radii of
    the discs the peaks are the centres of), by the neck two overlapping discs of those radii
    have there (:func:`_disc_neck_dip`); where ``strict`` ((N,) bool per peak) is False, by
    such a neck only.
    join: (components, (x, y) of the peaks, (x, y) of their higher peaks, levels) -> (K,) bool,
    whether a path of the component's pixels all above the level joins the two: a peak the
    segment's dip sets apart is still one particle with its higher peak when, along another path,
    it falls by less than ``JOIN_SHARE`` of that dip (:func:`_joined`) -- a ring's or an arc's
    peaks, whose segment crosses its darker inside.  joinable: (N,) bool per peak, those ``join`` may join (default all).
    """
    if len(comp) == 0:
        return comp, py, px
    order = np.lexsort((-value, comp))  # by component, highest first
    comp, py, px, value, floor = comp[order], py[order], px[order], value[order], floor[order]
    if discs is not None:
        discs = discs[order]
    if strict is not None:
        strict = strict[order]
    if joinable is not None:
        joinable = joinable[order]
    first = np.empty(len(comp), bool)
    first[0] = True
    np.not_equal(comp[1:], comp[:-1], out=first[1:])
    start = np.maximum.accumulate(np.where(first, np.arange(len(comp)), 0))
    rank = np.arange(len(comp)) - start  # peaks above this one in its component
    # every (peak, higher peak) pair of a component: peak i against ranks 0..rank_i-1
    i = np.repeat(np.arange(len(comp)), rank)
    j = np.repeat(start, rank) + (np.arange(len(i)) - np.repeat(np.cumsum(rank) - rank, rank))
    kept = first.copy()
    if len(i):
        d2 = (py[i] - py[j]) ** 2 + (px[i] - px[j]) ** 2
        pick = _first_minima(d2, rank[rank > 0])  # for each peak, its nearest higher peak
        i, j, d2 = i[pick], j[pick], d2[pick]
        far = d2 >= min_d2
        i, j = i[far], j[far]
        if len(i):
            # each segment sampled by its own length, under half a pixel apart either way (the
            # samples past its end at the higher peak); sampled alike at the longest pair's
            # spacing, a pair's dip hung on the other pairs in the frame
            dy, dx = py[j] - py[i], px[j] - px[i]
            steps = 2 + 2 * (np.abs(dy) + np.abs(dx))
            t = np.minimum(np.arange(int(steps.max()))[None, :] / (steps[:, None] - 1.0), 1.0)
            # rounded relative to the peak: in frame coordinates a sample halfway between two pixels
            # went to one or the other by the parity of where the pair lay (half to even)
            width = excess.shape[1]
            start = py[i] * width + px[i]
            at = np.rint(t * dy[:, None]).astype(np.intp)
            at *= width
            at += np.rint(t * dx[:, None]).astype(np.intp)
            at += start[:, None]
            dip = _gather(excess, start).astype(np.float64) - _gather(excess, at.ravel()).reshape(at.shape).min(axis=1)
            need = np.maximum(DIP_SHARE * value[i], floor[i])
            apart = dip >= need
            if join is not None and apart.any():
                level = value[i] - JOIN_SHARE * need
                pair = np.flatnonzero(apart if joinable is None else apart & joinable[i])
                apart[pair[join(comp[i[pair]], (px[i[pair]], py[i[pair]]), (px[j[pair]], py[j[pair]]),
                                level[pair])]] = False
            if strict is not None:
                apart &= strict[i]
            if discs is not None and discs[i].any():
                apart |= discs[i] & _disc_neck_dip(value[i], value[j], np.sqrt(d2[far]), dip)
            kept[i[apart]] = True
    return comp[kept], py[kept], px[kept]


def _joined(members: tuple[np.ndarray, np.ndarray, np.ndarray, int], image: np.ndarray, weights: float,
            comp: np.ndarray, a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray],
            level: np.ndarray) -> np.ndarray:
    """(K,) bool: whether peaks ``a`` and ``b`` ((x, y) each, (K,) of component ``comp``) are
    joined by a path (8-connected) of their component's pixels whose smoothed excess is above
    ``level`` -- the saddle between them is higher than the level, so they are one particle --
    for peaks ``JOIN_REACH`` working px apart or more; nearer ones are left apart.

    members: (label, x, y, labels) of the components' pixels; image: the smoothed excess, times
    ``weights`` (the peaks' values are the smoothed excess: a ring half a working pixel wide,
    pooled, is uneven along its length where smoothed it is not).  Each round draws the
    components that still have a level to look at into one strip (:func:`_strip`), each at its
    own level, and labels it once; levels are taken up to ``JOIN_LEVELS`` steps an octave (never
    joining more than asked), so the work is each component's pixels times its distinct levels."""
    out = np.zeros(len(comp), bool)
    far = np.flatnonzero((a[0] - b[0]) ** 2 + (a[1] - b[1]) ** 2 >= JOIN_REACH ** 2)
    if not len(far):
        return out
    lab, x, y, n = members
    involved = np.zeros(n, bool)
    involved[comp[far]] = True
    sel = involved[lab]  # only the pairs' components' pixels are read
    lab, x, y = lab[sel], x[sel], y[sel]
    step = np.ceil(np.log2(np.maximum(level[far] * weights, 1.0)) * JOIN_LEVELS)
    order = np.lexsort((step, comp[far]))
    far, step = far[order], step[order]
    c = comp[far]
    new = np.ones(len(far), bool)
    new[1:] = (c[1:] != c[:-1]) | (step[1:] != step[:-1])  # a component's next distinct level
    first = np.ones(len(far), bool)
    first[1:] = c[1:] != c[:-1]
    rank = np.cumsum(new) - 1
    rank -= np.maximum.accumulate(np.where(first, rank, 0))  # its rank among the component's levels
    values = _gather(image, y * image.shape[1] + x)
    for r in range(int(rank.max()) + 1):
        at = far[rank == r]
        wanted = np.zeros(n, bool)
        wanted[comp[at]] = True
        threshold = np.zeros(n)
        threshold[comp[at]] = np.exp2(step[rank == r] / JOIN_LEVELS)
        sel = wanted[lab]
        _, (shift_x, shift_y), strip = _strip(lab[sel], x[sel], y[sel], wanted,
                                              _bounds(lab[sel], x[sel], y[sel], n),
                                              values=(values[sel] > threshold[lab[sel]]).astype(np.uint8))
        _, labels = cv2.connectedComponents(strip, connectivity=8, ltype=cv2.CV_32S)
        ca = labels[a[1][at] + shift_y[comp[at]], a[0][at] + shift_x[comp[at]]]
        cb = labels[b[1][at] + shift_y[comp[at]], b[0][at] + shift_x[comp[at]]]
        out[at] = (ca > 0) & (ca == cb)
    return out


def _joined_in(image: np.ndarray, a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray],
               level: np.ndarray, step: float) -> np.ndarray:
    """(K,) bool: whether pixels ``a`` and ``b`` ((x, y) each, (K,)) of ``image`` lie in one
    8-connected region of pixels above ``level`` ((K,)), the levels taken up to whole ``step``s
    (never joining more than asked) so the image is labelled once per distinct level: the work
    is the image's pixels times the pairs' distinct levels (the shape test's few flat components)."""
    floor = np.ceil(level / step)
    joined = np.zeros(len(level), bool)
    above = np.empty(image.shape, np.uint8)
    for value in np.unique(floor):
        at = np.flatnonzero(floor == value)
        cv2.compare(image, float(value * step), cv2.CMP_GT, dst=above)
        _, labels = cv2.connectedComponents(above, connectivity=8, ltype=cv2.CV_32S)
        la, lb = labels[a[1][at], a[0][at]], labels[b[1][at], b[0][at]]
        joined[at] = (la > 0) & (la == lb)
    return joined


def _disc_neck_dip(low: np.ndarray, high: np.ndarray, apart: np.ndarray, dip: np.ndarray) -> np.ndarray:
    """(K,) bool: whether each dip (px) of a shape's distance transform between a peak of value
    ``low`` and its nearest higher one, ``high``, ``apart`` px away, is the neck of two overlapping
    discs of those radii.

    Two discs of radii r1 <= r2 whose centres are d apart meet on a chord at a = (d^2 + r1^2 -
    r2^2) / 2d from the smaller's centre, half as wide as w = sqrt(r1^2 - a^2): the distance to
    the shape's edge falls from r1 to about w there.  The test of :func:`_separate` (a dip of a
    quarter of the peak and at least a pixel) asks more than small discs can show.  A
    dip of ``DISC_DIP_SHARE`` of the discs' and at least ``DISC_DIP_FLOOR`` px splits them, where a
    lone irregular shape's peaks -- a ridge's, whose discs would leave a deep neck -- dip far
    less; a smaller disc within the larger (no chord) is one.  Only in flat cores (``DISC_PLATEAU``
    of them at the plateau): a bubble's rim and highlight make necks of disc pairs too."""
    r1, r2 = low, high
    a = (apart * apart + r1 * r1 - r2 * r2) / (2.0 * apart)
    w2 = r1 * r1 - a * a
    expected = r1 - np.sqrt(np.maximum(w2, 0.0))
    return (w2 > 0) & (dip >= DISC_DIP_SHARE * expected) & (dip >= DISC_DIP_FLOOR)


def _first_minima(values: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Where the first minimum of each segment of ``values`` is (indices into ``values``); the
    segments lie one after another, ``counts`` long (each at least 1) -- np.argmin per segment,
    for all of them at once."""
    segment = np.repeat(np.arange(len(counts)), counts)
    low = np.minimum.reduceat(values, np.cumsum(counts) - counts)
    at = np.flatnonzero(values == low[segment])
    first = np.ones(len(at), bool)
    np.not_equal(segment[at[1:]], segment[at[:-1]], out=first[1:])
    return at[first]


def _split_flat(lab: np.ndarray, x: np.ndarray, y: np.ndarray, weight: np.ndarray, n: int,
                comps: np.ndarray, full: tuple[np.ndarray, np.ndarray] | None = None,
                discs_only: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Peaks of flat or saturated components by shape, all of ``comps`` at once: touching discs
    with one plateau have two distance-transform peaks with a neck between them.  The core of
    each (its pixels above half its peak: the halo would hide the neck) goes into one image,
    whose distance transform's local maxima (5x5) are kept by :func:`_separate` as the
    intensity peaks are, a dip of a quarter of the peak's height or 1 px -- or the neck two
    overlapping discs of the peaks' radii make (:func:`_disc_neck_dip`), in a core mostly at its
    plateau (``DISC_PLATEAU``).  ``discs_only``: components (among ``comps``) split only so.  Returns (component,
    y, x) of the peaks of the components that have two or more (one call where a loop over the
    components cost ~100 us each: the seed tank has ~8 such components a frame).

    full: (the full-resolution frame, this frame's working background) when the working image is
    2x2 blocks of it: the shape is then taken at full resolution, each working pixel standing
    for its block (the excess over the background read from the frame).  At working resolution
    small white discs (radius 2-6 px, 1-3 working px) leave hardly a neck to find."""
    wanted = np.zeros(n, bool)
    wanted[comps] = True
    sel = wanted[lab]
    lab, x, y, weight = lab[sel], x[sel], y[sel], weight[sel]
    bounds = _bounds(lab, x, y, n)  # around every pixel, the core's among them (a quarter as many to read)
    if full is not None:  # each working pixel's 2x2 block of the frame
        grey, base = full
        bounds = (2 * bounds[0], 2 * bounds[1], 2 * bounds[2] + 1, 2 * bounds[3] + 1)
        below = np.repeat(_gather(base, y * base.shape[1] + x), 4)  # each block's background
        x = (2 * x[:, None] + _BLOCK_X).ravel()
        y = (2 * y[:, None] + _BLOCK_Y).ravel()
        lab = np.repeat(lab, 4)
        if 2 * base.shape[1] > grey.shape[1] or 2 * base.shape[0] > grey.shape[0]:
            inside = (x < grey.shape[1]) & (y < grey.shape[0])
            lab, x, y, below = lab[inside], x[inside], y[inside], below[inside]
        weight = _gather(grey, y * grey.shape[1] + x).astype(np.float64) - below
    top, = _group_max(lab, n, weight)
    core = weight >= 0.5 * top[lab]
    plateau = (weight >= _PLATEAU_SHARE * top[lab])[core]
    lab, x, y = lab[core], x[core], y[core]
    (cx, cy), (shift_x, shift_y), image = _strip(lab, x, y, wanted, bounds)
    distance = cv2.distanceTransform(image, cv2.DIST_L2, 3)
    # to 1/1024 px: OpenCV's passes sum the same steps in another order by where the component
    # lies in the strip, and equal distances came out a float's last bit apart -- a plateau's
    # maxima, and so the split, then hung on the boxes of the other components before it
    cv2.multiply(distance, _DISTANCE_STEPS, dst=distance)
    np.rint(distance, out=distance)
    cv2.multiply(distance, 1.0 / _DISTANCE_STEPS, dst=distance)
    value = distance[cy, cx]
    peak = value >= cv2.dilate(distance, _K5)[cy, cx]
    # a flat core (most of it at the plateau: white or saturated) may be discs whose necks are
    # shallow; a rim's or a highlight's (a bubble's) is no disc and keeps the strict test
    flat = np.bincount(lab[plateau], minlength=n) >= DISC_PLATEAU * np.bincount(lab, minlength=n)
    strict = np.ones(n, bool)
    if discs_only is not None:
        strict[discs_only] = False
    kept_c, kept_y, kept_x = _separate(lab[peak], cy[peak], cx[peak], value[peak].astype(np.float64),
                                       distance, np.full(int(peak.sum()), NECK_FLOOR), discs=flat[lab[peak]],
                                       strict=strict[lab[peak]],
                                       join=lambda _, a, b, level: _joined_in(distance, a, b, level, _JOIN_STEP))
    several = np.bincount(kept_c, minlength=n)[kept_c] >= 2
    kept_c = kept_c[several]
    kept_y, kept_x = kept_y[several] - shift_y[kept_c], kept_x[several] - shift_x[kept_c]
    if full is not None:  # kept peaks are 3 px or more apart: each lands in a working pixel of its own
        kept_y, kept_x = kept_y // 2, kept_x // 2
    return kept_c, kept_y, kept_x


def _bounds(lab: np.ndarray, x: np.ndarray, y: np.ndarray, n: int) -> tuple[np.ndarray, ...]:
    """(left, top, right, bottom): each label's pixel bounding box, inclusive ((n,) each, in the
    coordinates' integers; labels without pixels get left > right)."""
    if not _FAST_AT:
        right, bottom, left, top = _group_max(lab, n, x, y, -x, -y)
        return -left, -top, right, bottom
    right, bottom = np.full(n, -1, x.dtype), np.full(n, -1, y.dtype)
    left, top = np.full(n, np.iinfo(x.dtype).max, x.dtype), np.full(n, np.iinfo(y.dtype).max, y.dtype)
    np.maximum.at(right, lab, x)
    np.maximum.at(bottom, lab, y)
    np.minimum.at(left, lab, x)
    np.minimum.at(top, lab, y)
    return left, top, right, bottom


def _strip(lab: np.ndarray, x: np.ndarray, y: np.ndarray, wanted: np.ndarray,
           bounds: tuple[np.ndarray, ...], values: np.ndarray | int = 1):
    """The pixels of each wanted component drawn (as 1) in a box of its own, the boxes side by
    side in one strip with 3 px of background around each (for the distance transform and the
    5x5 maximum): an image as large as the components, where their common bounding box spanned
    the seed tank's whole band of discs (four times the work at full resolution).  ``bounds``:
    (left, top, right, bottom) of each component, inclusive, around its pixels here or more (the
    distances, maxima and dips at its pixels are the same in a larger box or another place).
    ``values``: what each pixel is drawn as (an array gives the image its type; default 1, uint8).  Returns the pixels' strip
    coordinates (x, y), each component's shift (strip = frame + shift; (n,) each) and the image."""
    left, top, right, bottom = (np.where(wanted, v, 0).astype(np.intp) for v in bounds)
    width = np.where(wanted, right - left + 4, 0)
    shift_x = np.cumsum(width) - width + 3 - left
    shift_y = 3 - top
    sx, sy = x + shift_x[lab], y + shift_y[lab]
    image = np.zeros((int((bottom - top)[wanted].max()) + 7, int(width.sum()) + 4),
                     np.asarray(values).dtype if np.ndim(values) else np.uint8)
    image.ravel().put(sy * image.shape[1] + sx, values)
    return (sx, sy), (shift_x, shift_y), image
