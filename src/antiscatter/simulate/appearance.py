"""How each particle kind looks: canonical sprite templates, drawn once per scene.

A template is a float32 image of side :data:`SIDE` with the particle centred
and its outline at radius :data:`RADIUS` (peak value 1).  Each frame a particle
is a template warped to its size, angle and sub-pixel position, then blurred by
defocus and motion (see :mod:`.scene`).  Several variants per kind give
variety; all randomness comes from the scene's generator.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["SIDE", "RADIUS", "bubble_templates", "snow_templates", "sand_templates", "pyramid"]

SIDE = 64
RADIUS = 24.0


def _grid() -> tuple[np.ndarray, np.ndarray]:
    c = (SIDE - 1) / 2.0
    yy, xx = np.mgrid[0:SIDE, 0:SIDE].astype(np.float32)
    return xx - c, yy - c


def bubble_templates(rng: np.random.Generator, count: int = 4) -> list[np.ndarray]:
    """Bubbles: a bright rim, a dimmer interior and a specular highlight towards the lamp."""
    xx, yy = _grid()
    rho = np.sqrt(xx * xx + yy * yy) / RADIUS
    out = []
    for _ in range(count):
        rim_width = rng.uniform(0.08, 0.16)
        interior = rng.uniform(0.35, 0.5)
        hx, hy = rng.uniform(-0.45, -0.2), rng.uniform(-0.45, -0.2)
        spot = rng.uniform(0.10, 0.18)
        rim = np.exp(-((rho - (1.0 - rim_width)) / rim_width) ** 2)
        body = np.where(rho <= 1.0, interior, 0.0)
        highlight = 0.6 * np.exp(-(((xx / RADIUS - hx) ** 2 + (yy / RADIUS - hy) ** 2) / (2 * spot ** 2)))
        t = np.maximum(rim, body + highlight) * (rho <= 1.0)
        t = np.where(rho <= 1.05, t, 0.0).astype(np.float32)
        out.append(t / t.max())
    return out


def snow_templates(rng: np.random.Generator, count: int = 12) -> list[np.ndarray]:
    """Marine snow: irregular, semi-transparent flakes with uneven texture."""
    c = (SIDE - 1) / 2.0
    out = []
    for _ in range(count):
        vertices = int(rng.integers(7, 14))
        angles = np.sort(rng.uniform(0, 2 * np.pi, vertices))
        radii = RADIUS * rng.uniform(0.45, 1.0, vertices)
        pts = np.column_stack([c + radii * np.cos(angles), c + radii * np.sin(angles)])
        mask = np.zeros((SIDE, SIDE), np.uint8)
        cv2.fillPoly(mask, [np.rint(pts * 16).astype(np.int32)], 255, cv2.LINE_8, 4)
        # fluffy texture: smoothed noise inside the outline, soft edges
        texture = cv2.GaussianBlur(rng.random((SIDE, SIDE)).astype(np.float32), (0, 0), 2.0)
        texture = (texture - texture.min()) / max(float(np.ptp(texture)), 1e-6)
        t = (mask.astype(np.float32) / 255.0) * (0.35 + 0.65 * texture)
        t = cv2.GaussianBlur(t, (0, 0), 1.2)
        out.append((t / t.max()).astype(np.float32))
    return out


def sand_templates(rng: np.random.Generator, count: int = 4) -> list[np.ndarray]:
    """Sand grains: small, compact, bright, slightly elongated."""
    xx, yy = _grid()
    out = []
    for _ in range(count):
        aspect = rng.uniform(1.0, 1.6)
        theta = rng.uniform(0, np.pi)
        u = (xx * np.cos(theta) + yy * np.sin(theta)) * aspect
        v = -xx * np.sin(theta) + yy * np.cos(theta)
        rho = np.sqrt(u * u + v * v) / RADIUS
        t = np.clip(1.0 - rho ** 4, 0.0, 1.0).astype(np.float32)
        out.append(t)
    return out


def pyramid(template: np.ndarray) -> list[np.ndarray]:
    """The template at sides 64, 32, 16, 8 (area-averaged), to warp down without aliasing."""
    levels = [template]
    while levels[-1].shape[0] > 8:
        levels.append(cv2.pyrDown(levels[-1]))
    return levels
