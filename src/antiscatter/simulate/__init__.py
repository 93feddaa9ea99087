"""Synthetic scenes with exact ground truth.

A scene is a stateful generator: ``scene.frame()`` returns the current image
and the truth of every particle, ``scene.step()`` advances one frame period.
Presets are picked by name from :data:`PRESETS`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Protocol

import numpy as np

from .truth import Truth

__all__ = ["Scene", "Truth", "PRESETS", "make_scene"]


class Scene(Protocol):
    """What every preset provides."""

    size: tuple[int, int]  # (width, height) in pixels
    fps: float

    def step(self) -> None:
        """Advance the particles by one frame period."""

    def render(self) -> np.ndarray:
        """The current frame, (H, W, 3) BGR uint8."""

    def truth(self) -> Truth:
        """Ground truth of every particle in the current frame."""


@dataclass(frozen=True)
class _Preset:
    build: Callable[..., Scene]
    default_size: tuple[int, int]
    summary: str


PRESETS: dict[str, _Preset] = {}


def make_scene(preset: str, *, rng: np.random.Generator,
               size: tuple[int, int] | None = None, background: str | None = None,
               current: tuple[float, float] | None = None) -> Scene:
    """Build the preset's scene at ``size`` (width, height; the preset's own by default).

    background: a path to an image or video replacing a realistic preset's background.
    current: (x, y) water current in m/s replacing a realistic preset's: every particle drifts with
        it across the view, on top of its own motion.
    """
    from ..errors import UsageError

    try:
        entry = PRESETS[preset]
    except KeyError:
        raise UsageError(f"unknown preset {preset!r}; allowed: {', '.join(sorted(PRESETS))}") from None
    if background is None and current is None:
        return entry.build(size=size or entry.default_size, rng=rng)
    if preset == "seed":
        raise UsageError("--background and the current apply to the realistic presets, not to 'seed' "
                         "(white on black)")
    from dataclasses import replace
    config = _REALISTIC[preset][0]
    if background is not None:
        from .background import load_background
        load_background(background, (8, 8))  # fail early with a clear message
        config = replace(config, background=str(background))
    if current is not None:
        config = replace(config, current=(float(current[0]), float(current[1])))
    return _RealisticScene(config, size=size or entry.default_size, rng=rng)


from . import report as _report  # noqa: E402
from .presets import REALISTIC as _REALISTIC  # noqa: E402
from .scene import RealisticScene as _RealisticScene  # noqa: E402

PRESETS["seed"] = _Preset(_report.ReportBubbles, (800, 600),
                          "the 2024 report's model: 300 white circles rising on black")


def _realistic(config):
    def build(*, size: tuple[int, int], rng: np.random.Generator) -> Scene:
        return _RealisticScene(config, size=size, rng=rng)
    return build


for _name, (_config, _size, _summary) in _REALISTIC.items():
    PRESETS[_name] = _Preset(_realistic(_config), _size, _summary)
