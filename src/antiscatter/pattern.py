"""The projector image: white light with black holes where the particles are."""

from __future__ import annotations

import cv2
import numpy as np

from .detections import Detections

__all__ = ["scale_mapping", "map_to_projector", "render_pattern", "blank_pattern", "camera_light", "grow_holes"]

#: frame width (camera px) that ``grow_holes``'s ``start`` is given for
GROW_REFERENCE_WIDTH = 800
#: run's and the twin's hole growth by default: ``grow`` and ``start`` of :func:`grow_holes`
#: (history: docs/decisions/005-light-and-pattern-tuning.md)
GROW, GROW_FROM = 0.6, 4.0

_SHIFT = 4  # sub-pixel bits for cv2.circle
_ONE = 1 << _SHIFT


def scale_mapping(camera_size: tuple[int, int], projector_size: tuple[int, int]) -> np.ndarray:
    """The default camera-to-projector mapping: identity scaled between the image sizes.

    Sizes are (width, height) in pixels; returns a (3, 3) float64 homography.
    """
    sx = projector_size[0] / camera_size[0]
    sy = projector_size[1] / camera_size[1]
    return np.array([[sx, 0.0, 0.0], [0.0, sy, 0.0], [0.0, 0.0, 1.0]])


def map_to_projector(detections: Detections, mapping: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centres and radii in projector pixels under the (3, 3) homography ``mapping``.

    Each radius is scaled by the square root of the homography's local area scale
    (the Jacobian determinant at the centre), so a hole keeps the particle's area.
    Returns ((N, 2) centres, (N,) radii).
    """
    n = len(detections)
    if n == 0:
        return np.empty((0, 2)), np.empty(0)
    h = np.asarray(mapping, dtype=np.float64)
    x, y = detections.centres[:, 0], detections.centres[:, 1]
    w = h[2, 0] * x + h[2, 1] * y + h[2, 2]
    u = (h[0, 0] * x + h[0, 1] * y + h[0, 2]) / w
    v = (h[1, 0] * x + h[1, 1] * y + h[1, 2]) / w
    # Jacobian of (u, v) with respect to (x, y)
    du_dx = (h[0, 0] - u * h[2, 0]) / w
    du_dy = (h[0, 1] - u * h[2, 1]) / w
    dv_dx = (h[1, 0] - v * h[2, 0]) / w
    dv_dy = (h[1, 1] - v * h[2, 1]) / w
    scale = np.sqrt(np.abs(du_dx * dv_dy - du_dy * dv_dx))
    return np.column_stack([u, v]), detections.radii * scale


def blank_pattern(size: tuple[int, int], out: np.ndarray | None = None) -> np.ndarray:
    """The projector fully lit: ``out`` (or a new (height, width) uint8 image) filled with 255."""
    width, height = size
    if out is None:
        out = np.empty((height, width), np.uint8)
    out.fill(255)
    return out


def grow_holes(holes: Detections, *, grow: float, start: float, frame_width: int) -> Detections:
    """Holes grown in proportion to their size: a radius r above ``start`` camera pixels (for a
    frame ``GROW_REFERENCE_WIDTH`` wide, in proportion for others) becomes r + grow (r - start);
    ``grow`` 0 leaves them as they are.

    What takes a hole off its particle grows as 1/distance, as the particle's image does: a near
    particle is fast across the view (the prediction's error), out of the projector's focus
    (the hole's blurred rim) and large; the many small far ones keep their holes and the scene
    its light.  ``GROW`` (0.6) from ``GROW_FROM`` (4 px) by default (run and twin): more of the
    backscatter removed for a little of the scene light, where a margin added to every hole
    cost more light and removed no more (history: docs/decisions/005-light-and-pattern-tuning.md).
    """
    if grow == 0 or len(holes) == 0:
        return holes
    floor = start * frame_width / GROW_REFERENCE_WIDTH
    radii = holes.radii + grow * np.maximum(holes.radii - floor, 0.0)
    return Detections(holes.centres, radii, holes.scores, holes.track_ids)


def render_pattern(detections: Detections, *, size: tuple[int, int] = (1280, 800),
                   mapping: np.ndarray | None = None, margin: float = 0.0,
                   out: np.ndarray | None = None, hole: int | np.ndarray = 0) -> np.ndarray:
    """Draw the projector pattern: white (255) with filled discs of ``hole`` (0 = black) at the particles.

    Parameters
    ----------
    detections : particles in camera pixels.
    size : projector (width, height) in pixels.
    mapping : (3, 3) camera-to-projector homography; identity when None.
    margin : pixels added to every hole's radius (in projector pixels).
    out : (height, width) uint8 buffer to draw into (reused between frames).
    hole : grey level of the holes, 0..255 (above 0 for dim holes), or one per detection ((N,)
        array, :class:`~antiscatter.levels.HoleLevels`); where holes overlap the brighter wins
        (each of the particles there must stay visible).

    Returns
    -------
    (height, width) uint8 image.
    """
    out = blank_pattern(size, out)
    if len(detections) == 0:
        return out
    centres, radii = map_to_projector(detections, np.eye(3) if mapping is None else mapping)
    cx = np.rint(centres[:, 0] * _ONE)
    cy = np.rint(centres[:, 1] * _ONE)
    cr = np.rint(np.maximum(radii + margin, 0.0) * _ONE)
    # keep coordinates inside int32 for OpenCV even for wild mappings
    limit = float(1 << 27)
    ok = (np.abs(cx) < limit) & (np.abs(cy) < limit) & (cr < limit)
    order = np.flatnonzero(ok)
    if np.ndim(hole) == 0:
        grey = np.full(len(detections), int(hole), np.int64)
    else:
        grey = np.asarray(hole, np.int64).reshape(-1)
        if len(grey) != len(detections):
            raise ValueError(f"hole: got {len(grey)} levels for {len(detections)} detections")
        order = order[np.argsort(grey[order], kind="stable")]  # the brightest drawn last
    circle, line = cv2.circle, cv2.LINE_8
    for x, y, r, g in zip(cx[order].astype(np.int64).tolist(), cy[order].astype(np.int64).tolist(),
                          cr[order].astype(np.int64).tolist(), grey[order].tolist()):
        circle(out, (x, y), r, g, -1, line, _SHIFT)
    return out


def camera_light(pattern: np.ndarray, camera_from_projector: np.ndarray, camera_size: tuple[int, int], *,
                 out: np.ndarray | None = None) -> np.ndarray:
    """The light a projector pattern puts on the camera's view: (height, width) uint8 in camera
    pixels, 255 = the full lamp (outside the projector's field too), for a pattern in uint8 or
    float (1 = full).  ``camera_from_projector``: (3, 3) homography from projector to camera
    pixels (the calibration's mapping at the working plane, inverted).

    At the camera's full resolution, so that the detector pools a hole's imprint exactly as it
    pools the frame: a map at its half-size working grid, sampled at the pixels' centres, put
    each hole's rim where no pooled frame has it.  Nearest projector pixel: bilinear's figures
    at less of the time (history: docs/decisions/005-light-and-pattern-tuning.md).  ``out``: a
    (height, width) uint8 buffer to fill (reused between frames: a new full-resolution image
    each frame cost more in page faults than the warp).
    """
    if pattern.dtype != np.uint8:
        pattern = cv2.convertScaleAbs(pattern, alpha=255.0)
    return cv2.warpPerspective(pattern, np.asarray(camera_from_projector, np.float64), camera_size, dst=out,
                               flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=255)
