"""The default detector, ``contrast``: particles as local, transient excess of light.

Backscatter is light that a small particle sends back from the lamp: a compact
spot brighter than what is behind it, moving against a scene that changes
slowly.  The detector therefore finds pixels brighter than a *background
estimate* by more than a multiple of the *local noise*, instead of above a
global level:

1. ``downsample`` -- one pass over the frame: for frames 640 px wide or more a
   2x2 area average (a matched filter for spots of 1 px radius and more, halving
   the noise and the work of every later stage), and one channel (green for
   BGR: the lamp's light in water, the least noisy Bayer channel; the Y plane or
   a grey frame is used as it is).
2. ``background`` -- the background at a coarse scale (cells of ``cell`` pixels):
   the 3x3-cell median of the cell means ignores a particle filling a cell, so
   uneven lamp cones and dim far scenes are followed while particles are not.  When frames follow each other (a video or the camera), a per-pixel
   background learnt over about ``memory`` frames -- updated only where no
   particle was found -- takes over, so static texture (seabed pebbles, tank
   padding) stops looking like particles; ``memory=0`` keeps the detector
   single-frame.
3. ``threshold`` -- the noise per coarse cell is the robust spread of
   (frame - background) there (median-filtered over cells so particles do not
   inflate it); a pixel is a particle candidate when it exceeds the background
   by ``k`` times that noise and by at least ``min_contrast`` grey levels.
4. ``label`` -- one connected-components pass on the candidate mask; statistics
   from its few non-zero pixels (vectorised, no per-pixel Python).
5. ``measure`` -- split a component where it holds separate intensity peaks
   (touching or overlapping particles), reject what is not a particle (see
   below), and give each particle its brightness-weighted centre and a radius
   covering its whole extent plus ``halo`` pixels of blur.

Rejection rule: a component is not a particle when its covering radius exceeds
``max_radius`` (pixels; scaled up for frames wider than 800 px, whose pixels
see less of the scene): a region that large and brighter than its surroundings is lit scene,
not backscatter (a 1 cm bubble 0.3 m from the lens is about 11 px at 800 px).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from ..detections import Detections
from . import Detector, Stage, register_detector

__all__ = ["ContrastParams", "downsample", "BackgroundModel", "threshold_mask", "label", "measure",
           "build_contrast"]


@dataclass(frozen=True)
class ContrastParams:
    """Settings of the ``contrast`` detector.

    k: detection threshold in units of the local noise (default 4).
    min_contrast: smallest excess over the background, grey levels (default 4).
    cell: background cell size in full-resolution pixels for frames up to 800 px wide, scaled with
        the width above that (default 16).
    memory: frames over which the per-pixel background is learnt; 0 = single-frame (default 20).
    halo: pixels added to each radius for the particle's blur halo (default 1).
    max_radius: largest particle radius in pixels, for frames up to 800 px wide; scaled with the
        width above that (default 48).
    split: split components with several intensity peaks (default true).
    factor: working resolution divisor, 1 or 2; 0 = 2 for frames 640 px wide or more, else 1 (default 0).
    """

    k: float = 4.0
    min_contrast: float = 4.0
    cell: int = 16
    memory: int = 20
    halo: float = 1.0
    max_radius: float = 48.0
    split: bool = True
    factor: int = 0

    def __post_init__(self) -> None:
        if self.factor not in (0, 1, 2):
            raise ValueError(f"factor: got {self.factor}, allowed 0 (automatic), 1 or 2")
        if not self.k > 0:
            raise ValueError(f"k: got {self.k}, allowed > 0")
        if self.min_contrast < 0:
            raise ValueError(f"min_contrast: got {self.min_contrast}, allowed >= 0")
        if self.cell < 4 or self.cell % 2:
            raise ValueError(f"cell: got {self.cell}, allowed an even integer >= 4")
        if self.memory < 0:
            raise ValueError(f"memory: got {self.memory}, allowed >= 0 (0 = single-frame)")
        if self.halo < 0:
            raise ValueError(f"halo: got {self.halo}, allowed >= 0")
        if not self.max_radius > 0:
            raise ValueError(f"max_radius: got {self.max_radius}, allowed > 0")


def working_factor(width: int, factor: int = 0) -> int:
    """The downsampling factor: ``factor`` if given, else 2 for frames 640 px wide or more, else 1."""
    if factor:
        return factor
    return 2 if width >= 640 else 1


def downsample(image: np.ndarray, *, factor: int = 2) -> np.ndarray:
    """(H, W, 3) BGR or (H, W) grey -> (H/f, W/f) uint8: f x f area mean of one channel (green for BGR);
    at f = 1 a 3x3 Gaussian instead, the same noise suppression without decimation."""
    height, width = image.shape[:2]
    if factor > 1:
        image = cv2.resize(image, (width // factor, height // factor), interpolation=cv2.INTER_AREA)
    if image.ndim == 3:
        image = cv2.extractChannel(image, 1 if image.shape[2] >= 3 else 0)
    if factor == 1:  # the same matched filter as the 2x2 mean, without decimation
        image = cv2.GaussianBlur(image, (3, 3), 0)
    return image


def spatial_background(half: np.ndarray, *, cell: int) -> np.ndarray:
    """Coarse background of a working-resolution frame: 3x3 median of the cell means, float32 (h, w).

    cell: cell size in working-resolution pixels.
    """
    h, w = half.shape
    c = max(cell, 1)
    cw, ch = max(w // c, 3), max(h // c, 3)
    means = cv2.resize(half, (cw, ch), interpolation=cv2.INTER_AREA)
    robust = cv2.medianBlur(means, 3)  # a particle spoils a cell, not its 3x3 median
    return cv2.resize(robust, (w, h), interpolation=cv2.INTER_LINEAR).astype(np.float32)


class BackgroundModel:
    """Per-pixel background learnt over ``memory`` frames, updated where no particle was found.

    The first frame (and any frame of another size) starts from the spatial
    background; ``memory=0`` keeps it single-frame.  This is the detector's only state.
    """

    def __init__(self, *, cell: int, memory: int) -> None:
        self.cell = cell
        self.alpha = 1.0 / memory if memory else 0.0
        self._previous: np.ndarray | None = None
        self._persist: np.ndarray | None = None
        self.background: np.ndarray | None = None
        self._frames = 0

    def reset(self) -> None:
        self.background = None
        self._previous = None
        self._persist = None
        self._frames = 0

    def estimate(self, half: np.ndarray) -> np.ndarray:
        """The background for this frame, float32 (h, w)."""
        if self.alpha == 0.0 or self.background is None or self.background.shape != half.shape:
            self.background = spatial_background(half, cell=self.cell)
            self._frames = 0
            self._previous = self._persist = None
        return self.background

    #: frames a pixel must stay under an unchanging "particle" before it counts as scene
    PERSIST = 8

    def learn(self, half: np.ndarray, particles: np.ndarray, steady_limit: np.ndarray) -> None:
        """Update from this frame.

        Pixels without a particle learn at the full rate.  Under a particle
        (``particles``: uint8, 255 = particle) a pixel learns at a quarter of it,
        so moving particles leave almost no trace -- unless it has stayed within
        2 noise units (``noise``, float32) of its last value for ``PERSIST``
        frames in a row: then it is scene the first frames mistook for a particle
        (a bright pebble, a padding highlight) and learns at the full rate.
        """
        if self.alpha == 0.0 or self.background is None:
            return
        rate = min(1.0, max(self.alpha, 1.0 / (self._frames + 2)))
        learn = cv2.bitwise_not(particles)
        if self._previous is not None and self._previous.shape == half.shape:
            change = cv2.absdiff(half, self._previous)
            steady = cv2.bitwise_and(cv2.compare(change, steady_limit, cv2.CMP_LE), particles)
            if self._persist is None or self._persist.shape != half.shape:
                self._persist = np.zeros(half.shape, np.uint8)
            cv2.add(self._persist, 1, dst=self._persist, mask=steady)
            cv2.bitwise_and(self._persist, steady, dst=self._persist)
            scene = cv2.compare(self._persist, self.PERSIST, cv2.CMP_GE)
            # scene mistaken for a particle is corrected quickly
            cv2.accumulateWeighted(half, self.background, min(1.0, 4 * rate), mask=scene)
        cv2.accumulateWeighted(half, self.background, rate / 4)
        cv2.accumulateWeighted(half, self.background, rate * 0.75, mask=learn)
        self._previous = half.copy()
        self._frames += 1


def threshold_mask(half: np.ndarray, background: np.ndarray, *, cell: int, k: float,
                   min_contrast: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(candidate mask uint8, positive excess over the background uint8, noise per coarse cell float32).

    Particles only ever add light, so the noise is measured on the *dark* side:
    per coarse cell, the mean of max(background - frame, 0), which for symmetric
    noise of spread s is 0.399 s, whatever bright particles the cell holds.  A
    3x3-cell median smooths the estimate.  A pixel is a candidate where the
    excess exceeds max(k * noise, min_contrast).
    """
    h, w = half.shape
    cw, ch = max(w // cell, 3), max(h // cell, 3)
    base = cv2.convertScaleAbs(background)  # rounded, saturated uint8 (the background is >= 0)
    deficit = cv2.subtract(base, half).astype(np.float32)  # max(background - frame, 0)
    spread = cv2.medianBlur(cv2.resize(deficit, (cw, ch), interpolation=cv2.INTER_AREA), 3)
    noise = spread * np.float32(2.5066)  # E[max(-x, 0)] = s / sqrt(2 pi) for x ~ N(0, s)
    limit = cv2.resize(np.maximum(k * noise, np.float32(min_contrast)), (w, h), interpolation=cv2.INTER_LINEAR)
    excess = cv2.subtract(half, base)  # max(frame - background, 0), uint8
    mask = cv2.compare(excess.astype(np.float32), limit, cv2.CMP_GT)
    return mask, excess, noise


def noise_at(noise: np.ndarray, x: np.ndarray, y: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """The coarse noise map sampled at working-resolution pixels (x, y)."""
    ch, cw = noise.shape
    h, w = shape
    return noise[np.minimum(y * ch // h, ch - 1), np.minimum(x * cw // w, cw - 1)]


def steady_limit(noise: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """3 noise units per pixel as uint8 (rounded up): the most a static pixel changes between frames."""
    h, w = shape
    return cv2.resize(np.ceil(3.0 * noise).clip(1, 255).astype(np.uint8), (w, h),
                      interpolation=cv2.INTER_NEAREST)


def label(mask: np.ndarray) -> dict[str, np.ndarray]:
    """Connected components (8-connected) of ``mask`` as per-pixel arrays of the non-zero pixels.

    Returns {"labels": (P,) component index 0.., "x": (P,), "y": (P,), "count": int}.
    """
    count, labels = cv2.connectedComponents(mask, connectivity=8, ltype=cv2.CV_32S)
    points = cv2.findNonZero(mask)
    if points is None:
        empty = np.empty(0, np.int64)
        return {"labels": empty, "x": empty, "y": empty, "count": 0}
    xy = points.reshape(-1, 2)
    x, y = xy[:, 0].astype(np.int64), xy[:, 1].astype(np.int64)
    return {"labels": labels[y, x].astype(np.int64) - 1, "x": x, "y": y, "count": count - 1}


def measure(components: dict[str, np.ndarray], excess: np.ndarray, noise: np.ndarray, *,
            halo: float, max_radius: float, split: bool, frame_width: int, factor: int = 2) -> Detections:
    """Centres (brightness-weighted) and covering radii of the components, in full-resolution pixels.

    excess: uint8 light above the background; noise: the coarse noise map (for splitting).
    """
    n = components["count"]
    if n == 0:
        return Detections.empty()
    lab, x, y = components["labels"], components["x"], components["y"]
    weight = np.maximum(excess[y, x].astype(np.float64), 1e-3)
    if split:
        lab, n = _split_peaks(lab, x, y, weight, excess, noise_at(noise, x, y, excess.shape), n)
    wsum = np.bincount(lab, weights=weight, minlength=n)
    cx = np.bincount(lab, weights=weight * x, minlength=n) / wsum
    cy = np.bincount(lab, weights=weight * y, minlength=n) / wsum
    # per-component maxima by sorting once (np.maximum.at is unbuffered and slow)
    order = np.argsort(lab, kind="stable")
    starts = np.flatnonzero(np.r_[True, np.diff(lab[order]) != 0])
    present = lab[order][starts]
    peak = np.zeros(n)
    peak[present] = np.maximum.reduceat(weight[order], starts)
    far = np.zeros(n)
    distance = np.hypot(x - cx[lab], y - cy[lab])
    far[present] = np.maximum.reduceat(distance[order], starts)
    # working -> full resolution: pixel centres map as u = f x + (f - 1) / 2
    offset = (factor - 1) / 2.0
    centres = np.column_stack([factor * cx + offset, factor * cy + offset])
    radii = factor * (far + 0.5) + halo  # the farthest pixel's far edge, plus the blur halo
    keep = (radii <= max_radius * max(1.0, frame_width / 800.0)) & (wsum > 0)
    return Detections(centres[keep], radii[keep], scores=peak[keep])


def _split_peaks(lab: np.ndarray, x: np.ndarray, y: np.ndarray, weight: np.ndarray, excess: np.ndarray,
                 noise: np.ndarray, n: int) -> tuple[np.ndarray, int]:
    """Split components that hold two or more particles (touching or overlapping).

    Within a component (of 8 pixels or more), the excess is smoothed (3x3) and
    its local maxima (5x5) found; a maximum is a separate particle when it is
    at least 3 px from a brighter one and the profile between them dips below
    it by both a quarter of its height and 3 noise units (read on the
    unsmoothed excess, so a narrow neck counts).  Flat or saturated particles
    have no intensity dip; for them the same test runs on the distance
    transform of the component's core (the pixels above half its peak; a neck
    at least a quarter narrower than the smaller disc).  Pixels go to the nearest kept peak.
    """
    area = np.bincount(lab, minlength=n)
    # candidates, found without Python loops: components holding two or more 5x5 maxima
    smooth_all = cv2.boxFilter(excess, cv2.CV_16U, (3, 3), normalize=False)  # exact 3x3 sums: no rounding ties
    is_max = smooth_all[y, x] >= cv2.dilate(smooth_all, np.ones((5, 5), np.uint8))[y, x]
    maxima = np.bincount(lab[is_max], minlength=n)
    big = np.flatnonzero((area >= 8) & (maxima >= 2))
    if len(big) == 0:
        return lab, n
    lab = lab.copy()
    next_label = n
    order = np.argsort(lab, kind="stable")
    bounds = np.concatenate([[0], np.cumsum(area)])
    kernel = np.ones((5, 5), np.uint8)
    for c in big.tolist():
        idx = order[bounds[c]:bounds[c + 1]]
        px, py, pw = x[idx], y[idx], weight[idx]
        x0, y0 = px.min() - 1, py.min() - 1
        patch = np.zeros((py.max() - y0 + 2, px.max() - x0 + 2), np.float32)
        patch[py - y0, px - x0] = pw
        smooth = cv2.blur(patch, (3, 3))
        inside = (patch > 0).astype(np.uint8)
        sigma = float(np.median(noise[idx]))
        # intensity peaks, read on the unsmoothed profile so narrow necks count
        chosen_yx = _separate_peaks(smooth, patch, inside, kernel, lambda v: max(v / 4, 3 * sigma))
        if len(chosen_yx) < 2:
            # shape: touching flat or saturated discs have one plateau but two
            # distance-transform peaks with a neck between them
            core = (patch >= 0.5 * patch.max()).astype(np.uint8)  # the halo would hide the neck
            distance = cv2.distanceTransform(core, cv2.DIST_L2, 3)
            chosen_yx = _separate_peaks(distance, distance, core, kernel, lambda v: max(v / 4, 1.0))
        if len(chosen_yx) < 2:
            continue
        chosen = chosen_yx
        sy = np.array([p[0] for p in chosen]) + y0
        sx = np.array([p[1] for p in chosen]) + x0
        d = (px[:, None] - sx[None, :]) ** 2 + (py[:, None] - sy[None, :]) ** 2
        nearest = np.argmin(d, axis=1)
        lab[idx] = np.where(nearest == 0, c, next_label + nearest - 1)
        next_label += len(chosen) - 1
    return lab, next_label


def _separate_peaks(surface: np.ndarray, profile: np.ndarray, inside: np.ndarray, kernel: np.ndarray,
                    min_dip) -> list[tuple[int, int]]:
    """Local maxima of ``surface`` inside the component that stand apart: each at
    least 3 px from a higher one, with ``profile`` dipping between them by
    ``min_dip(height)`` or more.  Returns (row, col) positions, highest first."""
    is_peak = (surface >= cv2.dilate(surface, kernel)) & (inside > 0)
    pys, pxs = np.nonzero(is_peak)
    if len(pys) < 2:
        return []
    values = surface[pys, pxs]
    chosen: list[int] = []
    for i in np.argsort(-values, kind="stable").tolist():
        if not chosen:
            chosen.append(i)
            continue
        j = min(chosen, key=lambda c: (pys[i] - pys[c]) ** 2 + (pxs[i] - pxs[c]) ** 2)
        if (pys[i] - pys[j]) ** 2 + (pxs[i] - pxs[j]) ** 2 < 9:
            continue
        steps = 2 + int(np.hypot(pys[i] - pys[j], pxs[i] - pxs[j]))
        ty = np.rint(np.linspace(pys[i], pys[j], steps)).astype(int)
        tx = np.rint(np.linspace(pxs[i], pxs[j], steps)).astype(int)
        if profile[pys[i], pxs[i]] - profile[ty, tx].min() >= min_dip(values[i]):
            chosen.append(i)
    return [(int(pys[i]), int(pxs[i])) for i in chosen]


def build_contrast(params: ContrastParams) -> Detector:
    """The ``contrast`` chain as timed stages (one background model per detector instance)."""
    model = BackgroundModel(cell=params.cell, memory=params.memory)
    state: dict[str, Any] = {"factor": 2, "cell": params.cell // 2}

    def stage_downsample(image: np.ndarray) -> np.ndarray:
        factor = working_factor(image.shape[1], params.factor)
        # cells cover the same share of the view at any width above 800 px
        cell = params.cell * max(1.0, image.shape[1] / 800.0)
        state["factor"], state["cell"], state["width"] = factor, max(int(round(cell / factor)), 2), image.shape[1]
        model.cell = state["cell"]
        return downsample(image, factor=factor)

    def stage_background(half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return half, model.estimate(half)

    def stage_threshold(value: tuple[np.ndarray, np.ndarray]):
        half, background = value
        mask, excess, noise = threshold_mask(half, background, cell=state["cell"], k=params.k,
                                             min_contrast=params.min_contrast)
        return half, mask, excess, noise

    def stage_label(value):
        half, mask, excess, noise = value
        return half, mask, excess, noise, label(mask)

    def stage_measure(value) -> Detections:
        half, mask, excess, noise, components = value
        found = measure(components, excess, noise, halo=params.halo, max_radius=params.max_radius,
                        split=params.split, frame_width=state["width"], factor=state["factor"])
        if model.alpha:
            model.learn(half, cv2.dilate(mask, None), steady_limit(noise, half.shape))
        return found

    stages = (
        Stage("downsample", "Downsample", stage_downsample),
        Stage("background", "Background Estimate", stage_background),
        Stage("threshold", "Local Threshold", stage_threshold),
        Stage("label", "Connected Components", stage_label),
        Stage("measure", "Measure Particles", stage_measure),
    )
    return Detector("contrast", stages, params, reset=model.reset)


register_detector("contrast", ContrastParams, build_contrast,
                  "local contrast over a learnt background, threshold in noise units, one labelling pass "
                  "(the default)",
                  sweep=("k", (2.0, 2.5, 3.0, 3.5, 4.0, 5.0, 6.0, 8.0, 10.0, 14.0)))
