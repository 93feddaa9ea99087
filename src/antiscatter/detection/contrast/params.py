"""Settings of the ``contrast`` detector: :class:`ContrastParams`, checked when made.

The measured history of each default is in ``docs/decisions/001-contrast-tuning.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

#: planes of a colour frame the detector can work on (ContrastParams.channel)
CHANNELS = ("luma", "green", "red", "blue", "min")


@dataclass(frozen=True)
class ContrastParams:
    """Settings of the ``contrast`` detector; a bad value raises ValueError naming the field, the
    value and what is allowed.  Why each default: ``docs/decisions/001-contrast-tuning.md``.

    k: detection threshold in units of the local noise (default 4).
    min_contrast: smallest excess over the background, grey levels (default 4).
    cell: background cell size in full-resolution pixels for frames up to 800 px wide, scaled with
        the width above that (default 16).
    memory: frames over which the per-pixel background is learnt; 0 = single-frame (default 40;
        while the view moves 10, ``BackgroundModel.MOVING_MEMORY``): long enough that the learnt
        background's own noise stays small, short enough to follow a slowly changing scene.
    halo: pixels added to each radius for the particle's blur halo (default 1).
    core: the radius reaches the farthest pixel brighter than this share of the particle's peak
        (default 0.5: its half-maximum extent, as the width of a blurred spot is measured; 0 =
        every pixel above the threshold, an extent that grows with the particle's brightness).
    max_radius: largest particle radius in pixels, for frames up to 800 px wide; scaled with the
        width above that (default 48).
    split: split components with several intensity peaks (default true).
    factor: working resolution divisor, 1 or 2; 0 = 2 for frames 640 px wide or more, else 1 (default 0).
    lone_k: noise units a component of a single working pixel must exceed; 0 = off (default 5: a
        lone noise spike is the commonest false alarm, and one that high comes once in 3.5 million pixels).
    k_expected: threshold in noise units where a tracked particle is expected (``expect``), so a
        particle dimmed under its own hole stays found; = k turns it off (default 3.5).
    persist_radius: working pixels within which the last frame's light keeps a single working pixel
        short of ``lone_k`` (a faint particle persists, a noise spike does not), once the
        background has been learnt; 0 = off (default 2).
    follow: move the learnt background with the view when the camera pans, turns or zooms
        (default true: a vehicle moves; false for a camera that holds still).
    texture: size of texture, full-resolution pixels scaled with the width above 800 px, that a
        single frame (the first, the first after a cut, every one with ``memory=0``) takes for
        background: its background follows its median over that window, and its particles must
        outshine rings of radius 3, 6, 12, ... up to it (:func:`prominence_level`); 0 = off, at
        most 128 (default 28).
    point: share of each working pixel taken from the maximum of its full-resolution block, the
        rest from the block's mean; 0 = the mean alone, 1 = the maximum alone (default 0.15: keeps
        specks smaller than a pixel, and little of a compressed frame's bright artefacts).
    channel: the plane of a colour (BGR) frame the detector works on, one of CHANNELS (a grey or Y
        frame is used as it is; default ``luma``, the camera's Y: the colours' noise averages while
        a whitish particle adds to all; ``red`` or ``min`` suit sunlit blue-green water).
    coarse: also look for wide, faint particles (defocused, near the lens) at a quarter of the
        working resolution, and let them replace the fragments the working resolution broke them
        into (default true; :mod:`~antiscatter.detection.contrast.scales`).
    max_particles: the most particles a frame reports, the brightest kept; what is left out is
        counted in the detections' ``cut`` (default 4096: over four times the densest catalogued
        scene's 874, and it bounds the tracker's and the pattern's work too; 0 = no ceiling).
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
    coarse: bool = True
    max_particles: int = 4096

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
        if self.max_particles < 0:
            raise ValueError(f"max_particles: got {self.max_particles}, allowed >= 0 (0 = no ceiling)")
        if not (math.isfinite(self.max_radius) and self.max_radius > 0):
            raise ValueError(f"max_radius: got {self.max_radius}, allowed a finite number > 0")
