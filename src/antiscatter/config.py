"""Run configuration: one frozen dataclass per section, filled from TOML and CLI flags.

A TOML file (``--config``) has the sections ``[source]``, ``[detector]`` (with
a sub-table ``[detector.<name>]`` holding that detector's parameters),
``[pattern]``, ``[output]``, ``[run]``, ``[track]`` and ``[light]``; their keys are the fields below.
Command-line flags set the same fields and win over the file.  Unknown keys
and bad values are rejected naming the key, the value and what is allowed.
"""

from __future__ import annotations

import math
import os
import tomllib
import types
import typing
import dataclasses
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from .errors import UsageError
from .levels import LEVELS, MIN_LEVEL, rest_for
from .lock import FLIP_MARGIN_S
from .probe import MIN_WORTH
from .pattern import GROW, GROW_FROM
from .strategies import strategies_that, strategy_entry, strategy_names

__all__ = ["SourceConfig", "DetectorConfig", "PatternConfig", "OutputConfig", "RunConfig", "TrackConfig",
           "LightConfig", "STRATEGIES", "Config", "load_config", "build_section", "parse_param", "parse_size"]


def parse_size(text: str, *, key: str = "size") -> tuple[int, int]:
    """``"WxH"`` -> (width, height), both positive."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"{key}: got {text!r}, allowed WIDTHxHEIGHT, e.g. 800x600") from None
    if w <= 0 or h <= 0:
        raise ValueError(f"{key}: got {text!r}, allowed positive WIDTHxHEIGHT")
    return w, h


@dataclass(frozen=True)
class SourceConfig:
    """Where frames come from.

    spec: ``sim``, ``camera``, ``webcam:N``, a folder of frames (``<int>.png``, or images named in
        order) or a video file.
    crop: ``"X0:X1,Y0:Y1"`` region of a video file, empty for the whole frame.
    loop: play a folder or video again from the start when it ends.
    preset: simulator preset for ``sim``.
    seed: random seed for ``sim``.
    size: ``"WxH"`` for sim, camera and webcam; empty for the source's own.
    camera_fps: frame rate asked of the camera, frames per second.
    camera_colour: BGR from the camera instead of the Y plane of YUV420 (the default, no conversion).
    camera_exposure_ms: a fixed camera exposure, milliseconds, automatic exposure and gain off
        (0, the default: automatic); ``pulse`` and ``flash`` need it inside one projector refresh.
    camera_gain: the analogue gain with a fixed exposure (0, the default: 1.0).
    camera_lock: lock the camera's exposures to the projector's refresh in software
        (:class:`~antiscatter.lock.PhaseLock`: each frame's duration nudged until its exposure
        sits in the middle of a refresh) so that pulsed holes or the flash light every exposure,
        as with the sensor's trigger on the projector's vsync.  Needs the camera with a fixed
        exposure inside one refresh, a frame period of whole refreshes, output ``kms`` (its flips
        say when the refreshes are) and mode ``single``; ``auto`` then picks ``pulse``.
    camera_lores: the camera's ISP also scales each frame to the detector's working resolution (a
        Picamera2 ``lores`` YUV420 stream), which the detector takes instead of pooling the full
        frame itself (default false: the ISP's filter is not the detector's pooling and costs
        accuracy, docs/decisions/009-lores.md).  Grey camera frames (not ``camera_colour``), a
        detector with a working resolution below the frame's, mode single or threads.
    """

    spec: str = "sim"
    crop: str = ""
    loop: bool = False
    preset: str = "seed"
    seed: int = 0
    size: str = ""
    camera_fps: float = 60.0
    camera_colour: bool = False
    camera_exposure_ms: float = 0.0
    camera_gain: float = 0.0
    camera_lock: bool = False
    camera_lores: bool = False

    def __post_init__(self) -> None:
        if not self.spec.strip():
            raise ValueError(f"spec: got {self.spec!r}, allowed sim, camera, webcam:N, a folder or a video file")
        if self.size:
            parse_size(self.size)
        if not self.camera_fps > 0:
            raise ValueError(f"camera_fps: got {self.camera_fps}, allowed > 0")
        from .sources.camera import GAIN_RANGE, exposure_fault, frame_us

        # 0 = automatic exposure / gain 1.0; the camera's own rule (exposure_fault), worded for these keys
        fault = exposure_fault(self.camera_fps, self.camera_exposure_ms or None, self.camera_gain or None)
        if fault == "exposure":
            raise ValueError(f"camera_exposure_ms: got {self.camera_exposure_ms}, allowed 0 (automatic) to the "
                             f"frame period ({frame_us(self.camera_fps) / 1e3:.2f} ms)")
        if fault == "gain" or self.camera_gain < 0:  # (a negative gain with automatic exposure: its range first)
            raise ValueError(f"camera_gain: got {self.camera_gain}, allowed 0 (1.0 with a fixed exposure) or "
                             f"{GAIN_RANGE[0]:g} to {GAIN_RANGE[1]:g}")
        if fault == "gain alone":
            raise ValueError(f"camera_gain: got {self.camera_gain}, goes with a fixed camera_exposure_ms")
        if self.seed < 0:
            raise ValueError(f"seed: got {self.seed}, allowed >= 0")
        if self.camera_lores and self.camera_colour:
            raise ValueError("camera_lores: got true with camera_colour true, allowed with the grey (Y) camera "
                             "frames only (the lores stream is the Y plane)")


@dataclass(frozen=True)
class DetectorConfig:
    """name: registered detector (``antiscatter run --help`` lists them); default ``contrast``."""

    name: str = "contrast"


#: the most projector pixels a pattern may have either way (an 8K projector is 7680 wide; a typo
#: of 100000 made three 128 MB pattern buffers and ran at 6 frames a second)
MAX_PROJECTOR_SIDE = 16384


@dataclass(frozen=True)
class PatternConfig:
    """The projector image.

    width, height: projector resolution in pixels (Optoma ML550: 1280x800).
    margin: projector pixels added to every hole's radius, 0 up to the projector's longer side.
    grow, grow_from: each hole's radius beyond ``grow_from`` camera pixels (for frames 800 px
        wide, in proportion for others) grows by ``grow`` times the excess
        (:func:`~antiscatter.pattern.grow_holes`); default 0.6 from 4 px; grow 0 = off.
    mapping: (3, 3) camera-to-projector homography as nested lists; empty =
        identity scaled from the camera size to the projector size.
    calibration: the calibration file the mapping came from (its depth model serves
        ``light.depth = "probe"``); empty = none.
    refresh_hz: the projector's refresh rate (ML550: 120 Hz); with pulsed holes and prediction the
        pattern lifted for an exposure is on for a refresh, and its holes are drawn for its middle.
    display_lag_ms: how long after a flip its image is light on the scene (0, the default; a DLP
        projector that formats one frame while it shows the last lags a refresh): the exposures
        under a pulse or flash, the camera lock's target and the prediction's horizon count it.
        Measure it: the camera sees a flip's image in the frames whose exposure began this long
        after it.
    """

    width: int = 1280
    height: int = 800
    margin: float = 0.0
    grow: float = GROW
    grow_from: float = GROW_FROM
    mapping: tuple = ()
    calibration: str = ""
    refresh_hz: float = 120.0
    display_lag_ms: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.refresh_hz) and self.refresh_hz > 0):
            raise ValueError(f"refresh_hz: got {self.refresh_hz}, allowed a number of refreshes a second > 0")
        if not (math.isfinite(self.display_lag_ms) and 0 <= self.display_lag_ms <= 1000):
            raise ValueError(f"display_lag_ms: got {self.display_lag_ms}, allowed 0..1000 ms")
        for name in ("width", "height"):  # the projector's pixels; three such buffers are kept
            if not 0 < getattr(self, name) <= MAX_PROJECTOR_SIDE:
                raise ValueError(f"{name}: got {getattr(self, name)}, allowed 1..{MAX_PROJECTOR_SIDE}")
        for name in ("margin", "grow", "grow_from"):
            value = getattr(self, name)
            if not math.isfinite(value) or value < 0:
                raise ValueError(f"{name}: got {value}, allowed a number >= 0")
        if self.margin > max(self.width, self.height):  # a wider hole darkens the whole projector
            raise ValueError(f"margin: got {self.margin:g}, allowed 0..{max(self.width, self.height)} px "
                             "(the projector's longer side)")
        if self.mapping:
            matrix = _as_matrix(self.mapping)
            object.__setattr__(self, "mapping", tuple(tuple(row) for row in matrix.tolist()))

    def matrix(self) -> np.ndarray | None:
        """The mapping as a (3, 3) array, None when the default applies."""
        return np.array(self.mapping, dtype=np.float64) if self.mapping else None


def _as_matrix(value: Any) -> np.ndarray:
    try:
        matrix = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        matrix = None
    if matrix is None or matrix.shape != (3, 3) or not np.isfinite(matrix).all():
        shown = list(value) if isinstance(value, tuple) else value
        raise ValueError(f"mapping: got {shown!r}, allowed a 3x3 matrix of finite numbers")
    if abs(np.linalg.det(matrix)) < 1e-12:
        raise ValueError("mapping: the 3x3 matrix is singular; allowed an invertible homography")
    return matrix


@dataclass(frozen=True)
class TrackConfig:
    """Tracking and latency-compensated prediction.

    enabled: track particles (Kalman filter) and draw holes from the tracks.
    predict: move each hole along its particle's velocity to the time the light is on.
    latency_ms: capture-to-light time to predict over; negative = measured by the runtime.
    confirm_hits: detections before a track is confirmed (and predicted).
    max_misses: frames a confirmed track keeps its hole without a detection (coasting).
    keep_misses: frames a confirmed track keeps its id without a detection (at least max_misses;
        unset = 12, or max_misses if more); found again after max_misses, it starts afresh
        (no old motion): see Tracker.
    max_dark: frames a confirmed track keeps its hole while its particle was under it during the
        exposure (its misses are expected); 0 = counted as ordinary misses (default; see Tracker).
    revive_frames: frames a deleted track may come back with its id when a detection appears
        where it would be (0 = off, default; better identities for counting, see Tracker).
    merge_reach: a detection holding the predictions of two or more confirmed tracks within this
        many times its radius is their particles merged in the image: it moves none of them and is
        a miss for none (0 = off; default 0.7, see Tracker).
    flux_ratio: a detection whose flux (the detector's score) is more than this many times a
        track's last, or less than its last over this, is not that track's particle -- unless its
        hole's light explains the change (0 = off; default 6; off where depth is probed, see Tracker).
    far_bright: a particle seen once, at least this many times brighter than the frame's median
        detection, may be found again anywhere within the widest gate when it and a detection of
        alike flux are each other's only candidate there: a near particle crosses the view fast
        (0 = off; default 6; off with flux_ratio, see Tracker).
    accel_floor: the least acceleration noise a track's may fall to as it is matched to its own
        motion, a share of the tracker's noise (1 = one noise for every track; default 0.1, see
        Tracker).
    miss_cost: px (at 800 px wide) a track left without a detection costs where tracks compete
        for detections: no chain of longer pairs to match one more (0 = the most matches first;
        default 30, see Tracker).
    flux_cost: px (at 800 px wide) a track's pair costs per unit of |log| of the change of its
        flux, where tracks compete for detections: of two near particles, the one alike in
        brightness is taken (0 = distance alone; default 16; off with flux_ratio, see Tracker).
    """

    enabled: bool = False
    predict: bool = True
    latency_ms: float = -1.0
    confirm_hits: int = 3
    max_misses: int = 5
    keep_misses: int | None = None
    max_dark: int = 0
    revive_frames: int = 0
    merge_reach: float = 0.7
    flux_ratio: float = 6.0
    far_bright: float = 6.0
    accel_floor: float = 0.1
    miss_cost: float = 30.0
    flux_cost: float = 16.0

    def __post_init__(self) -> None:
        if not math.isfinite(self.latency_ms):
            raise ValueError(f"latency_ms: got {self.latency_ms}, allowed a number (negative = measured)")
        if self.confirm_hits < 1:
            raise ValueError(f"confirm_hits: got {self.confirm_hits}, allowed >= 1")
        if self.max_misses < 0:
            raise ValueError(f"max_misses: got {self.max_misses}, allowed >= 0")
        if self.keep_misses is not None and self.keep_misses < self.max_misses:
            raise ValueError(f"keep_misses: got {self.keep_misses}, allowed >= max_misses ({self.max_misses})")
        if self.max_dark < 0:
            raise ValueError(f"max_dark: got {self.max_dark}, allowed >= 0 (0 = off)")
        if self.revive_frames < 0:
            raise ValueError(f"revive_frames: got {self.revive_frames}, allowed >= 0 (0 = off)")
        if not (math.isfinite(self.merge_reach) and self.merge_reach >= 0):
            raise ValueError(f"merge_reach: got {self.merge_reach}, allowed a number >= 0 (0 = off)")
        if not (math.isfinite(self.flux_ratio) and (self.flux_ratio == 0 or self.flux_ratio >= 1)):
            raise ValueError(f"flux_ratio: got {self.flux_ratio}, allowed 0 (off) or a number >= 1")
        if not (math.isfinite(self.far_bright) and (self.far_bright == 0 or self.far_bright >= 1)):
            raise ValueError(f"far_bright: got {self.far_bright}, allowed 0 (off) or a number >= 1")
        if not (math.isfinite(self.accel_floor) and 0 < self.accel_floor <= 1):
            raise ValueError(f"accel_floor: got {self.accel_floor}, allowed a share of the noise, > 0 and <= 1")
        if not (math.isfinite(self.miss_cost) and self.miss_cost >= 0):
            raise ValueError(f"miss_cost: got {self.miss_cost}, allowed a distance in px >= 0 (0 = the most matches first)")
        if not (math.isfinite(self.flux_cost) and self.flux_cost >= 0):
            raise ValueError(f"flux_cost: got {self.flux_cost}, allowed a distance in px >= 0 (0 = distance alone)")


#: the light strategies registered at import (antiscatter.strategies; validation reads the registry)
STRATEGIES = strategy_names()
#: what ``auto`` picks on the vehicle (the camera as source), with tracking and prediction on:
#: dim holes keep darkened particles visible, so tracks and (with a baseline) depth probing go
#: on, whatever the camera's timing.  ``pulse`` does better only with the camera locked to the
#: projector (``source.camera_lock``; or the IMX296's trigger on the projector's vsync), each
#: exposure inside the one refresh its holes are lifted in.  In the twin (120 Hz projector,
#: 60 Hz camera, 5 ms, mixed scene, seeds 1-6 over 5 s), co-located: locked pulse removes 0.953
#: keeping 0.959 of the scene light, dim 0.938 / 0.958; on a free-running camera
#: (``twin --camera-phase``, phases 0, 0.25, 0.5, 0.75 of a refresh) dim 0.940 / 0.958 and pulse
#: 0.856 / 0.954 (at 12 cm, probing: dim 0.811 / 0.955, pulse 0.713 / 0.907) -- it reads every other frame (each pulse waits for the first exposure to begin
#: once it is on screen) and the lifted holes stay on until that frame is read.  So ``auto``
#: keeps ``dim`` on a free-running camera.
HARDWARE_STRATEGY = "dim"
#: what ``auto`` picks with the camera locked to the projector (``source.camera_lock``): pulsed
#: holes, the twin's best co-located figures with a locked camera -- run's locked loop (``twin
#: --camera-lock``) 0.954 / 0.959 against dim's 0.938 / 0.958; with a projector that lags a
#: refresh (``pattern.display_lag_ms``) the loop puts each light out a frame ahead and still reads
#: every frame, 0.940 / 0.959 against dim's 0.906 / 0.960; lagging 12 ms it puts each light out
#: after its pattern, for the exposure after the next, and still reads every frame, 0.940 / 0.959
#: (dim 0.906 / 0.960).  A lag past that (14 ms with 5 ms of processing) leaves it every other
#: frame, 0.832 / 0.954 against dim's 0.906 / 0.960: ``auto`` then keeps ``dim``
#: (:func:`locked_light_reaches`)
LOCKED_STRATEGY = "pulse"
#: locked: how long after its exposure ends a frame is taken to be read, and a flip asked for
READ_MARGIN_S = FLIP_MARGIN_S


#: locked: the processing a frame is taken to need when its light must go out after its pattern,
#: before the next frame is read (:func:`locked_light_reaches`; the twin's default latency)
PROCESSING_BUDGET_S = 5e-3


def locked_light_reaches(source: "SourceConfig", pattern: "PatternConfig") -> bool:
    """With the camera locked to the projector, whether an exposure light can reach each exposure
    so that every frame is read.  Each exposure sits in the middle of a refresh's light, which
    comes ``display_lag_ms`` after its flip.  Either the light for the exposure after the frame
    just read goes out at a flip after the read (its exposure's end plus ``READ_MARGIN_S``) -- the
    frame's own light, or the last frame's put out ahead (runtime.light_ahead): lag < frame period
    - (refresh + exposure) / 2 - margin, 9.5 ms at 60 / 120 Hz with a 4 ms exposure -- or the
    frame's light goes out after its pattern, before the next frame is read, for the exposure
    after that (runtime.light_after): the frame read, processed (``PROCESSING_BUDGET_S``) and its
    pattern flipped a refresh before that light's flip: lag <= 2 frame periods - (3 refreshes +
    exposure) / 2 - margin - budget, 12.8 ms there."""
    period, refresh = 1.0 / source.camera_fps, 1.0 / pattern.refresh_hz
    exposure, lag = source.camera_exposure_ms / 1e3, pattern.display_lag_ms / 1e3
    return (light_ahead_reaches(source, pattern)
            or lag <= 2 * period - (3 * refresh + exposure) / 2 - READ_MARGIN_S - PROCESSING_BUDGET_S)


def light_ahead_reaches(source: "SourceConfig", pattern: "PatternConfig", slack_s: float = 0.0) -> bool:
    """With the camera locked to the projector, whether a light put out after the frame is read
    reaches the next exposure (lag < frame period - (refresh + exposure) / 2 - ``READ_MARGIN_S``,
    less ``slack_s``); when not, each frame's light goes out after its pattern (runtime.light_after)."""
    period, refresh = 1.0 / source.camera_fps, 1.0 / pattern.refresh_hz
    exposure = source.camera_exposure_ms / 1e3
    return pattern.display_lag_ms / 1e3 < period - (refresh + exposure) / 2 - READ_MARGIN_S - slack_s


@dataclass(frozen=True)
class LightConfig:
    """How the lamp works around the closed-loop catch (a particle dark in its hole is
    lost by the next frame's detector; see ``antiscatter twin``).

    strategy: ``auto`` (default: ``dim`` with tracking on with the camera as source, ``none``
        otherwise -- files and the simulator do not see the light), ``none`` (holes from this frame's detections), ``dim`` (holes at
        ``dim_level`` of full light, so dimmed particles stay visible), ``pulse`` (holes at
        ``dim_level`` while the camera exposes, dark the rest of the time: before each capture
        the lamp shows the last pattern with its holes lifted, after it the pattern again; needs
        mode ``single``), ``flash`` (before
        each capture the lamp shows a uniform ``flash_level`` frame and the camera is read
        under it, then the pattern again; needs mode ``single``) or ``coast``
        (tracked holes stay on particles that went dark; turns tracking on).
    dim_level, flash_level: fractions of full light, 0..1.  dim_level 0.1 (default): in the twin
        (co-located, 5 ms) it removed 0.04-0.10 more backscatter than 0.2 on every preset (bubbles,
        snow, sand, mixed, textured) with scene light kept within 0.01; at 0.05 removal rose
        further but on the seabed kept fell by 0.07 (the holes then fall below the detector's
        10 % "unlit" floor, and the noise it divides up there comes back as false holes).
    compensate: tell the detector the light each exposure got -- the pattern shown, taken back
        to camera pixels through the inverse mapping -- so the holes' imprint on the background
        is not taken for particles (mode single); None = on with the camera as source (files and
        the simulator never saw the pattern) and a mapping or calibration is configured (with the
        guessed identity mapping the light map would be wrong).
    depth: ``auto`` (default: ``probe`` where it can run -- strategy dim or pulse, mode single, a
        calibration with a baseline -- else ``fixed``), ``fixed`` (holes where the mapping puts a
        particle at the calibration's working distance) or ``probe`` (each track's depth found by bisection along its epipolar line,
        judged by the next exposures: needs strategy dim or pulse, tracking, mode single and a calibration
        with a baseline, i.e. measured at two distances or more; see antiscatter.probe).
    near_m, far_m: the working distances a particle may be at (probe).
    levels: ``auto`` (default: ``adaptive`` with the camera as source, ``fixed`` otherwise --
        files and the simulator never saw the light, so every particle would come back as bright
        under its hole as lit and every hole fall to ``min_level``), ``adaptive`` -- with ``dim``
        or ``pulse`` and tracking on, each hole (or depth probe) leaves its own particle just the
        light it needs to stay visible, from the detector's flux of it under its hole
        (:class:`~antiscatter.levels.HoleLevels`), between ``min_level`` and ``dim_level``: most of
        the backscatter comes from near, bright particles that are seen at a fraction of what the
        faintest need -- or ``fixed``: ``dim_level`` for every hole.  Detectors whose scores are
        not a flux (``seed``) keep ``dim_level``.
    min_level: the least light an adaptive hole leaves its particle, 0..1 (capped at ``dim_level``).
    rest: adaptive levels: frames a confirmed track's hole is left fully dark after each frame that
        found its particle, the tracker carrying it along its predicted path, before it is dimmed
        and looked at again (unset: 1 with pulsed holes, 2 with dim ones, ``rest_for``; 0 = always
        dimmed; not while probing depth; see :mod:`antiscatter.levels`).
    min_worth: probe: draw a hole only where the share of the frame's backscatter it withholds is
        at least this many times the share of the projector's field it darkens (0 = every hole;
        see :attr:`antiscatter.probe.DepthProbe.min_worth`).
    """

    strategy: str = "auto"
    dim_level: float = 0.1
    flash_level: float = 0.25
    compensate: bool | None = None
    depth: str = "auto"
    near_m: float = 0.3
    far_m: float = 3.0
    levels: str = "auto"
    min_level: float = MIN_LEVEL
    rest: int | None = None
    min_worth: float = MIN_WORTH

    def __post_init__(self) -> None:
        if self.levels not in ("auto", *LEVELS):
            raise ValueError(f"levels: got {self.levels!r}, allowed auto, {', '.join(LEVELS)}")
        if self.strategy not in ("auto", *strategy_names()):
            raise ValueError(f"strategy: got {self.strategy!r}, allowed auto, {', '.join(strategy_names())}")
        if self.depth not in ("auto", "fixed", "probe"):
            raise ValueError(f"depth: got {self.depth!r}, allowed auto, fixed, probe")
        if not (math.isfinite(self.near_m) and math.isfinite(self.far_m) and 0 < self.near_m < self.far_m):
            raise ValueError(f"near_m, far_m: got {self.near_m}, {self.far_m}; allowed 0 < near_m < far_m")
        for key in ("dim_level", "flash_level", "min_level"):
            value = getattr(self, key)
            if not (math.isfinite(value) and 0 <= value <= 1):
                raise ValueError(f"{key}: got {value}, allowed a number 0..1")
        if self.rest is not None and (isinstance(self.rest, bool) or not isinstance(self.rest, int) or self.rest < 0):
            raise ValueError(f"rest: got {self.rest!r}, allowed a whole number of frames >= 0")
        if not (math.isfinite(self.min_worth) and self.min_worth >= 0):
            raise ValueError(f"min_worth: got {self.min_worth}, allowed a number >= 0 (0 = every hole drawn)")


@dataclass(frozen=True)
class OutputConfig:
    """outputs: light outputs, any of framebuffer[:/dev/fbN], window, files:PATH, none, auto."""

    outputs: tuple[str, ...] = ("auto",)

    def __post_init__(self) -> None:
        if not self.outputs:
            raise ValueError("outputs: got an empty list, allowed one or more output names")


@dataclass(frozen=True)
class RunConfig:
    """The runtime loop.

    frames: stop after this many frames (0 = until the source ends or a stop).
    fps: pace the loop at this rate, frames per second (0 = as fast as possible).
    nice: process niceness to ask for (-20 highest .. 19), None = leave it.
    metrics: path of the per-frame metrics CSV, empty for none.
    detections: path of the detections CSV (frame,time,x,y,radius), empty for none.
    mode: ``single`` (one thread; default: it wins `bench --modes` on the simulator) or ``threads``
        (capture, processing and output overlap in three threads) or ``processes`` (detection in a
        worker process fed through shared memory) or ``processes-pickle`` (the report's design:
        frames pickled through a queue, for comparison).
    rt_priority: SCHED_FIFO priority 1..99, None = leave it.
    cpus: CPU numbers to run on, e.g. "2,3"; empty = all.
    mlock: lock the process's memory (no page faults in the loop).
    web: serve the control panel on ``[HOST:]PORT`` (host 127.0.0.1 unless given); empty = none.
    record_to: the .mkv the panel's Record button writes the input frames to (default: a
        timestamped file in the current folder).
    mcap: path of an MCAP file of ROS 2 messages (frames, detections, pattern, metrics per frame;
        :mod:`antiscatter.mcap_out`), empty for none.
    threads: threads detection runs on, 1 to four per CPU (default 1: one core's worth, as the
        light loop's budget is counted): the detector's frame-wide filters in bands of the frame
        and OpenCV's own functions; the detections are the same on any number
        (docs/decisions/008-threads.md).
    """

    frames: int = 0
    fps: float = 0.0
    nice: int | None = None
    metrics: str = ""
    detections: str = ""
    mode: str = "single"
    rt_priority: int | None = None
    cpus: str = ""
    mlock: bool = False
    web: str = ""
    record_to: str = ""
    mcap: str = ""
    threads: int = 1

    def __post_init__(self) -> None:
        from .detection import check_threads

        check_threads(self.threads)
        if self.mode not in ("single", "threads", "processes", "processes-pickle"):
            raise ValueError(f"mode: got {self.mode!r}, allowed single, threads, processes, processes-pickle")
        if self.rt_priority is not None and not 1 <= self.rt_priority <= 99:
            raise ValueError(f"rt_priority: got {self.rt_priority}, allowed 1..99")
        if self.cpus:
            try:
                cpus = [int(c) for c in self.cpus.split(",")]
            except ValueError:
                cpus = [-1]
            if not cpus or min(cpus) < 0:
                raise ValueError(f"cpus: got {self.cpus!r}, allowed CPU numbers separated by commas, e.g. 2,3")
            count = os.cpu_count() or 1
            if max(cpus) >= count:
                raise ValueError(f"cpus: got {self.cpus!r}, allowed CPU numbers 0..{count - 1} (this machine has "
                                 f"{count})")
        if self.frames < 0:
            raise ValueError(f"frames: got {self.frames}, allowed >= 0 (0 = no limit)")
        if not math.isfinite(self.fps) or self.fps < 0:
            raise ValueError(f"fps: got {self.fps}, allowed >= 0 (0 = as fast as possible)")
        if self.nice is not None and not -20 <= self.nice <= 19:
            raise ValueError(f"nice: got {self.nice}, allowed -20..19")


@dataclass(frozen=True)
class Config:
    """Everything ``antiscatter run`` needs."""

    source: SourceConfig = field(default_factory=SourceConfig)
    detector: DetectorConfig = field(default_factory=DetectorConfig)
    detector_params: Any = None
    pattern: PatternConfig = field(default_factory=PatternConfig)
    output: OutputConfig = field(default_factory=OutputConfig)
    run: RunConfig = field(default_factory=RunConfig)
    track: TrackConfig = field(default_factory=TrackConfig)
    light: LightConfig = field(default_factory=LightConfig)
    notes: tuple[str, ...] = ()  # what load_config decided that the user should hear of (run prints them)


_SECTIONS = {"source": SourceConfig, "detector": DetectorConfig, "pattern": PatternConfig,
             "output": OutputConfig, "run": RunConfig, "track": TrackConfig, "light": LightConfig}


def _type_name(tp: Any) -> str:
    return {int: "an integer", float: "a number", bool: "true or false", str: "a string"}.get(
        tp, getattr(tp, "__name__", str(tp)))


def _coerce(value: Any, tp: Any, key: str) -> Any:
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if value is None:
            return None
        return _coerce(value, args[0], key)
    if tp is bool:
        if isinstance(value, bool):
            return value
    elif tp is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
    elif tp is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
    elif tp is str:
        if isinstance(value, str):
            return value
    elif origin is tuple or tp is tuple:
        args = typing.get_args(tp)
        if isinstance(value, str) and args[:1] == (str,):
            return (value,)
        if isinstance(value, (list, tuple)):
            if args[:1] == (str,) and not all(isinstance(v, str) for v in value):
                raise ValueError(f"{key}: got {value!r}, allowed a list of strings")
            return tuple(value)
        raise ValueError(f"{key}: got {value!r}, allowed a list")
    else:
        return value
    raise ValueError(f"{key}: got {value!r}, allowed {_type_name(tp)}")


def build_section(cls: type, data: dict[str, Any], *, prefix: str) -> Any:
    """Build dataclass ``cls`` from ``data``, rejecting unknown keys and bad values.

    ``prefix`` ("detector.seed") is put before key names in messages.
    Raises UsageError with one line naming the key, the value and what is allowed.
    """
    hints = typing.get_type_hints(cls)
    known = {f.name: f for f in fields(cls)}
    kwargs = {}
    for key, value in data.items():
        if key not in known:
            raise UsageError(f"unknown key {prefix}.{key}; allowed: {', '.join(known)}")
        try:
            kwargs[key] = _coerce(value, hints[key], key)
        except ValueError as exc:
            raise UsageError(f"{prefix}.{exc}") from None
    try:
        return cls(**kwargs)
    except ValueError as exc:
        raise UsageError(f"{prefix}.{exc}") from None


def load_config(path: str | Path | None = None, overrides: dict[str, dict[str, Any]] | None = None,
                detector_overrides: dict[str, Any] | None = None) -> Config:
    """Read the TOML file (if any), apply ``overrides`` per section, validate everything.

    overrides: {"run": {"frames": 300}, ...} from command-line flags (None values ignored).
    detector_overrides: parameters of the chosen detector, from ``--param KEY=VALUE``.
    """
    from .detection import DETECTORS, detector_entry

    data: dict[str, Any] = {}
    where = "config"
    if path is not None:
        path = Path(path)
        where = str(path)
        try:
            with path.open("rb") as fh:
                data = tomllib.load(fh)
        except FileNotFoundError:
            raise UsageError(f"{path}: no such config file") from None
        except IsADirectoryError:
            raise UsageError(f"{path}: is a folder, expected a TOML config file") from None
        except tomllib.TOMLDecodeError as exc:
            raise UsageError(f"{path}: not valid TOML ({exc})") from None
        except UnicodeDecodeError as exc:
            raise UsageError(f"{path}: not UTF-8 text (byte {exc.start}); allowed a UTF-8 TOML config file") from None
    for key, value in data.items():
        if key not in _SECTIONS:
            raise UsageError(f"{where}: unknown section [{key}]; allowed: {', '.join(_SECTIONS)}")
        if not isinstance(value, dict):
            raise UsageError(f"{where}: {key} must be a [{key}] table")
    sections: dict[str, Any] = {}
    raw_detector = dict(data.get("detector", {}))
    nested = {k: raw_detector.pop(k) for k in list(raw_detector) if isinstance(raw_detector[k], dict)}
    for name, cls in _SECTIONS.items():
        section = dict(raw_detector if name == "detector" else data.get(name, {}))
        flags = {k: v for k, v in (overrides or {}).get(name, {}).items() if v is not None}
        try:
            sections[name] = build_section(cls, {**section, **flags}, prefix=name)
            if path is not None and section and flags:  # the file's own values, as if no flag overrode them
                build_section(cls, {**flags, **section}, prefix=name)
        except UsageError as exc:
            raise UsageError(f"{where}: {exc}" if path is not None else str(exc)) from None
    detector_name = sections["detector"].name
    detector_entry(detector_name)
    for other in nested:
        if other not in DETECTORS:
            raise UsageError(f"{where}: unknown section [detector.{other}]; allowed: "
                             + ", ".join(f"detector.{n}" for n in sorted(DETECTORS)))
    params_data = dict(nested.get(detector_name, {}))
    if params_data and detector_overrides:  # the file's own values, as if no --param overrode them
        try:
            build_section(DETECTORS[detector_name].params, {**detector_overrides, **params_data},
                          prefix=f"detector.{detector_name}")
        except UsageError as exc:
            raise UsageError(f"{where}: {exc}") from None
    params_data.update(detector_overrides or {})
    try:
        params = build_section(DETECTORS[detector_name].params, params_data,
                               prefix=f"detector.{detector_name}")
    except UsageError as exc:
        raise UsageError(f"{where}: {exc}" if path is not None and not detector_overrides else str(exc)) from None
    light = sections["light"]
    camera = sections["source"].spec.split(":")[0] == "camera"
    track = sections["track"]
    lock = sections["source"].camera_lock
    notes: tuple[str, ...] = ()
    if light.strategy == "auto":
        if lock and camera:
            _check_lock(sections["source"], sections["output"], sections["pattern"],
                        dataclasses.replace(light, strategy=LOCKED_STRATEGY))
            if not locked_light_reaches(sections["source"], sections["pattern"]):
                # pulse would read every other frame: dim holes, which need no lock, do better
                lock = False
                sections["source"] = dataclasses.replace(sections["source"], camera_lock=False)
                notes = (f"pattern.display_lag_ms {sections['pattern'].display_lag_ms:g}: no exposure light can "
                         "reach each exposure (the lag must be at most two frame periods less one and a half "
                         "refreshes, half the exposure, 1 ms and 5 ms of processing: 12.8 ms at 60 / 120 Hz with "
                         "4 ms exposures), so strategy auto takes dim holes without the camera lock (in the twin "
                         "at a 14 ms lag: 0.906 removed against locked pulse's 0.832, every other frame)",)
        light = dataclasses.replace(light, strategy=(LOCKED_STRATEGY if lock else HARDWARE_STRATEGY) if camera
                                    else "none")
        if camera:
            track = dataclasses.replace(track, enabled=True)
    if light.depth == "auto":
        probe = (strategy_entry(light.strategy).visible and sections["run"].mode == "single"
                 and _has_baseline(sections["pattern"].calibration))
        light = dataclasses.replace(light, depth="probe" if probe else "fixed")
    if light.rest is None:  # the strategy's own
        light = dataclasses.replace(light, rest=rest_for(light.strategy))
    if light.levels == "auto":  # only where the camera sees the light
        light = dataclasses.replace(light, levels="adaptive" if camera else "fixed")
    if light.compensate is None:  # only with a real mapping: a guessed one would put the light map wrong
        light = dataclasses.replace(light, compensate=camera and bool(sections["pattern"].mapping))
    if camera and sections["source"].camera_lores and sections["run"].mode.startswith("processes"):
        raise UsageError(f"source.camera_lores: goes with run.mode single or threads (a worker process is sent "
                         f"the full frame and pools it itself), got mode {sections['run'].mode}")
    strategy = strategy_entry(light.strategy)
    if strategy.exposing and sections["run"].mode != "single":
        raise UsageError(f"light.strategy: {light.strategy} needs run.mode single (the exposure's light, the "
                         f"capture and the pattern take turns), got mode {sections['run'].mode}")
    if lock:
        _check_lock(sections["source"], sections["output"], sections["pattern"], light)
    if strategy.tracks and not track.enabled:
        track = dataclasses.replace(track, enabled=True)  # coasting is what the tracker does
    if light.depth == "probe":
        if not strategy.visible or sections["run"].mode != "single":
            raise UsageError(f"light.depth: probe needs light.strategy {strategies_that('visible')} (a probed "
                             "particle must stay "
                             f"visible) and run.mode single; got strategy {light.strategy}, mode "
                             f"{sections['run'].mode}")
        if not _has_baseline(sections["pattern"].calibration):
            raise UsageError("light.depth: probe needs a calibration with a baseline (pattern.calibration, "
                             "--calibration FILE from 'antiscatter calibrate' at two or more distances)")
        track = dataclasses.replace(track, enabled=True)
    return Config(source=sections["source"], detector=sections["detector"], detector_params=params,
                  pattern=sections["pattern"], output=sections["output"], run=sections["run"],
                  track=track, light=light, notes=notes)


def _check_lock(source: "SourceConfig", output: Any, pattern: "PatternConfig", light: "LightConfig") -> None:
    """What source.camera_lock needs, each missing piece a one-line UsageError (mode single comes with
    pulse and flash)."""
    def fail(why: str) -> None:
        raise UsageError(f"source.camera_lock: {why}")

    if source.spec.split(":")[0] != "camera":
        fail(f"locks the camera (source camera), got source {source.spec!r}")
    if "kms" not in output.outputs:
        fail("needs output kms (its flips say when the projector's refreshes are), got "
             + ", ".join(output.outputs))
    if not strategy_entry(light.strategy).exposing:
        fail(f"times the pulse or the flash to the exposure: needs light.strategy {strategies_that('exposing')}, "
             f"got {light.strategy}")
    refresh_ms = 1e3 / pattern.refresh_hz
    if not 0 < source.camera_exposure_ms <= refresh_ms:
        fail(f"needs a fixed camera_exposure_ms inside one projector refresh (0 < exposure <= {refresh_ms:.2f} ms "
             f"at {pattern.refresh_hz:g} Hz), got {source.camera_exposure_ms or 'automatic'}")
    turns = pattern.refresh_hz / source.camera_fps
    if abs(turns - round(turns)) > 1e-3 or round(turns) < 1:
        fail(f"needs the camera's frame period a whole number of projector refreshes, got camera_fps "
             f"{source.camera_fps:g} with pattern.refresh_hz {pattern.refresh_hz:g}")


def _has_baseline(path: str) -> bool:
    """Whether the calibration file at ``path`` (empty = none) knows the camera-projector baseline."""
    if not path:
        return False
    from .calibration import load_calibration

    return load_calibration(path).baseline_m is not None


def parse_param(text: str, params_cls: type, *, detector: str) -> tuple[str, Any]:
    """``KEY=VALUE`` from ``--param`` -> (key, typed value) for ``params_cls``."""
    key, sep, raw = text.partition("=")
    key = key.strip().replace("-", "_")
    known = {f.name for f in fields(params_cls)}
    if not sep or not key:
        raise UsageError(f"--param {text!r}: expected KEY=VALUE, e.g. threshold=180")
    if key not in known:
        raise UsageError(f"unknown key detector.{detector}.{key}; allowed: {', '.join(sorted(known))}")
    tp = typing.get_type_hints(params_cls)[key]
    raw = raw.strip()
    try:
        if tp is bool:
            lowered = raw.lower()
            if lowered not in ("true", "false", "1", "0", "yes", "no", "on", "off"):
                raise ValueError
            value: Any = lowered in ("true", "1", "yes", "on")
        elif tp is int:
            value = int(raw)
        elif tp is float:
            value = float(raw)
        else:
            value = raw
    except ValueError:
        raise UsageError(f"detector.{detector}.{key}: got {raw!r}, allowed {_type_name(tp)}") from None
    return key, value

