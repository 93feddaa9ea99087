"""Realistic backscatter scenes: 3-D particles under the vehicle's lamp, seen by a camera.

Physics, per frame:

* particles (bubbles, marine snow, sand) live in 3-D in front of a pinhole
  camera (horizontal field ``hfov_deg``); pixel size and speed scale with
  1 / depth;
* the lamp sits at the camera: a particle's brightness is
  ``brightness * albedo * colour * cone(x, y) * exp(-2 * attenuation * Z) / Z**2``
  (inverse square, water attenuation out and back, per colour channel, and the
  lamp's cone lighting the frame unevenly);
* defocus: Gaussian blur of sigma ``defocus * (W / 800) * |focus_m / Z - 1|`` pixels;
* motion blur: the sprite is smeared along its image velocity over ``exposure_s``;
* the background (water, seabed, tank padding, or the user's image) is lit by
  the same lamp cone, tinted by the water colour;
* the vehicle may move (``vehicle_m_s``, ``yaw_deg_s``): the water and its particles
  move the other way in the camera's frame, and a background surface (seabed,
  padding, an image) ``ground_m`` away pans, turns, grows and brightens as the
  view moves over it and closes on it;
* the sensor adds shot noise (variance ``shot_noise * signal``) and read noise
  (``read_noise`` grey levels), then clips at 255 (``saturate``) or rolls the
  highlights off softly; optional JPEG artefacts (``jpeg_quality``).

Truth per particle: the mid-exposure centre, equivalent radius and visibility
of its footprint (the pixels where it adds at least ``FOOTPRINT`` of its own
peak), depth, kind, peak brightness and its label in the mask.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from .appearance import RADIUS, bubble_templates, pyramid, sand_templates, snow_templates
from .background import BACKGROUNDS, gradient, load_background, padding, seabed
from .truth import KINDS, Truth

__all__ = ["KindConfig", "SceneConfig", "RealisticScene", "FOOTPRINT"]

#: A pixel belongs to a particle's footprint where it adds at least this share of its peak.
FOOTPRINT = 0.2

#: at most this many samples a pixel across for particles smaller than a pixel (see _sprite)
MAX_SUPERSAMPLE = 64

#: a moving view's background surface is this many times the view's size (room to pan, turn and
#: back away over it)
GROUND_SCALE = 2

#: a particle closer than this to the lens (m) is gone (the vehicle went through it)
MIN_DEPTH_M = 0.1


@dataclass(frozen=True)
class KindConfig:
    """One particle population.

    count: particles kept in view.
    size_mm: physical radius range, millimetres (uniform).
    depth_m: distance range from the camera, metres (uniform).
    speed: speed range of each particle's own motion, m/s.
    direction_deg: mean image-plane direction of that motion (0 = right, 90 = down, -90 = up).
    spread_deg: random spread around the direction (uniform +-).
    albedo: reflectance range (uniform), 1 = white.
    colour: (B, G, R) tint of the reflected light.
    wobble: amplitude of a sideways oscillation, m/s; wobble_hz its frequency.
    growth: relative radius growth per second (rising bubbles).
    spin: maximum rotation speed, rad/s (tumbling flakes).
    """

    count: int = 0
    size_mm: tuple[float, float] = (1.0, 3.0)
    depth_m: tuple[float, float] = (0.3, 2.0)
    speed: tuple[float, float] = (0.1, 0.2)
    direction_deg: float = -90.0
    spread_deg: float = 10.0
    albedo: tuple[float, float] = (0.6, 1.0)
    colour: tuple[float, float, float] = (1.0, 1.0, 1.0)
    wobble: float = 0.0
    wobble_hz: float = 2.0
    growth: float = 0.0
    spin: float = 0.0

    def __post_init__(self) -> None:
        if self.count < 0:
            raise ValueError(f"count: got {self.count}, allowed >= 0")
        for name in ("size_mm", "depth_m", "speed", "albedo"):
            lo, hi = getattr(self, name)
            if not 0 <= lo <= hi:
                raise ValueError(f"{name}: got {getattr(self, name)}, allowed 0 <= low <= high")
        if self.depth_m[0] <= 0:
            raise ValueError(f"depth_m: got {self.depth_m}, allowed > 0")


@dataclass(frozen=True)
class SceneConfig:
    """Everything a realistic preset sets; each part can be switched off.

    background: ``black``, ``water``, ``seabed``, ``padding``, or a path to an image or video.
    background_level: grey level of a white background on the lamp's axis.
    current: (x, y) water current in m/s added to every particle.
    lamp_cone: light the frame unevenly (False = uniform light).
    lamp_centre: cone centre as a share of (width, height); lamp_width: its sigma as a share of width.
    brightness: grey level of a white particle at 1 m on the lamp axis (before attenuation).
    attenuation: (B, G, R) water attenuation per metre.
    water_colour: (B, G, R) tint of the background light.
    focus_m, defocus: focus distance (m) and blur strength (pixels, 0 = everything sharp).
    exposure_s: exposure time (motion blur; 0 = none).
    read_noise, shot_noise: sensor noise (grey levels; variance per grey level).
    saturate: clip at 255 (False: soft highlight roll-off, nothing flat-topped).
    jpeg_quality: 0 = off, else JPEG artefacts at this quality.
    hfov_deg: horizontal field of view; fps: frame rate.
    vehicle_m_s: the vehicle's own velocity in the camera's frame, (x, y) across the view and z
        towards the scene (m/s); yaw_deg_s: its turn about the camera's axis (degrees a second).
        The particles and the water move the other way; a background surface (seabed, padding,
        an image; not water, which is the light of the water itself, nor a video) lies
        ``ground_m`` away, square to the view: it pans at f v / distance pixels a second, turns
        the other way, and grows and brightens (inverse square) as the distance shrinks.
    """

    bubbles: KindConfig = field(default_factory=KindConfig)
    snow: KindConfig = field(default_factory=KindConfig)
    sand: KindConfig = field(default_factory=KindConfig)
    background: str = "water"
    background_level: float = 40.0
    current: tuple[float, float] = (0.0, 0.0)
    lamp_cone: bool = True
    lamp_centre: tuple[float, float] = (0.5, 0.4)
    lamp_width: float = 0.45
    brightness: float = 320.0
    attenuation: tuple[float, float, float] = (0.05, 0.07, 0.35)
    water_colour: tuple[float, float, float] = (1.0, 0.85, 0.5)
    focus_m: float = 1.0
    defocus: float = 0.8
    exposure_s: float = 1 / 250
    read_noise: float = 2.0
    shot_noise: float = 0.5
    saturate: bool = True
    jpeg_quality: int = 0
    hfov_deg: float = 63.0
    fps: float = 60.0
    vehicle_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    yaw_deg_s: float = 0.0
    ground_m: float = 2.5

    @property
    def moving(self) -> bool:
        """True when the vehicle moves or turns."""
        return any(v != 0 for v in self.vehicle_m_s) or self.yaw_deg_s != 0

    def __post_init__(self) -> None:
        if not (self.background in BACKGROUNDS or self.background):
            raise ValueError(f"background: got {self.background!r}, allowed {', '.join(BACKGROUNDS)} or a path")
        checks = {"background_level": self.background_level >= 0, "brightness": self.brightness >= 0,
                  "focus_m": self.focus_m > 0, "defocus": self.defocus >= 0,
                  "exposure_s": self.exposure_s >= 0, "read_noise": self.read_noise >= 0,
                  "shot_noise": self.shot_noise >= 0, "jpeg_quality": 0 <= self.jpeg_quality <= 100,
                  "hfov_deg": 0 < self.hfov_deg < 180, "fps": self.fps > 0, "lamp_width": self.lamp_width > 0,
                  "ground_m": self.ground_m > 0,
                  "vehicle_m_s": len(self.vehicle_m_s) == 3 and all(math.isfinite(v) for v in self.vehicle_m_s),
                  "yaw_deg_s": math.isfinite(self.yaw_deg_s)}
        for name, ok in checks.items():
            if not ok:
                raise ValueError(f"{name}: got {getattr(self, name)!r}, out of range")


_KIND_FIELDS = ("bubbles", "snow", "sand")


class RealisticScene:
    """A realistic scene (see the module docstring).

    Parameters
    ----------
    config : SceneConfig
    size : (width, height) in pixels.
    rng : the only source of randomness (templates, backgrounds, particles, noise).
    """

    def __init__(self, config: SceneConfig, *, size: tuple[int, int], rng: np.random.Generator) -> None:
        self.config = config
        self.size = (int(size[0]), int(size[1]))
        self.fps = config.fps
        self._rng = rng
        width, height = self.size
        self.focal = (width / 2) / math.tan(math.radians(config.hfov_deg) / 2)
        self.principal = ((width - 1) / 2, (height - 1) / 2)
        self.time = 0.0
        self._next_id = 1
        templates = [bubble_templates(rng), snow_templates(rng), sand_templates(rng)]
        self._pyramids = [[pyramid(t) for t in kind] for kind in templates]
        self._cone = self._make_cone()
        self._background_video = None
        # a moving view: the background surface (unlit, larger than the view), the vehicle's turn
        # (rad), its travel over the surface (m, in the surface's frame) and its distance (m)
        self._ground: np.ndarray | None = None
        self._yaw = 0.0
        self._travel = np.zeros(2)
        self._distance = config.ground_m
        self._background = self._make_background()
        if config.moving and self._background_video is not None:
            raise ValueError("vehicle_m_s, yaw_deg_s: a moving view needs a still background (water, seabed, "
                             "padding or an image), not a video")
        self._blur_scale = config.defocus * width / 800.0
        self._state = {k: np.empty(0) for k in (
            "X", "Y", "Z", "R", "bvx", "bvy", "albedo", "phase", "angle", "spin", "growth", "wobble",
            "wobble_hz")}
        self._state["ids"] = np.empty(0, np.int64)
        self._state["kind"] = np.empty(0, np.int8)
        self._state["template"] = np.empty(0, np.int64)
        for kind_index, name in enumerate(_KIND_FIELDS):
            kind = getattr(config, name)
            if kind.count:
                self._append(self._spawn(kind_index, kind.count, entering=False))
        self._truth: Truth | None = None
        self._noise_lut: np.ndarray | None = None
        self._noise_bank: np.ndarray | None = None

    # ----------------------------------------------------------------- set-up
    def _make_cone(self) -> np.ndarray:
        width, height = self.size
        c = self.config
        if not c.lamp_cone:
            return np.ones((height, width), np.float32)
        yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
        cx, cy = c.lamp_centre[0] * width, c.lamp_centre[1] * height
        sigma = c.lamp_width * width
        return np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * sigma * sigma)).astype(np.float32)

    def _make_background(self) -> np.ndarray | None:
        c = self.config
        width, height = self.size
        if c.background == "black" or c.background_level == 0:
            return None
        if c.background == "water":
            return self._light_background(gradient(self.size)[..., None] * 0.5)  # the water's own light: no surface
        # a moving view looks over a surface larger than itself
        surface = (GROUND_SCALE * width, GROUND_SCALE * height) if c.moving else self.size
        if c.background == "seabed":
            base = seabed(surface, self._rng)[..., None]
        elif c.background == "padding":
            base = padding(surface, self._rng)[..., None]
        else:
            base = load_background(c.background, surface)
            if base.ndim == 2:
                base = base[..., None]
            cap = cv2.VideoCapture(c.background)
            if cap.isOpened() and cap.get(cv2.CAP_PROP_FRAME_COUNT) > 1:
                self._background_video = cap
            else:
                cap.release()
        if c.moving:
            self._ground = base
            return self._view_of_ground()
        return self._light_background(base)

    def ground_transform(self) -> np.ndarray:
        """(2, 3) affine map from the background surface's pixels to the view's, now: at the start
        the surface's centre lies on the optical axis at ``ground_m``, one surface pixel to one view
        pixel; then p = principal + (ground_m / distance) R(-yaw) (g - centre - travel f / ground_m)."""
        scale = self.config.ground_m / self._distance
        cos, sin = math.cos(-self._yaw), math.sin(-self._yaw)
        a = scale * np.array([[cos, -sin], [sin, cos]])
        gh, gw = self._ground.shape[:2]
        origin = np.array([(gw - 1) / 2, (gh - 1) / 2]) + self._travel * self.focal / self.config.ground_m
        return np.column_stack([a, np.array(self.principal) - a @ origin])

    def _view_of_ground(self) -> np.ndarray:
        """The background surface as the view sees it now, lit (inverse square of its distance)."""
        ground = self._ground
        view = cv2.warpAffine(ground if ground.shape[2] > 1 else ground[..., 0], self.ground_transform(), self.size,
                              flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        if view.ndim == 2:
            view = view[..., None]
        return self._light_background(view) * np.float32((self.config.ground_m / self._distance) ** 2)

    def _light_background(self, base: np.ndarray) -> np.ndarray:
        c = self.config
        tint = np.array(c.water_colour, np.float32)
        return (base * (c.background_level * self._cone)[..., None] * tint).astype(np.float32)

    # -------------------------------------------------------------- particles
    def _spawn(self, kind_index: int, k: int, *, entering: bool) -> dict[str, np.ndarray]:
        """k new particles of one kind: inside the view, or entering from upstream."""
        rng = self._rng
        kind: KindConfig = getattr(self.config, _KIND_FIELDS[kind_index])
        width, height = self.size
        z = rng.uniform(*kind.depth_m, k)
        r = rng.uniform(*kind.size_mm, k) / 1000.0
        speed = rng.uniform(*kind.speed, k)
        direction = np.radians(kind.direction_deg + rng.uniform(-kind.spread_deg, kind.spread_deg, k))
        bvx, bvy = speed * np.cos(direction), speed * np.sin(direction)
        u = rng.uniform(0, width, k)
        v = rng.uniform(0, height, k)
        if entering:
            vx = bvx + self.config.current[0] - self.config.vehicle_m_s[0]
            vy = bvy + self.config.current[1] - self.config.vehicle_m_s[1]
            norm = np.hypot(vx, vy)
            moving = norm > 1e-9
            dx = np.where(moving, vx / np.where(moving, norm, 1), 0.0)
            dy = np.where(moving, vy / np.where(moving, norm, 1), 0.0)
            margin = self.focal * r / z * 1.2 + 3.0
            # walk back along -velocity to the frame edge (plus margin)
            with np.errstate(divide="ignore", invalid="ignore"):
                tx = np.where(dx > 0, (u + margin) / dx, np.where(dx < 0, (u - width - margin) / dx, np.inf))
                ty = np.where(dy > 0, (v + margin) / dy, np.where(dy < 0, (v - height - margin) / dy, np.inf))
            t = np.where(moving, np.minimum(tx, ty), 0.0)
            u = u - dx * t
            v = v - dy * t
        ids = np.arange(self._next_id, self._next_id + k, dtype=np.int64)
        self._next_id += k
        return {
            "ids": ids, "kind": np.full(k, kind_index, np.int8),
            "template": rng.integers(0, len(self._pyramids[kind_index]), k),
            "X": (u - self.principal[0]) * z / self.focal, "Y": (v - self.principal[1]) * z / self.focal,
            "Z": z, "R": r, "bvx": bvx, "bvy": bvy, "albedo": rng.uniform(*kind.albedo, k),
            "phase": rng.uniform(0, 2 * np.pi, k), "angle": rng.uniform(0, 2 * np.pi, k),
            "spin": rng.uniform(-kind.spin, kind.spin, k), "growth": np.full(k, kind.growth),
            "wobble": np.full(k, kind.wobble), "wobble_hz": np.full(k, kind.wobble_hz),
        }

    def _append(self, new: dict[str, np.ndarray]) -> None:
        for key, values in new.items():
            self._state[key] = np.concatenate([self._state[key], values.astype(self._state[key].dtype)])

    def _velocity(self) -> tuple[np.ndarray, np.ndarray]:
        s = self._state
        w = 2 * np.pi * s["wobble_hz"] * self.time + s["phase"]
        vehicle = self.config.vehicle_m_s
        vx = s["bvx"] + self.config.current[0] - vehicle[0] + s["wobble"] * np.sin(w)
        vy = s["bvy"] + self.config.current[1] - vehicle[1] + 0.3 * s["wobble"] * np.cos(w)
        return vx, vy

    def _project(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        s = self._state
        x = self.principal[0] + self.focal * s["X"] / s["Z"]
        y = self.principal[1] + self.focal * s["Y"] / s["Z"]
        return x, y, self.focal * s["R"] / s["Z"]

    def step(self) -> None:
        """Advance one frame period; particles that left the view are replaced from upstream."""
        dt = 1.0 / self.fps
        s = self._state
        vx, vy = self._velocity()
        s["X"] = s["X"] + vx * dt
        s["Y"] = s["Y"] + vy * dt
        c = self.config
        if c.moving:
            turn = math.radians(c.yaw_deg_s) * dt  # the vehicle turns: the water turns the other way
            cos, sin = math.cos(-turn), math.sin(-turn)
            s["X"], s["Y"] = cos * s["X"] - sin * s["Y"], sin * s["X"] + cos * s["Y"]
            s["Z"] = s["Z"] - c.vehicle_m_s[2] * dt
            self._yaw += turn
            cos, sin = math.cos(self._yaw), math.sin(self._yaw)  # the vehicle's heading over the surface
            self._travel = self._travel + np.array([[cos, -sin], [sin, cos]]) @ np.array(c.vehicle_m_s[:2]) * dt
            self._distance = max(self._distance - c.vehicle_m_s[2] * dt, 0.1 * c.ground_m)
            if self._ground is not None:
                self._background = self._view_of_ground()
        s["R"] = s["R"] * np.exp(s["growth"] * dt)
        s["angle"] = s["angle"] + s["spin"] * dt
        self.time += dt
        x, y, rp = self._project()
        width, height = self.size
        margin = rp * 1.2 + 4.0
        gone = (x < -margin) | (x > width + margin) | (y < -margin) | (y > height + margin) | (s["Z"] < MIN_DEPTH_M)
        if gone.any():
            kinds = s["kind"][gone]
            keep = ~gone
            for key in s:
                s[key] = s[key][keep]
            for kind_index in range(len(KINDS)):
                k = int((kinds == kind_index).sum())
                if k:
                    self._append(self._spawn(kind_index, k, entering=True))
        self._truth = None

    # -------------------------------------------------------------- rendering
    def particles(self, ahead_s: float = 0.0) -> dict[str, np.ndarray]:
        """Every particle in camera coordinates: ids, X, Y, Z, R (metres; Z along the view).

        ahead_s: where they will be that many seconds after the current frame's
        start, moving at their present velocity (0 <= ahead_s <= one frame period).
        """
        s = self._state
        if ahead_s:
            vx, vy = self._velocity()
            x, y = s["X"] + vx * ahead_s, s["Y"] + vy * ahead_s
        else:
            x, y = s["X"].copy(), s["Y"].copy()
        z = s["Z"] - self.config.vehicle_m_s[2] * ahead_s  # (a turn within a frame: left out)
        return {"ids": s["ids"].copy(), "X": x, "Y": y, "Z": z, "R": s["R"].copy()}

    def _lamp_gain(self) -> np.ndarray:
        """(N, 3) light each particle sends back under the full lamp on its axis: inverse square,
        albedo, colour and water attenuation out and back (grey levels, state order)."""
        c, s = self.config, self._state
        colours = np.array([getattr(c, k).colour for k in _KIND_FIELDS])[s["kind"]]
        att = np.array(c.attenuation)[None, :]
        return (c.brightness * s["albedo"] / s["Z"] ** 2)[:, None] * colours * np.exp(-2 * att * s["Z"][:, None])

    def full_light_brightness(self) -> np.ndarray:
        """(N,) brightness each particle sends back under the full lamp (grey levels, state order)."""
        return self._lamp_gain().mean(axis=1)

    def render(self, labels: np.ndarray | None = None, *,
               light: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        """The current frame, (H, W, 3) BGR uint8; fills ``labels`` ((H, W) uint16) if given.

        light: (particle factors (N,) in state order, background factors (H, W)), each 0..1,
            the share of the lamp's light that reached them during the exposure (the digital
            twin's projector pattern); None = the full lamp.
        """
        c = self.config
        width, height = self.size
        if self._background is None:
            frame = np.zeros((height, width, 3), np.float32)
        else:
            if self._background_video is not None:
                self._next_background_frame()
            frame = self._background.copy()
            if light is not None:
                frame *= light[1].astype(np.float32)[..., None]
        best = np.zeros((height, width), np.float32)
        owner = np.zeros((height, width), np.int32)
        s = self._state
        x, y, rp = self._project()
        vx, vy = self._velocity()
        pvx, pvy = self.focal * vx / s["Z"], self.focal * vy / s["Z"]
        streak_x, streak_y = pvx * c.exposure_s, pvy * c.exposure_s
        sigma = self._blur_scale * np.abs(c.focus_m / s["Z"] - 1.0)
        gain = self._lamp_gain()
        cone_at = self._cone[np.clip(np.rint(y), 0, height - 1).astype(int), np.clip(np.rint(x), 0, width - 1).astype(int)]
        gain *= cone_at[:, None]
        if light is not None:
            gain *= np.asarray(light[0], dtype=np.float64)[:, None]
        n = len(x)
        peaks = np.zeros(n)
        areas = np.zeros(n)
        rendered = np.zeros(n, bool)
        for i in range(n):
            patch, x0, y0 = self._sprite(s["kind"][i], s["template"][i], x[i], y[i], rp[i], s["angle"][i],
                                         sigma[i], streak_x[i], streak_y[i])
            peak = float(patch.max())
            if peak <= 0:
                continue
            footprint = patch >= FOOTPRINT * peak
            areas[i] = np.count_nonzero(footprint)
            g = gain[i]
            peaks[i] = peak * float(g.max())
            ph, pw = patch.shape
            fx0, fy0 = max(x0, 0), max(y0, 0)
            fx1, fy1 = min(x0 + pw, width), min(y0 + ph, height)
            if fx1 <= fx0 or fy1 <= fy0:
                continue
            rendered[i] = True
            sub = patch[fy0 - y0:fy1 - y0, fx0 - x0:fx1 - x0]
            frame[fy0:fy1, fx0:fx1] += sub[..., None] * g.astype(np.float32)
            light = sub * np.float32(g.mean())
            win_best = best[fy0:fy1, fx0:fx1]
            wins = footprint[fy0 - y0:fy1 - y0, fx0 - x0:fx1 - x0] & (light > win_best)
            win_best[wins] = light[wins]
            owner[fy0:fy1, fx0:fx1][wins] = i + 1
        image = self._sensor(frame)
        counts = np.bincount(owner.ravel(), minlength=n + 1)[1:]
        index = np.flatnonzero(rendered)
        label_of = np.zeros(n + 1, np.int32)
        label_of[index + 1] = np.arange(1, len(index) + 1, dtype=np.int32)
        visible = counts[index] > 0
        if labels is not None:
            labels[...] = label_of[owner]
        with np.errstate(divide="ignore", invalid="ignore"):
            visibility = np.clip(counts[index] / np.maximum(areas[index], 1), 0.0, 1.0)
            base = 0.0
            if self._background is not None:
                iy = np.clip(np.rint(y[index]), 0, height - 1).astype(int)
                ix = np.clip(np.rint(x[index]), 0, width - 1).astype(int)
                base = self._background[iy, ix].mean(axis=1)
            noise = np.sqrt(c.read_noise ** 2 + c.shot_noise * base)
            snr = np.where(noise > 0, peaks[index] / np.where(noise > 0, noise, 1.0), np.inf)
        self._truth = Truth(
            ids=s["ids"][index].copy(), centres=np.column_stack([x[index], y[index]]),
            radii=np.sqrt(areas[index] / np.pi), visibility=visibility, depths=s["Z"][index].copy(),
            kinds=s["kind"][index].copy(), peaks=peaks[index],
            labels=np.where(visible, np.arange(1, len(index) + 1), 0).astype(np.int32),
            snr=np.broadcast_to(snr, len(index)).astype(np.float64))
        return image

    def _sprite(self, kind: int, template: int, x: float, y: float, rp: float, angle: float,
                sigma: float, sx: float, sy: float) -> tuple[np.ndarray, int, int]:
        """One particle's light as a float32 patch and the patch's top-left pixel."""
        levels = self._pyramids[kind][template]
        level = 0
        while level + 1 < len(levels) and RADIUS / 2 ** (level + 1) >= rp:
            level += 1
        src = levels[level]
        src_radius = RADIUS / 2 ** level
        src_centre = (src.shape[0] - 1) / 2.0
        streak = math.hypot(sx, sy)
        half = int(math.ceil(rp * 1.1 + 3 * sigma + streak / 2 + 2))
        x0, y0 = int(math.floor(x)) - half, int(math.floor(y)) - half
        scale = rp / src_radius
        # a particle smaller than a pixel is drawn ``fine`` times finer, each pixel the mean of its
        # fine x fine samples (the light that falls on it) -- one sample at the pixel's centre missed
        # the grain between centres (gone from the frame) or caught its peak (up to 16 times its
        # light), by where it fell.  Only its own few pixels (the core) are drawn finely; blur and
        # streak spread it over the patch.
        fine = 1 if scale >= 0.5 else min(MAX_SUPERSAMPLE, math.ceil(0.5 / scale))
        core = half if fine == 1 else min(half, int(math.ceil(rp * 1.1 + 1)))
        pad = half - core
        cos_a, sin_a = math.cos(angle) * scale * fine, math.sin(angle) * scale * fine
        tx, ty = (x - x0 - pad + 0.5) * fine - 0.5, (y - y0 - pad + 0.5) * fine - 0.5
        m = np.array([[cos_a, -sin_a, tx - (cos_a * src_centre - sin_a * src_centre)],
                      [sin_a, cos_a, ty - (sin_a * src_centre + cos_a * src_centre)]], np.float64)
        side = (2 * core + 1) * fine
        patch = cv2.warpAffine(src, m, (side, side), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        if fine > 1:  # smaller than a pixel: each pixel its samples' mean, then the optics spread it
            patch = cv2.resize(patch, (2 * core + 1, 2 * core + 1), interpolation=cv2.INTER_AREA)
            if pad:
                patch = cv2.copyMakeBorder(patch, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=0)
            patch = cv2.GaussianBlur(patch, (0, 0), 0.5)  # over a pixel or so
        if sigma > 0.3:
            patch = cv2.GaussianBlur(patch, (0, 0), sigma)
        if streak > 0.5:
            k = int(math.ceil(streak)) | 1
            k = max(k, 3)
            kernel = np.zeros((k, k), np.float32)
            c = (k - 1) / 2.0
            ux, uy = sx / streak * streak / 2, sy / streak * streak / 2
            cv2.line(kernel, (round((c - ux) * 16), round((c - uy) * 16)),
                     (round((c + ux) * 16), round((c + uy) * 16)), 1.0, 1, cv2.LINE_AA, 4)
            kernel /= kernel.sum()
            patch = cv2.filter2D(patch, -1, kernel, borderType=cv2.BORDER_CONSTANT)
        return patch, x0, y0

    def _next_background_frame(self) -> None:
        ok, image = self._background_video.read()
        if not ok:
            self._background_video.set(cv2.CAP_PROP_POS_FRAMES, 0)
            ok, image = self._background_video.read()
        if ok:
            image = cv2.resize(image, self.size, interpolation=cv2.INTER_AREA).astype(np.float32) / 255.0
            self._background = self._light_background(image)

    def _sensor(self, frame: np.ndarray) -> np.ndarray:
        """Noise, highlight clipping or roll-off, quantisation, optional JPEG."""
        c = self.config
        if c.read_noise > 0 or c.shot_noise > 0:
            # sigma(signal) = sqrt(read^2 + shot * signal), looked up per grey level
            if self._noise_lut is None:
                levels = np.arange(256, dtype=np.float32)
                self._noise_lut = np.sqrt(c.read_noise ** 2 + c.shot_noise * levels).reshape(1, 256)
            sigma = cv2.LUT(cv2.convertScaleAbs(frame), self._noise_lut)
            frame += cv2.multiply(self._noise_field(), sigma)
        if not c.saturate:
            knee = np.float32(180.0)
            high = frame > knee
            frame[high] = knee + 74.0 * (1.0 - np.exp(-(frame[high] - knee) / 74.0))
        image = cv2.add(frame, 0.0, dtype=cv2.CV_8U)  # round and clip to 0..255
        if c.jpeg_quality:
            ok, encoded = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, c.jpeg_quality])
            image = cv2.imdecode(encoded, cv2.IMREAD_COLOR)
        return image

    def _noise_field(self) -> np.ndarray:
        """Unit Gaussian noise for one frame: a random window of a bank drawn once per scene.

        Drawing 3 x W x H normals every frame would cost more than the rest of
        the frame; windows at random offsets of a larger bank (4096 of them) are
        spatially white and differ from frame to frame.
        """
        width, height = self.size
        pad = 64
        if self._noise_bank is None:
            self._noise_bank = self._rng.standard_normal((height + pad, width + pad, 3), dtype=np.float32)
        ox, oy = (int(v) for v in self._rng.integers(0, pad, 2))
        return self._noise_bank[oy:oy + height, ox:ox + width]

    def truth(self) -> Truth:
        """Ground truth of the frame last rendered (render first)."""
        if self._truth is None:
            raise RuntimeError("render() the frame before asking for its truth")
        return self._truth
