"""The closed-loop digital twin: how much backscatter the light pattern really removes.

A pinhole camera at the origin and a pinhole projector ``baseline_m`` to its
right (parallel axes; 0 = co-located through a beamsplitter) look at the
simulator's 3-D particles in front of a background plane.  Time runs in
projector refreshes (sub-frames).  Each camera frame is rendered with the light
that was on during its exposure: the patterns the system displayed in those
sub-frames, averaged, sampled where each particle sits in projector pixels,
and warped onto the background plane.  The system under test -- the same
detector, tracker, pattern rendering and mapping as ``antiscatter run`` --
sees that frame; its pattern is ready ``latency`` after the exposure ends,
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

import copy
import math
from dataclasses import dataclass
from typing import Any, Callable, Mapping

import cv2
import numpy as np

from .console import progress
from .detection import make_detector
from .detections import Detections
from .errors import UsageError
from .levels import LEVELS, HoleLevels, rest_for
from .pattern import GROW, GROW_FROM, GROW_REFERENCE_WIDTH, camera_light, grow_holes, render_pattern, scale_mapping
from .simulate import make_scene
from .probe import MIN_WORTH, DepthProbe, Intervals
from .tracking import PREDICT_AHEAD, Prediction


@dataclass(frozen=True)
class _Fixed:
    """A queued pattern drawn once (light, 0..1) and the track ids of its holes."""

    light: np.ndarray
    ids: np.ndarray
    holes: Detections  # pulse: the holes lifted while the camera exposes, drawn for that time


@dataclass(frozen=True)
class _Probing:
    """A queued pattern of the ``probe`` mapping: tracks frozen at one update, and each one's interval."""

    prediction: Prediction
    probes: Mapping  # shown while the camera exposes
    between: Mapping  # shown between exposures: the probes (dim), each whole interval (pulse)
    at: float  # the time its holes are drawn for
    exposure_at: float  # ... and those the next exposure is taken under (pulse: the probes' halves)
    levels: HoleLevels | None  # each hole's light as it was when the pattern was made

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
        from .runtime import FLIP_MARGIN_NS, light_after, light_ahead

        r = self.refresh
        margin = FLIP_MARGIN_NS / 1e9
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

STRATEGIES = ("none", "dim", "pulse", "flash", "coast")
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
        if self.strategy not in STRATEGIES:
            raise ValueError(f"strategy: got {self.strategy!r}, allowed {', '.join(STRATEGIES)}")
        if self.mapping not in MAPPINGS:
            raise ValueError(f"mapping: got {self.mapping!r}, allowed {', '.join(MAPPINGS)}")
        if self.mapping == "probe" and self.strategy not in ("dim", "pulse"):
            raise ValueError("mapping: probe needs strategy dim or pulse (a probed particle must stay visible)")


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


def _holes_pattern(holes: Detections, run: TwinRun, *, size: tuple[int, int], mapping: np.ndarray,
                   buffer: np.ndarray, segments: DepthProbe | None = None,
                   probes: Mapping | None = None, levels: HoleLevels | None = None,
                   lifted: bool = False, frame_width: int = GROW_REFERENCE_WIDTH,
                   grow: bool = True) -> np.ndarray:
    """The projector pattern for ``holes`` (camera pixels) under the run's mapping; float 0..1.

    segments: draw each hole along its particle's epipolar segment -- over ``probes``' interval
    where given, over the whole near..far range otherwise -- instead of at ``mapping``.
    levels: each hole's own light (dim holes, or pulsed ones while the camera exposes:
    ``lifted``); None: ``dim_level`` for all.  ``grow``: the holes grow as the run says (``run.grow``,
    :func:`~antiscatter.pattern.grow_holes`, for camera frames ``frame_width`` wide), as run's do
    -- all but a probe the camera sees (grown, its halves would overlap).
    """
    if grow:
        holes = grow_holes(holes, grow=run.grow, start=run.grow_from, frame_width=frame_width)
    dim = run.strategy == "dim" or lifted
    own = levels.grey(holes.track_ids) if dim and levels is not None else 0
    if segments is not None:
        # probing: only the holes the probe found worth drawing (its intervals); else the whole range
        pattern = segments.render(holes, probes or {}, size=size, margin=run.margin_px, out=buffer, hole=own,
                                  given_only=probes is not None)
    else:
        pattern = render_pattern(holes, size=size, mapping=mapping, margin=run.margin_px, out=buffer, hole=own)
    light = pattern.astype(np.float32) / 255.0
    if dim and levels is None:
        np.maximum(light, run.dim_level, out=light)
    return light


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


def simulate_loop(run: TwinRun, *, geometry: TwinGeometry = TwinGeometry(), preset: str = "mixed",
                  frames: int = 90, seed: int = 1, latency_ms: float = 5.0, scene: Any = None,
                  calibration: Any = None, on_frame: Callable[[], Any] | None = None) -> dict[str, Any]:
    """Run one configuration in the loop; returns its figures (and per-frame series).

    scene: a RealisticScene to use instead of the preset (its size must be ``geometry.camera_size``).
    calibration: a :class:`~antiscatter.calibration.Calibration` for the ``calibrated`` and
        ``range`` mappings; None = the twin's exact geometry.
    on_frame: called as each camera frame begins (a progress bar's ``update``); None = nothing.
    """
    if scene is None:
        scene = twin_scene(geometry, preset, seed)
    detector = make_detector(run.detector) if run.detector else None
    tracker = None
    if run.strategy == "coast" or run.predict or run.mapping == "probe":
        from .tracking import Tracker
        # motion settings scale with the width; probing draws a new track's hole along its whole line,
        # and the light its probes give a particle is not known until their verdict (as run)
        probing = run.mapping == "probe"
        tracker = Tracker(frame_size=geometry.camera_size, flow_holes=not probing,
                          **({"flux_ratio": 0.0} if probing else {}))
    # holes along epipolar segments: probed intervals, or the whole range when depth is unknown
    segments = None
    if run.mapping == "probe" or (run.mapping == "range" and geometry.baseline_m > 0):
        segments = DepthProbe(calibration.mapping_at if calibration is not None else geometry.plane_mapping,
                              near_m=geometry.near_m, far_m=geometry.far_m, dim_level=run.dim_level,
                              projector_size=geometry.projector_size, min_worth=run.min_worth)
    probe = segments if run.mapping == "probe" else None
    rest = rest_for(run.strategy) if run.rest is None else run.rest
    levels = (HoleLevels(run.dim_level, rest=rest if probe is None else 0)  # probing reads no rest
              if run.levels == "adaptive" and run.strategy in ("dim", "pulse") and tracker is not None else None)
    shown_probes: Mapping = {}  # the intervals the pattern on during the last exposure gave each track
    shown_ids = None  # the tracks whose holes were on during the last exposure
    shown_rested = None  # of them, those left dark through it (HoleLevels.rest)
    pw, ph = geometry.projector_size
    if run.mapping == "identity":
        camera_mapping = scale_mapping(geometry.camera_size, geometry.projector_size)
    elif calibration is not None:
        camera_mapping = calibration.homography
    else:
        camera_mapping = geometry.plane_mapping(geometry.working_depth_m)
    # where the system believes its light lands behind the particles: the far working distance
    far_mapping = (camera_mapping if run.mapping == "identity" else
                   calibration.mapping_at(geometry.far_m) if calibration is not None else
                   geometry.plane_mapping(geometry.far_m))
    camera_from_far = np.linalg.inv(far_mapping)
    sub_per_frame = int(round(geometry.projector_hz / geometry.camera_hz))
    sub_s = 1.0 / geometry.projector_hz
    frame_s = 1.0 / geometry.camera_hz
    latency = latency_ms / 1e3
    full = np.ones((ph, pw), np.float32)
    flash = np.full((ph, pw), run.flash_level, np.float32)
    displayed = full  # the lamp is fully on until the first pattern is ready
    queue: list[tuple[float, np.ndarray]] = []  # (time the pattern goes on, pattern)
    buffer = np.empty((ph, pw), np.uint8)
    drawn = {"size": geometry.projector_size, "mapping": camera_mapping, "buffer": buffer, "segments": segments,
             "levels": levels, "frame_width": geometry.camera_size[0]}
    background_map = geometry.plane_mapping(geometry.background_m)
    inverse_bg = np.linalg.inv(background_map)
    lit_area = cv2.warpPerspective(full, inverse_bg, geometry.camera_size, flags=cv2.INTER_NEAREST,
                                   borderMode=cv2.BORDER_CONSTANT, borderValue=0.0) > 0.5
    lit_pixels = int(lit_area.sum())
    # the pattern's defocus on the background, in camera pixels (a normalised disc; None: sharp)
    background_blur = _disc_kernel(float(geometry.defocus_px(geometry.background_m))
                                   * geometry.camera_focal / geometry.projector_focal)
    # the full lamp's light on that view: the reference of the scene light kept (the view's size,
    # less what a blurred edge of the field spills outside it)
    lit_reference = float(lit_pixels if background_blur is None else
                          cv2.filter2D(lit_area.astype(np.float32), -1, background_blur,
                                       borderType=cv2.BORDER_CONSTANT)[lit_area].sum())
    if lit_pixels == 0:  # every figure would be 0 / 0
        raise UsageError(f"baseline {geometry.baseline_m:g} m: the projector lights none of the camera's view of "
                         f"the background {geometry.background_m:g} m away; allowed: a geometry whose views "
                         "overlap (a smaller --baseline-m)")
    on_particles = off_particles = 0.0
    on_scene = 0.0
    scene_samples = 0
    series = []
    exposure_pattern = None  # the pattern on during the last exposure (projector pixels, 1 = full)

    def _process(image: np.ndarray, t0: float, on_at: float) -> tuple[float, Any]:
        """The system under test on the exposure that began at ``t0``, its pattern going on at
        ``on_at``: (on_at, pattern or prediction)."""
        found = detector.detect(image)
        if tracker is not None:
            tracks = tracker.update(found, t0 + geometry.exposure_s / 2, unlit=shown_ids)
            if probe is not None:
                seen = Detections(found.centres, found.radii, found.scores, tracks.detection_ids)
                coasting = tracks.confirmed & (tracks.misses > 0)
                probe.observe(seen, shown_probes, tracks.ids[coasting],
                              exposure=exposure_pattern, coasting_centres=tracks.centres[coasting])
                probe.forget(tracks.ids)
            if levels is not None:  # how bright each came back under its own hole (or probe: its verdict)
                levels.update(found, tracks.detection_ids, shown_ids if probe is None else probe.dimmed,
                              tracks.ids, tracks.ids[tracks.confirmed], rested=shown_rested)
            # as run: one pattern a frame, on until the next; predicted, its holes are where the
            # particles will be halfway through that time (``PREDICT_AHEAD``)
            at = on_at + PREDICT_AHEAD * frame_s if run.predict else t0 + geometry.exposure_s / 2
            # pulse, as run: what the first exposure under this pattern is taken under is drawn for
            # its time -- the probes' halves for its start, the lifted pattern for the middle of its
            # refresh (a pattern ready after the next exposure began waits for the one after)
            exposure_at = at
            if run.predict and run.strategy == "pulse":
                exposure_at = (math.ceil((on_at - offset) / frame_s - 1e-9) * frame_s + offset
                               + (0.0 if probe is not None else sub_s / 2))
            if probe is not None:
                snapshot = tracker.snapshot()
                probes, covers = probe.plan(snapshot.holes(at))
                return on_at, _Probing(snapshot, probes, covers if run.strategy == "pulse" else probes, at,
                                       exposure_at, copy.copy(levels))  # (an update replaces its arrays)
            holes = tracker.holes(at)
            return on_at, _Fixed(_holes_pattern(holes, run, **drawn), holes.track_ids,
                                 holes if exposure_at == at else tracker.holes(exposure_at))
        return on_at, _holes_pattern(found, run, **drawn)

    def _shown(displayed: Any, lifted: bool) -> np.ndarray:
        """The light of a refresh: the pattern ``displayed``, or (``lifted``) the exposure's light
        -- the flash, or the pattern with its holes lifted (pulse)."""
        if detector is None:
            return full
        if run.strategy == "flash" and lifted:
            return flash  # the detection flash, timed to the exposure
        pulsed = lifted and run.strategy == "pulse"
        if isinstance(displayed, _Probing):
            # pulse: only the exposure's refresh needs the probe's half; the others keep the
            # whole interval that may hold the particle dark
            return _holes_pattern(displayed.prediction.holes(displayed.exposure_at if pulsed else displayed.at),
                                  run, lifted=pulsed, probes=displayed.probes if lifted else displayed.between,
                                  grow=not lifted and displayed.between is not displayed.probes,
                                  **{**drawn, "levels": displayed.levels})
        if isinstance(displayed, _Fixed):
            return _holes_pattern(displayed.holes, run, lifted=True, **drawn) if pulsed else displayed.light
        return np.maximum(displayed, run.dim_level) if pulsed else displayed  # holes dimmed while the camera exposes

    # the exposure's light: in the first refresh of each frame (camera locked to the projector),
    # or as run gives it on a free-running camera
    exposing = run.strategy in ("pulse", "flash") and detector is not None
    lag = geometry.display_lag_s
    # the light changes ``lag`` after each flip, so the refreshes of light are taken from then
    # (from the flips, a lag that is not whole refreshes moved every light into the refresh after
    # it: at 12 ms the light as run missed every exposure, dim holes came late)
    phase = lag % sub_s
    # the exposure's start after its frame's first refresh of light: triggered by it (the locked
    # ideal), in its middle (run's lock), or the free-running camera's phase into it
    offset = phase + (geometry.camera_phase * sub_s if geometry.camera_phase is not None else
                      (sub_s - geometry.exposure_s) / 2 if geometry.camera_lock else 0.0)
    free = None
    if exposing and geometry.camera_phase is not None:
        free = _FreeRunning(sub_s, latency, lag=lag)
    elif exposing and geometry.camera_lock:
        free = _LockedRun(sub_s, latency, lag, frame_s, geometry.exposure_s)
    lifted = False
    processed = 0
    for k in range(frames):
        if on_frame is not None:
            on_frame()
        if k:
            scene.step()
        t0 = k / geometry.camera_hz
        te = t0 + offset
        p = scene.particles()
        u, v = geometry.to_projector(p["X"], p["Y"], p["Z"])
        rp = geometry.projector_focal * p["R"] / p["Z"]
        cam_u, cam_v = geometry.to_camera(p["X"], p["Y"], p["Z"])
        visible = (cam_u >= 0) & (cam_u < geometry.camera_size[0]) & (cam_v >= 0) & (cam_v < geometry.camera_size[1])
        in_field = (u >= 0) & (u < pw) & (v >= 0) & (v < ph) & (p["Z"] > 0)
        # only what the projector -- the vehicle's lamp -- can light counts
        weight = backscatter_weight(scene, geometry, p) * visible * in_field
        frame_on = np.zeros(len(u))
        frame_full = np.zeros(len(u))
        frame_scene = 0.0
        exposure_on, exposure_bg = np.zeros(len(u)), 0.0  # the light the exposure gathers
        for j in range(sub_per_frame):
            ts = t0 + phase + j * sub_s
            while queue and queue[0][0] <= ts + 1e-12:
                displayed = queue.pop(0)[1]
                lifted = False  # a new pattern replaces the exposure's light
            lifted = free.light_at(ts, lifted) if free is not None else exposing and j == 0
            shown = _shown(displayed, lifted)
            # the scene's state is the frame's mid-exposure; particles keep moving through the
            # frame period, so each refresh lights them where they are in its middle
            q = scene.particles(ahead_s=phase + j * sub_s + sub_s / 2 - offset - geometry.exposure_s / 2)
            su, sv = geometry.to_projector(q["X"], q["Y"], q["Z"])
            blur = geometry.defocus_px(q["Z"]) if geometry.projector_aperture_m else None
            particle_light = _mean_over_discs(shown, su, sv, np.maximum(rp, 0.5), blur)
            frame_on += particle_light
            frame_full += _mean_over_discs(full, su, sv, np.maximum(rp, 0.5), blur)  # what the full lamp gives
            # the background plane: the share of the camera's view that is lit
            bg = cv2.warpPerspective(shown, inverse_bg, geometry.camera_size, flags=cv2.INTER_NEAREST,
                                     borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
            if background_blur is not None:  # the projector focused nearer or farther than the background
                bg = cv2.filter2D(bg, -1, background_blur, borderType=cv2.BORDER_CONSTANT)
            frame_scene += float(bg[lit_area].sum()) / lit_reference
            if detector is None:
                continue
            end = te + geometry.exposure_s
            # the share of the exposure in this refresh
            share = (1.0 if ts <= te and end <= ts + sub_s + 1e-12 else
                     (min(end, ts + sub_s) - max(te, ts)) / geometry.exposure_s)
            if share > 0:
                exposure_on = exposure_on + share * _mean_over_discs(
                    shown, u, v, np.maximum(rp, 0.5), geometry.defocus_px(p["Z"]) if blur is not None else None)
                exposure_bg = exposure_bg + share * bg
            if not ts < end <= ts + sub_s + 1e-12 or (free is not None and not free.take(te, end)):
                continue  # the exposure goes on, or run does not read this frame
            # the exposure's pattern goes on at a later refresh of this frame or the next
            processed += 1
            # what the system believes the exposure was taken under (free-running, with the
            # exposure's light: that light, whether or not it was on all through)
            # (run's locked loop starting its chain of lights after the pattern: under the pattern)
            under_pattern = getattr(free, "under_pattern", False)
            believed = shown if lifted or not exposing or under_pattern else _shown(displayed, True)
            exposure_pattern = believed  # what the probe's verdicts are judged against
            shown_probes = displayed.probes if isinstance(displayed, _Probing) and not under_pattern else {}
            # the tracks whose holes this exposure is taken under (none under a flash)
            shown_ids = (None if run.strategy == "flash" else
                         Intervals.of(displayed.probes).ids if isinstance(displayed, _Probing) else
                         displayed.ids if isinstance(displayed, _Fixed) else None)
            shown_rested = (shown_ids if under_pattern else  # (between exposures every hole is dark)
                            levels.rested(shown_ids) if levels is not None and shown_ids is not None else None)
            # the simulator's brightness is that of a 4 ms exposure: a shorter one gathers less
            gather = geometry.exposure_s / REFERENCE_EXPOSURE_S
            exposure_light = (gather * exposure_on, gather * exposure_bg)
            # the system knows the light it put on the scene during this exposure: its
            # pattern, taken back to camera pixels on a plane at the far working distance
            if run.mapping != "identity":  # as run: no compensation without a calibration
                detector.set_light(camera_light(believed, camera_from_far, geometry.camera_size))
            if tracker is not None and run.strategy != "flash" and run.mapping != "identity":
                # as run (with compensation): where tracked particles should be now
                detector.expect(tracker.snapshot().holes(te + geometry.exposure_s / 2))
            on_at = (free.processed(te, end) if free is not None else
                     math.ceil((end + latency) / sub_s - 1e-9) * sub_s + lag)
            queue.append(_process(scene.render(light=exposure_light), te, on_at))
            queue.sort(key=lambda item: item[0])
        frame_on /= sub_per_frame
        frame_scene /= sub_per_frame
        frame_full /= sub_per_frame
        on_particles += float((weight * frame_on).sum())
        off_particles += float((weight * frame_full).sum())
        on_scene += frame_scene
        scene_samples += 1
        total, lit = float((weight * frame_full).sum()), float((weight * frame_on).sum())
        series.append({"frame": k, "removed": 1 - lit / total if total else float("nan"), "kept": frame_scene,
                       "particle_light": lit, "particle_light_full": total})
    removed = 1.0 - on_particles / off_particles if off_particles else 0.0
    # after the start-up: the detector's background warm-up and the first tracks' confirmation
    settle = steady_from(frames)
    steady = series[settle:]
    steady_full = sum(f["particle_light_full"] for f in steady)
    removed_steady = 1.0 - sum(f["particle_light"] for f in steady) / steady_full if steady_full else 0.0
    kept_steady = float(np.mean([f["kept"] for f in steady])) if steady else 1.0
    return {"detector": "default" if run.detector == "contrast" else run.detector,
            "calibrated": run.detector is not None and run.mapping != "identity",
            "mapping": run.mapping if run.detector else "none", "predict": run.predict,
            "strategy": run.strategy if run.detector else "none", "dim_level": run.dim_level,
            "levels": ("adaptive" if levels is not None else "fixed") if run.strategy in ("dim", "pulse") else None,
            "rest": levels.rest if levels is not None else None,
            "grow": run.grow if run.detector else None,
            "grow_from": run.grow_from if run.detector and run.grow else None,
            "min_worth": run.min_worth if probe is not None else None,
            "latency_ms": latency_ms, "display_lag_ms": geometry.display_lag_s * 1e3,
            "camera": "free" if geometry.camera_phase is not None else "locked, as run" if geometry.camera_lock
            else "locked",
            "camera_phase": geometry.camera_phase, "frames_processed": processed if run.detector else 0,
            "baseline_m": geometry.baseline_m, "backscatter_removed": removed,
            "scene_light_kept": on_scene / scene_samples if scene_samples else 1.0, "frames": frames,
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
