"""Stages 2-3 from a single frame: its spatial background (:func:`spatial_background`), the
prominence test its particles must pass (:func:`prominence_level`, :func:`prominent_only`), and the
threshold against a background (:func:`threshold_mask`, :func:`_near`) with the noise helpers.

The learnt, per-pixel background that takes over when frames follow each other is
:class:`~antiscatter.detection.contrast.model.BackgroundModel`.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import cv2
import numpy as np

from ...detections import Detections
from .bands import BandPool
from .kernels import _disc


#: the widest median :func:`local_median` takes at its own resolution: OpenCV's 3x3 and 5x5 8-bit
#: medians are sorting networks, its 7-15 px ones on frames under a megapixel a per-column
#: histogram that costs tens of times more (docs/decisions/007-detector-speed.md)
MEDIAN_KERNEL = 5


def local_median(image: np.ndarray, window: int) -> np.ndarray:
    """uint8 (h, w): about the ``window`` x ``window`` median of ``image`` (uint8; window in its
    pixels), taken over block means ``ceil(window / MEDIAN_KERNEL)`` pixels a side -- a median of at
    most ``MEDIAN_KERNEL`` x ``MEDIAN_KERNEL`` blocks -- and upsampled linearly: the level of the
    scene at that scale, which a particle smaller than half the window does not move."""
    h, w = image.shape
    step = max(-(-int(window) // MEDIAN_KERNEL), 1)
    small = cv2.resize(image, (max(w // step, 1), max(h // step, 1)), interpolation=cv2.INTER_AREA)
    # OpenCV's 8-bit median takes windows up to 255 (frames over 6000 px wide ask for more)
    kernel = min(max(int(round(window / step)) | 1, 3), 255)
    return cv2.resize(cv2.medianBlur(small, kernel), (w, h), interpolation=cv2.INTER_LINEAR)


def spatial_background(half: np.ndarray, *, cell: int, window: int = 0, pool: BandPool | None = None) -> np.ndarray:
    """Background of a working-resolution frame from that frame alone, float32 (h, w): the 3x3
    median of the cell means (the lamp's cone, the scene's brightness at a coarse scale), raised
    to the frame's ``window`` x ``window`` median where that is brighter (texture: a pebble,
    a padding highlight larger than half the window stays background, a particle smaller does not).

    cell: cell size, window: median window (0 = none), both in working-resolution pixels.
    pool: threads the texture median runs on in bands (None: the caller's alone; the same result).
    """
    h, w = half.shape
    c = max(cell, 1)
    cw, ch = max(w // c, 3), max(h // c, 3)
    # in float: cell means rounded to whole grey levels biased the first frame's noise estimate
    means = cv2.resize(half.astype(np.float32), (cw, ch), interpolation=cv2.INTER_AREA)
    robust = cv2.medianBlur(means, 3)  # a particle spoils a cell, not its 3x3 median
    coarse = cv2.resize(robust, (w, h), interpolation=cv2.INTER_LINEAR)
    if window:
        # the median at half the resolution, where an edge of lit scene stays an edge (block means,
        # as local_median takes, blur it into false spots along lit patches' rims)
        small = cv2.resize(half, (w // 2, h // 2), interpolation=cv2.INTER_AREA)
        # OpenCV's 8-bit median takes windows up to 255 (frames over 6000 px wide ask for more)
        kernel = min(max(int(round(window / 2)) | 1, 3), 255)
        if pool is None or pool.threads == 1:
            texture = cv2.medianBlur(small, kernel)
        else:
            texture = pool.filter(lambda rows: cv2.medianBlur(rows, kernel), small, kernel // 2, np.empty_like(small))
        coarse = cv2.max(coarse, cv2.resize(texture, (w, h), interpolation=cv2.INTER_LINEAR).astype(coarse.dtype))
    return coarse.astype(np.float32, copy=False)


@functools.lru_cache(maxsize=64)
def _ring(radius: int, width: int = 2) -> np.ndarray:
    """uint8 kernel: the pixels at distance [radius, radius + width) from the centre (made once per
    radius: read-only, shared)."""
    r = radius + width
    y, x = np.mgrid[-r:r + 1, -r:r + 1]
    d = np.hypot(x, y)
    ring = ((d >= radius) & (d < radius + width)).astype(np.uint8)
    ring.flags.writeable = False
    return ring


def _rings(texture: int) -> tuple[int, ...]:
    """Ring radii (full-resolution pixels) of a single frame's prominence test: 3, 6, 12, ... up
    to ``texture`` (none when it is 0)."""
    radii = []
    while texture and 3 << len(radii) <= texture:
        radii.append(3 << len(radii))
    return tuple(radii)


def prominent_only(mask: np.ndarray, prominent: np.ndarray, reach: int, pool: BandPool | None = None) -> np.ndarray:
    """``mask`` (uint8) cut to its components that hold a ``prominent`` pixel, and within ``reach``
    pixels of one: a spot that outshines its rings is a particle and the rest of its component
    its rim (a neighbour it touches, which its rings cross, too); what holds none is texture.
    pool: threads the cut is made on in bands (the labelling once, whole; None: the caller's
    alone; the same result)."""
    count, labels = cv2.connectedComponents(mask, connectivity=8, ltype=cv2.CV_32S)
    keep = np.zeros(count, np.uint8)
    keep[labels[prominent > 0]] = 255
    keep[0] = 0
    disc = _disc(reach)
    if pool is None or pool.threads == 1:
        return cv2.bitwise_and(keep[labels], cv2.dilate(prominent, disc))
    out = np.empty_like(mask)
    rows = mask.shape[0]

    def work(r0: int, r1: int) -> None:
        a, b = max(r0 - reach, 0), min(r1 + reach, rows)
        cv2.bitwise_and(keep[labels[r0:r1]], cv2.dilate(prominent[a:b], disc)[r0 - a: r1 - a], dst=out[r0:r1])

    pool.run(work, pool.spans(rows))
    return out


#: the window (working pixels at 800 px wide, scaled with the width above) of the median a single
#: frame's noise is measured about: the spread at the scale of the rings, so the seabed's faint
#: pebbles and blotches count as the texture they are (history: docs/decisions/001-contrast-tuning.md)
NOISE_WINDOW = 13


def prominence_level(half: np.ndarray, rings: tuple[int, ...], *, cell: int,
                     window: int = NOISE_WINDOW, pool: BandPool | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(level uint8 (h, w), noise float32 per coarse cell) of a working-resolution frame, from that
    frame alone.

    level: for each pixel the lowest, over the rings of ``rings`` radii, of the brightest pixel on
    the ring around it -- what it must outshine to be a particle.  A compact bright spot smaller
    than a ring outshines it; a line, an edge or a patch larger than the ring does not (the ring
    crosses it), however bright.  noise: per ``cell`` x ``cell`` cell (3x3-cell median) the mean
    spread of the frame about its ``window`` x ``window`` median, both ways, as a Gaussian's sigma
    -- the sensor's noise on plain water, the texture's grain on textured ground, where a spot
    must outshine more to count (both ways: on one frame the texture's bright side is what
    makes false alarms).  pool: threads the rings run on in bands (None: the caller's alone; the
    same result).
    """
    h, w = half.shape
    if not rings:
        level = None
    elif pool is None or pool.threads == 1:
        level = ring_level(half, rings)
    else:  # a ring reaches its radius plus its width (2) from the centre
        level = pool.filter(lambda rows: ring_level(rows, rings), half, max(rings) + 2, np.empty_like(half))
    middle = local_median(half, window)
    spread = cv2.absdiff(half, middle).astype(np.float32)
    cells = cv2.resize(spread, (max(w // cell, 3), max(h // cell, 3)), interpolation=cv2.INTER_AREA)
    noise = cv2.medianBlur(cells, 3) * np.float32(1.2533)  # s = sqrt(pi / 2) E|x| for Gaussian noise
    return level, noise


def ring_level(half: np.ndarray, rings: tuple[int, ...]) -> np.ndarray:
    """uint8 (h, w): for each pixel the lowest, over the rings of ``rings`` radii (pixels, at least
    one), of the brightest pixel on the ring around it (see :func:`prominence_level`)."""
    level = cv2.dilate(half, _ring(rings[0]))
    for radius in rings[1:]:
        cv2.min(level, cv2.dilate(half, _ring(radius)), dst=level)
    return level


def threshold_mask(half: np.ndarray, base: np.ndarray, limit: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(candidate mask uint8, positive excess over the background uint8).

    A pixel is a candidate where its excess over the background, max(frame - base, 0),
    exceeds ``limit`` (the model's max(k * noise, min_contrast), both uint8).
    """
    excess = cv2.subtract(half, base)
    return cv2.compare(excess, limit, cv2.CMP_GT), excess


def noise_at(noise: np.ndarray, x: np.ndarray, y: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """The coarse noise map sampled at working-resolution pixels (x, y)."""
    ch, cw = noise.shape
    h, w = shape
    return noise[np.minimum(y * ch // h, ch - 1), np.minimum(x * cw // w, cw - 1)]


def _near(shape: tuple[int, int], expected: Detections, factor: int) -> np.ndarray:
    """uint8 mask (255) of the working pixels within about a radius + 1 of the expected particles:
    their pixels set at once, then one dilation by a disc of the median radius (at most 8 px)."""
    h, w = shape
    near = np.zeros(shape, np.uint8)
    x = np.rint(expected.centres[:, 0] / factor).astype(np.intp)
    y = np.rint(expected.centres[:, 1] / factor).astype(np.intp)
    inside = (x >= 0) & (x < w) & (y >= 0) & (y < h)
    near[y[inside], x[inside]] = 255
    radius = int(np.clip(np.ceil(np.median(expected.radii) / factor + 1), 1, 8))
    return cv2.dilate(near, _disc(radius))


def limit_map(noise: np.ndarray, shape: tuple[int, int], k: float, min_contrast: float) -> np.ndarray:
    """uint8 (h, w): max(k * noise, min_contrast) from the coarse ``noise`` map, rounded down
    (``excess > limit`` on integers is ``excess > k * noise``), saturated at 255."""
    h, w = shape
    limit = cv2.resize(np.maximum(k * noise, np.float32(min_contrast)), (w, h), interpolation=cv2.INTER_LINEAR)
    return cv2.convertScaleAbs(limit, beta=-0.4999)


class FrameAlone(NamedTuple):
    """A frame's candidates by the frame alone (:func:`frame_alone`)."""

    mask: np.ndarray  #: uint8 candidates, cut to the spots that outshine their rings
    excess: np.ndarray  #: uint8 excess over the spatial background
    noise: np.ndarray  #: float32 noise per coarse cell, at the rings' scale
    limit: np.ndarray  #: uint8 threshold the excess was held to


def frame_alone(half: np.ndarray, *, cell: int, window: int, rings: tuple[int, ...], noise_window: int,
                k: float, min_contrast: float, pool: BandPool | None = None) -> FrameAlone:
    """A frame's candidates by the frame alone, as a first frame is detected: its excess over its
    spatial background beyond ``k`` times the noise at the rings' scale (and ``min_contrast``), cut
    to the spots that outshine their ``rings``.  pool: threads its filters run on in bands (None:
    the caller's alone; the same result)."""
    base = cv2.convertScaleAbs(spatial_background(half, cell=cell, window=window, pool=pool))
    level, noise = prominence_level(half, rings, cell=cell, window=noise_window, pool=pool)
    limit = limit_map(noise, half.shape, k, min_contrast)
    mask, excess = threshold_mask(half, base, limit)
    mask = prominent_only(mask, threshold_mask(half, level, limit)[0], max(rings[-1] // 2, 1), pool)
    return FrameAlone(mask, excess, noise, limit)
