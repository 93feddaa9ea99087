"""Held-out material: annotated frames made from real photographs and a particle renderer of its
own, split into a development set (tune on it) and a test set (judge on it).

Nothing here comes from :mod:`antiscatter.simulate`: backgrounds are photographs
(scikit-image's ``skimage.data`` and the MSRB photograph) given an underwater look, and
particles are drawn by six models written for this material, so a detector tuned on the
simulator is not scored on the look it was designed around.  How the material is built and
why it is split: docs/decisions/002-heldout-material.md.
"""

from __future__ import annotations

import csv
import importlib
import json
import shutil
import time
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any, Callable, Iterator

import cv2
import numpy as np

from ..console import progress
from ..detection import Detector
from ..errors import UsageError
from .metrics import FrameScore, summarise
from .runs import Matching, _score
from .tables import FrameTruth

__all__ = ["SPLITS", "KINDS", "MODELS", "BACKGROUNDS", "MIXTURES", "MSRB_PHOTO", "Case", "HeldoutFrame",
           "cases", "require_skimage", "particle_shape", "render_particle", "light_truth", "local_spread",
           "render_still", "evaluate_case", "evaluate_heldout", "export_case", "export"]

SPLITS = ("dev", "test")
#: sequence kinds: unrelated stills; a camera panning over one view; a video cutting to another
#: view half-way; a lamp switched off and on again with its cone moved; sunlit stills; a fixed
#: camera with drifting particles
KINDS = ("stills", "pan", "cut", "lamp", "ambient", "video_still")
#: particle models: (a) Gaussian spot, (b) defocused disc, (c) ring / bubble, (d) textured flake,
#: (e) one-pixel speck, (f) semi-transparent sunlit flake (alpha-blended, sunlit scenes only)
MODELS = ("spot", "disc", "ring", "flake", "speck", "sunlit")
#: photographs behind each split's frames (no photograph is in both); ``msrb`` is
#: ``<data>/MSRB_PHOTO``, left out when absent
BACKGROUNDS = {"dev": ("gravel", "brick", "moon", "coffee", "coins"),
               "test": ("grass", "msrb", "camera", "rocket", "astronaut", "chelsea", "retina")}
MSRB_PHOTO = "msrb/174710351_orig.png"
#: share of each model (``MODELS`` order) among the particles of lamp-lit and of sunlit scenes:
#: dev mostly spots, discs and specks; test every model, rings, flakes and sunlit flakes weighted up
MIXTURES = {"dev": {"lamp": (0.40, 0.25, 0.05, 0.05, 0.25, 0.0), "sun": (0.30, 0.10, 0.05, 0.05, 0.25, 0.25)},
            "test": {"lamp": (0.15, 0.20, 0.25, 0.30, 0.10, 0.0), "sun": (0.10, 0.05, 0.15, 0.20, 0.05, 0.45)}}
#: first seed of each split's cases (case k: seed + k); the splits' seeds never meet
_SEEDS = {"dev": 1000, "test": 2000}
#: each split's cases: (kind, width, frames, shuffled); a shuffled case is the stills case of the
#: same width in another order, with its seed
_LAYOUT = (("stills", 1456, 8, False), ("stills", 800, 10, False), ("stills", 800, 10, True),
           ("pan", 1456, 10, False), ("pan", 800, 12, False), ("cut", 800, 12, False), ("lamp", 800, 12, False),
           ("ambient", 800, 8, False), ("video_still", 1456, 10, False))
_HEIGHTS = {1456: 1088, 800: 600}
#: grey = 0.114 B + 0.587 G + 0.299 R, as OpenCV converts
_LUMA = np.array([0.114, 0.587, 0.299], np.float32)
#: colour of a particle's light (grey 1) and of a sunlit flake (grey 1), BGR
_PARTICLE_BGR = np.array([1.0, 1.0, 0.92], np.float32) / float(_LUMA @ np.array([1.0, 1.0, 0.92], np.float32))
_FLAKE_BGR = np.array([1.0, 1.0, 0.95], np.float32) / float(_LUMA @ np.array([1.0, 1.0, 0.95], np.float32))
#: width the particle radii are given for (discs scale with width / this)
_REFERENCE_WIDTH = 1456
#: a particle is counted when its peak exceeds max(_MIN_PEAK, _NOISE_UNITS x the noise sigma,
#: _VISIBILITY x the clutter: the local spread of the particle-free frame around it, :func:`local_spread`)
#: and at least _MIN_INSIDE of its light falls inside the frame (docs/decisions/002-heldout-material.md)
_MIN_PEAK = 8.0
_NOISE_UNITS = 4.0
_VISIBILITY = 1.0
_MIN_INSIDE = 0.5
#: the clutter's window: (2 h + 1) px square, h = max(_MIN_HALF, _SURROUND x the particle's radius)
_SURROUND = 2.0
_MIN_HALF = 4


def require_skimage() -> Any:
    """``skimage.data``; a one-line UsageError naming the extra to install when it is missing."""
    try:
        return importlib.import_module("skimage.data")
    except ImportError:
        raise UsageError("the held-out material needs scikit-image: pip install 'antiscatter[eval]'") from None


@lru_cache(maxsize=16)
def _photograph(name: str, data: str) -> np.ndarray:
    """(h, w, 3) float32 BGR in 0..1 of a named photograph (read-only, cached)."""
    if name == "msrb":
        image = cv2.imread(str(Path(data) / MSRB_PHOTO), cv2.IMREAD_COLOR)
        if image is None:
            raise UsageError(f"{Path(data) / MSRB_PHOTO}: not a readable image")
    else:
        image = np.asarray(getattr(require_skimage(), name)())
        if image.dtype == bool:
            image = image.astype(np.uint8) * 255
        if image.ndim == 2:
            image = np.repeat(image[..., None], 3, axis=2)
        image = image[..., 2::-1]  # RGB(A) -> BGR
    out = np.ascontiguousarray(image, dtype=np.float32) / 255.0
    out.flags.writeable = False
    return out


def _backgrounds(split: str, data: Path | None) -> tuple[str, ...]:
    names = BACKGROUNDS[split]
    if data is None or not (Path(data) / MSRB_PHOTO).is_file():
        names = tuple(n for n in names if n != "msrb")
    return names


# ---------------------------------------------------------------- particles


def _sigmoid(t: np.ndarray) -> np.ndarray:
    return 0.5 * (1.0 + np.tanh(0.5 * t))


def _blob_template(radius: float, rng: np.random.Generator, *, roughness: float, grain: tuple[float, float],
                   soften: float) -> np.ndarray:
    """(S, S) float32, peak 1, centred at ((S - 1) / 2, (S - 1) / 2): an irregular blob of about
    ``radius`` px from thresholded smoothed noise, ``grain`` the internal texture's share and
    scale (px), blurred by ``soften`` px."""
    side = 2 * int(np.ceil(1.7 * radius + 3)) + 1
    c = (side - 1) / 2
    yy, xx = np.mgrid[0:side, 0:side].astype(np.float32)
    rho = np.hypot(xx - c, yy - c) / max(radius, 0.5)
    noise = cv2.GaussianBlur(rng.standard_normal((side, side)).astype(np.float32), (0, 0), max(0.8, radius / 2.5))
    noise /= max(float(np.abs(noise).max()), 1e-6)
    shape = 1.0 - rho + roughness * noise
    mask = (shape > 0).astype(np.uint8)
    mask[int(c), int(c)] = 1
    _, labels = cv2.connectedComponents(mask, connectivity=8)
    mask = labels == labels[int(c), int(c)]  # one piece: a fragment beside it would be a particle of its own
    texture = cv2.GaussianBlur(rng.random((side, side)).astype(np.float32), (0, 0), grain[1])
    texture = (texture - texture.min()) / max(float(np.ptp(texture)), 1e-6)
    blob = mask * ((1.0 - grain[0]) + grain[0] * texture)
    blob = cv2.GaussianBlur(blob.astype(np.float32), (0, 0), soften)
    return blob / max(float(blob.max()), 1e-6)


def particle_shape(model: str, size: float, rng: np.random.Generator) -> dict[str, Any]:
    """The fixed look of one particle of ``model`` (one of ``MODELS``) and ``size`` (spot: sigma,
    speck: unused, others: radius; px), drawn from ``rng``: what :func:`render_particle` draws each
    frame."""
    if model == "spot":
        return {"aspect": float(rng.uniform(1.0, 1.4)), "angle": float(rng.uniform(0, np.pi))}
    if model == "disc":
        return {"edge": float(rng.uniform(0.6, 2.0)), "tilt": tuple(rng.uniform(-0.12, 0.12, 2).tolist()),
                "rim": float(rng.uniform(0.0, 0.25))}
    if model == "ring":
        angle = rng.uniform(0, 2 * np.pi)
        return {"width": float(rng.uniform(0.6, 1.6)), "centre": float(rng.uniform(0.15, 0.5)),
                "highlight": float(rng.uniform(0.0, 0.8)), "towards": (float(np.cos(angle)), float(np.sin(angle)))}
    if model == "flake":
        return {"template": _blob_template(size, rng, roughness=0.55, grain=(0.6, float(rng.uniform(0.7, 1.5))),
                                           soften=float(rng.uniform(0.5, 0.9)))}
    if model == "speck":
        return {"spread": float(rng.uniform(0.1, 0.35)) if rng.random() < 0.5 else 0.0}
    if model == "sunlit":
        return {"template": _blob_template(size, rng, roughness=0.3, grain=(0.3, 1.0), soften=0.8)}
    raise ValueError(f"model: got {model!r}, allowed {', '.join(MODELS)}")


def _grid(x: float, y: float, half: int) -> tuple[int, int, np.ndarray, np.ndarray]:
    """(x0, y0, dx, dy): a (2 half + 1)-square window around the pixel nearest (x, y), offsets from (x, y)."""
    x0, y0 = int(round(x)) - half, int(round(y)) - half
    ys, xs = np.mgrid[0:2 * half + 1, 0:2 * half + 1].astype(np.float32)
    return x0, y0, xs + (x0 - x), ys + (y0 - y)


def _place(template: np.ndarray, x: float, y: float) -> tuple[int, int, np.ndarray]:
    """A template (centred at its middle pixel) shifted to (x, y) with bilinear interpolation."""
    side = template.shape[0]
    c = (side - 1) // 2
    fx, fy = x - np.floor(x), y - np.floor(y)
    shift = np.float32([[1, 0, fx + 1], [0, 1, fy + 1]])
    patch = cv2.warpAffine(template, shift, (side + 2, side + 2), flags=cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return int(np.floor(x)) - c - 1, int(np.floor(y)) - c - 1, patch


def render_particle(model: str, x: float, y: float, size: float,
                    shape: dict[str, Any] | None = None) -> tuple[int, int, np.ndarray]:
    """One particle's light, peak about 1, at (x, y) px (pixel centres at whole numbers).

    Parameters
    ----------
    model : one of ``MODELS``.
    x, y : centre, pixels.
    size : spot: Gaussian sigma; disc, ring, flake, sunlit: radius; speck: unused (pixels).
    shape : the particle's look from :func:`particle_shape`; None: round, plain (flake and
        sunlit need theirs).

    Returns
    -------
    x0, y0 : the patch's top-left pixel in the frame.
    patch : (h, w) float32 light (sunlit: opacity), 0..about 1.
    """
    shape = shape or {}
    if model == "spot":
        aspect, angle = shape.get("aspect", 1.0), shape.get("angle", 0.0)
        sx = np.sqrt(size ** 2 + 1 / 12)  # a pixel integrates the spot over its width
        sy = np.sqrt((size * aspect) ** 2 + 1 / 12)
        x0, y0, dx, dy = _grid(x, y, int(np.ceil(3.5 * max(sx, sy))) + 1)
        u = dx * np.cos(angle) + dy * np.sin(angle)
        v = -dx * np.sin(angle) + dy * np.cos(angle)
        return x0, y0, np.exp(-0.5 * (u * u / (sx * sx) + v * v / (sy * sy))).astype(np.float32)
    if model == "disc":
        edge, (gx, gy), rim = shape.get("edge", 1.0), shape.get("tilt", (0.0, 0.0)), shape.get("rim", 0.0)
        x0, y0, dx, dy = _grid(x, y, int(np.ceil(size + 4 * edge)) + 2)
        rho = np.hypot(dx, dy)
        body = _sigmoid((size - rho) / edge)
        light = body * (1.0 + gx * dx / size + gy * dy / size)
        light += rim * body * np.exp(-(((rho - (size - 1.5 * edge)) / (1.2 * edge)) ** 2))
        return x0, y0, (light / max(float(light.max()), 1e-6)).astype(np.float32)
    if model == "ring":
        width, centre = shape.get("width", 1.0), shape.get("centre", 0.3)
        highlight, (hx, hy) = shape.get("highlight", 0.0), shape.get("towards", (-0.7, -0.7))
        x0, y0, dx, dy = _grid(x, y, int(np.ceil(size + 3 * width)) + 2)
        rho = np.hypot(dx, dy)
        light = np.maximum(np.exp(-(((rho - size) / width) ** 2)), centre * _sigmoid((size - rho) / 0.7))
        spot = 0.2 * size + 0.5
        light += highlight * np.exp(-0.5 * ((dx - 0.45 * size * hx) ** 2 + (dy - 0.45 * size * hy) ** 2) / spot ** 2)
        return x0, y0, (light / max(float(light.max()), 1e-6)).astype(np.float32)
    if model == "speck":
        b = shape.get("spread", 0.0)
        kernel = np.array([[b * b, b, b * b], [b, 1.0, b], [b * b, b, b * b]], np.float32)
        return int(round(x)) - 1, int(round(y)) - 1, kernel
    if model in ("flake", "sunlit"):
        if "template" not in shape:
            raise ValueError(f"model {model!r}: the shape needs its template (particle_shape)")
        return _place(shape["template"], x, y)
    raise ValueError(f"model: got {model!r}, allowed {', '.join(MODELS)}")


def _clip(x0: int, y0: int, patch: np.ndarray, size: tuple[int, int]) -> tuple[slice, slice, slice, slice] | None:
    """(frame rows, frame cols, patch rows, patch cols) of the part of a patch inside the frame."""
    h, w = patch.shape
    fx0, fy0 = max(x0, 0), max(y0, 0)
    fx1, fy1 = min(x0 + w, size[0]), min(y0 + h, size[1])
    if fx1 <= fx0 or fy1 <= fy0:
        return None
    return slice(fy0, fy1), slice(fx0, fx1), slice(fy0 - y0, fy1 - y0), slice(fx0 - x0, fx1 - x0)


def light_truth(x0: int, y0: int, light: np.ndarray, size: tuple[int, int] | None = None) -> tuple[float, ...]:
    """Truth of one particle from the light it adds.

    Parameters
    ----------
    x0, y0 : the patch's top-left pixel in the frame.
    light : (h, w) added light, grey levels (negative values count as none).
    size : (width, height) of the frame: light outside it is not seen (None: all seen).

    Returns
    -------
    (x, y, radius, peak, inside) : the light-weighted centroid of the light seen (px); the
    half-maximum extent -- the farthest pixel at half the peak or more, plus half a pixel,
    at least 1 (px); the peak (grey levels); the share of the light inside the frame (0..1).
    Zeros when no light is seen.
    """
    light = np.maximum(light, 0)
    total = float(light.sum())
    if size is not None:
        part = _clip(x0, y0, light, size)
        if part is None:
            return 0.0, 0.0, 0.0, 0.0, 0.0
        light, x0, y0 = light[part[2], part[3]], x0 + part[3].start, y0 + part[2].start
    seen = float(light.sum())
    if seen <= 0:
        return 0.0, 0.0, 0.0, 0.0, 0.0
    ys, xs = np.mgrid[0:light.shape[0], 0:light.shape[1]]
    cx, cy = float((light * xs).sum() / seen), float((light * ys).sum() / seen)
    peak = float(light.max())
    half = light >= 0.5 * peak
    radius = max(1.0, float(np.hypot(xs[half] - cx, ys[half] - cy).max()) + 0.5)
    return x0 + cx, y0 + cy, radius, peak, seen / total


def local_spread(background: np.ndarray, x: float, y: float, radius: float) -> float:
    """The clutter a particle is seen against: 1.4826 x the median absolute deviation (a robust
    standard deviation) of the particle-free frame in a window around it.

    Parameters
    ----------
    background : (H, W) grey levels of the frame without particles or noise (view x lighting).
    x, y : the particle's centre, pixels.
    radius : its half-maximum extent, pixels; the window is (2 h + 1) px square, h = max(4, ceil(2 x
        radius)), cut by the frame's edges.

    Returns
    -------
    The spread, grey levels (0 on a flat background; 0 when the window is outside the frame).
    """
    height, width = background.shape
    half = max(_MIN_HALF, int(np.ceil(_SURROUND * radius)))
    col, row = int(round(x)), int(round(y))
    window = background[max(row - half, 0):max(min(row + half + 1, height), 0),
                        max(col - half, 0):max(min(col + half + 1, width), 0)]
    if window.size == 0:
        return 0.0
    return 1.4826 * float(np.median(np.abs(window - np.median(window))))


@dataclass
class _Particle:
    """One particle of the water: model index, position and velocity (px, px/frame), size (px),
    brightness at full light (grey levels; sunlit: the flake's grey level), opacity (sunlit) and look."""

    ident: int
    model: int
    x: float
    y: float
    vx: float
    vy: float
    size: float
    peak: float
    alpha: float
    shape: dict[str, Any]
    flicker: float = 1.0


def _new_particle(rng: np.random.Generator, ident: int, mixture: tuple[float, ...], size: tuple[int, int],
                  *, moving: bool, drift: tuple[float, float] = (0.0, 0.0)) -> _Particle:
    width, height = size
    p = np.asarray(mixture, np.float64)
    model = int(rng.choice(len(MODELS), p=p / p.sum()))
    name = MODELS[model]
    scale = width / _REFERENCE_WIDTH
    extent = {"spot": lambda: rng.uniform(0.5, 4.0), "disc": lambda: rng.uniform(6, 40) * scale,
              "ring": lambda: rng.uniform(3, 15), "flake": lambda: rng.uniform(2, 12), "speck": lambda: 1.0,
              "sunlit": lambda: rng.uniform(1, 6)}[name]()
    if name == "disc":
        peak = rng.uniform(8, 30)  # near and out of focus: faint
    elif name == "sunlit":
        peak = rng.uniform(180, 250)
    elif rng.random() < 0.75:
        peak = float(np.exp(rng.uniform(np.log(25), np.log(180))))
    else:
        peak = rng.uniform(4, 25)
    alpha = rng.uniform(0.2, 0.8) if name == "sunlit" else 1.0
    margin = extent * (3.0 if name == "spot" else 1.0)
    x, y = rng.uniform(-margin, width + margin), rng.uniform(-margin, height + margin)
    vx = vy = 0.0
    if moving:
        fast = rng.uniform(2.0, 4.0) if name == "disc" else 1.0  # near particles cross the view faster
        vx, vy = (drift[0] + rng.normal(0, 1.2)) * fast, (drift[1] + rng.normal(0, 1.2)) * fast
    return _Particle(ident, model, float(x), float(y), float(vx), float(vy), float(extent), float(peak),
                     float(alpha), particle_shape(name, float(extent), rng))


class _Water:
    """The particles of one stretch of video: they drift, tumble (flakes flicker) and are replaced
    by new ones (new ids) once out of the frame."""

    def __init__(self, rng: np.random.Generator, size: tuple[int, int], mixture: tuple[float, ...], *,
                 count: int, first_id: int) -> None:
        self.rng, self.size, self.mixture = rng, size, mixture
        self.drift = (float(rng.uniform(-2, 2)), float(rng.uniform(-2, 2)))
        self.next_id = first_id
        self.particles = [self._new() for _ in range(count)]

    def _new(self) -> _Particle:
        self.next_id += 1
        return _new_particle(self.rng, self.next_id, self.mixture, self.size, moving=True, drift=self.drift)

    def step(self) -> None:
        width, height = self.size
        for i, p in enumerate(self.particles):
            p.vx += self.rng.normal(0, 0.2)
            p.vy += self.rng.normal(0, 0.2)
            p.x += p.vx
            p.y += p.vy
            if MODELS[p.model] in ("flake", "sunlit"):
                p.flicker = float(np.clip(1.0 + self.rng.normal(0, 0.1), 0.7, 1.3))
            reach = 3 * p.size + 2
            if not (-reach < p.x < width + reach and -reach < p.y < height + reach):
                self.particles[i] = self._new()


# ---------------------------------------------------------------- scenes


@dataclass(frozen=True)
class _View:
    """What the camera looks at, at full light: (h, w, 3) float32 BGR radiance in grey levels
    (the photograph made underwater, with the distractors), the distractors' (h, w) light
    and the veil of light scattered by the water, (3,) BGR grey levels."""

    name: str
    radiance: np.ndarray
    objects: np.ndarray
    veil: np.ndarray

    def crop(self, x: float, y: float, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        """(radiance, distractor mask) of the (width, height) window with its top-left corner at (x, y)."""
        centre = (x + (size[0] - 1) / 2, y + (size[1] - 1) / 2)
        if x == int(x) and y == int(y):
            rows, cols = slice(int(y), int(y) + size[1]), slice(int(x), int(x) + size[0])
            return self.radiance[rows, cols], self.objects[rows, cols] > 2.0
        return (cv2.getRectSubPix(self.radiance, size, centre),
                cv2.getRectSubPix(self.objects, size, centre) > 2.0)


def _compose_photo(photo: np.ndarray, size: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    """(H, W, 3) float32: the photograph mirrored or turned at random, scaled 1x-3x, mirror-tiled
    where it is smaller than ``size`` (width, height), cropped at a random place."""
    width, height = size
    image = photo[:, ::-1] if rng.random() < 0.5 else photo
    if rng.random() < 0.25:
        image = np.rot90(image)
    s = rng.uniform(1.0, 3.0)
    image = cv2.resize(np.ascontiguousarray(image), None, fx=s, fy=s, interpolation=cv2.INTER_LINEAR)
    pad_y, pad_x = max(0, height - image.shape[0]), max(0, width - image.shape[1])
    if pad_y or pad_x:
        top, left = int(rng.integers(0, pad_y + 1)), int(rng.integers(0, pad_x + 1))
        image = np.pad(image, ((top, pad_y - top), (left, pad_x - left), (0, 0)), mode="symmetric")
    y = int(rng.integers(0, image.shape[0] - height + 1))
    x = int(rng.integers(0, image.shape[1] - width + 1))
    return np.ascontiguousarray(image[y:y + height, x:x + width])


def _distractors(size: tuple[int, int], rng: np.random.Generator, count: int) -> np.ndarray:
    """(H, W) float32 light at full lamp of ``count`` things that are not particles: lit objects
    (rectangles, ellipses) over 60 px each way, and straight lines and bars (equipment)."""
    width, height = size
    light = np.zeros((height, width), np.float32)
    scale = max(width / _REFERENCE_WIDTH, 0.75)
    for _ in range(count):
        layer = np.zeros_like(light)
        kind = rng.choice(("object", "line", "bar"))
        centre = (float(rng.uniform(0.1, 0.9) * width), float(rng.uniform(0.1, 0.9) * height))
        angle = float(rng.uniform(0, 180))
        if kind == "object":
            axes = (float(rng.uniform(85, 260) * scale), float(rng.uniform(85, 200) * scale))
            if rng.random() < 0.5:
                box = cv2.boxPoints((centre, axes, angle))
                cv2.fillPoly(layer, [np.rint(box * 16).astype(np.int32)], 1.0, cv2.LINE_AA, 4)
            else:
                cv2.ellipse(layer, (centre, axes, angle), 1.0, -1, cv2.LINE_AA)
            texture = cv2.GaussianBlur(rng.random((height, width)).astype(np.float32), (0, 0), 6)
            texture = (texture - texture.min()) / max(float(np.ptp(texture)), 1e-6)
            layer *= 0.7 + 0.3 * texture
            level = rng.uniform(40, 150)
        else:
            length = float(rng.uniform(0.4, 1.0) * width)
            thick = (float(rng.uniform(2, 6)) if kind == "line" else float(rng.uniform(20, 50) * scale))
            box = cv2.boxPoints((centre, (length, thick), angle))
            cv2.fillPoly(layer, [np.rint(box * 16).astype(np.int32)], 1.0, cv2.LINE_AA, 4)
            level = rng.uniform(60, 180)
        light += cv2.GaussianBlur(layer, (0, 0), 1.0) * np.float32(level)
    return light


def _view(name: str, size: tuple[int, int], rng: np.random.Generator, data: Path | None, *, sunlit: bool,
          distractors: int) -> _View:
    """A view of the photograph ``name`` at ``size`` (width, height) with an underwater look: colour
    and contrast reduced, tinted blue-green, dimmed (or, sunlit, bright), veiled, with ``distractors``."""
    scene = _compose_photo(_photograph(name, str(data or "")), size, rng)
    grey = (scene @ _LUMA)[..., None]
    scene = grey + (scene - grey) * np.float32(rng.uniform(0.2, 0.7))  # water takes the colours out
    mean = scene.mean(axis=(0, 1), keepdims=True)
    scene = mean + (scene - mean) * np.float32(rng.uniform(0.45, 1.0))
    if sunlit:
        tint = np.float32([rng.uniform(0.9, 1.0), rng.uniform(0.85, 1.0), rng.uniform(0.5, 0.85)])
        level, veil = rng.uniform(100, 170), rng.uniform(0, 25)
    else:
        tint = np.float32([rng.uniform(0.85, 1.0), rng.uniform(0.8, 1.0), rng.uniform(0.3, 0.65)])
        level, veil = rng.uniform(35, 110), rng.uniform(0, 12)
    scene = np.clip(scene, 0, 1) * tint
    scene *= np.float32(level / max(float((scene.reshape(-1, 3) @ _LUMA).mean()), 1e-3))
    objects = _distractors(size, rng, distractors)
    scene += objects[..., None]
    water = np.float32([1.0, 0.9, 0.45])
    return _View(name, scene, objects, water / float(_LUMA @ water) * np.float32(veil))


def _cone(size: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    """(H, W) float32 lamp cone fixed in the image: 1 at its brightest, a vignetted flat-topped
    Gaussian with a floor of 0.03-0.12."""
    width, height = size
    cx, cy = width * rng.uniform(0.3, 0.7), height * rng.uniform(0.3, 0.7)
    sx, sy = width * rng.uniform(0.3, 0.6), height * rng.uniform(0.35, 0.7)
    power, floor, vignette = rng.uniform(0.8, 1.6), rng.uniform(0.03, 0.12), rng.uniform(0.1, 0.35)
    yy, xx = np.ogrid[0:height, 0:width]
    r2 = ((xx - cx) / sx) ** 2 + ((yy - cy) / sy) ** 2
    corner = ((xx - width / 2) ** 2 + (yy - height / 2) ** 2) / ((width / 2) ** 2 + (height / 2) ** 2)
    cone = (floor + (1 - floor) * np.exp(-0.5 * r2 ** power)) * (1 - vignette * corner)
    return (cone / cone.max()).astype(np.float32)


def _lighting(mode: str, size: tuple[int, int], rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray | None]:
    """(field multiplying the view, field multiplying the particles' light or None for 1): a lamp
    cone; the lamp off (dim ambient light, particles barely lit); or sunlight (a gentle gradient
    from the surface, particles lit by the sun)."""
    width, height = size
    if mode == "lamp":
        cone = _cone(size, rng)
        return cone, cone
    if mode == "dim":
        level = np.float32(rng.uniform(0.12, 0.25))
        return np.full((height, width), level, np.float32), np.full((height, width), level, np.float32)
    gradient = np.linspace(1.0, rng.uniform(0.7, 0.95), height, dtype=np.float32)[:, None]
    return np.repeat(gradient, width, axis=1), None


@dataclass(frozen=True)
class _Sensor:
    """Read noise (grey levels), shot noise (variance per grey level) and JPEG quality (0 = none)."""

    read: float
    shot: float
    jpeg: int

    @classmethod
    def draw(cls, rng: np.random.Generator, jpeg_share: float) -> "_Sensor":
        read, shot = rng.uniform(1.5, 3.0), rng.uniform(0.02, 0.08)
        return cls(float(read), float(shot), int(rng.integers(75, 96)) if rng.random() < jpeg_share else 0)


@dataclass(frozen=True, eq=False)
class HeldoutFrame:
    """One frame of held-out material and its truth.

    image: (H, W, 3) uint8 BGR.
    truth: every particle (centres (N, 2) px, radii (N,) px, counted (N,), ids (N,); labels -1).
    models: (N,) int index into ``MODELS``.
    peaks: (N,) the particle's peak added light over the background, grey levels, after saturation
        (a sunlit flake: the frame minus the background where the flake adds most).
    clutter: (N,) the local spread of the particle-free frame around it (:func:`local_spread`), grey levels.
    thresholds: (N,) the peak it needs to be counted: max(8, 4 x the noise sigma there, the clutter),
        grey levels.
    light: (H, W) float32 noise-free light added by the additive particles, grey levels.
    distractors: (H, W) bool pixels of the things that are not particles.
    background: the photograph's name.
    """

    index: int
    image: np.ndarray
    truth: FrameTruth
    models: np.ndarray
    peaks: np.ndarray
    clutter: np.ndarray
    thresholds: np.ndarray
    light: np.ndarray
    distractors: np.ndarray
    background: str


def _render(index: int, radiance: np.ndarray, distractors: np.ndarray, view: _View,
            lighting: tuple[np.ndarray, np.ndarray | None], particles: list[_Particle], sensor: _Sensor,
            rng: np.random.Generator) -> HeldoutFrame:
    """Light the view, add the particles, the sensor's noise and its JPEG; measure each particle's truth."""
    field_, particle_field = lighting
    height, width = field_.shape
    size = (width, height)
    scene = (radiance + view.veil) * field_[..., None]
    grey = scene @ _LUMA
    image = scene.copy()
    light = np.zeros((height, width), np.float32)
    rows = []
    for p in particles:
        name = MODELS[p.model]
        x0, y0, patch = render_particle(name, p.x, p.y, p.size, p.shape)
        part = _clip(x0, y0, patch, size)
        if part is None:
            continue
        fr, fc, pr, pc = part
        under = np.zeros_like(patch)
        under[pr, pc] = grey[fr, fc]
        if name == "sunlit":
            alpha = patch * np.float32(p.alpha * p.flicker)
            added = alpha * (np.float32(p.peak) - under)  # outside the frame: only for the share inside
            a = alpha[pr, pc][..., None]
            before = image[fr, fc] @ _LUMA
            image[fr, fc] = image[fr, fc] * (1 - a) + a * (np.float32(p.peak) * _FLAKE_BGR)
            added[pr, pc] = image[fr, fc] @ _LUMA - before  # what the flake changes in the frame, may be negative
        else:
            at = (min(max(int(round(p.y)), 0), height - 1), min(max(int(round(p.x)), 0), width - 1))
            gain = 1.0 if particle_field is None else float(particle_field[at])
            added = patch * np.float32(p.peak * p.flicker * gain)
            light[fr, fc] += added[pr, pc]
        cx, cy, radius, _, inside = light_truth(x0, y0, added, size)
        if inside == 0:
            continue
        seen = np.minimum(np.maximum(added, 0), 255.0 - under)  # a saturated pixel shows no more light
        seen_in = np.zeros_like(seen)
        seen_in[pr, pc] = seen[pr, pc]
        k = np.unravel_index(int(np.argmax(seen_in)), seen_in.shape)
        peak = float(seen_in[k])
        sigma = float(np.sqrt(sensor.read ** 2 + sensor.shot * max(float(under[k]), 0.0)))
        clutter = local_spread(grey, cx, cy, radius)
        threshold = max(_MIN_PEAK, _NOISE_UNITS * sigma, _VISIBILITY * clutter)
        rows.append((cx, cy, radius, peak > threshold and inside >= _MIN_INSIDE, p.ident, p.model, peak, clutter,
                     threshold))
    image += light[..., None] * _PARTICLE_BGR
    sigma = np.sqrt(np.float32(sensor.read ** 2) + np.float32(sensor.shot) * np.maximum(image, 0))
    image += rng.standard_normal(image.shape, dtype=np.float32) * sigma
    out = np.clip(np.rint(image), 0, 255).astype(np.uint8)
    if sensor.jpeg:
        _, buffer = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, sensor.jpeg])
        out = cv2.imdecode(buffer, cv2.IMREAD_COLOR)
    n = len(rows)
    table = np.array([r[:3] for r in rows], np.float64).reshape(n, 3)
    truth = FrameTruth(table[:, :2], table[:, 2], np.array([r[3] for r in rows], bool),
                       np.full(n, -1, np.int64), np.array([r[4] for r in rows], np.int64))
    peaks, clutter, thresholds = (np.array([r[c] for r in rows], np.float64) for c in (6, 7, 8))
    return HeldoutFrame(index, out, truth, np.array([r[5] for r in rows], np.int64), peaks, clutter, thresholds,
                        light, distractors, view.name)


def _count(rng: np.random.Generator, size: tuple[int, int], sunlit: bool) -> int:
    """Particles in a frame: 30-80 a megapixel lamp-lit, 60-140 sunlit."""
    density = rng.uniform(60, 140) if sunlit else rng.uniform(30, 80)
    return int(rng.poisson(density * size[0] * size[1] / 1e6))


def render_still(rng: np.random.Generator, size: tuple[int, int], *, background: str, split: str = "dev",
                 lighting: str = "lamp", particles: int | None = None, distractors: int | None = None,
                 data: Path | None = None, index: int = 0, first_id: int = 0) -> HeldoutFrame:
    """One still frame of held-out material.

    Parameters
    ----------
    rng : the only source of randomness.
    size : (width, height), pixels.
    background : a name of ``BACKGROUNDS`` (``msrb`` needs ``data``).
    split : whose particle mixture (``MIXTURES``).
    lighting : lamp (a cone), sun (bright, no cone) or dim (the lamp off).
    particles, distractors : how many (None: drawn, 30-140 particles a megapixel, 0-2 distractors).
    data : folder holding ``MSRB_PHOTO``.
    index, first_id : the frame's number and the particles' ids after ``first_id``.
    """
    if lighting not in ("lamp", "sun", "dim"):
        raise ValueError(f"lighting: got {lighting!r}, allowed lamp, sun, dim")
    sunlit = lighting == "sun"
    distractors = int(rng.choice((0, 0, 1, 2))) if distractors is None else distractors
    view = _view(background, size, rng, data, sunlit=sunlit, distractors=distractors)
    light = _lighting(lighting, size, rng)
    sensor = _Sensor.draw(rng, 0.3)
    mixture = MIXTURES[split]["sun" if sunlit else "lamp"]
    count = _count(rng, size, sunlit) if particles is None else particles
    crowd = [_new_particle(rng, first_id + k + 1, mixture, size, moving=False) for k in range(count)]
    return _render(index, view.radiance, view.objects > 2.0, view, light, crowd, sensor, rng)


# ---------------------------------------------------------------- cases


@dataclass(frozen=True)
class Case:
    """A named, deterministic sequence of held-out frames.

    name: e.g. ``pan-1456``; split: ``dev`` or ``test``; kind: one of ``KINDS``; size: (width,
    height) px, at least 64x48; count: frames (>= 1); seed: of its generator; shuffled: a
    stills case's frames in another order (the same frames as the unshuffled case of that seed);
    data: folder holding ``MSRB_PHOTO`` (None: the photograph is left out).
    """

    name: str
    split: str
    kind: str
    size: tuple[int, int]
    count: int
    seed: int
    shuffled: bool = False
    data: Path | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        if self.split not in SPLITS:
            raise ValueError(f"split: got {self.split!r}, allowed {', '.join(SPLITS)}")
        if self.kind not in KINDS:
            raise ValueError(f"kind: got {self.kind!r}, allowed {', '.join(KINDS)}")
        if self.size[0] < 64 or self.size[1] < 48:
            raise ValueError(f"size: got {self.size[0]}x{self.size[1]}, allowed at least 64x48")
        if self.count < 1:
            raise ValueError(f"count: got {self.count}, allowed >= 1")
        if self.shuffled and self.kind not in ("stills", "ambient"):
            raise ValueError(f"shuffled: only stills and ambient cases, got kind {self.kind!r}")

    @property
    def backgrounds(self) -> tuple[str, ...]:
        """The photographs this case draws from."""
        return _backgrounds(self.split, self.data)

    def render(self) -> Iterator[HeldoutFrame]:
        """Every frame with its truth and what made it."""
        if self.kind in ("stills", "ambient"):
            yield from self._stills()
        else:
            yield from self._video()

    def __len__(self) -> int:
        return self.count

    def frames(self) -> Iterator[tuple[int, np.ndarray, FrameTruth]]:
        """(index, (H, W, 3) uint8 BGR image, FrameTruth) of every frame."""
        for frame in self.render():
            yield frame.index, frame.image, frame.truth

    def _stills(self) -> Iterator[HeldoutFrame]:
        order = np.arange(self.count)
        if self.shuffled:
            order = np.random.default_rng([self.seed, 1]).permutation(self.count)
        for index, k in enumerate(order.tolist()):
            rng = np.random.default_rng([self.seed, 0, k])  # frame k is the same in any order
            lighting = "sun" if self.kind == "ambient" or rng.random() < 0.2 else "lamp"
            background = str(rng.choice(self.backgrounds))
            yield render_still(rng, self.size, background=background, split=self.split, lighting=lighting,
                               data=self.data, index=index, first_id=(k + 1) * 100000)

    def _video(self) -> Iterator[HeldoutFrame]:
        rng = np.random.default_rng(self.seed)
        size, n = self.size, self.count
        mixture = MIXTURES[self.split]["lamp"]
        sensor = _Sensor.draw(rng, 0.4)
        half, third = max(1, n // 2), max(1, n // 3)
        # stretches of video: (first frame, view, pan velocity px/frame, lighting, water)
        stretches = []
        if self.kind == "lamp":
            view, water = self._new_view(rng, 0.0), _Water(rng, size, mixture, count=_count(rng, size, False),
                                                           first_id=0)
            for start, mode in ((0, "lamp"), (third, "dim"), (2 * third, "lamp")):
                stretches.append((start, view, (0.0, 0.0), _lighting(mode, size, rng), water))
        else:
            cuts = (0, half) if self.kind == "cut" else (0,)
            for number, start in enumerate(cuts):
                speed = {"pan": rng.uniform(2, 4), "cut": rng.uniform(0, 1.5)}.get(self.kind, 0.0)
                heading = rng.uniform(0, 2 * np.pi)
                velocity = (float(speed * np.cos(heading)), float(speed * np.sin(heading)))
                view = self._new_view(rng, speed * n)
                water = _Water(rng, size, mixture, count=_count(rng, size, False), first_id=number * 100000)
                stretches.append((start, view, velocity, _lighting("lamp", size, rng), water))
        last = None
        for index in range(n):
            start, view, (vx, vy), lighting, water = [s for s in stretches if s[0] <= index][-1]
            if water is last:  # time passes for the same water; a cut brings new water
                water.step()
            last = water
            span_x = view.radiance.shape[1] - size[0]
            span_y = view.radiance.shape[0] - size[1]
            t = index - start
            x = span_x / 2 + vx * t - (vx * (n - start) / 2)
            y = span_y / 2 + vy * t - (vy * (n - start) / 2)
            radiance, objects = view.crop(float(np.clip(x, 0, span_x)), float(np.clip(y, 0, span_y)), size)
            yield _render(index, radiance, objects, view, lighting, water.particles, sensor, rng)

    def _new_view(self, rng: np.random.Generator, travel: float) -> _View:
        """A view of a random photograph of the split, ``travel`` px larger each way for a pan."""
        pad = int(np.ceil(travel)) + 4 if travel else 0
        size = (self.size[0] + pad, self.size[1] + pad)
        background = str(rng.choice(self.backgrounds))
        return _view(background, size, rng, self.data, sunlit=False, distractors=int(rng.choice((0, 1, 1, 2))))


def cases(split: str, *, frames: int | None = None, data: Path | None = None) -> list[Case]:
    """The named cases of a split.

    Parameters
    ----------
    split : ``dev`` (tune on it) or ``test`` (judge on it).
    frames : frames per case (None: each case's own, 8-12).
    data : folder holding ``MSRB_PHOTO``, a test background (None or absent: left out).
    """
    if split not in SPLITS:
        raise ValueError(f"split: got {split!r}, allowed {', '.join(SPLITS)}")
    if frames is not None and frames < 1:
        raise ValueError(f"frames: got {frames}, allowed >= 1")
    out = []
    for k, (kind, width, count, shuffled) in enumerate(_LAYOUT):
        seed = _SEEDS[split] + (k - 1 if shuffled else k)  # the stills case just before it
        name = f"{kind}-{width}" + ("-shuffled" if shuffled else "")
        out.append(Case(name, split, kind, (width, _HEIGHTS[width]), frames or count, seed, shuffled, data))
    return out


# ---------------------------------------------------------------- scoring and export


def _times(ns: list[int]) -> dict[str, float]:
    """Median and slowest frame times (ms) and their ratio."""
    if not ns:
        return {"frame_ms_median": float("nan"), "frame_ms_worst": float("nan"), "worst_over_median": float("nan")}
    median, worst = float(np.median(ns)) / 1e6, float(max(ns)) / 1e6
    return {"frame_ms_median": median, "frame_ms_worst": worst,
            "worst_over_median": worst / median if median > 0 else float("nan")}


def _run_case(case: Case, detectors: dict[str, Detector], m: Matching,
              clock: Callable[[], int]) -> tuple[dict[str, list[FrameScore]], dict[str, list[int]], int]:
    scores: dict[str, list[FrameScore]] = {name: [] for name in detectors}
    times: dict[str, list[int]] = {name: [] for name in detectors}
    counted = 0
    for detector in detectors.values():
        detector.reset()  # a new case; within it the detector may learn from frame to frame
    for index, image, truth in case.frames():
        counted += int(truth.counted.sum())
        for name, detector in detectors.items():
            start = clock()
            found = detector.detect(image)
            times[name].append(clock() - start)
            scores[name].append(_score(index, truth, found.centres, found.radii, m))
    return scores, times, counted


def evaluate_case(case: Case, detectors: dict[str, Detector], m: Matching, *,
                  clock: Callable[[], int] = time.perf_counter_ns) -> dict[str, Any]:
    """Every detector on the same frames of one case (each reset at its start, none between its frames).

    Returns {"case", "kind", "size", "frames", "counted", "backgrounds", "detectors": {name: summary
    (:func:`~antiscatter.evaluate.metrics.summarise`) with the median and slowest frame's detection
    time (ms), their ratio and every frame's time "frame_ms"}}.  ``clock``: nanoseconds.
    """
    scores, times, counted = _run_case(case, detectors, m, clock)
    return _case_row(case, scores, times, counted)


def _case_row(case: Case, scores: dict[str, list[FrameScore]], times: dict[str, list[int]],
              counted: int) -> dict[str, Any]:
    return {"case": case.name, "kind": case.kind, "size": f"{case.size[0]}x{case.size[1]}", "frames": case.count,
            "counted": counted, "backgrounds": list(case.backgrounds),
            "detectors": {name: {**summarise(scores[name]), **_times(times[name]),
                                 "frame_ms": [t / 1e6 for t in times[name]]} for name in scores}}


def evaluate_heldout(split: str, detectors: dict[str, Detector], m: Matching, *, frames: int | None = None,
                     data: Path | None = None, clock: Callable[[], int] = time.perf_counter_ns,
                     log: Callable[[str], None] = lambda s: None) -> dict[str, Any]:
    """Every detector on every case of a split.

    Returns {"split", "frames", "counted", "backgrounds", "cases": [:func:`evaluate_case`'s rows],
    "overall": {name: summary over every frame of the split, and "worst_over_median": the largest
    of the cases' ratios (a case holds one frame size; the split mixes two)}}.
    """
    require_skimage()
    rows, pooled = [], {n: [] for n in detectors}
    for case in progress(cases(split, frames=frames, data=data), desc=f"held-out {split}", unit="case"):
        log(f"held-out {split}: {case.name}")
        scores, times, counted = _run_case(case, detectors, m, clock)
        rows.append(_case_row(case, scores, times, counted))
        for name in detectors:
            pooled[name] += scores[name]
    return {"split": split, "frames": sum(r["frames"] for r in rows), "counted": sum(r["counted"] for r in rows),
            "backgrounds": list(_backgrounds(split, data)), "cases": rows,
            "overall": {name: {**summarise(pooled[name]),
                               "worst_over_median": max(r["detectors"][name]["worst_over_median"] for r in rows)}
                        for name in detectors}}


def export_case(case: Case, folder: Path) -> Path:
    """Write a case as ``folder``: ``<frame>.png`` (from 0), ``truth.csv`` (frame,x,y,radius,id of the
    counted particles: hand annotations, each row counted), ``gt.txt`` (MOTChallenge ground truth of
    every particle, the uncounted ones with the "considered" flag 0, so neither to be found nor a
    false alarm: ``antiscatter evaluate FOLDER --truth FOLDER/gt.txt`` scores as in memory) and
    ``case.json``.  Written beside it and moved into place at the end; ``folder`` must not exist."""
    folder = Path(folder)
    if folder.exists():
        raise UsageError(f"{folder}: already exists; allowed a new folder")
    staging = folder.with_name(folder.name + ".partial")
    if staging.exists():
        shutil.rmtree(staging)
    staging.mkdir(parents=True)
    with (staging / "truth.csv").open("w", newline="") as plain, (staging / "gt.txt").open("w", newline="") as mot:
        rows, boxes = csv.writer(plain), csv.writer(mot)
        rows.writerow(["frame", "x", "y", "radius", "id"])
        for index, image, truth in case.frames():
            cv2.imwrite(str(staging / f"{index}.png"), image)
            for (x, y), r, counted, ident in zip(truth.centres.tolist(), truth.radii.tolist(),
                                                 truth.counted.tolist(), truth.ids.tolist()):
                if counted:
                    rows.writerow([index, repr(x), repr(y), repr(r), ident])
                boxes.writerow([index + 1, ident, repr(x - r), repr(y - r), repr(2 * r), repr(2 * r),
                                int(counted), 1, 1])
    (staging / "case.json").write_text(json.dumps(
        {"name": case.name, "split": case.split, "kind": case.kind, "size": list(case.size), "frames": case.count,
         "seed": case.seed, "shuffled": case.shuffled, "backgrounds": list(case.backgrounds)}, indent=2) + "\n")
    staging.rename(folder)
    return folder


def export(split: str, out_dir: Path, *, frames: int | None = None, data: Path | None = None) -> list[Path]:
    """Write every case of a split as ``out_dir/<split>/<case>/`` (:func:`export_case`)."""
    require_skimage()
    chosen = cases(split, frames=frames, data=data)
    for case in chosen:
        if (Path(out_dir) / split / case.name).exists():
            raise UsageError(f"{Path(out_dir) / split / case.name}: already exists; allowed a new folder")
    return [export_case(case, Path(out_dir) / split / case.name) for case in chosen]
