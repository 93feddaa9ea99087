"""The ``contrast`` chain as named stages: :func:`build_contrast`.

downsample -> background -> threshold -> label -> measure, then ``update`` (after the detections
are out, off the latency path).  The stages hand each frame's values on by return value; what one
stage leaves for a later one, or for the next frame, is a :class:`ChainState`.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ...detections import Detections
from .. import Detector, Pooled, Stage
from .bands import BandPool, downsample_in_bands
from .background import NOISE_WINDOW, _near, _rings, prominent_only, threshold_mask
from .components import brightest, label, measure
from .kernels import _disc
from .model import BackgroundModel
from .params import ContrastParams
from .scales import coarse_particles, merge_scales
from .working import UNLIT, _upper_light, _working_light, downsample, to_channel, working_factor


#: the split's bound on its work a frame, pixel-peak pairs per working pixel: 4 times the most
#: any catalogued scene needs (the seed tank's clusters, 1.0), so no frame can make it run long
SPLIT_BUDGET = 4

#: share of the single-frame limit at which the frame alone must also show a learnt-background
#: candidate while the view moves or the model is young (``BackgroundModel.YOUNG``); 0 = off
MOVING_SCALE = 0.5


@dataclass
class ChainState:
    """What the stages of one ``contrast`` detector leave for later stages and later frames.

    Lifetimes: *frames* lasts across frames until replaced; *frame* is set by one stage of a frame
    and read by a later stage of the same frame; *handed on* is read once and cleared by its reader.
    """

    #: working resolution divisor for frames of ``width`` (frames: set when the width changes)
    factor: int = 2
    #: width (full-resolution pixels) the scales (factor, cells, rings) are for; 0 = none yet (frames)
    width: int = 0
    #: this frame's single channel at full resolution, (H, W) uint8; None for a :class:`Pooled`
    #: frame without its full plane (frame: downsample -> measure)
    grey: np.ndarray | None = None
    #: share of each block's maximum in this frame's working pixels: ``ContrastParams.point``, or 0
    #: for a :class:`Pooled` frame (the ISP's filter taken as the 2x2 mean), so the light map is
    #: pooled as the frame was (frame: downsample -> background)
    point: float = 0.0
    #: the lamp's light map given by ``set_light``, (H, W) in camera pixels, 1 or 255 = full;
    #: None = full everywhere (frames: until the next ``set_light``)
    light: np.ndarray | None = None
    #: buffer of the light map dilated by :func:`_upper_light`, (H, W) uint8 (frames)
    dilated: np.ndarray | None = None
    #: working pixels left unlit by the lamp (uint8, 255 = unlit), None without a light map
    #: (frame: background -> measure)
    frozen: np.ndarray | None = None
    #: the background this frame was thresholded against, (h, w) uint8 (frame: threshold -> measure)
    base: np.ndarray | None = None
    #: particles the tracker expects in the next frame, camera pixels (handed on: ``expect`` ->
    #: the next frame's threshold)
    expected: Detections | None = None
    #: (reflectance, mask, frozen) the model learns from after the detections (handed on:
    #: measure -> update)
    learn: tuple[np.ndarray, np.ndarray, np.ndarray | None] | None = None
    #: where the last frame was bright: its mask dilated by ``persist_radius``, (h, w) uint8
    #: (handed on: update -> the next frame's measure, once the background has been learnt)
    seen: np.ndarray | None = None


def build_contrast(params: ContrastParams, *, threads: int = 1) -> Detector:
    """The ``contrast`` chain as timed stages (one background model per detector instance).

    threads: threads the frame-wide filters run on in bands of rows, and the components are
    measured on in bands of labels beside the coarse scale (:class:`~.bands.BandPool`; default 1);
    the detections and what the model learns are the same on any number."""
    pool = BandPool(threads)
    model = BackgroundModel(cell=params.cell, memory=params.memory, k=params.k, min_contrast=params.min_contrast,
                            follow=params.follow, defer_looks=True, pool=pool if threads > 1 else None)
    state = ChainState()
    persist_kernel = _disc(params.persist_radius) if params.persist_radius else None

    def working_size(width: int, height: int) -> tuple[int, int] | None:
        """The plane a Pooled frame of width x height px carries: the working resolution (factor 2 or
        more; at factor 1 the working image is the frame itself, blurred, and nothing is pooled)."""
        factor = working_factor(width, params.factor)
        return (width // factor, height // factor) if factor > 1 else None

    def stage_downsample(image: np.ndarray | Pooled) -> np.ndarray:
        # a Pooled frame (the camera's ISP scaled it): the scales are its full size's, nothing to pool
        width = image.size[0] if isinstance(image, Pooled) else image.shape[1]
        if width != state.width:
            factor = working_factor(width, params.factor)
            wide = max(1.0, width / 800.0)  # cells and rings cover the same share of the view above 800 px
            state.factor, state.width = factor, width
            model.cell = max(int(round(params.cell * wide / factor)), 2)
            model.window = max(int(round(params.texture / factor)), 3) if params.texture else 0
            model.rings = tuple(sorted({max(int(round(r * wide / factor)), 2) for r in _rings(params.texture)}))
            model.noise_window = int(round(NOISE_WINDOW * wide)) | 1
        factor = state.factor
        if isinstance(image, Pooled):
            state.grey, state.point = image.full, 0.0
            return image.working
        if pool.threads > 1 and factor > 1 and image.shape[0] % factor == 0 and image.shape[1] % factor == 0:
            state.point = params.point
            state.grey, half = downsample_in_bands(image, pool, factor=factor, channel=params.channel,
                                                   point=params.point)
            return half
        grey = image if image.ndim == 2 else to_channel(image, params.channel)
        state.grey, state.point = grey, params.point
        return downsample(grey, factor=factor, channel=params.channel, point=params.point)

    def set_light(light: np.ndarray | None) -> None:
        state.light = light

    def stage_background(half: np.ndarray):
        light = _working_light(state.light, half.shape, state.factor, state.point)
        state.frozen = None
        if light is None:
            return half, half, *model.estimate(half)
        # the model learns the scene under the full lamp; this frame's background is that times the
        # light; where the lamp gave less than UNLIT of its light the frame says nothing about it
        reflectance = cv2.divide(half, light, scale=255)
        state.frozen = cv2.compare(light, UNLIT * 255, cv2.CMP_LT)
        if model.base is not None and model.base.shape == half.shape:
            # where the lamp gave too little, the frame divided by the light is noise times up to
            # 255; the model's own background stands in for it there (see UNLIT)
            cv2.copyTo(model.base, state.frozen, reflectance)
        base, limit = model.estimate(reflectance)
        # the frame is compared with its background under the most light it may have had (a
        # hole's rim a pixel off the map is not a particle), learnt under the light it had
        upper, state.dilated = _upper_light(state.light, half.shape, state.factor, state.point, state.dilated)
        return half, reflectance, cv2.multiply(base, light if upper is None else upper, scale=1 / 255), limit

    def expect(where: Detections | None) -> None:
        state.expected = where

    def stage_threshold(value):
        half, reflectance, base, limit = value
        state.base = base
        mask, excess = threshold_mask(half, base, limit)
        prominent, model.prominent = model.prominent, None
        if prominent is not None:
            # a single frame's candidates cut to what stands out; the model learns from the cut mask,
            # so the texture the cut left out is learnt as background from this frame on
            mask = prominent_only(mask, prominent, max(model.rings[-1] // 2, 1), model.pool)
        elif MOVING_SCALE and state.frozen is None and model.rings and (model.moving() or model.young()):
            # while the view moves the learnt background is resampled and lags, and in its first
            # frames it still holds much of the spatial start: a candidate must also stand out in
            # the frame alone (at MOVING_SCALE of its limit), as texture a follow left misregistered,
            # or not yet learnt, does not
            cv2.bitwise_and(mask, cv2.dilate(model.single_mask(half, MOVING_SCALE), None), dst=mask)
        expected, state.expected = state.expected, None  # for this frame only
        if expected is not None and len(expected) and params.k_expected < params.k:
            # around particles the tracker expects, a lower threshold: faint light there is them
            near = _near(mask.shape, expected, state.factor)
            low = cv2.convertScaleAbs(limit, alpha=params.k_expected / params.k)
            cv2.bitwise_or(mask, cv2.bitwise_and(cv2.compare(excess, low, cv2.CMP_GT), near), dst=mask)
        return reflectance, mask, excess

    def stage_label(value):
        reflectance, mask, excess = value
        return reflectance, mask, excess, label(mask)

    def stage_measure(value):
        reflectance, mask, excess, components = value
        # where the last frame was bright (once static texture has been learnt into the background)
        seen = None
        if model.learnt():
            seen, state.seen = state.seen, None
        if seen is not None and seen.shape != mask.shape:
            seen = None

        # measured on this thread: in bands the measuring's many small numpy calls took turns at
        # the GIL (docs/decisions/008-threads.md)
        found = measure(components, excess, model.noise, halo=params.halo, core=params.core,
                        max_radius=params.max_radius, split=params.split, frame_width=state.width,
                        factor=state.factor, lone_k=params.lone_k, seen=seen,
                        full=None if state.grey is None else (state.grey, state.base), fine=state.frozen is None,
                        split_budget=int(SPLIT_BUDGET * mask.size))
        if params.coarse and state.frozen is None:
            still = model.learnt() and not model.moving() and model.base is not None
            found = merge_scales(found, coarse_particles(
                reflectance, model.base if still else None, factor=state.factor, width=state.width, k=params.k,
                min_contrast=params.min_contrast, core=params.core, halo=params.halo, max_radius=params.max_radius))
        state.learn = (reflectance, mask, state.frozen)
        return brightest(found, params.max_particles)

    def stage_update(found: Detections) -> Detections:
        """For the next frames: the background learns from this one, and where it was bright is kept."""
        (reflectance, mask, frozen), state.learn = state.learn, None
        model.look_deferred(reflectance)  # a still view's routine look at its flow, off the latency path
        model.learn(reflectance, mask, frozen)
        if persist_kernel is not None:
            state.seen = cv2.dilate(mask, persist_kernel)
        return found

    stages = (
        Stage("downsample", "Downsample", stage_downsample),
        Stage("background", "Background Estimate", stage_background),
        Stage("threshold", "Local Threshold", stage_threshold),
        Stage("label", "Connected Components", stage_label),
        Stage("measure", "Measure Particles", stage_measure),
        Stage("update", "Background Update", stage_update, after=True),
    )
    return Detector("contrast", stages, params, reset=model.reset, set_light=set_light, expect=expect,
                    working_size=working_size)
