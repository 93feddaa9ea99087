"""The closed-loop digital twin: how much backscatter the light pattern really removes.

A pinhole camera at the origin and a pinhole projector ``baseline_m`` to its
right (parallel axes; 0 = co-located through a beamsplitter) look at the
simulator's 3-D particles in front of a background plane.  Time runs in
projector refreshes (sub-frames).  Each camera frame is rendered with the light
that was on during its exposure: the patterns the system displayed in those
sub-frames, averaged, sampled where each particle sits in projector pixels,
and warped onto the background plane.  The system under test -- the
:class:`~antiscatter.system.System` ``antiscatter run`` drives, built as run
builds it -- sees that frame; its pattern is ready ``latency`` after the exposure ends,
goes on at the next projector refresh and stays on until the next pattern, a
frame later -- one pattern a frame, as ``run`` shows them, its predicted holes
drawn for the middle of that time (``tracking.PREDICT_AHEAD``).

Figures, integrated over every sub-frame (flashes included):

* backscatter removed = 1 - (light on particles with the system / under full light),
  each particle weighted by the light it would send back to the camera under the
  full lamp (its brightness times its image's area);
* scene light kept = light on the background with the system / under full light;
* both again over the frames after the start-up (``_steady``: from frame
  ``SETTLE_FRAMES``, at most half the run), what a long dive sees.

Strategies against the closed-loop catch (a particle in its hole goes dark,
is lost, its hole closes, it is lit again):

* ``none``: the naive loop;
* ``dim``: holes at ``dim_level`` of full light, so darkened particles stay visible;
* ``pulse``: holes at ``dim_level`` in the refresh the camera exposes in, dark in the
  others -- the detector still sees darkened particles, which get half the light ``dim``
  leaves them (at 120 Hz with a 60 Hz camera);
* ``flash``: every camera exposure sits in a uniform flash sub-frame of
  ``flash_level``; the pattern is shown in the other sub-frames;
* ``coast``: holes follow tracked particles on their predicted path while dark.

Mappings: ``identity`` (camera pixels scaled to the projector), ``calibrated``
(the mapping of a plane at the working depth), ``range`` (each hole stretched
over its particle's whole disparity range, near..far) and ``probe`` (with
``dim`` or ``pulse``: each track's depth found by bisection over the next
exposures, :class:`~antiscatter.probe.DepthProbe`; under ``pulse`` only the
exposure's refresh shows the probe's half, lifted, and the other refreshes keep
the whole interval that may hold the particle dark).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable

import cv2
import numpy as np

from .console import progress
from .detection import make_detector
from .errors import UsageError
from .levels import LEVELS, HoleLevels, rest_for
from .pattern import GROW, GROW_FROM, scale_mapping
from .simulate import make_scene
from .probe import MIN_WORTH, DepthProbe
from .strategies import strategies_that, strategy_entry, strategy_names
from .system import Exposure, LoopSettings, Step, System, make_tracker


@dataclass(frozen=True)
class _Light:
    """One step's light as the twin integrates it (projector pixels, float32, 1 = full), and what
    the system takes an exposure under it to have been."""

    pattern: np.ndarray  # between exposures
    exposure: np.ndarray  # while the camera exposes: pulse the holes lifted, flash the flash, else the pattern
    made: Exposure | None  # what the system records for an exposure under ``exposure`` (None: nothing yet)
    under_pattern: Exposure | None  # ... for one under ``pattern`` (run's locked chain of lights starting)


def _flip_lands(t: float, refresh: float) -> float:
    """When a flip asked for at ``t`` lands: the first refresh boundary after it (a display flips
    on vertical blank)."""
    return (math.floor(t / refresh + 1e-9) + 1) * refresh


class _FreeRunning:
    """``run``'s turn in mode single with ``pulse`` or ``flash`` on a free-running camera and a
    display that flips on vertical blank (output ``kms``), in twin time (seconds):

    the exposure's light is handed over once the last pattern's flip has landed (``show`` waits
    for a pending flip), and lands a refresh later; frames that ended before it was handed over
    are gone (the camera keeps no queue); of the rest, those whose exposure began before the light
    can have been on screen are skipped (at most ``MAX_STALE_FRAMES``); once a frame is read (at
    its exposure's end) the pattern goes back if the light's flip has landed; the frame's pattern
    is ready ``latency`` later and is shown at the next flip, after any pending one.
    """

    def __init__(self, refresh: float, latency: float, skip_before: str = "on screen", lag: float = 0.0) -> None:
        from .runtime import MAX_STALE_FRAMES

        self.refresh, self.latency, self.most_stale, self.lag = refresh, latency, MAX_STALE_FRAMES, lag
        self.skip_before = skip_before
        self.handed = 0.0  # when the exposure's light was handed over (run's flash_on)
        self.stale = 0
        # (when it is light on the scene: its flip + the display's lag, the exposure's light on)
        self.events = [(_flip_lands(0.0, refresh) + lag, True)]

    def light_at(self, t: float, on: bool) -> bool:
        """Whether the exposure's light is on in the refresh starting at ``t`` (``on``: it was until
        now, False when a new pattern has just landed)."""
        while self.events and self.events[0][0] <= t + 1e-12:
            on = self.events.pop(0)[1]
        return on

    def take(self, start: float, end: float) -> bool:
        """Whether the frame exposed ``start``..``end`` is one ``run`` processes."""
        if end <= self.handed + 1e-12:
            return False  # ended before it was asked for
        # run's rule: began once the light is on screen; "handed over": the frame stamped after it
        # was handed over (what run did while the camera's stamp was taken for the capture time)
        fresh = (start >= self.handed + self.refresh + self.lag - 1e-9 if self.skip_before == "on screen"
                 else end >= self.handed)
        if not fresh and self.stale < self.most_stale:
            self.stale += 1
            return False
        return True

    def processed(self, start: float, end: float) -> float:
        """The frame exposed ``start``..``end``, read at its end: when its pattern is light on the
        scene.  Schedules the pattern put back after it and the next exposure's light."""
        lit = _flip_lands(self.handed, self.refresh)
        pending = lit
        if end >= lit - 1e-12:  # the light's flip has landed: the last pattern back at the next one
            pending = _flip_lands(end, self.refresh)
            self.events.append((pending + self.lag, False))
        lands = _flip_lands(max(end + self.latency, pending), self.refresh)
        self.handed, self.stale = lands, 0  # the next light waits for that flip
        self.events.append((_flip_lands(lands, self.refresh) + self.lag, True))
        return lands + self.lag


class _LockedRun(_FreeRunning):
    """``run``'s locked loop (``--camera-lock``) once the lock holds: each exposure begins in the
    middle of a refresh's light; a frame read at its exposure's end is ready ``latency`` later,
    and its exposure light goes out at the flip whose light (``lag`` after it) covers the first
    exposure still to come that it can reach, the new pattern in the flips before it, the
    pattern again at the flip after; a frame that began before the light was on is skipped (at
    most ``MAX_STALE_FRAMES``).  When the frame cannot be ready in time for the next exposure's
    flip and that flip is the next one (a display lagging about a refresh), the last frame's light
    goes out there before the frame is processed -- the light ahead (``runtime.light_ahead``) --
    and the frame's pattern at the flip after.  When that flip comes before the frame is even read
    (a longer lag), each frame's light goes out after its pattern, for the exposure after the next
    (``runtime.light_after``), until the next frame's pattern.  ``period``, ``exposure``: the
    camera's frame period and exposure time.
    """

    def __init__(self, refresh: float, latency: float, lag: float, period: float, exposure: float) -> None:
        super().__init__(refresh, latency, lag=lag)
        self.period, self.exposure = period, exposure
        self.events = []  # the full lamp until the first pattern
        self.lit = 0.0  # when the last exposure light is on the scene
        self.pending = 0.0  # when the last flip asked for lands
        self.posted = False  # the last frame's light went out after its pattern (runtime.light_after) ...
        self.posted_lit = 0.0  # ... on the scene from then
        self.under_pattern = False  # the next frame taken is under the pattern (the first such light to come)

    def take(self, start: float, end: float) -> bool:
        if end <= self.handed + 1e-12:
            return False  # ended before it was asked for
        if start < self.lit - 1e-9 and self.stale < self.most_stale:
            self.stale += 1
            return False
        return True

    def processed(self, start: float, end: float) -> float:
        from .lock import FLIP_MARGIN_S
        from .runtime import light_after, light_ahead

        r = self.refresh
        margin = FLIP_MARGIN_S
        coming = start + self.period
        now = _flip_lands(max(end, self.pending), r)  # what a flip asked for on reading lands at
        posted, self.posted = self.posted, False
        first = _flip_lands(max(end + self.latency, self.pending), r)  # what a flip asked for now lands at
        after = light_after(first, coming + self.period, self.lag, coming + self.exposure + margin, r)
        ahead = not posted and light_ahead(now, end + self.latency + margin, coming - self.lag, r)
        if posted or (after is not None and not ahead):
            # the next exposure's light went out after the last frame's pattern (or, the first time,
            # none did: the next frame is taken under this pattern); this frame's pattern, then its
            # light at the flip that covers the exposure after the next
            self.events.append((first + self.lag, False))
            self.lit = self.posted_lit if posted else 0.0
            self.under_pattern = not posted
            self.handed, self.pending, self.stale = first, first, 0
            if after is not None:
                self.events.append((after + self.lag, True))
                self.posted, self.posted_lit, self.pending = True, after + self.lag, after
                self.handed = after - r  # (run waits for the flip before the light's to put it out)
            return first + self.lag
        self.under_pattern = False
        if ahead:
            pattern = _flip_lands(max(end + self.latency, now), r)  # after the light's flip
            self.events += [(now + self.lag, True), (pattern + self.lag, False)]
            self.lit, self.pending, self.handed, self.stale = now + self.lag, pattern, now, 0
            return pattern + self.lag
        while coming < first + self.lag - 1e-9:
            coming += self.period
        lift = max(first, math.floor((coming - self.lag) / r + 1e-9) * r)  # the last flip whose light covers it
        self.events += [(lift + self.lag, True), (lift + r + self.lag, False)]
        self.lit, self.pending, self.handed, self.stale = lift + self.lag, lift + r, lift, 0
        return first + self.lag  # the new pattern: in the flips before the light's, or with it


__all__ = ["TwinGeometry", "TwinRun", "simulate_loop", "default_runs", "backscatter_weight", "STRATEGIES", "MAPPINGS"]

#: the light strategies registered at import (antiscatter.strategies; TwinRun reads the registry)
STRATEGIES = strategy_names()
#: frames the system needs to start up (the detector's 16-frame background warm-up, the first
#: tracks' confirmation); the ``_steady`` figures leave them out (at most half a run)
SETTLE_FRAMES = 20
#: the exposure the simulator's brightness is set for (seconds); the twin scales the light a
#: camera frame gathers by exposure / this
REFERENCE_EXPOSURE_S = 0.004
MAPPINGS = ("identity", "calibrated", "range", "probe")


def steady_from(frames: int) -> int:
    """The first frame of a run of ``frames`` that the ``_steady`` figures count."""
    return min(SETTLE_FRAMES, frames // 2)


@dataclass(frozen=True)
class TwinGeometry:
    """Camera, projector and timing.

    Defaults follow the report's hardware: the IMX296 (its 1456x1088 frame is
    scaled to ``camera_size``) behind a 6 mm lens, about 63 degrees across;
    an Optoma ML550-class projector, 1280x800, throw ratio 1.2, refreshing at
    120 Hz; the camera at 60 Hz with a 4 ms exposure; the background plane at 3 m.

    camera_phase: None (default) is the camera locked to the projector (its external trigger on
    the projector's vsync): each exposure starts with a refresh.  A number 0..1 is a free-running
    camera, each exposure starting that share of a refresh after one's light begins (its clock drifts
    against the projector's by parts per million: the phase holds over a run).  With ``pulse``
    and ``flash`` the loop is then ``run``'s on such a camera (:class:`_FreeRunning`).
    camera_lock: with ``pulse`` and ``flash``, the loop ``run --camera-lock`` runs once its lock
    holds (:class:`_LockedRun`) instead of the locked ideal: one thread, so a frame's light must be
    ready for the next exposure, or go out a frame ahead (a lag of about a refresh), or after its
    pattern for the exposure after the next (a longer one), or the loop reads every other frame.
    display_lag_s: how long after a flip its image is light on the scene (a DLP projector that
    formats one frame while it shows the last lags a refresh); every pattern, pulse and flash is on
    that much later.  With the locked ideal the camera is taken to be triggered by the light.  The
    refreshes of light are counted from the flips plus the lag (and a free-running camera's phase
    from the start of one).

    projector_aperture_m: the projector lens's aperture diameter; 0 (default) is the pinhole
    projector, sharp at every depth.  Above 0 the pattern is sharp only at ``projector_focus_m``
    (0 = the background's distance): a particle at depth Z gets the pattern blurred by a disc of
    radius :meth:`defocus_px` projector pixels (thin lens, geometric optics) -- the near
    particles that send back most of the light get soft-edged holes.
    """

    camera_size: tuple[int, int] = (800, 600)
    hfov_deg: float = 63.0
    projector_size: tuple[int, int] = (1280, 800)
    throw_ratio: float = 1.2
    baseline_m: float = 0.12
    projector_hz: float = 120.0
    camera_hz: float = 60.0
    exposure_s: float = 0.004
    background_m: float = 3.0
    near_m: float = 0.3
    far_m: float = 3.0
    projector_aperture_m: float = 0.0
    projector_focus_m: float = 0.0
    camera_phase: float | None = None
    camera_lock: bool = False
    display_lag_s: float = 0.0

    def __post_init__(self) -> None:
        for key in ("projector_aperture_m", "projector_focus_m", "display_lag_s"):
            value = getattr(self, key)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{key}: got {value}, allowed a number >= 0")
        if not (math.isfinite(self.baseline_m) and self.baseline_m >= 0):
            raise ValueError(f"baseline_m: got {self.baseline_m}, allowed a number >= 0")
        for key in ("camera_hz", "projector_hz", "throw_ratio", "background_m"):
            value = getattr(self, key)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{key}: got {value}, allowed a number > 0")
        if not (math.isfinite(self.hfov_deg) and 0 < self.hfov_deg < 180):
            raise ValueError(f"hfov_deg: got {self.hfov_deg}, allowed 0 < hfov < 180 degrees")
        ratio = self.projector_hz / self.camera_hz
        if abs(ratio - round(ratio)) > 1e-6 or ratio < 1:
            raise ValueError(f"projector_hz: got {self.projector_hz}, allowed a whole multiple of camera_hz "
                             f"({self.camera_hz})")
        if not 0 < self.exposure_s <= 1 / self.projector_hz + 1e-12:
            raise ValueError(f"exposure_s: got {self.exposure_s}, allowed 0 < exposure <= one projector refresh "
                             f"({1 / self.projector_hz:.4f} s)")
        if self.camera_lock and self.camera_phase is not None:
            raise ValueError("camera_lock: the locked camera's exposures sit in the middle of a refresh's light; "
                             "allowed without camera_phase (a free-running camera)")
        if self.camera_phase is not None and not (
                math.isfinite(self.camera_phase) and 0 <= self.camera_phase < 1
                and self.camera_phase / self.projector_hz + self.exposure_s <= 1 / self.camera_hz + 1e-12):
            raise ValueError(f"camera_phase: got {self.camera_phase}, allowed 0 <= phase < 1 (of a projector refresh) "
                             "with the exposure ending inside its camera frame")

    @property
    def camera_focal(self) -> float:
        return (self.camera_size[0] / 2) / math.tan(math.radians(self.hfov_deg) / 2)

    @property
    def projector_focal(self) -> float:
        return self.throw_ratio * self.projector_size[0]

    def to_camera(self, X: np.ndarray, Y: np.ndarray, Z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Camera pixel (u, v) of camera-frame points (metres)."""
        fc = self.camera_focal
        return fc * X / Z + (self.camera_size[0] - 1) / 2, fc * Y / Z + (self.camera_size[1] - 1) / 2

    def to_projector(self, X: np.ndarray, Y: np.ndarray, Z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Projector pixel (u, v) of camera-frame points (metres)."""
        fp = self.projector_focal
        cx, cy = (self.projector_size[0] - 1) / 2, (self.projector_size[1] - 1) / 2
        return fp * (X - self.baseline_m) / Z + cx, fp * Y / Z + cy

    def plane_mapping(self, depth_m: float) -> np.ndarray:
        """The exact camera-to-projector homography for points at ``depth_m`` (3x3)."""
        fc, fp = self.camera_focal, self.projector_focal
        ccx, ccy = (self.camera_size[0] - 1) / 2, (self.camera_size[1] - 1) / 2
        pcx, pcy = (self.projector_size[0] - 1) / 2, (self.projector_size[1] - 1) / 2
        s = fp / fc
        return np.array([[s, 0, pcx - s * ccx - fp * self.baseline_m / depth_m],
                         [0, s, pcy - s * ccy], [0, 0, 1.0]])

    def defocus_px(self, Z: np.ndarray) -> np.ndarray:
        """(N,) radius in projector pixels of the disc that blurs the pattern on points at depths
        ``Z`` (metres): the cone of light from the aperture A through the point in focus at F, cut
        at Z, is A |Z - F| / F across, which the projector sees as A |1/F - 1/Z| radians."""
        Z = np.asarray(Z, np.float64)
        if self.projector_aperture_m == 0:
            return np.zeros(Z.shape)
        focus = self.projector_focus_m or self.background_m
        return 0.5 * self.projector_focal * self.projector_aperture_m * np.abs(1.0 / focus - 1.0 / Z)

    @property
    def working_depth_m(self) -> float:
        """Where a calibration on a flat target would be made: the geometric middle of near..far."""
        return math.sqrt(self.near_m * self.far_m)


@dataclass(frozen=True)
class TwinRun:
    """One configuration of the system under test (``detector`` None = no system: full light).

    Defaults are ``antiscatter run``'s: holes at 0.1 of full light, no margin added to the holes
    (2 projector px more kept 0.007-0.02 less scene light and removed no more backscatter), and
    with ``dim`` or ``pulse`` and a tracker each hole's light set for its own particle
    (``levels="adaptive"``, :class:`~antiscatter.levels.HoleLevels`; ``dim_level`` is then the most
    a hole gives; with depth probing, a track is taken to have had its level when its verdict
    found it dimmed under its own probe or hole), and then, unless probing, a confirmed track's
    hole left fully dark for ``rest`` frames after each frame that found its particle.
    """

    detector: str | None = "contrast"
    mapping: str = "calibrated"
    strategy: str = "none"
    predict: bool = False
    dim_level: float = 0.1
    flash_level: float = 0.25
    margin_px: float = 0.0
    levels: str = "adaptive"
    min_worth: float = MIN_WORTH
    rest: int | None = None  # None: the strategy's own (levels.rest_for), as run
    grow: float = GROW
    grow_from: float = GROW_FROM

    def __post_init__(self) -> None:
        if self.levels not in LEVELS:
            raise ValueError(f"levels: got {self.levels!r}, allowed {', '.join(LEVELS)}")
        strategy = strategy_entry(self.strategy)  # (ValueError naming the allowed ones)
        if self.mapping not in MAPPINGS:
            raise ValueError(f"mapping: got {self.mapping!r}, allowed {', '.join(MAPPINGS)}")
        if self.mapping == "probe" and not strategy.visible:
            raise ValueError(f"mapping: probe needs strategy {strategies_that('visible')} (a probed particle must "
                             "stay visible)")


#: 32 points spread evenly over the unit disc (a sunflower spiral): a disc's mean light is their mean
_DISC = np.array([[math.sqrt((i + 0.5) / 32) * math.cos(i * 2.399963229728653),
                   math.sqrt((i + 0.5) / 32) * math.sin(i * 2.399963229728653)] for i in range(32)])


#: 8 points spread evenly over the unit disc: the blur disc's share of the sum of two discs
_BLUR = np.array([[math.sqrt((i + 0.5) / 8) * math.cos(i * 2.399963229728653 + 1.0),
                   math.sqrt((i + 0.5) / 8) * math.sin(i * 2.399963229728653 + 1.0)] for i in range(8)])


def _mean_over_discs(light: np.ndarray, u: np.ndarray, v: np.ndarray, r: np.ndarray,
                     blur: np.ndarray | None = None) -> np.ndarray:
    """Mean of ``light`` ((H, W) float) over each disc of radius r around (u, v), sampled at 32
    points spread evenly over it (nearest pixel); points outside the projector's field get no light.

    blur: (N,) radius of each disc's defocus (projector px; see TwinGeometry.defocus_px), or None:
    the light the disc gets is then the pattern averaged over the disc blurred by a disc of that
    radius -- each of the 32 points spread over 8 points of the blur disc (the sum of two discs)."""
    h, w = light.shape
    r = np.asarray(r, np.float64)
    dx, dy = r[:, None] * _DISC[None, :, 0], r[:, None] * _DISC[None, :, 1]
    if blur is not None and np.any(blur > 0):
        b = np.asarray(blur, np.float64)[:, None, None]
        dx = (dx[:, :, None] + b * _BLUR[None, None, :, 0]).reshape(len(r), -1)
        dy = (dy[:, :, None] + b * _BLUR[None, None, :, 1]).reshape(len(r), -1)
    x = np.rint(np.asarray(u, np.float64)[:, None] + dx).astype(np.int64)
    y = np.rint(np.asarray(v, np.float64)[:, None] + dy).astype(np.int64)
    inside = (x >= 0) & (x < w) & (y >= 0) & (y < h)
    values = np.where(inside, light[np.clip(y, 0, h - 1), np.clip(x, 0, w - 1)], 0.0)
    return values.mean(axis=1) if len(values) else np.zeros(0)


def _disc_kernel(radius: float) -> np.ndarray | None:
    """A disc of ``radius`` pixels as a float32 kernel summing to 1, pixels weighted by how much of
    each the disc covers (4 x 4 samples each); None below half a pixel (no blur to speak of)."""
    if radius < 0.5:
        return None
    n = int(math.ceil(radius))
    sub = (np.arange(4) + 0.5) / 4 - 0.5
    y, x = np.mgrid[-n:n + 1, -n:n + 1].astype(np.float64)
    yy = y[:, :, None, None] + sub[None, None, :, None]
    xx = x[:, :, None, None] + sub[None, None, None, :]
    kernel = (np.hypot(xx, yy) <= radius).mean(axis=(2, 3)).astype(np.float32)
    return kernel / kernel.sum()


def backscatter_weight(scene: Any, geometry: "TwinGeometry", particles: dict[str, np.ndarray]) -> np.ndarray:
    """(N,) the light each particle sends back to the camera under the full lamp: its brightness
    (lamp irradiance, albedo, two-way attenuation) times its image's area in pixels -- a 4 mm
    bubble outweighs a 0.4 mm grain at the same distance a hundredfold."""
    return scene.full_light_brightness() * (geometry.camera_focal * particles["R"] / particles["Z"]) ** 2


def twin_scene(geometry: "TwinGeometry", preset: str, seed: int, current: float | None = None) -> Any:
    """The simulator's scene of ``preset`` as the twin's camera sees it: its frame size, field of
    view and frame rate (particles move a frame period of the twin's camera each step); ``current``
    (m/s across the view) replaces the preset's water current."""
    from dataclasses import replace

    from .simulate.scene import RealisticScene

    scene = make_scene(preset, rng=np.random.default_rng(seed), size=geometry.camera_size,
                       current=None if current is None else (current, 0.0))
    if isinstance(scene, RealisticScene) and (scene.config.fps, scene.config.hfov_deg) != (geometry.camera_hz,
                                                                                           geometry.hfov_deg):
        scene = RealisticScene(replace(scene.config, fps=geometry.camera_hz, hfov_deg=geometry.hfov_deg),
                               size=geometry.camera_size, rng=np.random.default_rng(seed))
    return scene


def _twin_system(run: TwinRun, geometry: TwinGeometry, calibration: Any) -> System | None:
    """The system under test, built for this configuration as ``run`` builds its own (None: no system,
    the full lamp)."""
    if not run.detector:
        return None
    probing, strategy = run.mapping == "probe", strategy_entry(run.strategy)
    # motion settings scale with the width; probing: as run (system.make_tracker)
    tracker = (make_tracker(probing=probing, frame_size=geometry.camera_size)
               if strategy.tracks or run.predict or probing else None)
    # holes along epipolar segments: probed intervals, or the whole range when depth is unknown
    segments = None
    if probing or (run.mapping == "range" and geometry.baseline_m > 0):
        segments = DepthProbe(calibration.mapping_at if calibration is not None else geometry.plane_mapping,
                              near_m=geometry.near_m, far_m=geometry.far_m, dim_level=run.dim_level,
                              projector_size=geometry.projector_size, min_worth=run.min_worth)
    rest = rest_for(run.strategy) if run.rest is None else run.rest
    levels = (HoleLevels(run.dim_level, rest=0 if probing else rest)  # probing reads no rest
              if run.levels == "adaptive" and strategy.visible and tracker is not None else None)
    if run.mapping == "identity":
        mapping = scale_mapping(geometry.camera_size, geometry.projector_size)
    elif calibration is not None:
        mapping = calibration.homography
    else:
        mapping = geometry.plane_mapping(geometry.working_depth_m)
    # where the system believes its light lands behind the particles: the far working distance
    far_mapping = (mapping if run.mapping == "identity" else
                   calibration.mapping_at(geometry.far_m) if calibration is not None else
                   geometry.plane_mapping(geometry.far_m))
    settings = LoopSettings(strategy=run.strategy, dim_level=run.dim_level, flash_level=run.flash_level,
                            predict=run.predict, display_lag_s=geometry.display_lag_s,
                            refresh_s=1.0 / geometry.projector_hz, grow=run.grow, grow_from=run.grow_from,
                            margin=run.margin_px,
                            # as run: no compensation without a calibration, nor under a flash
                            compensate=run.mapping != "identity" and strategy.exposure != "flash")
    return System(make_detector(run.detector), tracker, mapping=mapping, camera_size=geometry.camera_size,
                  projector_size=geometry.projector_size, settings=settings, levels=levels,
                  probe=segments if probing else None, ranges=None if probing else segments,
                  light_mapping=far_mapping)


def _light_of(system: System, step: Step) -> _Light:
    """The light of ``step``'s pattern as run shows it -- the pattern, the exposure's light (the
    flash, or with pulse the pattern lifted) -- and what the system records of an exposure under each."""
    light = system.lift(step, step.pattern)  # (pulse: the pattern lifted; else the pattern)
    shown = system.flash_image if system.flash_image is not None else light
    pattern = step.pattern.astype(np.float32) / 255.0
    exposure = pattern if shown is step.pattern else shown.astype(np.float32) / 255.0
    return _Light(pattern, exposure, system.made(step, light.copy()),
                  system.made(step, step.pattern.copy(), pattern=True))


class _View:
    """The camera's view of the background plane, and the full lamp's light on it (the reference of
    the scene light kept: the view's size, less what a blurred edge of the field spills outside it)."""

    def __init__(self, geometry: TwinGeometry) -> None:
        pw, ph = geometry.projector_size
        self.size = geometry.camera_size
        self.inverse = np.linalg.inv(geometry.plane_mapping(geometry.background_m))
        self.lit_area = cv2.warpPerspective(np.ones((ph, pw), np.float32), self.inverse, self.size,
                                            flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT,
                                            borderValue=0.0) > 0.5
        lit_pixels = int(self.lit_area.sum())
        # the pattern's defocus on the background, in camera pixels (a normalised disc; None: sharp)
        self.blur = _disc_kernel(float(geometry.defocus_px(geometry.background_m))
                                 * geometry.camera_focal / geometry.projector_focal)
        self.reference = float(lit_pixels if self.blur is None else
                               cv2.filter2D(self.lit_area.astype(np.float32), -1, self.blur,
                                            borderType=cv2.BORDER_CONSTANT)[self.lit_area].sum())
        if lit_pixels == 0:  # every figure would be 0 / 0
            raise UsageError(f"baseline {geometry.baseline_m:g} m: the projector lights none of the camera's view "
                             f"of the background {geometry.background_m:g} m away; allowed: a geometry whose views "
                             "overlap (a smaller --baseline-m)")

    def light(self, light: np.ndarray) -> np.ndarray:
        """(H, W) float camera image of projector light ``light`` on the background plane."""
        bg = cv2.warpPerspective(light, self.inverse, self.size, flags=cv2.INTER_NEAREST,
                                 borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
        if self.blur is not None:  # the projector focused nearer or farther than the background
            bg = cv2.filter2D(bg, -1, self.blur, borderType=cv2.BORDER_CONSTANT)
        return bg


class _Loop:
    """The world around one system: time in projector refreshes, the light each refresh puts on the
    particles and the background, the camera's exposures, and the patterns queued to go on."""

    def __init__(self, run: TwinRun, geometry: TwinGeometry, scene: Any, system: System | None,
                 latency_ms: float) -> None:
        self.geometry, self.scene, self.system = geometry, scene, system
        self.view = _View(geometry)
        pw, ph = geometry.projector_size
        self.full = np.ones((ph, pw), np.float32)
        # the lamp is fully on until the first pattern is ready (the exposure's light: the flash)
        flash = system.flash_image.astype(np.float32) / 255.0 if system is not None and system.flash_image is not None \
            else self.full
        self.displayed = _Light(self.full, flash, None, None)
        self.queue: list[tuple[float, _Light]] = []  # (time the pattern is light on the scene, its light)
        self.sub_s = 1.0 / geometry.projector_hz
        self.latency = latency_ms / 1e3
        # the exposure's light: in the first refresh of each frame (camera locked to the projector),
        # or as run gives it on a free-running camera
        self.exposing = strategy_entry(run.strategy).exposing and system is not None
        lag = geometry.display_lag_s
        # the light changes ``lag`` after each flip, so the refreshes of light are taken from then
        # (from the flips, a lag that is not whole refreshes moved every light into the refresh after
        # it: at 12 ms the light as run missed every exposure, dim holes came late)
        self.phase = lag % self.sub_s
        # the exposure's start after its frame's first refresh of light: triggered by it (the locked
        # ideal), in its middle (run's lock), or the free-running camera's phase into it
        self.offset = self.phase + (geometry.camera_phase * self.sub_s if geometry.camera_phase is not None else
                                    (self.sub_s - geometry.exposure_s) / 2 if geometry.camera_lock else 0.0)
        self.free: _FreeRunning | None = None
        if self.exposing and geometry.camera_phase is not None:
            self.free = _FreeRunning(self.sub_s, self.latency, lag=lag)
        elif self.exposing and geometry.camera_lock:
            self.free = _LockedRun(self.sub_s, self.latency, lag, 1.0 / geometry.camera_hz, geometry.exposure_s)
        self.lifted = False
        self.processed = 0
        self.series: list[dict[str, float]] = []

    def frame(self, k: int) -> None:
        """Camera frame ``k``: each refresh's light on the particles and the background, the
        exposure gathered and, once it ends, the system's step on it; one entry of ``series``."""
        geometry, scene = self.geometry, self.scene
        pw, ph = geometry.projector_size
        t0 = k / geometry.camera_hz
        te = t0 + self.offset
        p = scene.particles()
        u, v = geometry.to_projector(p["X"], p["Y"], p["Z"])
        rp = np.maximum(geometry.projector_focal * p["R"] / p["Z"], 0.5)
        cam_u, cam_v = geometry.to_camera(p["X"], p["Y"], p["Z"])
        visible = (cam_u >= 0) & (cam_u < geometry.camera_size[0]) & (cam_v >= 0) & (cam_v < geometry.camera_size[1])
        in_field = (u >= 0) & (u < pw) & (v >= 0) & (v < ph) & (p["Z"] > 0)
        # only what the projector -- the vehicle's lamp -- can light counts
        weight = backscatter_weight(scene, geometry, p) * visible * in_field
        frame_on, frame_full, frame_scene = np.zeros(len(u)), np.zeros(len(u)), 0.0
        exposure_on, exposure_bg = np.zeros(len(u)), 0.0  # the light the exposure gathers
        sub_s, blurred = self.sub_s, bool(geometry.projector_aperture_m)
        sub_per_frame = int(round(geometry.projector_hz / geometry.camera_hz))
        for j in range(sub_per_frame):
            ts = t0 + self.phase + j * sub_s
            shown = self._light_at(ts, j)
            # the scene's state is the frame's mid-exposure; particles keep moving through the
            # frame period, so each refresh lights them where they are in its middle
            q = scene.particles(ahead_s=self.phase + j * sub_s + sub_s / 2 - self.offset - geometry.exposure_s / 2)
            su, sv = geometry.to_projector(q["X"], q["Y"], q["Z"])
            blur = geometry.defocus_px(q["Z"]) if blurred else None
            frame_on += _mean_over_discs(shown, su, sv, rp, blur)
            frame_full += _mean_over_discs(self.full, su, sv, rp, blur)  # what the full lamp gives
            bg = self.view.light(shown)  # the background plane: the share of the camera's view that is lit
            frame_scene += float(bg[self.view.lit_area].sum()) / self.view.reference
            if self.system is None:
                continue
            end = te + geometry.exposure_s
            # the share of the exposure in this refresh
            share = (1.0 if ts <= te and end <= ts + sub_s + 1e-12 else
                     (min(end, ts + sub_s) - max(te, ts)) / geometry.exposure_s)
            if share > 0:
                exposure_on = exposure_on + share * _mean_over_discs(
                    shown, u, v, rp, geometry.defocus_px(p["Z"]) if blurred else None)
                exposure_bg = exposure_bg + share * bg
            if not ts < end <= ts + sub_s + 1e-12 or (self.free is not None and not self.free.take(te, end)):
                continue  # the exposure goes on, or run does not read this frame
            self._step(te, end, exposure_on, exposure_bg)
        frame_on /= sub_per_frame
        frame_full /= sub_per_frame
        total, lit = float((weight * frame_full).sum()), float((weight * frame_on).sum())
        self.series.append({"frame": k, "removed": 1 - lit / total if total else float("nan"),
                            "kept": frame_scene / sub_per_frame, "particle_light": lit, "particle_light_full": total})

    def _light_at(self, ts: float, j: int) -> np.ndarray:
        """The light of the refresh starting at ``ts`` (refresh ``j`` of its frame): the pattern on
        then, or the exposure's light."""
        while self.queue and self.queue[0][0] <= ts + 1e-12:
            self.displayed = self.queue.pop(0)[1]
            self.lifted = False  # a new pattern replaces the exposure's light
        self.lifted = self.free.light_at(ts, self.lifted) if self.free is not None else self.exposing and j == 0
        if self.system is None:
            return self.full
        return self.displayed.exposure if self.lifted else self.displayed.pattern

    def _step(self, te: float, end: float, exposure_on: np.ndarray, exposure_bg: Any) -> None:
        """The exposure ``te``..``end`` is read: the system's step on it, its pattern queued."""
        geometry, system = self.geometry, self.system
        self.processed += 1
        # what the system takes the exposure to have been under: the light it made for it (the
        # exposure's light, free-running whether or not it was on all through), or (run's locked
        # loop starting its chain of lights after the pattern) the pattern
        made = self.displayed.under_pattern if getattr(self.free, "under_pattern", False) else self.displayed.made
        if made is not None:  # (run tells it nothing before its first pattern)
            system.expose(made)
        # the simulator's brightness is that of a 4 ms exposure: a shorter one gathers less
        gather = geometry.exposure_s / REFERENCE_EXPOSURE_S
        image = self.scene.render(light=(gather * exposure_on, gather * exposure_bg))
        # the exposure's pattern goes on at a later refresh of this frame or the next
        on_at = (self.free.processed(te, end) if self.free is not None else
                 math.ceil((end + self.latency) / self.sub_s - 1e-9) * self.sub_s + geometry.display_lag_s)
        step = system.render(system.analyse(image, te + geometry.exposure_s / 2, exposure_s=geometry.exposure_s,
                                            on_s=on_at))
        self.queue.append((on_at, _light_of(system, step)))
        self.queue.sort(key=lambda item: item[0])


def simulate_loop(run: TwinRun, *, geometry: TwinGeometry = TwinGeometry(), preset: str = "mixed",
                  frames: int = 90, seed: int = 1, latency_ms: float = 5.0, scene: Any = None,
                  calibration: Any = None, on_frame: Callable[[], Any] | None = None) -> dict[str, Any]:
    """Run one configuration in the loop; returns its figures (and per-frame series).

    The system under test is :class:`~antiscatter.system.System`, the step ``run`` drives, built
    for ``run`` as ``run`` builds its own; the twin keeps the world: particles, geometry, the light
    of each refresh, the camera's exposures and run's loop timing.

    scene: a RealisticScene to use instead of the preset (its size must be ``geometry.camera_size``).
    calibration: a :class:`~antiscatter.calibration.Calibration` for the ``calibrated`` and
        ``range`` mappings; None = the twin's exact geometry.
    on_frame: called as each camera frame begins (a progress bar's ``update``); None = nothing.
    """
    if scene is None:
        scene = twin_scene(geometry, preset, seed)
    system = _twin_system(run, geometry, calibration)
    loop = _Loop(run, geometry, scene, system, latency_ms)
    for k in range(frames):
        if on_frame is not None:
            on_frame()
        if k:
            scene.step()
        loop.frame(k)
    return _figures(run, geometry, loop, frames, latency_ms)


def _figures(run: TwinRun, geometry: TwinGeometry, loop: _Loop, frames: int, latency_ms: float) -> dict[str, Any]:
    """The loop's figures over the whole run and from ``steady_from`` on, and its settings."""
    series = loop.series
    on_particles = sum(f["particle_light"] for f in series)
    off_particles = sum(f["particle_light_full"] for f in series)
    removed = 1.0 - on_particles / off_particles if off_particles else 0.0
    # after the start-up: the detector's background warm-up and the first tracks' confirmation
    settle = steady_from(frames)
    steady = series[settle:]
    steady_full = sum(f["particle_light_full"] for f in steady)
    removed_steady = 1.0 - sum(f["particle_light"] for f in steady) / steady_full if steady_full else 0.0
    kept_steady = float(np.mean([f["kept"] for f in steady])) if steady else 1.0
    levels = loop.system.levels if loop.system is not None else None
    probe = loop.system.probe if loop.system is not None else None
    return {"detector": "default" if run.detector == "contrast" else run.detector,
            "calibrated": run.detector is not None and run.mapping != "identity",
            "mapping": run.mapping if run.detector else "none", "predict": run.predict,
            "strategy": run.strategy if run.detector else "none", "dim_level": run.dim_level,
            "levels": ("adaptive" if levels is not None else "fixed") if strategy_entry(run.strategy).visible
            else None,
            "rest": levels.rest if levels is not None else None,
            "grow": run.grow if run.detector else None,
            "grow_from": run.grow_from if run.detector and run.grow else None,
            "min_worth": run.min_worth if probe is not None else None,
            "latency_ms": latency_ms, "display_lag_ms": geometry.display_lag_s * 1e3,
            "camera": "free" if geometry.camera_phase is not None else "locked, as run" if geometry.camera_lock
            else "locked",
            "camera_phase": geometry.camera_phase, "frames_processed": loop.processed if run.detector else 0,
            "baseline_m": geometry.baseline_m, "backscatter_removed": removed,
            "scene_light_kept": float(np.mean([f["kept"] for f in series])) if series else 1.0, "frames": frames,
            "steady_from_frame": settle, "backscatter_removed_steady": removed_steady,
            "scene_light_kept_steady": kept_steady, "series": series}


def default_runs(baseline_m: float) -> list[TwinRun]:
    """Full light, seed and default detectors with identity mapping, and the default with the calibrated
    mapping under each strategy, with and without prediction (dim and pulsed holes with prediction also
    at ``dim_level`` for every hole, against each hole's own level)."""
    runs = [TwinRun(detector=None), TwinRun("seed", "identity"), TwinRun("contrast", "identity"),
            TwinRun("contrast", "calibrated")]
    runs += [TwinRun("contrast", "calibrated", strategy) for strategy in ("dim", "pulse", "flash", "coast")]
    runs += [TwinRun("contrast", "calibrated", "coast", predict=True),
             TwinRun("contrast", "calibrated", "dim", predict=True),
             TwinRun("contrast", "calibrated", "pulse", predict=True),
             TwinRun("contrast", "calibrated", "dim", predict=True, levels="fixed"),
             TwinRun("contrast", "calibrated", "pulse", predict=True, levels="fixed"),
             TwinRun("contrast", "calibrated", "flash", predict=True)]
    if baseline_m > 0:
        runs.append(TwinRun("contrast", "range", "flash", predict=True))
        runs += [TwinRun("contrast", "probe", strategy, predict=predict)
                 for strategy in ("dim", "pulse") for predict in (False, True)]
        runs.append(TwinRun("contrast", "probe", "pulse", predict=True, min_worth=0.0))
    return runs


def particle_speed(scene: Any, geometry: TwinGeometry) -> float:
    """Median speed (camera pixels a second) of the scene's particles in view, from their motion now."""
    fps = geometry.camera_hz
    now, later = scene.particles(), scene.particles(ahead_s=1.0 / fps)
    u, v = geometry.to_camera(now["X"], now["Y"], now["Z"])
    u1, v1 = geometry.to_camera(later["X"], later["Y"], later["Z"])
    seen = (now["Z"] > 0) & (u >= 0) & (u < geometry.camera_size[0]) & (v >= 0) & (v < geometry.camera_size[1])
    return float(np.median(np.hypot(u1 - u, v1 - v)[seen]) * fps) if seen.any() else 0.0


def plot_curves(path: str, *, geometry: TwinGeometry, preset: str = "mixed", frames: int = 60, seed: int = 1,
                latencies_ms: tuple[float, ...] = (0.0, 5.0, 10.0, 20.0, 40.0),
                baselines_m: tuple[float, ...] = (0.0, 0.03, 0.06, 0.12, 0.2),
                currents_m_s: tuple[float, ...] = (0.0, 0.1, 0.2, 0.4, 0.8),
                focuses_m: tuple[float, ...] = (0.3, 0.4, 0.5, 0.7, 1.0, 1.5, 3.0),
                dim_level: float = 0.1, flash_level: float = 0.25) -> dict[str, Any]:
    """Backscatter removed and scene light kept against latency (at the geometry's baseline), against
    baseline (at 5 ms) and against particle speed (a water current across the view, m/s, replacing the
    preset's; at the geometry's baseline and 5 ms), for the default detector with the calibrated mapping
    (and depth probing) and, beside them, the report's ``seed`` detector with the identity mapping;
    written as a PNG.  ``speed_px_s``: each current's median particle speed in the image.  With a
    projector lens (``geometry.projector_aperture_m`` > 0) also against the distance it is focused at
    (``by_focus``, at the geometry's baseline and 5 ms)."""
    from dataclasses import replace as _replace

    from .bench import _pyplot, save_figure

    runs = {"seed, identity": TwinRun("seed", "identity"),
            "none": TwinRun("contrast", "calibrated"), "coast+predict": TwinRun("contrast", "calibrated", "coast", True),
            "dim+predict": TwinRun("contrast", "calibrated", "dim", True),
            "pulse+predict": TwinRun("contrast", "calibrated", "pulse", True),
            "flash+predict": TwinRun("contrast", "calibrated", "flash", True),
            "probe+pulse+predict": TwinRun("contrast", "probe", "pulse", True)}
    runs = {name: _replace(run, dim_level=dim_level, flash_level=flash_level) for name, run in runs.items()}
    def drifting(current: float) -> Any:  # the same scene (same seed) in another current
        return twin_scene(geometry, preset, seed, current)

    speeds = [particle_speed(drifting(c), geometry) for c in currents_m_s]
    curves: dict[str, Any] = {"latency_ms": list(latencies_ms), "baseline_m": list(baselines_m),
                              "current_m_s": list(currents_m_s), "speed_px_s": speeds, "by_latency": {},
                              "by_baseline": {}, "by_speed": {}}
    panels = [("by_latency", latencies_ms, "processing latency (ms)"),
              ("by_baseline", baselines_m, "camera-projector baseline (m)"),
              ("by_speed", currents_m_s, "current across the view (m/s) and the median particle speed in the "
                                         "image (px/s)")]
    if geometry.projector_aperture_m > 0:
        curves["focus_m"], curves["by_focus"] = list(focuses_m), {}
        panels.append(("by_focus", focuses_m, f"distance the projector is focused at (m; aperture "
                                              f"{geometry.projector_aperture_m * 1e3:g} mm)"))
    loops = len(runs) * sum(len(xs) for _, xs, _ in panels)
    with progress(total=loops * frames, desc="twin plot") as bar:
        for name, run in runs.items():
            curves["by_latency"][name] = [simulate_loop(run, geometry=geometry, preset=preset, frames=frames,
                                                        seed=seed, latency_ms=lat, on_frame=bar.update)
                                          for lat in latencies_ms]
            curves["by_baseline"][name] = [simulate_loop(run, geometry=_replace(geometry, baseline_m=b),
                                                         preset=preset, frames=frames, seed=seed, latency_ms=5.0,
                                                         on_frame=bar.update) for b in baselines_m]
            curves["by_speed"][name] = [simulate_loop(run, geometry=geometry, scene=drifting(c), frames=frames,
                                                      latency_ms=5.0, on_frame=bar.update) for c in currents_m_s]
            if "by_focus" in curves:
                curves["by_focus"][name] = [simulate_loop(run, geometry=_replace(geometry, projector_focus_m=f),
                                                          preset=preset, frames=frames, seed=seed, latency_ms=5.0,
                                                          on_frame=bar.update) for f in focuses_m]
    plt = _pyplot()
    # one row per figure (removed, kept): each panel holds one line per configuration, told apart by
    # colour and marker, under one legend; the two figures of a run no longer share a panel
    figures = (("backscatter_removed", "backscatter removed"), ("scene_light_kept", "scene light kept"))
    fig, axes = plt.subplots(len(figures), len(panels), figsize=(5.5 * len(panels), 8.5), sharey="row",
                             squeeze=False)
    markers = "osD^v<>xP*"
    for row, (figure, ylabel) in enumerate(figures):
        for ax, (key, xs, label) in zip(axes[row], panels):
            for i, (name, results) in enumerate(curves[key].items()):
                ax.plot(xs, [r[figure] for r in results], marker=markers[i % len(markers)], color=f"C{i}",
                        label=name)
            ax.set_ylim(0, 1.02)
            ax.grid(alpha=0.3)
            if row == len(figures) - 1:
                ax.set_xlabel(label)
        axes[row][0].set_ylabel(f"{ylabel} (share, 0..1)")
    titles = [f"against latency (baseline {geometry.baseline_m:g} m)", "against baseline (latency 5 ms)",
              f"against particle speed (baseline {geometry.baseline_m:g} m, 5 ms)",
              f"against projector focus (baseline {geometry.baseline_m:g} m, 5 ms)"]
    for ax, title in zip(axes[0], titles):
        ax.set_title(title, fontsize=10)
    speed_ticks = [f"{c:g}\n{s:.0f}" for c, s in zip(currents_m_s, speeds)]
    for row in range(len(figures)):
        axes[row][2].set_xticks(list(currents_m_s), speed_ticks)
        if "by_focus" in curves:
            axes[row][3].set_xscale("log")
            axes[row][3].minorticks_off()  # the log axis's own labels would sit among the distances'
            axes[row][3].set_xticks(list(focuses_m), [f"{f:g}" for f in focuses_m])
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=(len(labels) + 1) // 2, fontsize=10,
               title="configuration (default detector, calibrated mapping; seed: identity)", title_fontsize=10)
    fig.suptitle(f"antiscatter twin: {preset}, {frames} frames a point")
    fig.tight_layout(rect=(0, 0.1, 1, 0.97))
    save_figure(fig, path)
    plt.close(fig)
    for key, _, _ in panels:
        for results in curves[key].values():
            for r in results:
                r.pop("series", None)
    return curves
