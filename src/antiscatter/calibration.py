"""Camera-to-projector calibration with Gray-code stripes (OpenCV contrib's GrayCodePattern).

The projector shows the Gray-code sequence (columns and rows, each with its
inverse) on a flat target; the camera captures each one.  Every sampled camera
pixel is decoded to the projector pixel that lit it, and a homography is fitted
to those pairs (RANSAC): exact for points on the target's plane, and for every
depth when camera and projector are co-located.  With targets at two known
depths the baseline follows from the shift between their homographies
(x-offset difference = f_p * b * (1/d1 - 1/d2), f_p = scale * f_c), which gives
the depth-aware mapping H(d) = [[s, 0, t_x - f_p b / d], [0, s, t_y], [0, 0, 1]]
for parallel optical axes (the twin's geometry and a typical housing).

``capture(pattern) -> camera image`` is supplied by a rig: the twin renders the
target under the pattern; on the vehicle the projector output shows it and the
camera source captures it.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import cv2
import numpy as np

from .errors import UsageError

__all__ = ["Calibration", "decode_plane", "calibrate_planes", "load_calibration", "TwinRig", "HardwareRig",
           "mapping_error_px"]


def gray_code_patterns(projector_size: tuple[int, int]) -> tuple[object, list[np.ndarray], np.ndarray, np.ndarray]:
    """(GrayCodePattern, the stripe patterns, all-white, all-black) for the projector."""
    width, height = projector_size
    code = cv2.structured_light.GrayCodePattern.create(width, height)
    ok, patterns = code.generate()
    if not ok:
        raise RuntimeError("GrayCodePattern.generate failed")
    white = np.full((height, width), 255, np.uint8)
    black = np.zeros((height, width), np.uint8)
    return code, list(patterns), white, black


def decode_plane(capture: Callable[[np.ndarray], np.ndarray], projector_size: tuple[int, int], *,
                 step: int = 8, white_threshold: int = 5, black_threshold: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """Project the sequence, capture it, decode every ``step``-th camera pixel.

    Returns ((N, 2) camera pixels, (N, 2) projector pixels) of the pixels that decoded.
    """
    code, patterns, white, black = gray_code_patterns(projector_size)
    captures = [cv2.cvtColor(c, cv2.COLOR_BGR2GRAY) if c.ndim == 3 else c for c in map(capture, patterns)]
    lit, dark = capture(white), capture(black)
    lit = cv2.cvtColor(lit, cv2.COLOR_BGR2GRAY) if lit.ndim == 3 else lit
    dark = cv2.cvtColor(dark, cv2.COLOR_BGR2GRAY) if dark.ndim == 3 else dark
    code.setWhiteThreshold(white_threshold)
    code.setBlackThreshold(black_threshold)
    height, width = captures[0].shape
    shadow = cv2.absdiff(lit, dark) > black_threshold  # pixels the projector actually lights
    camera, projector = [], []
    for y in range(step // 2, height, step):
        for x in range(step // 2, width, step):
            if not shadow[y, x]:
                continue
            error, pixel = code.getProjPixel(captures, x, y)
            if not error:
                camera.append((x, y))
                projector.append((pixel[0], pixel[1]))
    return np.array(camera, np.float64).reshape(-1, 2), np.array(projector, np.float64).reshape(-1, 2)


def fit_homography(camera: np.ndarray, projector: np.ndarray) -> tuple[np.ndarray, float]:
    """(3x3 camera-to-projector homography, median reprojection error in projector pixels).

    A decoded projector pixel is the integer index of the pixel whose area
    (centred on that index) lit the camera pixel: the fit targets it as is.
    """
    if len(camera) < 8:
        raise UsageError(f"calibration: only {len(camera)} camera pixels decoded; is the target lit and in view?")
    target = projector
    H, inliers = cv2.findHomography(camera, target, cv2.RANSAC, 2.0)
    if H is None:
        raise UsageError("calibration: no homography fits the decoded pixels")
    mapped = cv2.perspectiveTransform(camera.reshape(-1, 1, 2), H).reshape(-1, 2)
    error = np.hypot(*(mapped - target).T)
    return H, float(np.median(error[inliers.ravel() > 0]))


@dataclass(frozen=True)
class Calibration:
    """The camera-to-projector mapping a calibration found.

    homography: for the working distance (what ``run`` uses); planes: [(depth_m, homography)];
    baseline_m and the focal lengths where two planes at different depths were measured.
    """

    camera_size: tuple[int, int]
    projector_size: tuple[int, int]
    homography: np.ndarray
    working_depth_m: float
    planes: tuple = ()
    baseline_m: float | None = None
    camera_focal_px: float | None = None
    projector_focal_px: float | None = None
    errors_px: tuple = field(default=())

    def mapping_at(self, depth_m: float) -> np.ndarray:
        """The homography for particles at ``depth_m`` (needs the baseline; else the working one)."""
        if self.baseline_m is None or self.projector_focal_px is None:
            return self.homography
        H = self.homography.copy()
        H[0, 2] += self.projector_focal_px * self.baseline_m * (1 / self.working_depth_m - 1 / depth_m)
        return H

    def save(self, path: str | Path) -> None:
        data = {"version": 1, "camera_size": list(self.camera_size), "projector_size": list(self.projector_size),
                "homography": self.homography.tolist(), "working_depth_m": self.working_depth_m,
                "planes": [{"depth_m": d, "homography": h.tolist()} for d, h in self.planes],
                "baseline_m": self.baseline_m, "camera_focal_px": self.camera_focal_px,
                "projector_focal_px": self.projector_focal_px, "errors_px": list(self.errors_px)}
        Path(path).write_text(json.dumps(data, indent=2))


def _matrix(value: object, where: str) -> np.ndarray:
    try:
        m = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        m = None
    if m is None or m.shape != (3, 3) or not np.isfinite(m).all() or abs(np.linalg.det(m)) < 1e-12:
        raise UsageError(f"{where}: expected an invertible 3x3 matrix of numbers")
    return m


def load_calibration(path: str | Path) -> Calibration:
    """Read a calibration file; a bad one is a one-line UsageError naming the file and the key."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise UsageError(f"{path}: no such calibration file") from None
    except (json.JSONDecodeError, UnicodeDecodeError):
        raise UsageError(f"{path}: not a calibration file (expected JSON from 'antiscatter calibrate')") from None
    if not isinstance(data, dict) or data.get("version") != 1:
        raise UsageError(f"{path}: version: expected 1")
    try:
        camera = tuple(int(v) for v in data["camera_size"])
        projector = tuple(int(v) for v in data["projector_size"])
        depth = float(data["working_depth_m"])
        H = _matrix(data["homography"], f"{path}: homography")
        planes = tuple((float(p["depth_m"]), _matrix(p["homography"], f"{path}: planes")) for p in data.get("planes", []))
    except KeyError as exc:
        raise UsageError(f"{path}: missing key {exc.args[0]!r}") from None
    except (TypeError, ValueError):
        raise UsageError(f"{path}: camera_size, projector_size and working_depth_m must be numbers") from None
    if len(camera) != 2 or len(projector) != 2 or min(camera + projector) <= 0 or not depth > 0:
        raise UsageError(f"{path}: camera_size and projector_size need two positive integers, working_depth_m > 0")
    optional = {k: (float(data[k]) if data.get(k) is not None else None)
                for k in ("baseline_m", "camera_focal_px", "projector_focal_px")}
    return Calibration(camera, projector, H, depth, planes, **optional, errors_px=tuple(data.get("errors_px", [])))


def calibrate_planes(captures: dict[float, Callable[[np.ndarray], np.ndarray]], *, camera_size: tuple[int, int],
                     projector_size: tuple[int, int], camera_focal_px: float | None = None,
                     step: int = 8) -> Calibration:
    """Calibrate from a flat target at one or more known depths (``{depth_m: capture}``)."""
    planes, errors = [], []
    for depth, capture in sorted(captures.items()):
        camera, projector = decode_plane(capture, projector_size, step=step)
        H, error = fit_homography(camera, projector)
        planes.append((depth, H))
        errors.append(error)
    depths = [d for d, _ in planes]
    working = math.sqrt(depths[0] * depths[-1])
    baseline = projector_focal = None
    if len(planes) >= 2 and camera_focal_px:
        (d1, h1), (d2, h2) = planes[0], planes[-1]
        scale = (h1[0, 0] + h2[0, 0] + h1[1, 1] + h2[1, 1]) / 4
        projector_focal = scale * camera_focal_px
        baseline = (h2[0, 2] - h1[0, 2]) / (projector_focal * (1 / d1 - 1 / d2))
    if len(planes) >= 2 and baseline is not None:
        # the working homography from the depth model (between the measured planes)
        H = planes[0][1].copy()
        H[0, 2] += projector_focal * baseline * (1 / planes[0][0] - 1 / working)
    else:
        H = planes[len(planes) // 2][1]
    return Calibration(camera_size, projector_size, H, working, tuple(planes), baseline, camera_focal_px,
                       projector_focal, tuple(errors))


class TwinRig:
    """The twin's camera looking at a flat target at ``depth_m`` lit by the projector.

    capture(pattern) renders what the camera sees: the pattern warped through the
    true plane homography onto a grey target, plus sensor noise (``noise`` grey levels).
    """

    def __init__(self, geometry: object, depth_m: float, *, noise: float = 2.0, ambient: float = 10.0,
                 rng: np.random.Generator | None = None) -> None:
        self.geometry = geometry
        self.depth_m = depth_m
        self.noise = noise
        self.ambient = ambient
        self.rng = rng or np.random.default_rng(0)
        self.truth = geometry.plane_mapping(depth_m)  # camera -> projector

    def capture(self, pattern: np.ndarray) -> np.ndarray:
        size = self.geometry.camera_size
        seen = cv2.warpPerspective(pattern.astype(np.float32), self.truth, size,
                                   flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_CONSTANT,
                                   borderValue=0.0)
        image = self.ambient + 0.8 * seen + self.rng.normal(0, self.noise, seen.shape)
        return np.clip(np.rint(image), 0, 255).astype(np.uint8)


def mapping_error_px(estimate: np.ndarray, truth: np.ndarray, camera_size: tuple[int, int],
                     projector_size: tuple[int, int] | None = None) -> dict[str, float]:
    """How far ``estimate`` puts camera pixels from where ``truth`` does, in projector pixels
    (over a grid of the camera frame; only points landing inside the projector when its size is given)."""
    w, h = camera_size
    xs, ys = np.meshgrid(np.linspace(0, w - 1, 33), np.linspace(0, h - 1, 25))
    points = np.column_stack([xs.ravel(), ys.ravel()]).reshape(-1, 1, 2)
    a = cv2.perspectiveTransform(points, estimate).reshape(-1, 2)
    b = cv2.perspectiveTransform(points, truth).reshape(-1, 2)
    if projector_size is not None:
        inside = (b[:, 0] >= 0) & (b[:, 0] < projector_size[0]) & (b[:, 1] >= 0) & (b[:, 1] < projector_size[1])
        a, b = a[inside], b[inside]
    error = np.hypot(*(a - b).T)
    return {"mean_px": float(error.mean()), "max_px": float(error.max())}


class HardwareRig:
    """The vehicle's projector (a light output) and camera (a frame source) as a calibration rig.

    capture(pattern) shows the pattern, lets ``settle`` frames pass (the projector's
    and camera's pipelines), and returns the next frame.
    """

    def __init__(self, source: object, outputs: list, *, settle: int = 3) -> None:
        self.source, self.outputs, self.settle = source, outputs, settle

    def capture(self, pattern: np.ndarray) -> np.ndarray:
        for output in self.outputs:
            output.show(pattern)
        frame = None
        for _ in range(self.settle + 1):
            frame = self.source.read()
            if frame is None:
                raise UsageError("calibration: the camera source ended during the pattern sequence")
        return frame.image
