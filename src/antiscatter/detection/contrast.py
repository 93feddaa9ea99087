"""The default detector, ``contrast``: particles as local, transient excess of light.

Backscatter is light that a small particle sends back from the lamp: a compact
spot brighter than what is behind it, moving against a scene that changes
slowly.  The detector therefore finds pixels brighter than a *background
estimate* by more than a multiple of the *local noise*, instead of above a
global level:

1. ``downsample`` -- one pass over the frame: for frames 640 px wide or more a
   2x2 area average (a matched filter for spots of 1 px radius and more, halving
   the noise and the work of every later stage), and one channel (for BGR the
   luma, as the camera's Y plane: a whitish particle adds to all three colours
   while their noise averages; the Y plane or a grey frame is used as it is).
2. ``background`` -- the background at a coarse scale (cells of ``cell`` pixels):
   the 3x3-cell median of the cell means ignores a particle filling a cell, so
   uneven lamp cones and dim far scenes are followed while particles are not;
   where a median over ``texture`` pixels is brighter, that (bright texture
   larger than a particle is background from the first frame), and a single
   frame's particles must outshine the rings of pixels around them (lines,
   edges and larger patches do not: see ``texture``).  When frames
   follow each other (a video or the camera), a per-pixel background learnt over
   about ``memory`` frames -- updated only where no particle was found -- takes
   over, so static texture (seabed pebbles, tank padding) stops looking like
   particles, and it moves with the view when the vehicle moves; ``memory=0``
   keeps the detector single-frame.
3. ``threshold`` -- the noise per coarse cell is the robust spread of
   (frame - background) there (median-filtered over cells so particles do not
   inflate it); a pixel is a particle candidate when it exceeds the background
   by ``k`` times that noise and by at least ``min_contrast`` grey levels.
4. ``label`` -- one connected-components pass on the candidate mask; statistics
   from its few non-zero pixels (vectorised, no per-pixel Python).
5. ``measure`` -- split a component where it holds separate intensity peaks
   (touching or overlapping particles), reject what is not a particle (see
   below), and give each particle its brightness-weighted centre, a radius
   reaching its half-maximum extent (``core``) plus ``halo`` pixels of blur, and
   for its score the light it sends back: its excess summed over its pixels
   (see :func:`measure`).

Rejection rule: a component is not a particle when its covering radius exceeds
``max_radius`` (pixels; scaled up for frames wider than 800 px, whose pixels
see less of the scene): a region that large and brighter than its surroundings is lit scene,
not backscatter (a 1 cm bubble 0.3 m from the lens is about 11 px at 800 px).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from ..detections import Detections
from . import Detector, Stage, register_detector

#: planes of a colour frame the detector can work on (ContrastParams.channel)
CHANNELS = ("luma", "green", "red", "blue", "min")

__all__ = ["ContrastParams", "CHANNELS", "to_channel", "downsample", "BackgroundModel", "threshold_mask", "label", "measure",
           "build_contrast"]


@dataclass(frozen=True)
class ContrastParams:
    """Settings of the ``contrast`` detector.

    k: detection threshold in units of the local noise (default 4).
    min_contrast: smallest excess over the background, grey levels (default 4).
    cell: background cell size in full-resolution pixels for frames up to 800 px wide, scaled with
        the width above that (default 16).
    memory: frames over which the per-pixel background is learnt; 0 = single-frame (default 40;
        while the view moves 10, ``BackgroundModel.MOVING_MEMORY``).  The learnt background is a
        running mean of noisy frames, and its own noise adds to every pixel's excess and to the
        noise measured on its dark side: in the dense cloud, thresholded against the noise-free
        background instead, F1 0.897 -> 0.914 and snow 0.970 -> 0.979.  Against 20: F1 snow 0.970
        -> 0.974, mixed 0.964 -> 0.967, textured 0.963 -> 0.967, fullres +0.001, bubbles +0.001,
        dense +0.001, sand and seed the same, survey (moving) the same; isolated-particle IDF1
        seed tank (seeds 1-3) 0.906 / 0.900 / 0.906 -> 0.920 / 0.919 / 0.914 (fewer false alarms
        to start tracks: precision 0.981 -> 0.986), dense 0.895 / 0.903 / 0.876 -> 0.897 / 0.906 /
        0.870, snow 0.961 -> 0.965, textured 0.961 -> 0.966, mixed, fullres +0.002, the rest the
        same; twin (pulse, prediction, 5 ms, 60 frames, scene seeds 1-12) co-located 0.928 /
        0.958 -> 0.928 / 0.957 removed / kept, dim 0.913 -> 0.913, at 12 cm with probing 0.819 ->
        0.822 at 5 ms and 0.756 -> 0.752 at 20 ms.  60: F1 and IDF1 within 0.005 of 40 (seed
        tank +0.004, fullres -0.002); a longer memory follows a slowly changing scene more slowly.
    halo: pixels added to each radius for the particle's blur halo (default 1).
    core: the radius reaches the farthest pixel brighter than this share of the particle's peak
        (default 0.5: its half-maximum extent, as the width of a blurred spot is measured; 0 =
        every pixel above the threshold).  The threshold's extent grows with brightness -- a
        bright particle's blur halo clears the noise far out -- so holes were 2.3-3.1 px wider
        than the particles on the catalogue; at half maximum 1.3-1.8 px: scene light kept +0.01
        to +0.06 (dense 0.884 -> 0.940), the particles' light under holes -0.003 to -0.016; in
        the twin co-located 0.889 / 0.937 -> 0.879 / 0.948, at 12 cm with probing 0.785 / 0.816
        -> 0.793 / 0.833.
    max_radius: largest particle radius in pixels, for frames up to 800 px wide; scaled with the
        width above that (default 48).
    split: split components with several intensity peaks (default true).
    factor: working resolution divisor, 1 or 2; 0 = 2 for frames 640 px wide or more, else 1 (default 0).
    lone_k: a component of a single working pixel must exceed this many noise units (a lone noise
        spike is the commonest false alarm; a particle's light spreads over its neighbours); 0 = off
        (default 5: a Gaussian spike that high comes once in 3.5 million pixels).
    k_expected: threshold in noise units where a tracked particle is expected (``expect``):
        a particle dimmed under its own hole stays found (default 3.5; = k turns it off).  In the
        twin (pulse, prediction) with ``point`` 0.33, 2.5 / 3 / 3.5 / 3.75 / 4 removed 0.751 /
        0.756 / 0.779 / 0.769 / 0.753 at 12 cm with probing (six scenes; twelve: 3 0.752, 3.5
        0.766) at the same scene light, and co-located 0.878 / 0.882 / 0.880 / 0.877 / 0.874
        keeping 0.946 / 0.952 / 0.955 / 0.956 / 0.956: lower thresholds find more noise near the
        tracks, higher ones lose the dimmed particles the depth probe needs.  With ``point``
        0.15, 3 and 3.5 the same (12 scenes: 0.752 / 0.749 at 12 cm; co-located 0.879 / 0.950
        and 0.882 / 0.954).
    persist_radius: a single working pixel above the threshold but short of ``lone_k`` is kept
        when the last frame had light above the threshold within this many working pixels -- a
        faint particle persists from frame to frame, a noise spike almost never lands where the
        last frame was bright (4 spikes a frame in 120k pixels: 1 in 1000 within 2 px).  Only once
        the background has been learnt (static texture persists too).  0 = off (default 2).
    follow: move the learnt background with the view when the camera pans, turns or zooms
        (default true: a vehicle moves; at 800x600 pans ~80 us a frame, turns and zooms 0.1-0.15 ms
        on average in a still view, more while it moves -- false for a camera that holds still).
    texture: the size of texture (full-resolution pixels, scaled with the width above 800 px;
        default 28; 0 = off; at most 128) that a single frame -- the first, a still, the first after a cut,
        every frame with ``memory=0`` -- takes for background.  (1) The background taken from such
        a frame follows the frame's median over that window where it is brighter than the coarse
        background (the median at half the working resolution: 0.15 ms at 400x300).  (2) Its
        particles must outshine the rings around them (:func:`prominence_level`: rings of radius
        3, 6, 12, ... up to ``texture``): a compact spot does, a line, an edge or a patch larger
        than the rings does not, however bright; the threshold there is ``k`` times the frame's
        spread about its median at the rings' scale (the texture's grain where there is texture,
        the sensor's noise on plain water), not the spread about the coarse background, which
        counts a blotchy seabed's blotches as noise.  A component of the frame's excess over its
        background is kept only where it holds such a spot (within half the largest ring of one:
        a particle's rim, and a neighbour it touches, lie on its rings).  Against (1) alone: the
        two sunlit MSRB photographs 0.311 / 0.355 -> 0.395 / 0.421 (the single frame is all
        there is); the catalogue's first frame (three seeds each) sand 0.732 -> 0.804, mixed 0.792
        -> 0.830, survey 0.824 -> 0.877, textured 0.647 -> 0.692, fullres 0.838 -> 0.845, dense
        0.854 -> 0.835 (a particle with a brighter neighbour inside its rings), snow and bubbles
        within 0.003, the seed tank's first frame finds next to nothing either way.  The model
        learns from that frame as before (the pixels over the old limit do not learn), so the
        frames after it are detected exactly as before.  Learning from the cut mask instead
        gained on frames 1-9 (sand 0.861 -> 0.889, mixed 0.868 -> 0.881, survey 0.919 -> 0.930:
        fewer false alarms to unlearn); not kept, for the frames after the first to stay as they
        were (the dense cloud's tracking moved from IDF1 0.789 to 0.781 on the catalogue's seed
        but from 0.682-0.696 to 0.700-0.709 on seeds 2-4 over 60 frames with the first frame's
        detections alone changed: the tracking loop amplifies any change, either way).  The rings
        and the median's window scale with the width, as ``cell`` does: at 1456x1088 unscaled they took the seabed's faint 30-40 px
        pebbles for particles (fullres first frame 0.751, the run 0.962 -> 0.952).  Costs about
        1.3 ms on such frames at 800x600 (four dilations by rings, a median at half resolution,
        one more labelling).  Rings up to 12 only: MSRB 0.411 / 0.446 but the saturated
        overlapping pairs of the tests (29 px long) lost; (2) with the ring level itself as the
        background (no component rule): MSRB 0.372 / 0.503 but a particle with a neighbour
        within its rings is lost and a disc's rim lies under its own rings (radius 5.5 for an
        8 px disc; touching discs found as one).  Against none at all: F1 on the catalogue
        -0.001..+0.053 (fullres 0.899 -> 0.952, sand 0.942 -> 0.963; on the seabed the first
        frames had 150-215 texture false alarms each).
    point: share of each working pixel taken from the maximum of its full-resolution block, the
        rest from the block's mean (default 0.15; 0 = the mean alone, 1 = the maximum alone).  The
        mean is the matched filter for a particle that fills the block, but one smaller than a
        pixel -- a far or small flake, a grain -- keeps only a quarter of its peak in it and sinks
        below the threshold (on the catalogue, half the particles missed were such specks: their
        working excess 0.2-0.25 of their true peak); the maximum keeps all of it -- and every
        bright artefact of a compressed frame too.  F1 with point 0 / 0.15 / 0.33 on clean
        frames: snow 0.943 / 0.959 / 0.965, mixed 0.942 / 0.950 / 0.956, textured 0.940 / 0.946 /
        0.951, fullres 0.952 / 0.955 / 0.959, sand 0.963 / 0.963 / 0.965, dense 0.839 / 0.846 /
        0.850, seed 0.737 / 0.724 / 0.724; the same frames JPEG-compressed at quality 85 (snow,
        mixed, textured, fullres, sand): 0.926 / 0.930 / 0.926, 0.934 / 0.933 / 0.926, 0.936 /
        0.939 / 0.942, 0.949 / 0.950 / 0.945, 0.958 / 0.949 / 0.933, and at 75 0.15 loses
        0.005-0.022 against the mean, 0.33 0.03-0.065 (compression's ringing and block edges are
        bright single pixels the maximum keeps).  0.15 keeps most of the gain on the camera's
        raw frames and little of the loss on compressed files; 0.5-1 gained no more on clean
        frames and cost the seed tank 0.03-0.07.  White noise's bright tail stays as the
        dark-side noise estimate expects (4 units at 0.33: 4.1e-5 against 3.2e-5 for the mean).
        In the twin (12 scenes) at 12 cm with probing 0 / 0.15 / 0.33 removed 0.758 / 0.749 /
        0.767, the same within its noise.  +50 us a frame at 800x600.  Needs sub-pixel view
        following: a block's maximum depends on where the texture falls in it.
    channel: the plane of a colour (BGR) frame the detector works on (a grey or Y frame is used
        as it is): ``luma`` (default: the Y the camera's YUV stream gives, so files and camera
        see the same), ``green``, ``red``, ``blue`` or ``min`` (darkest of the three).  Luma
        against green, the earlier default: F1 +0.000..+0.016 on every catalogued scenario (snow
        0.926 -> 0.942; the three channels' noise averages while a whitish particle adds to
        all), MSRB stills 0.223 -> 0.240 and 0.326 -> 0.359, and the conversion is cheaper than
        extracting a plane.  ``red`` (or ``min``) suits sunlit blue-green water, where the
        background has lost its red and whitish snow has not: MSRB 0.316 and 0.462 (luma 0.300
        and 0.354), but on the lamp-lit simulator scenes 0.01-0.08 below luma.
    """

    k: float = 4.0
    min_contrast: float = 4.0
    cell: int = 16
    memory: int = 40
    halo: float = 1.0
    max_radius: float = 48.0
    split: bool = True
    factor: int = 0
    lone_k: float = 5.0
    k_expected: float = 3.5
    persist_radius: int = 2
    follow: bool = True
    channel: str = "luma"
    texture: int = 28
    core: float = 0.5
    point: float = 0.15

    def __post_init__(self) -> None:
        if not (math.isfinite(self.point) and 0 <= self.point <= 1):
            raise ValueError(f"point: got {self.point}, allowed 0 <= point <= 1 (0 = block mean, 1 = block maximum)")
        if not (math.isfinite(self.core) and 0 <= self.core < 1):
            raise ValueError(f"core: got {self.core}, allowed 0 <= core < 1 (0 = the whole mask)")
        if self.texture != 0 and not 3 <= self.texture <= 128:
            raise ValueError(f"texture: got {self.texture}, allowed 0 (off) or 3..128")
        if self.channel not in CHANNELS:
            raise ValueError(f"channel: got {self.channel!r}, allowed {', '.join(CHANNELS)}")
        if self.factor not in (0, 1, 2):
            raise ValueError(f"factor: got {self.factor}, allowed 0 (automatic), 1 or 2")
        if not (math.isfinite(self.k) and self.k > 0):
            raise ValueError(f"k: got {self.k}, allowed a number > 0")
        if not (math.isfinite(self.min_contrast) and self.min_contrast >= 0):
            raise ValueError(f"min_contrast: got {self.min_contrast}, allowed a number >= 0")
        if self.cell < 4 or self.cell % 2:
            raise ValueError(f"cell: got {self.cell}, allowed an even integer >= 4")
        if self.memory < 0:
            raise ValueError(f"memory: got {self.memory}, allowed >= 0 (0 = single-frame)")
        if not (math.isfinite(self.halo) and self.halo >= 0):
            raise ValueError(f"halo: got {self.halo}, allowed a number >= 0")
        if not (math.isfinite(self.k_expected) and 0 < self.k_expected <= self.k):
            raise ValueError(f"k_expected: got {self.k_expected}, allowed 0 < k_expected <= k ({self.k})")
        if not 0 <= self.persist_radius <= 64:
            raise ValueError(f"persist_radius: got {self.persist_radius}, allowed 0..64 (0 = off)")
        if not (math.isfinite(self.lone_k) and self.lone_k >= 0):
            raise ValueError(f"lone_k: got {self.lone_k}, allowed >= 0 (0 = off)")
        if not self.max_radius > 0:
            raise ValueError(f"max_radius: got {self.max_radius}, allowed > 0")


def working_factor(width: int, factor: int = 0) -> int:
    """The downsampling factor: ``factor`` if given, else 2 for frames 640 px wide or more, else 1."""
    if factor:
        return factor
    return 2 if width >= 640 else 1


def to_channel(image: np.ndarray, channel: str = "luma") -> np.ndarray:
    """(H, W, 3) BGR -> (H, W) uint8: ``channel`` of CHANNELS (luma = the Y of YUV, Rec. 601)."""
    if image.shape[2] < 3:
        return cv2.extractChannel(image, 0)
    if channel == "luma":
        return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    if channel == "min":
        return cv2.min(cv2.min(image[..., 0], image[..., 1]), image[..., 2])
    return cv2.extractChannel(image, {"blue": 0, "green": 1, "red": 2}[channel])


def downsample(image: np.ndarray, *, factor: int = 2, channel: str = "luma", point: float = 0.0) -> np.ndarray:
    """(H, W, 3) BGR or (H, W) grey -> (H/f, W/f) uint8: one channel (:func:`to_channel` for
    BGR) pooled over f x f blocks: (1 - point) x their mean + point x their maximum; at f = 1 a
    3x3 Gaussian instead, the same noise suppression without decimation.

    The mean is the matched filter for a particle that fills a block; one smaller than a pixel
    keeps 1/f^2 of its peak in it, the maximum all of it (see ``ContrastParams.point``)."""
    height, width = image.shape[:2]
    if image.ndim == 3:  # the channel first: resizing one plane is cheaper than three (same result)
        image = to_channel(image, channel)
    if factor > 1:
        size = (width // factor, height // factor)
        mean = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
        if point <= 0:
            return mean
        peak = _block_max(image, factor)
        return peak if point >= 1 else cv2.addWeighted(mean, 1.0 - point, peak, point, 0.0)
    return cv2.GaussianBlur(image, (3, 3), 0)  # the same matched filter as the 2x2 mean, without decimation


def _block_max(image: np.ndarray, factor: int) -> np.ndarray:
    """(H/f, W/f): the maximum of each f x f block of ``image`` (uint8).  For f = 2 the rows are
    paired by one cv2.max of two strided views and the columns by splitting the result as two
    interleaved channels (36 us at 800x600, where a dilation and a resize took 71)."""
    h, w = image.shape[0] // factor, image.shape[1] // factor
    if factor != 2:
        whole = image[: h * factor, : w * factor]
        return cv2.resize(cv2.dilate(whole, np.ones((factor, factor), np.uint8), anchor=(0, 0)), (w, h),
                          interpolation=cv2.INTER_NEAREST)
    rows = cv2.max(image[0: 2 * h: 2, : 2 * w], image[1: 2 * h: 2, : 2 * w])
    left, right = cv2.split(rows.reshape(h, w, 2))
    return cv2.max(left, right)


def spatial_background(half: np.ndarray, *, cell: int, window: int = 0) -> np.ndarray:
    """Background of a working-resolution frame from that frame alone, float32 (h, w): the 3x3
    median of the cell means (the lamp's cone, the scene's brightness at a coarse scale), raised
    to the frame's ``window`` x ``window`` median where that is brighter (texture: a pebble,
    a padding highlight larger than half the window stays background, a particle smaller does not).

    cell: cell size, window: median window (0 = none), both in working-resolution pixels.
    """
    h, w = half.shape
    c = max(cell, 1)
    cw, ch = max(w // c, 3), max(h // c, 3)
    # in float: cell means rounded to whole grey levels biased the first frame's noise estimate
    means = cv2.resize(half.astype(np.float32), (cw, ch), interpolation=cv2.INTER_AREA)
    robust = cv2.medianBlur(means, 3)  # a particle spoils a cell, not its 3x3 median
    coarse = cv2.resize(robust, (w, h), interpolation=cv2.INTER_LINEAR)
    if window:  # the median at half the resolution: 0.15 ms at 400x300 where the full one takes 3.6
        small = cv2.resize(half, (w // 2, h // 2), interpolation=cv2.INTER_AREA)
        # OpenCV's 8-bit median takes windows up to 255 (frames over 6000 px wide ask for more)
        texture = cv2.medianBlur(small, min(max(int(round(window / 2)) | 1, 3), 255))
        coarse = cv2.max(coarse, cv2.resize(texture, (w, h), interpolation=cv2.INTER_LINEAR).astype(coarse.dtype))
    return coarse.astype(np.float32, copy=False)


def _ring(radius: int, width: int = 2) -> np.ndarray:
    """uint8 kernel: the pixels at distance [radius, radius + width) from the centre."""
    r = radius + width
    y, x = np.mgrid[-r:r + 1, -r:r + 1]
    d = np.hypot(x, y)
    return ((d >= radius) & (d < radius + width)).astype(np.uint8)


def _rings(texture: int) -> tuple[int, ...]:
    """Ring radii (full-resolution pixels) of a single frame's prominence test: 3, 6, 12, ... up
    to ``texture`` (none when it is 0)."""
    radii = []
    while texture and 3 << len(radii) <= texture:
        radii.append(3 << len(radii))
    return tuple(radii)


def prominent_only(mask: np.ndarray, prominent: np.ndarray, reach: int) -> np.ndarray:
    """``mask`` (uint8) cut to its components that hold a ``prominent`` pixel, and within ``reach``
    pixels of one: a spot that outshines its rings is a particle and the rest of its component
    its rim (a neighbour it touches, which its rings cross, too); what holds none is texture."""
    count, labels = cv2.connectedComponents(mask, connectivity=8, ltype=cv2.CV_32S)
    keep = np.zeros(count, np.uint8)
    keep[labels[prominent > 0]] = 255
    keep[0] = 0
    return cv2.bitwise_and(keep[labels], cv2.dilate(prominent, _disc(reach)))


#: the window (working pixels at 800 px wide, scaled with the width above) of the median a single
#: frame's noise is measured about: the spread at the scale of the rings, so the seabed's faint
#: pebbles and blotches count as the texture they are.  5 (the sensor's grain alone) took them for
#: particles: the catalogue's first frames sand / mixed / fullres 0.780 / 0.815 / 0.771 (fullres
#: precision 0.661) against 0.835 / 0.852 / 0.847 with 13; MSRB 0.372 / 0.503 with 5, 0.415 /
#: 0.491 with 9, 0.417 / 0.458 with 13, 0.424 / 0.458 with 15, 0.374 / 0.391 with 25 (rings up to
#: 12, the median at full resolution, without the component rule).
NOISE_WINDOW = 13


def prominence_level(half: np.ndarray, rings: tuple[int, ...], *, cell: int,
                     window: int = NOISE_WINDOW) -> tuple[np.ndarray, np.ndarray]:
    """(level uint8 (h, w), noise float32 per coarse cell) of a working-resolution frame, from that
    frame alone.

    level: for each pixel the lowest, over the rings of ``rings`` radii, of the brightest pixel on
    the ring around it -- what it must outshine to be a particle.  A compact bright spot smaller
    than a ring outshines it; a line, an edge or a patch larger than the ring does not (the ring
    crosses it), however bright.  noise: per ``cell`` x ``cell`` cell (3x3-cell median) the mean
    spread of the frame about its ``window`` x ``window`` median, both ways, as a Gaussian's sigma
    -- the sensor's noise on plain water, the texture's grain on textured ground, where a spot
    must outshine more to count (both ways: on one frame the texture's bright side is what
    makes false alarms).
    """
    h, w = half.shape
    level = None
    for radius in rings:
        ring = cv2.dilate(half, _ring(radius))
        level = ring if level is None else cv2.min(level, ring)
    # the median at half the resolution (upsampled): 0.4 ms at 400x300 where the full one takes 4
    small = cv2.resize(half, (max(w // 2, 1), max(h // 2, 1)), interpolation=cv2.INTER_AREA)
    middle = cv2.resize(cv2.medianBlur(small, max(window // 2, 1) | 1), (w, h), interpolation=cv2.INTER_LINEAR)
    spread = cv2.absdiff(half, middle).astype(np.float32)
    cells = cv2.resize(spread, (max(w // cell, 3), max(h // cell, 3)), interpolation=cv2.INTER_AREA)
    noise = cv2.medianBlur(cells, 3) * np.float32(1.2533)  # s = sqrt(pi / 2) E|x| for Gaussian noise
    return level, noise


class BackgroundModel:
    """Per-pixel background and sensor noise, learnt over ``memory`` frames in horizontal bands.

    The first frame (and any frame of another size, or of a new scene: see
    :meth:`new_scene`) starts from the spatial background and measures the noise
    everywhere; when the view pans, the learnt background moves with it
    (:meth:`follow`).  After that, each frame
    updates one of ``bands`` horizontal bands -- background, noise and the
    threshold map there -- at ``bands`` times the per-frame rate, so every frame
    costs the same and a fraction of a full update; ``memory=0`` keeps the
    detector single-frame (everything recomputed from each frame).  This is the
    detector's only state.

    Attributes read by the detector: ``base`` (uint8 background), ``limit``
    (uint8: a pixel is a candidate where frame - base > limit) and ``noise``
    (float32 per coarse cell, grey levels).
    """

    #: frames a pixel must stay under an unchanging "particle" before it counts as scene, counted
    #: in band updates (``bands`` frames apart, at least two of them); PERSIST / 2 frames during
    #: the warm-up.  4 (2 in the warm-up) learnt the seabed sooner (F1 +0.015-0.02 there) but
    #: took a slow particle for scene within two frames, and a textured test scene then
    #: filled with false alarms -- an unstable rule, not kept.
    PERSIST = 8
    #: share of the learning rate at which a pixel under a particle learns (what it sees is mostly
    #: the particle).  0.25 let slow particles (drifting snow, the seed's rising discs) sink into
    #: the background while they were seen; 0.05 after the warm-up raised F1 on the catalogue
    #: by up to 0.023 (dense 0.814 -> 0.837, seed 0.729 -> 0.739, snow and mixed +0.008; sand
    #: -0.001) and left the twin's figures within 0.002.  During the warm-up, when the static
    #: scene is still being told from particles, 0.25 (``UNDER_WARM``): 0.05 there too cost the
    #: seabed scenes 0.014-0.023 F1 at the start.
    UNDER = 0.05
    UNDER_WARM = 0.25
    #: in the warm-up, a frame's pixel is learnt as at most this many detection limits above the
    #: background.  Particles only add light, so what lies far above the background is a particle,
    #: not the scene; learnt at full height, each bright particle in the warm-up left a quarter of
    #: itself (UNDER_WARM at the warm-up's running-mean rate) and faint ones under the limit all
    #: of theirs.  In the dense cloud the background then lay ~1.4 grey levels above the water
    #: where no particle was, the noise measured on the dark side of it (which that bias inflates)
    #: came out at 2.2 grey levels against ~1.5, and the limit, raised by both, hid the faint
    #: particles for the rest of the run (recall over its last 15 frames 0.80; 0.85 capped).
    #: F1 on the catalogue: dense 0.855 -> 0.894, mixed 0.959 -> 0.962, fullres 0.962 -> 0.964,
    #: textured +0.001, bubbles, snow and survey the same, sand 0.970 -> 0.968 (its seabed's faint
    #: texture, mistaken for particles at first, is learnt more slowly), seed 0.775 -> 0.770 (its
    #: 300 discs start in one band and merge; learning the band in cut it into pieces).  Down it
    #: learns at once (a cap there holds a background that is too high), and a moving view is not
    #: capped (a background off by the move is off both ways).  After the warm-up too: dense 0.900,
    #: but a background off by a move not yet registered (the vehicle closing on the seabed at
    #: 0.1 m/s) stayed off: 360 false alarms a frame.  4 limits: dense 0.888, 8: 0.878.  Not under
    #: the lamp's own pattern (the detector told the light, learning the scene's reflectance): in
    #: the twin at 12 cm (probe, pulse, prediction; scenes 1-12, 60 frames) it removed 0.741
    #: against 0.762 (4 limits: 0.764 against 0.774 on scenes 1-6; each scene moved by -0.14 to
    #: +0.04, the closed loop amplifying every change); why it loses there was not found.
    LEARN_REACH = 2.0

    #: a pixel under a particle is steady while it lies within the detection limit of what it was
    #: when its run of steady updates began (True), not of its last update: a flake creeping 0.05
    #: px a frame changes each core pixel by less than the limit from one update to the next, and
    #: sank into the background within 30 frames (found in 8-18 of the last 30 of 60 frames,
    #: against 24-30 now); what does not move at all is learnt as before.  F1 on the catalogue:
    #: dense 0.894 -> 0.897, textured 0.960 -> 0.963, snow 0.968 -> 0.970, mixed 0.962 -> 0.964,
    #: survey and fullres +0.001, sand 0.968 -> 0.967, seed and bubbles the same; in the twin
    #: (pulse, prediction, 5 ms, mixed) co-located 0.929 -> 0.930, at 12 cm with probing 0.815 ->
    #: 0.810 over scene seeds 1-6 and 0.795 -> 0.812 over 7-12; dense (1-3) 0.874 -> 0.875 and
    #: 0.745 -> 0.741.  Regions that changed anywhere counting as moving everywhere (3 pixels and
    #: 40 % of one) gained dense another 0.002 but cost the seed tank 0.002 and needed a labelling
    #: a band: not kept (20 %: sand -0.003).
    ANCHORED = True

    def __init__(self, *, cell: int, memory: int, k: float = 4.0, min_contrast: float = 4.0,
                 bands: int = 4, follow: bool = True, window: int = 0, defer_looks: bool = False) -> None:
        self.cell = cell
        self.window = window
        self.rings: tuple[int, ...] = ()
        self.prominent: np.ndarray | None = None
        self.noise_window = NOISE_WINDOW
        self.follows = follow
        #: routine looks at a still view's flow are taken by :meth:`look_deferred` (after the
        #: detections) instead of in :meth:`register`
        self.defer_looks = defer_looks
        self.k = k
        self.min_contrast = min_contrast
        self.alpha = 1.0 / memory if memory else 0.0
        self.bands = bands if memory else 1
        self.reset()

    def reset(self) -> None:
        self.background: np.ndarray | None = None
        self.base: np.ndarray | None = None
        self.limit: np.ndarray | None = None
        self.noise: np.ndarray | None = None
        self._deficit: np.ndarray | None = None  # mean of max(base - frame, 0) per coarse cell
        self._cap: float | None = None  # largest deficit a pixel adds to it (NOISE_CAP)
        self._previous: np.ndarray | None = None
        self._persist: np.ndarray | None = None
        self._updates = np.zeros(max(self.bands, 1), np.int64)
        self._next = 0
        self._frames = 0
        self._profiles: tuple | None = None  # the background opened at half resolution, its profiles (follow)
        self._profiled = 0  # frames since they were taken
        # register: the grid of points it follows and the size it is for, frames until the next look,
        # the last look's move of the frame's corners
        self._turn_grid = np.empty((0, 1, 2), np.float32)
        self._turn_size: tuple[int, int] | None = None
        self._turn_wait = 0
        self._turn_last: np.ndarray | None = None
        self._turn_retries = 0  # looks in a row whose move was turned down after one that saw it
        self._moved_ago = 1 << 30  # frames since the view last moved (pan or turn)
        self._turn_moving = False  # a turn was made and the view has not been seen still since
        self._turn_still = 0  # looks in a row that found it still
        self._turn_moves: list[np.ndarray] = []  # while it moves: the corners' moves of the last looks
        self._look_due = False  # a routine look left for after the detections (defer_looks)
        # the frame (at half the working resolution) a look last moved the background to fit, and
        # the pans follow() made since
        self._look_ref: np.ndarray | None = None
        self._panned = np.zeros(2)
        self._growths: list[float] = []  # the last moves' growth of the view's area (BRIGHTEN)
        self._typical_noise = 0.0  # the noise map's median
        # match_gain: the rows it reads, for frames of this shape; the pixels of them it compares
        # (flat indices) and frames since they were chosen; the last frame's rows (None: nothing
        # to compare); the brightness change since the background was last scaled, its variance
        self._gain_shape: tuple[int, int] | None = None
        self._gain_rows = np.empty(0, np.intp)
        self._gain_pixels = np.empty(0, np.intp)
        self._gain_age = 0
        self._gain_last: np.ndarray | None = None
        self._gain = 1.0
        self._gain_var = 0.0

    def _rows(self, band: int, height: int) -> tuple[int, int, int, int]:
        """Pixel rows [r0, r1) and coarse-cell rows [c0, c1) of ``band``: bands hold whole cell rows."""
        cells = max(height // self.cell, 3)
        c0, c1 = band * cells // self.bands, (band + 1) * cells // self.bands
        return c0 * height // cells, c1 * height // cells, c0, c1

    def estimate(self, half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(base, limit) for this frame, both uint8 (h, w).  The learnt background follows the view
        when it pans or turns; a new scene starts the model again.  For ``MOVED_FRAMES`` frames
        after the view moved, the limit also takes ``MISREGISTRATION`` times the background's own
        slope: a background off by a fraction of a pixel is wrong by that much at every edge of
        the ground's texture."""
        if self.background is not None and self.background.shape == half.shape:
            if self.alpha > 0.0:
                # the view panned, then turned (each on its own: a vehicle yaws as it goes)
                if self.follows and (self.follow(half) != (0, 0)) | self.register(half):
                    # the view moved: the last frame's pixels are elsewhere now, start again
                    self._gain_last, self._gain, self._gain_var = None, 1.0, 0.0
                    self._moved_ago = 0
                else:
                    self._moved_ago = 0 if self._turn_moving else self._moved_ago + 1
                self.match_gain(half)
            if self.new_scene(half):
                self.reset()
            elif self._moved_ago <= self.MOVED_FRAMES:
                return self.base, cv2.add(self.limit, self._slope_limit())
        if self.alpha == 0.0 or self.background is None or self.background.shape != half.shape:
            if self.background is not None and self.background.shape != half.shape:
                self.reset()  # frames of another size: another stream, nothing carries over
            h, w = half.shape
            self._deficit = np.zeros((max(h // self.cell, 3), max(w // self.cell, 3)), np.float32)
            self.background = spatial_background(half, cell=self.cell, window=self.window)
            self.base = cv2.convertScaleAbs(self.background)  # rounded, saturated uint8 (background >= 0)
            for band in range(self.bands):
                self._measure_noise(half, band)
            self._update_limit(half.shape)
            self._previous = self._persist = None
            self._profiles = None
            self._updates[:] = 0
            self._next = 0
            if self.rings:  # a single frame: its particles must stand out (the learning starts as before)
                level, self.noise = prominence_level(half, self.rings, cell=self.cell, window=self.noise_window)
                limit = self._limit_map(self.noise, half.shape)
                self.prominent = threshold_mask(half, level, limit)[0]
                return self.base, limit
        return self.base, self.limit

    #: how far (working pixels) the learnt background may lie from the frame while the view moves:
    #: the pan follower's whole-pixel steps leave up to half a pixel, and the background learnt over
    #: the last frames lags.  In the survey scene (the vehicle moving sideways at 0.25 m/s and
    #: turning 4 degrees a second over the seabed) F1 0.829 / 0.887 / 0.905 / 0.915 / 0.918 with 0 /
    #: 0.3 / 0.5 / 1 / 1.5; on bare seabed drifting 0.25 m/s 100 false detections a frame -> 16,
    #: at 0.1 m/s 37 -> 3.  Still views: none (the catalogue's F1 moved by +0.002 on the seed tank,
    #: -0.001 on snow, where the pan follower took a few false steps; the rest the same).
    MISREGISTRATION = 1.0
    #: frames after a move for which the view counts as moving (4 and 16 gave the same)
    MOVED_FRAMES = 8
    #: the learning's memory (frames) while the view moves, when the detector's own is longer.
    #: Each move resamples the learnt background, and what it learnt long ago has been resampled
    #: at every move since: over bare seabed drifting 0.25 m/s (noise, no particles) it grew
    #: smoother than the ground (a Laplacian term of 0.13 px^2 at frame 10, 0.31 from frame 40
    #: on, in a fit of its error against the noise-free ground; shifts under 0.1 px), and the
    #: false detections with it: 3 a frame over frames 10-19, 23 from frame 70 on (memory 20).
    #: With 10: 5, and 2.7 with 7; memory 40: 98.  Survey F1 0.945 / 0.955 / 0.956 (20 / 10 / 7);
    #: the still scenes the same.  (Sharper resampling did not help: bicubic instead of linear for
    #: the pan follower's fractions of a pixel, 40 a frame; Lanczos for both, 16.)
    MOVING_MEMORY = 10

    def _slope_limit(self) -> np.ndarray:
        """uint8 (h, w): ``MISREGISTRATION`` times the learnt background's slope (grey levels a working
        pixel, |d/dx| + |d/dy| from Sobel's 3x3, which is 8 times the slope)."""
        gx = cv2.Sobel(self.base, cv2.CV_16S, 1, 0)
        gy = cv2.Sobel(self.base, cv2.CV_16S, 0, 1)
        scale = self.MISREGISTRATION / 8
        return cv2.add(cv2.convertScaleAbs(gx, alpha=scale), cv2.convertScaleAbs(gy, alpha=scale))

    def _measure_noise(self, half: np.ndarray, band: int, frozen: np.ndarray | None = None) -> None:
        """Particles only ever add light, so the noise is measured on the *dark* side:
        per coarse cell, the mean of max(background - frame, 0), which for symmetric noise
        of spread s is s / sqrt(2 pi), whatever bright particles the cell holds.
        ``frozen`` pixels (unlit) are left out; a cell that is mostly frozen keeps its value.

        Against the float background, not the rounded ``base``: after 2x2 pooling a quiet
        sensor's noise is under a grey level, and the rounding (up to half a grey level either
        way) moved the dark-side mean by a large part of it -- for a working-image noise of
        0.59 the estimate was 0.28-0.85 depending on where the scene's level fell between
        grey levels (0.55-0.66 now), and plain noise at level 20, sigma 2 gave 3-10 false
        detections a frame (under 1 now).  Catalogue F1 bubbles +0.001, sand +0.003, mixed
        +0.002, fullres +0.002, dense -0.002, the rest unchanged; the twin's figures the same
        within their scene-to-scene spread (24 scenes, 12 cm and co-located)."""
        r0, r1, c0, c1 = self._rows(band, half.shape[0])
        if c1 <= c0 or r1 <= r0:
            return
        deficit = cv2.subtract(self.background[r0:r1], half[r0:r1], dtype=cv2.CV_32F)
        cv2.max(deficit, 0.0, dst=deficit)
        if self._cap is not None and frozen is None:  # a pixel whose background is wrong says nothing
            cv2.min(deficit, self._cap, dst=deficit)  # about the noise (under no pattern: see NOISE_CAP)
        size = (self._deficit.shape[1], c1 - c0)
        if frozen is None or not frozen[r0:r1].any():
            cv2.resize(deficit, size, dst=self._deficit[c0:c1], interpolation=cv2.INTER_AREA)
            return
        live = (frozen[r0:r1] == 0).astype(np.float32)
        total = cv2.resize(deficit * live, size, interpolation=cv2.INTER_AREA)
        share = cv2.resize(live, size, interpolation=cv2.INTER_AREA)
        measured = share > 0.25
        self._deficit[c0:c1][measured] = total[measured] / share[measured]

    def _update_limit(self, shape: tuple[int, int]) -> None:
        """noise (3x3-cell median of the dark-side spread, so a few cells of particles
        do not inflate it) and the per-pixel limit max(k * noise, min_contrast) as
        uint8, rounded down (``excess > limit`` on integers is ``excess > k * noise``)."""
        self.noise = cv2.medianBlur(self._deficit, 3) * np.float32(2.5066)  # s = sqrt(2 pi) E[max(-x, 0)]
        self._typical_noise = float(np.median(self.noise))
        self._cap = max(self.NOISE_CAP * self._typical_noise, 2.0)
        self.limit = self._limit_map(self.noise, shape)

    def _limit_map(self, noise: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        """uint8 (h, w): max(k * noise, min_contrast) from the coarse ``noise`` map, rounded down
        (``excess > limit`` on integers is ``excess > k * noise``), saturated at 255."""
        h, w = shape
        limit = cv2.resize(np.maximum(self.k * noise, np.float32(self.min_contrast)), (w, h),
                           interpolation=cv2.INTER_LINEAR)
        return cv2.convertScaleAbs(limit, beta=-0.4999)

    def follow(self, half: np.ndarray) -> tuple[int, int]:
        """Move the learnt background with the view: the shift between it and this frame, from their
        column and row brightness profiles (high-passed, so the lamp's cone does not count) after
        an opening at half resolution that takes out particles (small bright blobs) and keeps the
        ground's texture.  When only one axis's profiles match, the other's are taken again over
        the ground both views share (:func:`_overlap_shift`).  A plain view (open water) has no
        texture to go by and is left alone; a move is made only when it brings the background
        closer to the frame (:func:`_fits_better`), and by the shift measured, to a fraction of a
        pixel (linear interpolation: whole pixels left the texture up to half a pixel off, which
        ``point`` pooling shows as false detections); the ground that came into view takes its
        background from the frame (:meth:`_fill_entered`).  The background's opened image and
        profiles are renewed every ``bands`` frames (one learning cycle) and after each move.
        Returns the move in whole working pixels (dx, dy)."""
        sub = (slice(None, None, 2), slice(None, None, 2))
        if self._profiles is None or self._profiled >= self.bands:
            base = cv2.morphologyEx(self.base[sub], cv2.MORPH_OPEN, _K3)
            self._profiles = (base, [_highpass(cv2.reduce(base, axis, cv2.REDUCE_AVG, dtype=cv2.CV_32F).ravel())
                                     for axis in (0, 1)])
            self._profiled = 0
        self._profiled += 1
        opened, profiles = self._profiles  # the background opened, its column and row profiles high-passed
        frame = cv2.morphologyEx(half[sub], cv2.MORPH_OPEN, _K3)
        # 0: column profile -> x shift; 1: row profile -> y shift
        shifts = [_profile_shift(profiles[axis], cv2.reduce(frame, axis, cv2.REDUCE_AVG, dtype=cv2.CV_32F).ravel(),
                                 MAX_FOLLOW // 2) for axis in (0, 1)]
        if (shifts[0] is None) != (shifts[1] is None):
            # a pan along one axis changes the other profile as ground enters and leaves the view:
            # that one is taken again over the ground both views share
            axis = 0 if shifts[0] is None else 1
            shifts[axis] = _overlap_shift(opened, frame, axis, int(round(shifts[1 - axis])))
        if shifts[0] is None or shifts[1] is None:
            return 0, 0
        shifts = [2 * v for v in shifts]
        dx, dy = (int(round(v)) for v in shifts)
        if (dx == 0 and dy == 0) or not _fits_better(half, self.base, dx, dy):
            return 0, 0
        h, w = half.shape
        m = np.float32([[1, 0, dx], [0, 1, dy]])

        def move(image: np.ndarray) -> np.ndarray:
            return cv2.warpAffine(image, m, (w, h), flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
        fine = np.float32([[1, 0, shifts[0]], [0, 1, shifts[1]]])
        self._panned += shifts
        self.background = cv2.warpAffine(self.background, fine, (w, h), flags=cv2.INTER_LINEAR,
                                         borderMode=cv2.BORDER_REPLICATE)
        self._fill_entered(half, (max(dx, 0), max(-dx, 0), max(dy, 0), max(-dy, 0)))
        self.base = cv2.convertScaleAbs(self.background)
        self._profiles = None
        if self._previous is not None:
            self._previous = move(self._previous)
        if self._persist is not None:
            self._persist = move(self._persist)
        return dx, dy

    def register(self, half: np.ndarray) -> bool:
        """Turn and scale the learnt background with the view: the vehicle yawing or rolling, closing
        on or leaving the ground, or drifting across it a fraction of a pixel a frame.
        :meth:`follow` takes whole-pixel translation only (a row or column profile says nothing
        about a turn), and on textured ground, with 20 particles, a turn of 0.1 / 0.3 / 1 degree a
        frame gave 80 / 490 / 800 false detections a frame, a zoom of 0.2 / 0.5 / 1 % a frame 46 /
        136 / 400; now 20 / 23 / 21 and 20 / 21 / 21, 21 with a pan of 3 px a frame on top.  In
        the simulator's survey (the mixed scene from a vehicle moving sideways at 0.25 m/s over the
        seabed 2.5 m away and turning 4 degrees a second) 413 unmatched detections a frame -> 56,
        F1 0.49 -> 0.83.

        Lucas-Kanade optical flow (OpenCV) at half the working resolution from a grid of
        ``TURN_GRID`` points of the learnt background to this frame (the background's brightness
        matched to the frame's first: the flow takes brightness for constant, and an exposure ramp
        read as a turn), and the similarity transform (turn, scale, shift) that fits them (RANSAC:
        particles on a point are outliers).  The first move is made when the transform moves
        some corner of the frame by more than ``TURN_MIN`` working pixels, ``TURN_INLIERS`` points
        agree with it, the background so moved lies closer to the frame by ``TURN_GAIN`` (:meth:`_misfit`)
        than where it is and than moved the other way -- resampled by a fraction of a pixel any
        background comes out smoother and fits a noisy frame a little better, whichever way -- and
        the look before found the view moving the same way (a still view's looks point anywhere).
        From then on the view is followed every frame, each move made however small while it fits
        better than none and than its reverse, until ``TURN_STILL_LOOKS`` looks in a row find the
        view still (no corner moving ``TURN_STILL``) or the moves of the last ``TURN_DRIFT_LOOKS``
        cancel out (:meth:`_drifted`); a look whose move is turned down does not
        count as still -- the view closing on the ground at 0.1 m/s grows 0.07 % a frame, each
        frame's estimate of that is noisy with particles on the points, and counted as still, such
        looks ended the following within a few frames (245 false detections a frame, 38 now).
        Looks every ``TURN_EVERY`` frames while the view holds still, none in the first
        ``TURN_AFTER``.

        While it follows, the flow is taken from the frame the background was last moved to fit
        (both opened with ``FLOW_OPEN``, which takes the particles out) instead of from the learnt
        background: a background learnt while the view grows or turns every frame is a blur of
        where the ground was, and particles flowing faster than the ground (nearer) pulled the
        fit.  In the mixed scene closing on the seabed at 0.3 m/s (the view grows 0.2 % a frame)
        the background's flow took the growth for 0.4-0.8 %, half the moves were turned down and
        from frame 14 none was made (F1 0.50, 500 false alarms a frame at the end); frame to
        frame, unopened, the growth came out 0.07 % too large at 0.3 m/s and twice its size at
        0.1 m/s (particles), opened within 0.03 %.  A move smaller than ``TURN_STEP`` waits
        for the next look, measured over more frames then.  And as the vehicle closes on the
        ground its lamp lights it more (``BRIGHTEN``).  No move in any catalogued scene or in the
        twin (their camera holds still).
        Cost: 0.1-0.15 ms a frame on average in a still view at 800x600 (0.05 median; a look,
        0.25-0.6 ms, is mostly the flow), 0.15-0.2 at 1456x1088; every frame while the view moves.
        Returns True when it moved the background."""
        if self._frames < self.TURN_AFTER:  # the first frames' background is mostly a guess
            return False
        if self._turn_wait > 0 and not self._turn_moving:
            self._turn_wait -= 1
            return False
        self._turn_wait = self.TURN_EVERY - 1 if self._frames >= self.WARMUP else 0
        if self.defer_looks and not self._turn_moving and self._turn_last is None:
            # a routine look at a still view cannot move it (that takes two looks that agree): it is
            # taken after the detections are out (:meth:`look_deferred`)
            self._look_due = True
            return False
        return self._look(half)

    def look_deferred(self, half: np.ndarray) -> None:
        """The routine look :meth:`register` left for after this frame's detections (call before
        :meth:`learn`, with the frame :meth:`estimate` had): the same look, on the same
        background; if it sees the view move, the next frame looks again, before its detection."""
        if self._look_due:
            self._look_due = False
            self._look(half)

    def _look(self, half: np.ndarray) -> bool:
        """One look at the view's flow (see :meth:`register`); True when it moved the background."""
        h, w = half.shape
        size = (w // 2, h // 2)
        if min(size) < 32:
            return False
        if self._turn_size != size:  # the grid, at half the working resolution
            (nx, ny), self._turn_size = self.TURN_GRID, size
            ys, xs = np.mgrid[0:ny, 0:nx]
            self._turn_grid = np.column_stack([(xs.ravel() + 0.5) * size[0] / nx, (ys.ravel() + 0.5) * size[1] / ny]
                                              ).astype(np.float32).reshape(-1, 1, 2)
        small = cv2.resize(half, size, interpolation=cv2.INTER_AREA)
        total = cv2.sumElems(small)[0]
        ref = self._look_ref
        chained = self._turn_moving and ref is not None and ref.shape == small.shape
        if chained:  # following: from the frame the background was last moved to fit, particles out
            source = cv2.convertScaleAbs(ref, alpha=total / max(cv2.sumElems(ref)[0], 1.0))
            source, target = (cv2.morphologyEx(image, cv2.MORPH_OPEN, self.FLOW_OPEN) for image in (source, small))
        else:
            small_base = cv2.resize(self.base, size, interpolation=cv2.INTER_AREA)
            gain = total / max(cv2.sumElems(small_base)[0], 1.0)  # an exposure change not yet followed
            source, target = cv2.convertScaleAbs(small_base, alpha=gain), small
        points = self._turn_grid
        moved, status, _ = cv2.calcOpticalFlowPyrLK(source, target, points, None, winSize=(11, 11), maxLevel=2,
                                                    criteria=_LK_STOP, minEigThreshold=1e-5)
        ok = status.ravel() == 1
        if ok.sum() < self.TURN_INLIERS:
            return False
        # in working pixels: the half-resolution pixel centres map as u = 2 x + 0.5
        m, inliers = cv2.estimateAffinePartial2D(2 * points[ok] + 0.5, 2 * moved[ok] + 0.5, method=cv2.RANSAC,
                                                 ransacReprojThreshold=1.0, maxIters=100)
        if m is None or int(inliers.sum()) < self.TURN_INLIERS:
            return False
        if chained:  # the pans made since are in the background already
            m[:, 2] -= m[:, :2] @ self._panned
        corners = np.array([[0.0, 0.0], [w - 1.0, 0.0], [0.0, h - 1.0], [w - 1.0, h - 1.0]])
        shift = corners @ m[:, :2].T + m[:, 2] - corners  # where the move takes each corner
        far = float(np.abs(shift).sum(axis=1).max())
        if self._turn_moving:  # every move, however small, that fits better than none and than its reverse
            if far < self.TURN_STILL:
                self._turn_still += 1
                self._turn_moving = self._turn_still < self.TURN_STILL_LOOKS
                self._drifted(None)
                return False
            self._turn_still = 0
            if chained and far < self.TURN_STEP:  # measured again over more frames at the next look
                self._drifted(None)
                return False
            if not chained and not self._fits_better(half, m, gain, 0.0):
                self._drifted(None)
                return False  # a poor estimate this frame: the view still counts as moving
            self._move_to(m, half, small)
            self._drifted(shift)
            return True
        last, self._turn_last = self._turn_last, None
        if far <= self.TURN_MIN:
            return False
        if not self._fits_better(half, m, gain, self.TURN_GAIN):
            if last is not None and self._turn_retries < self.TURN_RETRIES and self._frames < self.WARMUP:
                # the look before saw the view move and this one's estimate was poor: look again next frame
                self._turn_last, self._turn_wait = last, 0
                self._turn_retries += 1
            return False
        self._turn_retries = 0
        self._turn_last = shift
        self._turn_wait = 0  # look again next frame
        if last is None or float((last * shift).sum()) < 0.25 * float((last * last).sum()):
            return False  # the first look that saw it, or one that saw the view move another way
        self._move_to(m, half, small)
        self._turn_moving, self._turn_still, self._turn_moves = True, 0, []
        return True

    def _move_to(self, m: np.ndarray, half: np.ndarray, small: np.ndarray) -> None:
        """A look's move: the background moved by ``m`` now fits this frame (``small``: at half
        the working resolution), which the next look's flow starts from."""
        self._move_background(m, half)
        self._look_ref = small
        self._panned = np.zeros(2)

    def _drifted(self, shift: np.ndarray | None) -> None:
        """While following a turning view: this look's move of the frame's corners (None: none made).
        Over the last ``TURN_DRIFT_LOOKS`` looks the moves of a view that holds still cancel -- each
        look's estimate, noisy with particles on the points, moves the background a little, and
        the next takes it back -- where a turning or zooming view's add up; when they sum to less
        than ``TURN_STILL`` a look on average the view is still.  (Counted one look at a time, a
        still view's estimates stay over ``TURN_STILL`` most of the time: after a survey's vehicle
        stopped, the view was followed on every frame, 8 moves in 10 frames, for as long as it
        held still.)"""
        if not self._turn_moving:
            return
        self._turn_moves = (self._turn_moves + [np.zeros((4, 2)) if shift is None else shift])[-self.TURN_DRIFT_LOOKS:]
        if len(self._turn_moves) < self.TURN_DRIFT_LOOKS:
            return
        net = float(np.abs(np.sum(self._turn_moves, axis=0)).sum(axis=1).max())
        if net < self.TURN_STILL * self.TURN_DRIFT_LOOKS:
            self._turn_moving, self._turn_still, self._turn_moves = False, 0, []

    def _fits_better(self, half: np.ndarray, m: np.ndarray, gain: float, margin: float) -> bool:
        """True when the background moved by ``m`` lies closer to the frame, by ``margin`` (a share),
        than both where it is and moved the reverse way (resampled by a fraction of a pixel any
        background comes out smoother and fits a noisy frame a little better, whichever way)."""
        rivals = min(self._misfit(half, None, gain), self._misfit(half, cv2.invertAffineTransform(m), gain))
        return self._misfit(half, m, gain) < (1.0 - margin) * rivals

    def _misfit(self, half: np.ndarray, move: np.ndarray | None, gain: float) -> float:
        """How far the background moved by ``move`` (None: where it is) lies from the frame: the
        summed difference over every 4th row (the background warped for those rows alone), each
        pixel's capped at 3 noise units so particles count as little as they can."""
        rows = slice(None, None, 4)
        seen = self.background[rows]
        if move is not None:
            inverse = cv2.invertAffineTransform(move)
            inverse[:, 1] *= 4  # the check's row y' is the frame's row 4 y'
            seen = cv2.warpAffine(self.background, inverse, (half.shape[1], seen.shape[0]),
                                  flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE)
        cap = max(3.0 * self._typical_noise, 2.0)
        return cv2.sumElems(cv2.min(cv2.absdiff(half[rows], cv2.convertScaleAbs(seen, alpha=gain)), cap))[0]

    def _move_background(self, m: np.ndarray, half: np.ndarray) -> None:
        """Move the learnt background (and the learning's per-pixel state) by the affine map ``m``;
        what came into view is this frame's, as for a pan (:meth:`_fill_entered`).  (Filled band by
        band along the edges, as deep as the columns or rows that held any of it, it was left out
        whenever the new ground touched every column or row: a diagonal drift, 4 of the survey's
        88 moves; survey F1 0.955 -> 0.956.)  Bicubic: the
        view moving a fraction of a pixel every frame, bilinear resampling blurred the background
        frame after frame (over the moving seabed 133 false detections a frame against 24)."""
        h, w = self.background.shape
        self.background = cv2.warpAffine(self.background, m, (w, h), flags=cv2.INTER_CUBIC,
                                         borderMode=cv2.BORDER_REPLICATE)
        if self.BRIGHTEN:  # the lamp rides with the camera: ground that grows by s came closer by s
            # and is lit s^2 brighter; the median of the last moves' s^2, as one look's s is noisy
            # (+-0.5 % for a turn over fractal ground) where a vehicle's approach is steady
            self._growths = (self._growths + [abs(float(np.linalg.det(m[:, :2])))])[-self.BRIGHTEN:]
            self.background *= np.float32(np.median(self._growths))
            np.minimum(self.background, 255.0, out=self.background)
        entered = cv2.warpAffine(np.ones((h, w), np.uint8), m, (w, h), flags=cv2.INTER_NEAREST,
                                 borderMode=cv2.BORDER_CONSTANT, borderValue=0) == 0
        np.copyto(self.background, half, where=entered, casting="unsafe")  # the ground that came into view
        self.base = cv2.convertScaleAbs(self.background)
        for name in ("_previous", "_persist"):
            image = getattr(self, name)
            if image is not None:
                setattr(self, name, cv2.warpAffine(image, m, (w, h), flags=cv2.INTER_NEAREST,
                                                   borderMode=cv2.BORDER_REPLICATE))
        self._profiles = None

    #: points of the grid (across, down) that :meth:`register` follows, at half the working resolution
    TURN_GRID = (8, 6)
    #: points that must agree with a turn (RANSAC inliers within 1 working pixel)
    TURN_INLIERS = 12
    #: smallest move of a frame corner (working pixels, |dx| + |dy|) that turns the background
    TURN_MIN = 0.5
    #: share by which the background must lie closer to the frame for the first move (true first moves
    #: gained 1.5-12 %; a still view's false candidates 0.4-0.8 %)
    TURN_GAIN = 0.01
    #: frames learnt before the first look.  8 once, when a young background's small false moves
    #: fitted the frame better (still 320x240 and 1456x1088 views); the check against the reverse
    #: move since stops those, and 8 left the survey's view unfollowed while it turned: false
    #: detections climbed from 31 to 276 a frame over frames 1-8 (then 20).  With 2: at most 60
    #: (frame 2, before the two agreeing looks), survey F1 0.916 -> 0.939, IDF1 0.873 -> 0.897;
    #: no move in the catalogue's still scenes, the twin, or 18 more still runs (textured, mixed
    #: at 1456x1088, bubbles, snow, sand at 320x240-800x600, seeds 2-4) but for snow at 320x240,
    #: where drifting flakes over plain water made 2-4 moves with 8 as well.
    TURN_AFTER = 2
    #: frames between looks while the view holds still
    TURN_EVERY = 6
    #: in the warm-up, the view is looked at every frame, and a first look whose move is turned down
    #: after one that saw the view move is taken again the next frame, this many times in a row.
    #: (After it, such retries gave a still view's noisy looks more chances to agree: the bench's
    #: frames, played forwards and back, were followed from frame 55 on, 0.3 ms a frame.)
    #: A young background's flow is a poor guide: closing on the seabed at 0.6 m/s the second
    #: look's estimate of the growth was 0.8 % a frame for 0.2, turned down, and the next look 6
    #: frames later found the view too far gone to follow (1000+ false alarms a frame); at 0.1 m/s
    #: the view was first followed at frame 20 (50-214 false alarms a frame over frames 9-19, 0-4
    #: now).  No move in the catalogue's still scenes (their figures unchanged); looks cost
    #: 0.25-0.6 ms each, every frame of the first 16 (after the detections, off the latency path).
    TURN_RETRIES = 3
    #: once the view turns it is followed every frame until this many looks in a row find it moving
    #: no corner by more than ``TURN_STILL`` working pixels
    TURN_STILL = 0.15
    TURN_STILL_LOOKS = 4
    #: ... or the moves of this many looks in a row add up to less than ``TURN_STILL`` a look (:meth:`_drifted`)
    TURN_DRIFT_LOOKS = 16
    #: while following, a move of no corner by this much (working pixels) waits for the next look
    TURN_STEP = 0.3
    #: opening of both frames before the flow while following (particles out, ground texture kept)
    FLOW_OPEN = np.ones((3, 3), np.uint8)
    #: a move that scales the view by s scales the background's brightness by s^2 (the median over
    #: this many moves; 0 = never): the lamp rides with the camera, and ground that grows by s came
    #: s times closer.  :meth:`match_gain` cannot
    #: follow the brightness across moves (it compares a frame with the last, whose pixels saw other
    #: ground), and the learning alone lagged: the mixed scene closing on the seabed (F1 of the
    #: catalogue's counting, frames 20-59) at 0.1 / 0.3 / 0.6 m/s gave 0.897 / 0.828 / 0.506 with the
    #: flow above alone, 0.919 / 0.950 / 0.927 with this (0.850 / 0.501 / 0.188 before either; the
    #: survey 0.956 / 0.955).  Ground lit by daylight does not brighten as the vehicle closes in:
    #: there the background runs too bright until it learns (at 0.5 % growth a frame over fractal
    #: ground, 15-19 of 20 particles found instead of 20, and no false alarms).
    BRIGHTEN = 5

    def match_gain(self, half: np.ndarray) -> float:
        """Follow a change of the whole scene's brightness at once: the camera's exposure or gain
        stepping or drifting (auto-exposure), the lamp dimmed, the vehicle closing on the ground.
        Learning alone lags such a change by many frames, and every pixel of textured ground
        then shows as a particle: an exposure ramp of 0.5 % a frame gave thousands of false
        detections a frame (30 particles); ramps of 0.1-5 % a frame and steps of -30 % to +50 %
        now give 30-35.

        The change from the last frame is the ratio of the two frames' sums over about
        ``GAIN_SAMPLES`` pixels of rows spread over the frame whose learnt background is at
        least ``GAIN_MIN_LEVEL``, leaving out those whose difference is far from the typical
        one (particles, moving, are a few per cent of them).  The two frames being alike, it is unbiased whatever the
        noise's shape; a median of ratios stuck at exactly 1 on whole grey levels, and pixels
        chosen by either frame's brightness biased it by their noise.  Its standard error
        comes from what the ratio leaves unexplained.  The changes are multiplied up, with
        their variances, until their product differs from 1 by more than ``GAIN_STEP`` and
        ``GAIN_SIGMAS`` standard errors; the learnt background is then scaled by it.  A steady
        scene's noise never gets there (no step in any catalogued scene or the twin); a drift
        of 0.3 % a frame does within two frames.  Nothing is read across a pan (:meth:`follow`
        moved the background: the sampled pixels saw other ground; a vertical pan over the
        seabed gave 200 false detections a frame) or when the frames differ by more than a
        brightness change and ``GAIN_SPREAD`` times the noise (the view moved by less than
        ``follow`` takes up, or the scene changed).  During the warm-up the background learns
        fast enough to follow by itself.  About 40 us a frame at 800x600, 80 at 1456x1088 (in the
        bench, 3 % of the detector).  Returns the factor applied (1.0: none)."""
        if self._gain_shape != half.shape:
            h, w = self._gain_shape = half.shape
            # whole rows spread over the frame, read as contiguous memory (every pixel sees the
            # same exposure): enough of them for GAIN_SAMPLES pixels
            count = max(2, min(h, -(-self.GAIN_SAMPLES // w)))
            self._gain_rows = (np.arange(count) * (h - 1) // (count - 1)).astype(np.intp)
            self._gain_age = self.bands
            self._gain_last = None
        # those rows of this frame and of the last (a copy: the frame itself is not kept alive)
        rows, previous = half[self._gain_rows], self._gain_last
        self._gain_last = rows
        if not self.learnt() or previous is None:
            return 1.0
        if self._gain_age >= self.bands:  # the pixels used, chosen again as the background is learnt:
            # by the learnt background -- chosen by either frame, their noise would bias the ratio
            self._gain_pixels = np.flatnonzero(self.background[self._gain_rows] >= self.GAIN_MIN_LEVEL)
            self._gain_age = 0
        self._gain_age += 1
        if len(self._gain_pixels) < self.GAIN_SAMPLES // 10:
            return 1.0
        now = rows.reshape(-1).take(self._gain_pixels).astype(np.float32)
        before = previous.reshape(-1).take(self._gain_pixels).astype(np.float32)
        diff = now - before
        middle = _middle(diff)
        deviation = np.abs(diff - middle)
        # particles (and the odd noise spike) out: differences far from the typical one.  Centred
        # on the median difference: a sum ratio over all pixels would be pulled by particles --
        # in the dense cloud those pixels whose background is lit at all are mostly where
        # particles were, and are leaving -- and 0.5 % a frame added up to false steps of 25 %
        keep = deviation <= 2.5 * 1.4826 * _middle(deviation) + 1.0
        if np.count_nonzero(keep) < self.GAIN_SAMPLES // 10:
            return 1.0
        now, before = now[keep], before[keep]
        total = float(before.sum())
        if total <= 0.0:  # the last frame black there (particles the background learnt have gone)
            return 1.0
        ratio = float(now.sum()) / total
        left = now - np.float32(ratio) * before
        residual = math.sqrt(max(float(np.dot(left, left)) / len(left) - (float(left.sum()) / len(left)) ** 2, 0.0))
        if residual > self.GAIN_SPREAD * math.sqrt(2.0) * self._typical_noise:
            self._gain, self._gain_var = 1.0, 0.0  # not the same view: nothing to read
            return 1.0
        # (the kept pixels' spread is cut at the window: never below the two frames' noise)
        error = max(residual, math.sqrt(2.0) * self._typical_noise) * math.sqrt(len(now)) / total
        self._gain *= ratio
        self._gain_var += error * error
        change = self._gain
        if abs(change - 1.0) <= max(self.GAIN_STEP, self.GAIN_SIGMAS * math.sqrt(self._gain_var)):
            return 1.0
        self._gain, self._gain_var = 1.0, 0.0
        self.background *= np.float32(change)
        np.minimum(self.background, 255.0, out=self.background)
        self.base = cv2.convertScaleAbs(self.background)
        self._profiles = None
        return change

    #: pixels the brightness ratio is taken over (whole rows spread over the frame)
    GAIN_SAMPLES = 2000
    #: backgrounds darker than this (grey levels) say little about a ratio: their noise is most of them
    GAIN_MIN_LEVEL = 8.0
    #: smallest change of brightness followed at once (over textured ground at levels of 40-100
    #: with a noise of 2, one frame's ratio is good to about 0.1 %)
    GAIN_STEP = 0.003
    #: ... and it must exceed this many standard errors (over dark water, levels near 10 with a
    #: noise of 1.5, one frame's ratio is good to about 0.5 % only)
    GAIN_SIGMAS = 4.0
    #: frames whose difference, the brightness change taken out, spreads more than this many
    #: times the two frames' noise are not the same view: not compared
    GAIN_SPREAD = 2.0

    def _fill_entered(self, half: np.ndarray, depths: tuple[int, int, int, int]) -> None:
        """The ground that came into view with a pan has nothing learnt: its background is this
        frame itself, over a band along each edge ``depths`` (left, right, top, bottom) pixels
        deep (a turn's new ground, thin wedges along every edge, is filled the same way by
        :meth:`_move_background`); a particle in it is taken for ground for a frame (it
        moves on, off what was learnt of it).  Before, the edge was repeated across it and its
        texture showed as particles at the leading edge (panning over fractal seabed 28-128
        detections a frame for 20 particles, 21 now; a turn of 1 degree a frame 48 -> 21); then the
        frame's spatial background (as at the start) took the ground's finer texture for
        particles: in the survey scene 4.9 false detections a frame within 20 px of the edges (2.9
        at the leading one), now 1.7 (F1 0.939 -> 0.945); bare seabed drifting 0.25 m/s 16 -> 9
        a frame; still scenes and the turn, zoom and pan tests the same."""
        h, w = half.shape
        for edge, d in enumerate(depths):
            if d <= 0:
                continue
            size = w if edge < 2 else h
            a, b = (0, d) if edge % 2 == 0 else (size - d, size)  # the band [a, b) along this edge
            strip = (slice(None), slice(a, b)) if edge < 2 else (slice(a, b), slice(None))
            self.background[strip] = half[strip]

    def new_scene(self, half: np.ndarray) -> bool:
        """True when more than ``NEW_SCENE`` of the frame (every 4th row) differs from the background by
        more than the limit, either way: the camera turned to another scene, the light changed.
        Particles cover a few per cent (the dense preset 7 %); after a cut it is over 90 %."""
        rows = slice(None, None, 4)
        changed = cv2.compare(cv2.absdiff(half[rows], self.base[rows]), self.limit[rows], cv2.CMP_GT)
        return cv2.countNonZero(changed) > self.NEW_SCENE * changed.size

    #: share of the frame that must differ from the background for a new scene
    NEW_SCENE = 0.3

    #: a pixel's deficit counts towards its cell's noise up to this many times the frame's typical
    #: (median) noise.  Where particles pass all the time -- the seed tank's band of rising discs,
    #: the dense cloud -- the background learnt some of them, and the dark frames after they left
    #: gave deficits of a hundred grey levels or more: a few such pixels in a cell took its noise,
    #: and the threshold, to 15-255 (the seed tank's limit in its particle band, frames 30-100);
    #: with the cap 4-19.  For Gaussian noise a deficit beyond 4 sigma comes once in
    #: 30,000 pixels, so the estimate is unchanged where the background is right; where the noise
    #: really varies (shot noise: 15 and 220 grey levels side by side, sigma 2.7-21) the false
    #: alarms did not change.  F1 against no cap: seed 0.724 -> 0.743, dense 0.846 -> 0.852,
    #: textured 0.946 -> 0.947, fullres 0.955 -> 0.957, the other scenes the same; 8 gave seed
    #: 0.743, dense 0.848.  Not while a pattern is on the scene (``frozen`` given): there the
    #: deficits also carry the pattern's misregistration at the holes' rims, a real part of what
    #: the threshold must clear -- capped, the twin's co-located loop found 8-19 false particles
    #: a frame instead of 3-4 and kept 0.944 of the scene light instead of 0.956.
    NOISE_CAP = 4.0

    def learnt(self) -> bool:
        """True once the warm-up is over: static scene has been told apart from particles."""
        return self._frames >= self.WARMUP

    #: weight of the spatial start (the first frame's background from that frame alone) against
    #: each frame learnt after it, for the pixels where no particle was found: 0, the first
    #: learnt frame takes its place (a running mean of the frames seen, then the memory's rate).
    #: On textured ground the spatial start is off by the texture, and the noise measured against
    #: it is the texture's: with weight 1 the textured scene's noise estimate took 15 frames to fall
    #: from 15 grey levels to 2.7, and recall over its first 16 frames was 0.77 (0.93 later); with
    #: 0 it is 3.3 by the third frame.  F1 on the catalogue: textured 0.949 -> 0.955, dense 0.860
    #: -> 0.867, seed 0.773 -> 0.774, mixed 0.955 -> 0.956, fullres 0.960 -> 0.961, the rest the
    #: same; in the twin (12 scenes, 60 frames) at 12 cm 0.749 / 0.881 -> 0.765 / 0.881,
    #: co-located 0.873 / 0.956 -> 0.875 / 0.956.  Pixels under a particle keep the old schedule:
    #: at the faster one too, sand gained 0.006 more (its warm-up's texture false alarms learnt
    #: sooner) but a twinkling flake in place sank into the background (found in 40 of the last
    #: 60 frames instead of 47) and dense lost its gain.  Measuring the second frame's noise
    #: against the first before thresholding it (recall on that frame 0.49 -> 0.78) cost snow,
    #: sand and fullres 0.002-0.004: not kept.
    START_WEIGHT = 0.0

    #: frames after a (re)start during which every band learns every frame, so the first
    #: frames' static scene is absorbed in PERSIST / 2 frames (at least 2)
    WARMUP = 16

    def learn(self, half: np.ndarray, mask: np.ndarray, frozen: np.ndarray | None = None) -> None:
        """Update one band from this frame (``mask``: uint8, 255 = particle candidate; ``frozen``:
        uint8, 255 = pixels this frame says nothing about -- left unlit by the lamp -- which keep
        their background).

        Pixels without a particle (the mask grown by one pixel) learn at the full
        rate.  Under a particle a pixel learns at ``UNDER`` of it, so moving and
        slow particles leave almost no trace -- unless it has stayed within the
        detection limit (``limit``) of its first value over ``PERSIST`` frames (``ANCHORED``):
        then it is scene the first frames mistook for a particle (a bright pebble,
        a padding highlight) and learns at four times the rate.  The band's noise
        is measured too; the threshold map follows once every band has been.
        During the first ``WARMUP`` frames every band learns every frame and
        PERSIST / 2 frames suffice (at least 2): everything static is still to be told apart;
        there (while the view holds still, with no pattern of the lamp's on it) a pixel counts as at most ``LEARN_REACH`` limits
        above the background, so the particles of a thick cloud do not leave their light in it.
        """
        if self.alpha == 0.0 or self.background is None:
            return
        if self._previous is None or self._previous.shape != half.shape:
            self._previous = half.copy()
            self._persist = np.zeros(half.shape, np.uint8)
            self._frames = 0
            first = True
        else:
            first = False
        warm = self._frames < self.WARMUP
        self._frames += 1
        moving = self._moved_ago <= self.MOVED_FRAMES  # then a shorter memory (MOVING_MEMORY), no cap
        if warm:
            # the cap (LEARN_REACH): not while the view moves (a moved background is off both ways)
            # nor under the lamp's pattern
            capped = not (first or moving) and frozen is None
            for band in range(self.bands):
                self._learn_band(half, mask, band, first, per_update=1, needed=max(2, self.PERSIST // 2),
                                 under=self.UNDER_WARM, frozen=frozen, capped=capped)
            self._next = 0
            self._update_limit(half.shape)
            return
        band = self._next
        self._next = (band + 1) % self.bands
        self._learn_band(half, mask, band, first, per_update=self.bands,
                         needed=max(2, -(-self.PERSIST // self.bands)), under=self.UNDER, frozen=frozen,
                         alpha=max(self.alpha, 1.0 / self.MOVING_MEMORY) if moving else self.alpha)
        if self._next == 0:  # a whole cycle of bands: the noise map has been renewed
            self._update_limit(half.shape)

    def _learn_band(self, half: np.ndarray, mask: np.ndarray, band: int, first: bool, *, per_update: int,
                    needed: int, under: float, frozen: np.ndarray | None = None,
                    alpha: float | None = None, capped: bool = False) -> None:
        """Learn the rows of ``band``; ``per_update`` frames pass between its updates, ``needed``
        steady updates make a "particle" scene, pixels under a particle learn at ``under`` of the rate
        (``alpha`` a frame once learnt; None: the model's)."""
        alpha = self.alpha if alpha is None else alpha
        h, w = half.shape
        r0, r1, c0, c1 = self._rows(band, h)
        if r1 <= r0:
            return
        self._measure_noise(half, band, frozen)  # against the base this frame was thresholded with
        frame = half[r0:r1]
        top, bottom = max(r0 - 1, 0), min(r1 + 1, h)
        particles = cv2.dilate(mask[top:bottom], None)[r0 - top:r0 - top + (r1 - r0)]
        updates = int(self._updates[band])
        rate = min(1.0, max(alpha * per_update, 1.0 / (updates + 2)))
        # scene pixels: a running mean of the frames seen (then the memory's rate); the spatial start
        # is a guess, not a frame's worth of evidence (see START_WEIGHT)
        fresh = min(1.0, max(alpha * per_update, 1.0 / (updates + 1 + self.START_WEIGHT)))
        background = self.background[r0:r1]
        live = None if frozen is None else cv2.bitwise_not(frozen[r0:r1])  # pixels that may learn
        if live is not None:
            particles = cv2.bitwise_or(particles, frozen[r0:r1])
        if not first:
            change = cv2.absdiff(frame, self._previous[r0:r1])
            steady = cv2.bitwise_and(cv2.compare(change, self.limit[r0:r1], cv2.CMP_LE), particles)
            persist = self._persist[r0:r1]
            cv2.add(persist, 1, dst=persist, mask=steady)
            cv2.bitwise_and(persist, steady, dst=persist)
            scene = cv2.compare(persist, needed, cv2.CMP_GE)
            cv2.accumulateWeighted(frame, background, min(1.0, 4 * rate), mask=scene)
            if self.ANCHORED:
                cv2.copyTo(frame, cv2.bitwise_not(steady), self._previous[r0:r1])
            else:
                self._previous[r0:r1] = frame
        sample = frame
        if capped:  # particles only add light: what lies far above the background is not it
            sample = np.minimum(frame, background + self.limit[r0:r1] * np.float32(self.LEARN_REACH))
        cv2.accumulateWeighted(sample, background, rate * under, mask=live)
        cv2.accumulateWeighted(sample, background, fresh * (1 - under), mask=cv2.bitwise_not(particles))
        cv2.convertScaleAbs(background, dst=self.base[r0:r1])
        self._updates[band] = updates + 1


def _middle(values: np.ndarray) -> float:
    """The median of a 1-D array (the upper middle when even), by one partition: a quarter of
    np.median's time on a few thousand values."""
    k = len(values) // 2
    return float(np.partition(values, k)[k])


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


def label(mask: np.ndarray) -> dict[str, np.ndarray]:
    """Connected components (8-connected) of ``mask`` as per-pixel arrays of the non-zero pixels.

    Returns {"labels": (P,) component index 0.., "x": (P,), "y": (P,), "flat": (P,) index into the
    raveled image (y * width + x), "count": int}.
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


def _gather(image: np.ndarray, flat: np.ndarray) -> np.ndarray:
    """``image`` at the raveled indices ``flat``: one 1-D take on a contiguous image, a
    quarter of the time of indexing by (y, x) for a few thousand pixels."""
    return np.ascontiguousarray(image).ravel().take(flat)


def measure(components: dict[str, np.ndarray], excess: np.ndarray, noise: np.ndarray, *,
            halo: float, max_radius: float, split: bool, frame_width: int, factor: int = 2,
            lone_k: float = 0.0, seen: np.ndarray | None = None, core: float = 0.0,
            full: tuple[np.ndarray, np.ndarray] | None = None, fine: bool = True) -> Detections:
    """Centres (brightness-weighted), covering radii and scores of the components; centres and
    radii in full-resolution pixels.

    The radius reaches the farthest pixel whose excess is at least ``core`` of the component's
    peak (0: the farthest of all), plus ``halo``.  The score is the particle's flux: its excess
    summed over its pixels (grey levels x working pixels) -- the light it sends back.  Its peak
    was the score before, but a near particle, which sends back most of the light, is clipped
    at white both lit and under a probe's tenth of the lamp (in the twin a bubble 0.36 m away
    read 52-253 under its probe against 180-250 lit, and its depth probe's verdicts went wrong
    by turns); its flux falls with the light in the clipped core (fewer pixels reach any level)
    and in its wings (they sink below the threshold).  The flux also goes as the fourth power of
    the distance for a particle the camera resolves and one it does not alike (the lamp's inverse
    square times the image's area, or times the camera's own inverse square), where the peak
    goes as its square or its fourth power by the particle's size.  In the twin (12 cm, depth
    probing, pulse, prediction, 5 ms, 60 frames, scene seeds 25-72) removed 0.772 -> 0.802
    keeping 0.894 -> 0.892 (with the depth prior's slope for the flux, ``DepthProbe.SLOPE``);
    dim holes (seeds 1-12) 0.686 -> 0.722; co-located, where no verdict is read, the same.

    excess: uint8 light above the background; noise: the coarse noise map (for splitting and
    ``lone_k``: a component of one working pixel is kept only when its excess exceeds ``lone_k``
    noise units -- a noise spike is almost always alone, a particle's light spreads; 0 = off --
    or where ``seen`` (uint8 working-resolution mask, optional) is set: where the last frame was
    bright, so a faint particle that persists is kept).

    full: (the full-resolution frame, its working background) when the working image is its 2x2
    blocks: flat components are split by their shape at full resolution (:func:`_split_flat`).
    fine: components are split at the 3x3 maxima of the excess smoothed by the 3x3 binomial
    kernel, 2 px apart or more, where the 3x3-summed excess and a 5x5 window kept peaks 3 px
    apart (6 at full resolution): two particles that close were one detection between them.
    F1 against the coarse split: seed tank 0.764 -> 0.773, bubbles 0.983 -> 0.986, snow 0.960
    -> 0.962, sand 0.962 -> 0.966, mixed 0.950 -> 0.953, textured 0.947 -> 0.949, dense 0.852
    -> 0.862, fullres 0.957 -> 0.958; JPEG quality 75 +0.002..+0.005, 90 +0.001..+0.004; MSRB
    0.302 -> 0.299, 0.354 -> 0.351.  Unsmoothed maxima gained more (seed 0.808, dense 0.868)
    but split a slow flake whose middle the background had partly learnt (a ring of excess):
    found in 43 of 60 frames instead of 59-60.  +17 us a frame at 800x600, +120 at 1456x1088.
    The detector splits coarsely while its own pattern is on the scene: there the edge of a
    hole crossing a particle is a dip in its light, and in the twin at 12 cm (12 scenes, 120
    frames) the fine split removed 0.017 less backscatter.  Peaks taken from the
    full-resolution frame instead gave about the unsmoothed figures at +0.4 ms a frame
    (800x600).
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
    if split:
        unsplit = lab
        lab, n = _split_peaks(lab, x, y, weight, excess, noise, n, full=full if factor == 2 else None,
                              fine=fine, area=area, peak=peak, flat=flat)
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
    return Detections(centres[keep], radii[keep], scores=wsum[keep])



def _split_peaks(lab: np.ndarray, x: np.ndarray, y: np.ndarray, weight: np.ndarray, excess: np.ndarray,
                 noise: np.ndarray, n: int, full: tuple[np.ndarray, np.ndarray] | None = None,
                 fine: bool = True, area: np.ndarray | None = None, peak: np.ndarray | None = None,
                 flat: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """Split components that hold two or more particles (touching or overlapping).

    Within each component of 8 pixels or more, the local maxima (3x3) of the
    excess smoothed by the 3x3 binomial kernel are its candidate peaks, and with
    ``fine`` the compact spots of the unsmoothed excess (:func:`_spots`).  A peak
    other than the component's highest is a separate particle when its nearest
    higher peak is at least 2 px away and the excess on the segment between them
    dips below it by both a quarter of its height and 3 noise units (so a narrow
    neck counts).  This runs on all components at once, without Python loops.
    ``fine=False``: the maxima (5x5) of the 3x3-summed excess, at least 3 px
    apart (see :func:`measure`).
    Flat or saturated particles have no intensity dip; for components without
    an intensity split -- and, with ``fine``, flat ones (``_PLATEAU``) -- whose core
    (the pixels above half the peak) has ``_MIN_CORE`` pixels or more, the same test
    runs on the distance transform of
    the core (a neck at least a quarter narrower than the smaller disc; at full
    resolution when ``full`` is given, see :func:`_split_flat`).  Pixels go to
    the nearest kept peak of their component.  ``area`` (pixels) and ``peak`` (highest weight) of
    each component, and ``flat`` (the pixels' raveled indices), when known.  Returns ``lab`` itself
    when nothing was split.
    """
    area = np.bincount(lab, minlength=n) if area is None else area
    inside = area[lab] >= 8
    if not inside.any():
        return lab, n
    idx = np.flatnonzero(inside)
    px, py, pl = x[idx], y[idx], lab[idx]
    pf = py * excess.shape[1] + px if flat is None else flat[idx]
    # exact sums, so equal neighbours tie exactly: the binomial's x16 in 16 bits (at most 4080; 30 %
    # faster than in float32, the same values)
    if fine:
        smooth_img, window, weights, min_d2 = cv2.sepFilter2D(excess, cv2.CV_16S, _BINOMIAL, _BINOMIAL), _K3, 16.0, 4
    else:
        smooth_img, window, weights, min_d2 = cv2.boxFilter(excess, cv2.CV_16U, (3, 3), normalize=False), _K5, 9.0, 9
    s = smooth_img.ravel().take(pf)
    is_max = s >= cv2.dilate(smooth_img, window).ravel().take(pf)
    pw = weight[idx]
    top = peak if peak is not None else _group_max(pl, n, pw)[0]
    if fine:  # and the spots the smoothing hid beside a brighter neighbour (inside the frame's rim)
        h, w = excess.shape
        strict = cv2.compare(excess, cv2.dilate(excess, _AROUND), cv2.CMP_GT).ravel().take(pf)
        bump = np.flatnonzero((strict > 0) & ~is_max)  # strict maxima of the excess not yet peaks
        bx, by = px[bump], py[bump]
        bump = bump[(excess.ravel().take(pf[bump]) < SPOT_SHARE * top[pl[bump]])
                    & (bx > 0) & (bx < w - 1) & (by > 0) & (by < h - 1)]
        is_max[bump[_spots(excess, pf[bump])]] = True
    maxima = np.bincount(pl[is_max], minlength=n)
    peaks = np.flatnonzero(is_max & (maxima[pl] >= 2))
    kept_c, kept_y, kept_x = _separate(pl[peaks], py[peaks], px[peaks], s[peaks].astype(np.float64) / weights,
                                       excess, noise_at(noise, px[peaks], py[peaks], excess.shape), min_d2=min_d2)
    counts = np.bincount(kept_c, minlength=n)
    shaped = counts < 2  # the components whose shape is looked at: those the intensity did not split,
    if fine:  # and flat ones, whose intensity maxima are where pooling cut their plateau's edges
        shaped |= np.bincount(pl[pw >= _PLATEAU_SHARE * top[pl]], minlength=n) >= _PLATEAU
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
    if not split.any():
        return lab, n
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
    return lab, n + int((counts[comps] - 1).sum())


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


#: where :func:`_nearest_peak`'s missing peaks lie, in 32-bit coordinates: for working images up
#: to a third of this a side, farther than any pixel is from its own peaks, with squared distances
#: that still fit 32 bits (larger ones are measured in 64)
_FAR = 30000


def _spots(excess: np.ndarray, flat: np.ndarray) -> np.ndarray:
    """Which of the pixels at raveled indices ``flat`` of ``excess`` (uint8 (h, w); none on the
    frame's outermost rows and columns) are compact spots: brighter than all 8 neighbours, and
    on no ridge -- every line of 3 pixels through the pixel falls below half its height at one
    end or both.  Indices into ``flat``.

    The peaks of :func:`_split_peaks` are the maxima of the 3x3-smoothed excess, which a
    faint particle 2-4 working pixels from a bright one is not: the bright one's light, smoothed
    into the pixels between them, outweighs the faint one's (in the dense cloud, 56 % of the
    particles missed alone -- in no detection's disc, overlapping no other particle -- were in
    the mask, most of them such neighbours: SNR 10-20 0.82 of them, above 20 0.93).  Such a
    particle is a strict maximum of the unsmoothed excess; so is a noise bump on a bubble's
    rim or any bright edge, but the rim runs on through it (a ridge).  F1 over the catalogue
    (frames as catalogued) dense 0.899 -> 0.907, sand 0.967 -> 0.970, mixed 0.967 -> 0.969, snow
    0.974 -> 0.976, bubbles 0.988 -> 0.989, survey 0.956 -> 0.958, textured 0.967 -> 0.968,
    fullres and the seed tank the same; held-out scene seeds (2) dense 0.909 -> 0.918, mixed
    0.961 -> 0.963, sand 0.966 -> 0.968; the MSRB photographs the same.  Without the ridge rule
    fullres lost 0.004 (its bubbles, 1.8 times as many pixels across, split at their rims); a
    ridge at 0.7 / 0.35 of the height: dense 0.908 / 0.906, fullres 0.965 / 0.966.  Tracking
    (isolated-particle IDF1): dense 0.903 -> 0.910, snow 0.965 -> 0.971, sand 0.968 -> 0.971,
    mixed, survey, bubbles, fullres +0.001..+0.002, the seed tank 0.943 -> 0.942 (see
    ``SPOT_SHARE``).  Side by side on the same frames (AMD EPYC, one thread), the detector +2-5 %
    a frame (mixed 2096 -> 2190 us median, dense 2777 -> 2897, fullres 3918 -> 4030, seed 4905 ->
    4986).  The caller takes its candidates from one 8-neighbour dilation of the frame (strict
    maxima already); the check here is repeated on those few so the function stands alone.
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


#: the spots of :func:`_spots` are looked for below this share of their component's peak: one as
#: bright as the peak is the bright particle itself -- or, in a flat one, a pixel of its plateau
#: that the 2x2 pooling cut (the seed tank's hard-edged white discs: isolated-particle IDF1 0.938
#: against 0.943 without the spots, 0.942 with them below 0.9 of the peak; F1 there and on every
#: other scene within 0.0004 of no such limit)
SPOT_SHARE = 0.9


_K5 = np.ones((5, 5), np.uint8)
_AROUND = np.array([[1, 1, 1], [1, 0, 1], [1, 1, 1]], np.uint8)  # the 8 neighbours
#: smallest core (pixels above half the peak) that can hold two discs with a neck
_MIN_CORE = 20
#: a component with this many working pixels at ``_PLATEAU_SHARE`` of its peak or more is flat (a
#: saturated or uniform particle, or several): its shape is looked at even when its intensity had
#: maxima to split at -- they lie where the 2x2 pooling cut the plateau's edges, not at particles.
#: Only while no pattern of the lamp's is on the scene (as the fine split).  Before, a cluster with
#: such maxima was split there or not at all: the seed tank's touching white discs F1 0.770 ->
#: 0.811, its isolated-particle IDF1 0.817 -> 0.844; every other scene within 0.001 (plateaus of
#: 2 / 4 px: sand 0.968 -> 0.967, fullres 0.964 -> 0.963; every component, flat or not: the same
#: and seed the same).  It costs where there are flat clusters: the seed tank's measure ~1.1 ->
#: ~1.9 ms a frame at 800x600 (more components through the full-resolution shape test), the mixed
#: scene's +3-6 % (the whole detector +2 %: 1184 against 1160 us median, side by side).
_PLATEAU = 8
_PLATEAU_SHARE = 0.97


#: numpy 1.25 made ufunc.at fast (per-label maxima of 2000 pixels: 7 us, where sorting the labels
#: first takes 27 and np.maximum.at on numpy 1.24 91): older numpy sorts
_FAST_AT = np.lib.NumpyVersion(np.__version__) >= "1.25.0"


def _groups(lab: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(order, starts): the permutation that sorts ``lab`` (labels 0..n-1; stable, and 16-bit
    labels sort by radix) and where each label's run starts in the sorted order."""
    keys = lab.astype(np.uint16) if n <= 65536 else lab
    order = np.argsort(keys, kind="stable")
    sorted_lab = lab[order]
    change = np.empty(len(lab), bool)
    change[:1] = True
    np.not_equal(sorted_lab[1:], sorted_lab[:-1], out=change[1:])
    return order, np.flatnonzero(change)


def _group_max(lab: np.ndarray, n: int, *values: np.ndarray, fast: bool | None = None) -> list[np.ndarray]:
    """Per-label maxima of each of ``values`` (0 for absent labels).  With numpy >= 1.25 (``fast``, default: this numpy's)
    np.maximum.at; before, by sorting the labels once (np.maximum.at was unbuffered and slow)."""
    if len(lab) == 0:
        return [np.zeros(n) for _ in values]
    if _FAST_AT if fast is None else fast:
        out = []
        for v in values:  # in the values' own type (the fast path wants one dtype), then as float
            low = np.iinfo(v.dtype).min if v.dtype.kind in "iu" else -np.inf
            m = np.full(n, low, v.dtype)
            np.maximum.at(m, lab, v)
            m = m.astype(np.float64)
            m[m == low] = 0.0
            out.append(m)
        return out
    order, starts = _groups(lab, n)
    present = lab[order[starts]]
    out = []
    for v in values:
        m = np.zeros(n)
        m[present] = np.maximum.reduceat(v[order], starts)
        out.append(m)
    return out


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
              sigma: np.ndarray, min_d2: int = 9, discs: np.ndarray | None = None,
              strict: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The peaks that stand apart, for all components at once: (component, y, x) of each kept peak.

    The highest peak of each component is kept; another is kept when its
    nearest higher peak (same component) is at least sqrt(min_d2) px away and the
    excess on the segment between them dips below its own by max(value / 4, 3 sigma) --
    or, where ``discs`` ((N,) bool per peak; ``excess`` a distance transform, values the radii of
    the discs the peaks are the centres of), by the neck two overlapping discs of those radii
    have there (:func:`_disc_neck_dip`); where ``strict`` ((N,) bool per peak) is False, by
    such a neck only.
    """
    if len(comp) == 0:
        return comp, py, px
    order = np.lexsort((-value, comp))  # by component, highest first
    comp, py, px, value, sigma = comp[order], py[order], px[order], value[order], sigma[order]
    if discs is not None:
        discs = discs[order]
    if strict is not None:
        strict = strict[order]
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
            apart = dip >= np.maximum(value[i] / 4.0, 3.0 * sigma[i])
            if strict is not None:
                apart &= strict[i]
            if discs is not None and discs[i].any():
                apart |= discs[i] & _disc_neck_dip(value[i], value[j], np.sqrt(d2[far]), dip)
            kept[i[apart]] = True
    return comp[kept], py[kept], px[kept]


#: a shape's two distance-transform peaks are two discs when the dip between them is at least this
#: share of the dip two overlapping discs of their radii, that far apart, make (see _disc_neck_dip)
DISC_DIP_SHARE = 0.25
#: ... and at least this many pixels: the distance transform's own steps are a few tenths of one
DISC_DIP_FLOOR = 0.2
#: ... in a core of which this share or more lies at the plateau (``_PLATEAU_SHARE`` of its peak)
DISC_PLATEAU = 0.7
#: a flat core is looked at for necks up to this compactness (others up to 0.8, see _necked)
FLAT_COMPACT = 0.94


def _disc_neck_dip(low: np.ndarray, high: np.ndarray, apart: np.ndarray, dip: np.ndarray) -> np.ndarray:
    """(K,) bool: whether each dip (px) of a shape's distance transform between a peak of value
    ``low`` and its nearest higher one, ``high``, ``apart`` px away, is the neck of two overlapping
    discs of those radii.

    Two discs of radii r1 <= r2 whose centres are d apart meet on a chord at a = (d^2 + r1^2 -
    r2^2) / 2d from the smaller's centre, half as wide as w = sqrt(r1^2 - a^2): the distance to
    the shape's edge falls from r1 to about w there.  The test of :func:`_separate` (a dip of a
    quarter of the peak and at least a pixel) asks more than small discs can show: two of the
    report's white discs of radius 4, 4 px apart, dip 0.54 px; 5.3 px apart, 1.0.  A
    dip of ``DISC_DIP_SHARE`` of the discs' and at least ``DISC_DIP_FLOOR`` px splits them, where a
    lone irregular shape's peaks -- a ridge's, whose discs would leave a deep neck -- dip far
    less; a smaller disc within the larger (no chord) is one.  Only in flat cores (``DISC_PLATEAU``
    of them at the plateau): a bubble's rim and highlight make necks of disc pairs too, and split
    so fullres lost 0.001 (31 false alarms over its 60 frames, pieces of bright bubbles).  With
    the nearly compact flat cores looked at as well (``FLAT_COMPACT``, see :func:`_necked`), share
    0.25: seed tank F1 0.811 -> 0.863 (recall 0.688 -> 0.770, precision 0.986 -> 0.981; its seeds
    2 / 3 0.795 / 0.803 -> 0.853 / 0.857), isolated-particle IDF1 0.930 -> 0.943 (seeds 2 / 3
    0.931 / 0.934 -> 0.951 / 0.937); bubbles, snow, dense and fullres within 25 detections of
    before, sand, mixed, survey, textured and the MSRB
    photographs the same; the seed tank's detector +8 % a frame (more clusters through the
    full-resolution shape test), the mixed scene's the same.  Share 0.5 / 0.35 / 0.15: seed
    0.858 / 0.862 / 0.863 (seeds 2 and 3 alike), the floor decides below 0.25; 0.3 / 0.5 / 0.7
    in every core (flat or not) of compactness under 0.8: 0.849 / 0.845 / 0.839; any dip at all, in any core
    (0.03 px): seed 0.855 but sand, mixed and survey -0.001, fullres -0.003; compactness up to 0.9
    / 0.94 for every core, not the flat ones alone: seed 0.858 / 0.861, but sand, mixed and
    fullres 9-16 false alarms more (the strict test splitting their compact cores).  A plateau
    read from the frame's own brightness instead of the excess: seed 0.860, fullres 16 false
    alarms more (saturated bubbles).  The test of a flat core's two discs for their own shape
    (the core's share of its convex hull) cost the seed tank its gain: its clusters are chains."""
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
    the report's white discs (radius 2-6 px, 1-3 working px) left hardly a neck to find: F1 on
    the seed tank 0.743 -> 0.764, the other scenes within 0.001; +0.2-0.3 ms a frame there."""
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
                                       distance, np.full(int(peak.sum()), 1.0 / 3.0), discs=flat[lab[peak]],
                                       strict=strict[lab[peak]])
    several = np.bincount(kept_c, minlength=n)[kept_c] >= 2
    kept_c = kept_c[several]
    kept_y, kept_x = kept_y[several] - shift_y[kept_c], kept_x[several] - shift_x[kept_c]
    if full is not None:  # kept peaks are 3 px or more apart: each lands in a working pixel of its own
        kept_y, kept_x = kept_y // 2, kept_x // 2
    return kept_c, kept_y, kept_x


#: the shape test's distances are taken to this many steps a pixel (see :func:`_split_flat`)
_DISTANCE_STEPS = 1024.0
_BINOMIAL = np.array([1.0, 2.0, 1.0], np.float32)
_BLOCK_X = np.array([0, 1, 0, 1])
_BLOCK_Y = np.array([0, 0, 1, 1])


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
           bounds: tuple[np.ndarray, ...]):
    """The pixels of each wanted component drawn (as 1) in a box of its own, the boxes side by
    side in one strip with 3 px of background around each (for the distance transform and the
    5x5 maximum): an image as large as the components, where their common bounding box spanned
    the seed tank's whole band of discs (four times the work at full resolution).  ``bounds``:
    (left, top, right, bottom) of each component, inclusive, around its pixels here or more (the
    distances, maxima and dips at its pixels are the same in a larger box or another place).
    Returns the pixels' strip coordinates (x, y), each component's shift (strip = frame + shift;
    (n,) each) and the image."""
    left, top, right, bottom = (np.where(wanted, v, 0).astype(np.intp) for v in bounds)
    width = np.where(wanted, right - left + 4, 0)
    shift_x = np.cumsum(width) - width + 3 - left
    shift_y = 3 - top
    sx, sy = x + shift_x[lab], y + shift_y[lab]
    image = np.zeros((int((bottom - top)[wanted].max()) + 7, int(width.sum()) + 4), np.uint8)
    image.ravel().put(sy * image.shape[1] + sx, 1)
    return (sx, sy), (shift_x, shift_y), image


def build_contrast(params: ContrastParams) -> Detector:
    """The ``contrast`` chain as timed stages (one background model per detector instance)."""
    model = BackgroundModel(cell=params.cell, memory=params.memory, k=params.k, min_contrast=params.min_contrast,
                            follow=params.follow, defer_looks=True)
    state: dict[str, Any] = {"factor": 2, "width": 0}  # the scales below are for frames of this width
    persist_kernel = _disc(params.persist_radius) if params.persist_radius else None

    def stage_downsample(image: np.ndarray) -> np.ndarray:
        width = image.shape[1]
        if width != state["width"]:
            factor = working_factor(width, params.factor)
            wide = max(1.0, width / 800.0)  # cells and rings cover the same share of the view above 800 px
            state["factor"], state["width"] = factor, width
            model.cell = max(int(round(params.cell * wide / factor)), 2)
            model.window = max(int(round(params.texture / factor)), 3) if params.texture else 0
            model.rings = tuple(sorted({max(int(round(r * wide / factor)), 2) for r in _rings(params.texture)}))
            model.noise_window = int(round(NOISE_WINDOW * wide)) | 1
        factor = state["factor"]
        grey = image if image.ndim == 2 else to_channel(image, params.channel)
        state["grey"] = grey
        return downsample(grey, factor=factor, channel=params.channel, point=params.point)

    def set_light(light: np.ndarray | None) -> None:
        state["light"] = light

    def stage_background(half: np.ndarray):
        light = _working_light(state.get("light"), half.shape, state["factor"], params.point)
        state["frozen"] = None
        if light is None:
            return half, half, *model.estimate(half)
        # the model learns the scene under the full lamp; this frame's background is that times the
        # light; where the lamp gave less than UNLIT of its light the frame says nothing about it
        reflectance = cv2.divide(half, light, scale=255)
        state["frozen"] = cv2.compare(light, UNLIT * 255, cv2.CMP_LT)
        if model.base is not None and model.base.shape == half.shape:
            # where the lamp gave too little, the frame divided by the light is noise times up to
            # 255; the model's own background stands in for it there (see UNLIT)
            cv2.copyTo(model.base, state["frozen"], reflectance)
        base, limit = model.estimate(reflectance)
        # the frame is compared with its background under the most light it may have had (a
        # hole's rim a pixel off the map is not a particle), learnt under the light it had
        upper = _upper_light(state.get("light"), half.shape, state["factor"], params.point, state)
        return half, reflectance, cv2.multiply(base, light if upper is None else upper, scale=1 / 255), limit

    def expect(where: Detections | None) -> None:
        state["expected"] = where

    def stage_threshold(value):
        half, reflectance, base, limit = value
        state["base"] = base
        mask, excess = threshold_mask(half, base, limit)
        prominent, model.prominent = model.prominent, None
        if prominent is not None:
            # the model learns from this frame as it always has (see ``texture``): only the
            # detections are cut to what stands out
            state["learn_mask"] = cv2.compare(excess, model.limit, cv2.CMP_GT)
            mask = prominent_only(mask, prominent, max(model.rings[-1] // 2, 1))
        expected = state.pop("expected", None)  # for this frame only
        if expected is not None and len(expected) and params.k_expected < params.k:
            # around particles the tracker expects, a lower threshold: faint light there is them
            near = _near(mask.shape, expected, state["factor"])
            low = cv2.convertScaleAbs(limit, alpha=params.k_expected / params.k)
            cv2.bitwise_or(mask, cv2.bitwise_and(cv2.compare(excess, low, cv2.CMP_GT), near), dst=mask)
        return reflectance, mask, excess

    def stage_label(value):
        reflectance, mask, excess = value
        return reflectance, mask, excess, label(mask)

    def stage_measure(value):
        reflectance, mask, excess, components = value
        # where the last frame was bright (once static texture has been learnt into the background)
        seen = state.pop("seen", None) if model.learnt() else None
        if seen is not None and seen.shape != mask.shape:
            seen = None
        found = measure(components, excess, model.noise, halo=params.halo, core=params.core,
                        max_radius=params.max_radius, split=params.split, frame_width=state["width"],
                        factor=state["factor"], lone_k=params.lone_k, seen=seen,
                        full=(state["grey"], state["base"]), fine=state.get("frozen") is None)
        learn_mask = state.pop("learn_mask", None)
        state["learn"] = (reflectance, mask if learn_mask is None else learn_mask, state.get("frozen"))
        return found

    def stage_update(found: Detections) -> Detections:
        """For the next frames: the background learns from this one, and where it was bright is kept."""
        reflectance, mask, frozen = state.pop("learn")
        model.look_deferred(reflectance)  # a still view's routine look at its flow, off the latency path
        model.learn(reflectance, mask, frozen)
        if persist_kernel is not None:
            state["seen"] = cv2.dilate(mask, persist_kernel)
        return found

    stages = (
        Stage("downsample", "Downsample", stage_downsample),
        Stage("background", "Background Estimate", stage_background),
        Stage("threshold", "Local Threshold", stage_threshold),
        Stage("label", "Connected Components", stage_label),
        Stage("measure", "Measure Particles", stage_measure),
        Stage("update", "Background Update", stage_update, after=True),
    )
    return Detector("contrast", stages, params, reset=model.reset, set_light=set_light, expect=expect)


#: below this share of the lamp's light a pixel's brightness says too little about the scene to learn
#: from.  Nor is it shown to the model's estimates (the view's pan and turn, its brightness, a new
#: scene): the frame's reflectance there is the learnt background.  It had been the frame divided
#: by the light -- the sensor's noise times 10-255 in every hole -- and a view moving under dark
#: holes was followed wrongly: in the twin (co-located, 5 ms, prediction, scenes 1-6) the survey
#: scene (the vehicle moving sideways) kept 0.886 of the scene light with pulsed holes and 0.891
#: with dim ones, 0.955 and 0.958 now, removing 0.858 -> 0.867 and 0.829 -> 0.842 (at 12 cm with
#: probing 0.754 / 0.833 -> 0.767 / 0.836); mixed, textured, dense and sand within 0.004.
UNLIT = 0.1


#: largest view shift between two frames that the background follows (working pixels)
MAX_FOLLOW = 16
#: a profile whose high-passed spread is below this (grey levels) is a plain view with nothing to
#: follow.  0.2 took smooth seabed for plain: averaged over a whole row its texture varies by only
#: ~0.2, and vertical and diagonal pans over it were not followed (400-950 false detections a
#: frame, 24-145 now); noise alone correlates below the 0.8 the shift needs anyway.
PLAIN = 0.1


def _fits_better(frame: np.ndarray, base: np.ndarray, dx: int, dy: int) -> bool:
    """True when the background moved by (dx, dy) lies closer to the frame than where it is (mean
    absolute difference over every 4th row of the overlap).  The profiles of a still view
    jitter: a big bright bubble passing once measured a 0.56 px shift, which rounded to a 1 px
    move and misaligned the learnt seabed (in the twin, detections a frame 70 -> 145 for the
    next 10 frames and more); the move is checked against the whole image before it is made."""
    h, w = frame.shape
    ys, xs = slice(max(dy, 0), h + min(dy, 0)), slice(max(dx, 0), w + min(dx, 0))
    moved = base[max(-dy, 0):h - max(dy, 0), max(-dx, 0):w - max(dx, 0)]  # base[y - dy, x - dx]
    here = frame[ys, xs][::4]
    return cv2.norm(here, moved[::4], cv2.NORM_L1) < cv2.norm(here, base[ys, xs][::4], cv2.NORM_L1)


_K3 = np.ones((3, 3), np.uint8)
#: Lucas-Kanade iterations stop after 10 or a move under 0.03 px (OpenCV's default 30 / 0.01 cost a
#: flat view's points 30 iterations each: 0.55 ms a look in the mixed scene)
_LK_STOP = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 10, 0.03)


#: the correlation a profile taken again over the shared ground needs (the first axis's shift
#: found, and the move still has to fit better): 0.8 left diagonal and sideways pans over ground
#: with little structure across them unfollowed one frame in two (bursts of 60-800 false
#: detections a frame with ``point`` pooling); 0.6 took the seed tank's rising discs for a move
OVERLAP_SCORE = 0.7


def _overlap_shift(reference: np.ndarray, frame: np.ndarray, axis: int, other: int) -> float | None:
    """:func:`_profile_shift` along ``axis`` (0: x from column profiles, 1: y from row profiles) of
    two images whose view moved by ``other`` samples along the other axis: the profiles are taken
    over the part both show."""
    n = reference.shape[axis]  # the other axis's length: rows for x (axis 0), columns for y
    if abs(other) >= n // 2:
        return None
    keep = slice(max(0, -other), n - max(0, other))  # in the reference; the frame's is shifted by other
    seen = slice(max(0, other), n - max(0, -other))
    ref, cur = (reference[keep], frame[seen]) if axis == 0 else (reference[:, keep], frame[:, seen])
    profiles = [cv2.reduce(v, axis, cv2.REDUCE_AVG, dtype=cv2.CV_32F).ravel() for v in (ref, cur)]
    return _profile_shift(_highpass(profiles[0]), profiles[1], MAX_FOLLOW // 2, OVERLAP_SCORE)


def _highpass(profile: np.ndarray) -> np.ndarray | None:
    """A brightness profile (1-D) minus its 15-sample running mean, float32, so the lamp's cone does
    not count; None for a plain view (open water: spread below ``PLAIN``), with nothing to follow."""
    row = profile.astype(np.float32).reshape(1, -1)
    row -= cv2.blur(row, (15, 1), borderType=cv2.BORDER_REPLICATE)
    return None if cv2.meanStdDev(row)[1][0, 0] < PLAIN else row.ravel()


def _profile_shift(reference: np.ndarray | None, profile: np.ndarray, max_shift: int,
                   min_score: float = 0.8) -> float | None:
    """Shift (samples, sub-sample) that best lays ``reference`` onto ``profile`` (1-D float32, same
    length), within +-max_shift; None when their high-passed correlation there is below 0.8 (no
    texture to go by, or the view changed more than it moved).  ``reference`` is already
    :func:`_highpass`'s (None: a plain view), as :meth:`BackgroundModel.follow` keeps it."""
    n = len(profile)
    if n < 4 * max_shift:
        return None
    p = None if reference is None else _highpass(profile)
    if p is None:
        return None
    # normalised correlation of the profile's middle with every window of the reference (OpenCV, one
    # call); the window starting at j stands for the shift max_shift - j: reversed, index i <-> i - max
    middle = p[max_shift:n - max_shift].reshape(1, -1)
    scores = cv2.matchTemplate(reference.reshape(1, -1), middle, cv2.TM_CCOEFF_NORMED).ravel()[::-1]
    best = int(np.argmax(scores))
    if scores[best] < min_score:
        return None
    offset = 0.0
    if 0 < best < len(scores) - 1:  # parabola through the peak and its neighbours
        a, b, c = scores[best - 1], scores[best], scores[best + 1]
        denominator = a - 2 * b + c
        if denominator < 0:
            offset = 0.5 * (a - c) / denominator
    return float(best - max_shift + offset)


def _disc(radius: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))


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


def _working_light(light: np.ndarray | None, shape: tuple[int, int], factor: int,
                   point: float = 0.0) -> np.ndarray | None:
    """The lamp's light map at working resolution as uint8 (255 = full, at least 1); None when full.

    A map of the frame's size goes through the same downsampling as the frame, so the
    edges of holes blur exactly as the image of them does."""
    if light is None:
        return None
    light = np.asarray(light)
    if light.dtype != np.uint8:
        light = cv2.convertScaleAbs(light, alpha=255.0)  # 0..1 -> 0..255, saturated
    if light.shape == (shape[0] * factor, shape[1] * factor) or (factor == 1 and light.shape == shape):
        light = downsample(light, factor=factor, point=point)
    if light.shape != shape:
        light = cv2.resize(light, (shape[1], shape[0]), interpolation=cv2.INTER_AREA)
    return cv2.max(light, 1)


def _upper_light(light: np.ndarray | None, shape: tuple[int, int], factor: int, point: float,
                 buffers: dict) -> np.ndarray | None:
    """The most light each working pixel may have had when the pattern landed up to a camera
    pixel off the map (calibration error, the lens, a background off the calibrated plane): a
    map of the frame's size dilated by one pixel, then pooled as the frame is.  None for a map
    of another size (coarser than a pixel: taken as it is).

    A hole's rim a pixel off on a bright seabed is a crescent of light the map does not explain;
    each was taken for a particle, given a hole, and made rims of its own.  In the twin
    (pulsed holes, prediction, 5 ms, scenes 1-6) with its calibration (from ``calibrate
    --twin``) one camera pixel off in x and in y, removed / kept without this slack and with
    it: co-located on the textured seabed 0.720 / 0.771 and 0.861 / 0.941, mixed 0.844 / 0.902
    and 0.888 / 0.961, at 12 cm with probing 0.780 / 0.888 and 0.789 / 0.927.  With the
    calibration as recovered (0.07 projector px off) 0.911 / 0.964 and 0.905 / 0.970, 0.916 /
    0.961 and 0.915 / 0.963, 0.803 / 0.928 and 0.807 / 0.928.  Two pixels of slack lost the
    particles dimmed in small holes (mixed 0.867 removed, textured 0.838).  Measuring the flux
    against the map itself (only the decision against this) failed the probe's verdicts on a
    bright bubble (its settled hole at the wrong depth: 0.7 removed where 0.8 is the dim level).
    Only the comparison uses it: the background is learnt under the map itself.  ``buffers``: a
    dict that keeps the dilated map's buffer between frames (the detector's state)."""
    if light is None or np.shape(light)[:2] != (shape[0] * factor, shape[1] * factor):
        return None
    light = np.asarray(light)
    if light.dtype != np.uint8:
        light = cv2.convertScaleAbs(light, alpha=255.0)
    kept = buffers.get("dilated")
    if kept is None or kept.shape != light.shape:
        kept = buffers["dilated"] = np.empty_like(light)
    return _working_light(cv2.dilate(light, _K3, dst=kept), shape, factor, point)


register_detector("contrast", ContrastParams, build_contrast,
                  "local contrast over a learnt background, threshold in noise units, one labelling pass "
                  "(the default)",
                  sweep=("k", (2.0, 2.5, 3.0, 3.5, 4.0, 5.0, 6.0, 8.0, 10.0, 14.0)), sweep_scaled=("k_expected",))
