"""The Raspberry Pi camera through Picamera2 (``camera``), imported lazily.

Picamera2 is not usable from PyPI off the Pi: on Raspberry Pi OS it is the
``python3-picamera2`` package, seen from a virtual environment made with
``--system-site-packages``.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Callable

import numpy as np

from ..detection import Pooled
from ..errors import UsageError
from .base import Frame, FrameSource

__all__ = ["CameraSource", "load_picamera2", "camera_controls", "exposure_fault", "frame_us", "lores_fault",
           "GAIN_RANGE", "DEFAULT_SIZE"]

#: the camera's frame size unless one is given, (width, height) px: half the IMX296 sensor, as in the report
DEFAULT_SIZE = (728, 544)

#: the sensor's analogue gain, lowest to highest (IMX296)
GAIN_RANGE = (1.0, 64.0)


def frame_us(fps: float) -> int:
    """The frame period in whole microseconds, as the camera's ``FrameDurationLimits`` take it."""
    return int(round(1e6 / fps))


def exposure_fault(fps: float, exposure_ms: float | None, gain: float | None) -> str | None:
    """What is wrong with a fixed exposure (None: automatic) and gain (None: 1.0 with a fixed
    exposure) at ``fps``: ``"exposure"`` (not within 0 < exposure <= the frame period),
    ``"gain"`` (outside ``GAIN_RANGE``), ``"gain alone"`` (a gain with automatic exposure), or
    None.  The one rule; the config and :func:`camera_controls` word it each for their keys."""
    if exposure_ms is None:
        return None if gain is None else "gain alone"
    if not (math.isfinite(exposure_ms) and 0 < exposure_ms * 1e3 <= frame_us(fps)):
        return "exposure"
    if gain is not None and not (math.isfinite(gain) and GAIN_RANGE[0] <= gain <= GAIN_RANGE[1]):
        return "gain"
    return None


def lores_fault(size: tuple[int, int], lores: tuple[int, int]) -> str | None:
    """Why the ISP cannot give a ``lores`` YUV420 stream of ``lores`` (width, height) px beside a main
    stream of ``size`` as the detector needs it, or None.  The ISP only scales down (Picamera2
    refuses a lores larger than main) and YUV420 halves the chroma both ways (even sides); the
    detector maps its particles back by a whole factor, the same both ways (main = factor x lores)."""
    (w, h), (lw, lh) = size, lores
    if lw <= 0 or lh <= 0 or lw % 2 or lh % 2:
        return "its sides must be even (YUV420)"
    if lw > w or lh > h:
        return f"larger than the main stream's {w}x{h} (the ISP only scales down)"
    if w % lw or h % lh or w // lw != h // lh or w // lw < 2:
        return (f"the main stream's {w}x{h} must be a whole multiple of it, 2 or more, the same both ways "
                "(the detections are mapped back by that factor)")
    return None


def load_picamera2() -> tuple[Callable[[], Any], Any]:
    """The ``Picamera2`` and ``MappedArray`` classes, or a one-line UsageError off the Pi."""
    try:
        from picamera2 import MappedArray, Picamera2  # type: ignore[import-not-found]
    except ImportError:
        raise UsageError("source 'camera' needs the picamera2 package on a Raspberry Pi "
                         "(sudo apt install python3-picamera2, and a venv made with "
                         "--system-site-packages); use sim, webcam:N, a folder or a video here") from None
    return Picamera2, MappedArray


def camera_controls(fps: float, exposure_ms: float | None = None, gain: float | None = None) -> dict[str, Any]:
    """The libcamera controls for a frame rate and, when given, a fixed exposure and gain; a bad
    value is a one-line UsageError naming it and what is allowed."""
    period = frame_us(fps)
    controls: dict[str, Any] = {"FrameDurationLimits": (period, period)}
    fault = exposure_fault(fps, exposure_ms, gain)
    if fault == "gain alone":
        raise UsageError("camera gain: goes with a fixed exposure (camera_exposure_ms)")
    if fault == "exposure":
        raise UsageError(f"camera exposure {exposure_ms} ms: allowed 0 < exposure <= the frame period "
                         f"({period / 1e3:.2f} ms at {fps:g} frames/s)")
    if fault == "gain":
        raise UsageError(f"camera gain {gain}: allowed {GAIN_RANGE[0]} to {GAIN_RANGE[1]:g}")
    if exposure_ms is None:
        return controls
    gain = 1.0 if gain is None else gain
    controls.update({"AeEnable": False, "ExposureTime": int(round(exposure_ms * 1e3)), "AnalogueGain": float(gain)})
    return controls


class CameraSource(FrameSource):
    """Frames from the Pi camera, tuned for latency.

    size: (width, height), default (728, 544) = half the IMX296 sensor, as in the report.
    fps: frame rate, set explicitly through ``FrameDurationLimits`` (a video
        configuration otherwise defaults to 30 fps).
    colour: False (default) streams YUV420 and hands on the Y plane, read in
        place through ``MappedArray`` -- grey without any colour conversion, one
        plane copied out of the camera buffer so the buffer goes straight back;
        True streams ISP-processed BGR (Picamera2's "RGB888" is B, G, R in memory).
    exposure_ms: a fixed exposure time, milliseconds (0 < exposure <= the frame period), with the
        camera's automatic exposure and gain off; None (default): automatic.  The light
        strategies that time the lamp to the exposure (``pulse``, ``flash``) need it short and
        fixed: automatic exposure stretches it towards the frame period over dark water, across
        several projector refreshes.
    gain: the analogue gain with a fixed exposure (1.0 to 64; default 1.0).
    lores: (width, height) of a second, ``lores`` YUV420 stream the ISP scales from the same frame,
        whose Y plane each frame carries (``Frame.pooled``, with the main Y plane as its full
        plane) so the detector never pools the full frame; the detector's working size
        (``Detector.working_size``); None (default): main stream only.  Grey main stream only
        (``colour`` False); a size :func:`lores_fault` refuses is a one-line UsageError.
    picamera2, mapped_array: the Picamera2 and MappedArray classes (tests pass
        fakes); loaded lazily when None.

    Three buffers and ``queue=False``: a frame handed out is never a stale
    queued one.  Frames carry the middle of their exposure, from the sensor
    timestamp (``SensorTimestamp`` metadata, ns, the ``CLOCK_MONOTONIC`` clock of
    ``time.monotonic_ns()``: the end of the exposure) less half the ``ExposureTime``,
    and the exposure's length, when the camera reports them; the same time is the frame's
    ``media_time_ns`` (its true time, written into recordings and CSVs), with ``AnalogueGain``.
    """

    name = "camera"
    live = True

    def __init__(self, *, size: tuple[int, int] = DEFAULT_SIZE, fps: float = 60.0, colour: bool = False,
                 exposure_ms: float | None = None, gain: float | None = None, lores: tuple[int, int] | None = None,
                 picamera2: Callable[[], Any] | None = None, mapped_array: Any = None) -> None:
        controls = camera_controls(fps, exposure_ms, gain)
        streams: dict[str, Any] = {}
        if lores is not None:
            lores = (int(lores[0]), int(lores[1]))
            fault = "goes with the grey (Y) main stream, not camera colour" if colour else lores_fault(size, lores)
            if fault:
                raise UsageError(f"camera lores {lores[0]}x{lores[1]} beside main {size[0]}x{size[1]}: {fault}")
            streams["lores"] = {"size": lores, "format": "YUV420"}
        self.lores = lores
        if picamera2 is None:
            picamera2, mapped_array = load_picamera2()
        factory = picamera2
        self._mapped = mapped_array
        self.colour = colour
        try:
            self._cam = factory()
        except (RuntimeError, IndexError, OSError) as exc:
            raise UsageError(f"source 'camera': no camera could be opened ({exc})") from None
        # Picamera2's "RGB888" is stored B, G, R per pixel: OpenCV's BGR order.
        config = self._cam.create_video_configuration(
            main={"size": tuple(size), "format": "RGB888" if colour else "YUV420"}, buffer_count=3, queue=False,
            controls=controls, **streams)
        try:
            self._cam.configure(config)
        except RuntimeError as exc:  # Picamera2 / libcamera refusing the streams (a lores it cannot make)
            self._cam.close()
            raise UsageError(f"source 'camera': the camera refused its configuration ({exc})") from None
        if lores is not None:
            self._check_adjusted(config, size, lores)
        self._cam.start()
        self.size = (int(size[0]), int(size[1]))
        self.fps = float(fps)
        self._count = 0

    def read(self) -> Frame | None:
        request = self._cam.capture_request()
        try:
            if self.colour or self._mapped is None:
                image = request.make_array("main")
                if not self.colour:
                    image = image[: self.size[1], : self.size[0]].copy()
            else:
                with self._mapped(request, "main") as mapped:
                    # YUV420: the first `height` rows are Y; copy that plane only
                    image = mapped.array[: self.size[1], : self.size[0]].copy()
            pooled = None if self.lores is None else self._read_lores(request, image)
            metadata = request.get_metadata()
        finally:
            request.release()
        stamp = metadata.get("SensorTimestamp")
        # SensorTimestamp marks the start of the readout, i.e. the end of the exposure, on the
        # global-shutter IMX296 (the ISP's start-of-frame interrupt; picamera2 issue 821):
        # the frame's time is the exposure's middle, ExposureTime (us) before that by half
        exposure_ns = int(round(float(metadata.get("ExposureTime") or 0) * 1e3)) if stamp else 0
        gain = float(metadata.get("AnalogueGain") or 0.0)
        if stamp:  # the sensor's time is the frame's true time (media_time_ns): the same clock
            middle = int(stamp) - exposure_ns // 2
            frame = Frame(image, self._count, middle, exposure_ns, media_time_ns=middle, analogue_gain=gain)
        else:  # no sensor time: the read time, the same clock
            stamp = self.now_ns()
            frame = Frame(image, self._count, stamp, media_time_ns=stamp, analogue_gain=gain)
        if pooled is not None:
            frame = dataclasses.replace(frame, pooled=pooled)
        self._count += 1
        return frame

    def _check_adjusted(self, config: Any, size: tuple[int, int], lores: tuple[int, int]) -> None:
        """A one-line UsageError when libcamera adjusted the main or lores size it was asked for
        (Picamera2 then only logs it and writes the sizes it gives back into ``config``): the
        detections would be mapped back by the wrong factor."""
        try:
            given = {name: tuple(int(v) for v in config[name]["size"]) for name in ("main", "lores")}
        except (KeyError, TypeError):  # a configuration object of another form: taken as asked
            return
        asked = {"main": tuple(size), "lores": tuple(lores)}
        if given != asked:
            self._cam.close()
            raise UsageError("source 'camera': the camera gives " + ", ".join(
                f"{name} {given[name][0]}x{given[name][1]}" for name in given)
                + f", not the main {size[0]}x{size[1]} and lores {lores[0]}x{lores[1]} asked; allowed sizes it "
                "keeps (try --size 1456x1088 or 728x544)")

    def _read_lores(self, request: Any, full: np.ndarray) -> Pooled:
        """The lores stream's Y plane copied out of the request (its first rows, the row padding
        cut off), with ``full`` (the main Y plane) as its full plane."""
        w, h = self.lores
        if self._mapped is None:
            plane = request.make_array("lores")[:h, :w].copy()
        else:
            with self._mapped(request, "lores") as mapped:
                plane = mapped.array[:h, :w].copy()
        return Pooled(plane, self.size[0] // w, full)

    @property
    def shortest_frame_ns(self) -> int:
        """The shortest frame the sensor can give in this configuration (``FrameDurationLimits``'
        minimum, us), 0 when the camera does not say."""
        limits = getattr(self._cam, "camera_controls", {}).get("FrameDurationLimits")
        return int(limits[0]) * 1000 if limits and limits[0] else 0

    def set_frame_duration_ns(self, duration_ns: int) -> None:
        """Ask for frames of ``duration_ns`` (whole us) from now on; the sensor applies it a few
        frames later (the software phase lock, :mod:`antiscatter.lock`)."""
        us = int(round(duration_ns / 1000))
        self._cam.set_controls({"FrameDurationLimits": (us, us)})

    def close(self) -> None:
        try:
            self._cam.stop()
        finally:
            self._cam.close()
