"""Stage 1, the working image: one channel of the frame pooled to the working resolution
(:func:`downsample`), and the lamp's light map brought to the same pixels (:func:`_working_light`).
"""

from __future__ import annotations

import cv2
import numpy as np

from .kernels import _K3


def working_factor(width: int, factor: int = 0) -> int:
    """The downsampling factor: ``factor`` if given, else 2 for frames 640 px wide or more, else 1."""
    if factor:
        return factor
    return 2 if width >= 640 else 1


def to_channel(image: np.ndarray, channel: str = "luma", out: np.ndarray | None = None) -> np.ndarray:
    """(H, W, 3) BGR -> (H, W) uint8: ``channel`` of CHANNELS (luma = the Y of YUV, Rec. 601),
    written into ``out`` when given (contiguous (H, W) uint8)."""
    if image.shape[2] < 3:
        return cv2.extractChannel(image, 0, dst=out)
    if channel == "luma":
        return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY, dst=out)
    if channel == "min":
        return cv2.min(cv2.min(image[..., 0], image[..., 1]), image[..., 2], dst=out)
    return cv2.extractChannel(image, {"blue": 0, "green": 1, "red": 2}[channel], dst=out)


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


#: below this share of the lamp's light (0..1) a pixel's brightness says too little about the scene:
#: it does not learn there, and the model's estimates (pan, turn, brightness, new scene) see the
#: learnt background there instead of the frame divided by the light (history: docs/decisions/001-contrast-tuning.md)
UNLIT = 0.1


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
                 dilated: np.ndarray | None = None) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The most light each working pixel may have had when the pattern landed up to a camera
    pixel off the map (calibration error, the lens, a background off the calibrated plane): a
    map of the frame's size dilated by one pixel, then pooled as the frame is.  None for a map
    of another size (coarser than a pixel: taken as it is).

    A hole's rim a pixel off on a bright seabed is a crescent of light the map does not explain;
    each was taken for a particle, given a hole, and made rims of its own (figures:
    docs/decisions/001-contrast-tuning.md).  Only the comparison uses it: the background is learnt under the
    map itself.

    dilated: the buffer of the dilated map the last call returned (the caller keeps it between
    frames).  Returns (the map, or None; the buffer to keep)."""
    if light is None or np.shape(light)[:2] != (shape[0] * factor, shape[1] * factor):
        return None, dilated
    light = np.asarray(light)
    if light.dtype != np.uint8:
        light = cv2.convertScaleAbs(light, alpha=255.0)
    if dilated is None or dilated.shape != light.shape:
        dilated = np.empty_like(light)
    return _working_light(cv2.dilate(light, _K3, dst=dilated), shape, factor, point), dilated
