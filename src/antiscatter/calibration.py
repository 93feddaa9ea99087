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

from .console import progress
from .errors import UsageError

__all__ = ["Calibration", "decode_plane", "calibrate_planes", "load_calibration", "TwinRig", "HardwareRig",
           "mapping_error_px", "Board", "Stereo", "BoardRig", "calibrate_board", "decode_dense", "twin_board_poses"]


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
    captures = [_grey(capture(p)) for p in progress(patterns, desc="calibrate", unit="pattern", leave=False)]
    lit, dark = _grey(capture(white)), _grey(capture(black))
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


def _grey(image: np.ndarray) -> np.ndarray:
    return image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)


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
    stereo: "Stereo | None" = None

    def mapping_at(self, depth_m: float) -> np.ndarray:
        """The homography for particles at ``depth_m`` (needs the baseline; else the working one).

        From a board calibration, the stereo pair's exact plane mapping; from flat targets at
        several depths, the parallel-axes model."""
        if self.stereo is not None:
            return self.stereo.plane_mapping(depth_m)
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
        if self.stereo is not None:
            data["stereo"] = self.stereo.as_dict()
        from .writing import write_whole

        write_whole(path, json.dumps(data, indent=2).encode())  # whole or not at all (a full disk)


def _matrix(value: object, where: str) -> np.ndarray:
    try:
        m = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        m = None
    if m is None or m.shape != (3, 3) or not np.isfinite(m).all() or abs(np.linalg.det(m)) < 1e-12:
        raise UsageError(f"{where}: expected an invertible 3x3 matrix of numbers")
    return m


def load_calibration(path: str | Path, *, sizes: tuple[tuple[int, int], tuple[int, int]] | None = None,
                     user: str = "this run") -> Calibration:
    """Read a calibration file; a bad one is a one-line UsageError naming the file and the key.

    sizes: (camera, projector) (width, height) it is to be used at -- a calibration made for other
    sizes is refused too: its mapping would put every hole in the wrong place (a crop, binning or
    another resolution moves and scales the camera's pixels); ``user`` names who has those sizes."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise UsageError(f"{path}: no such calibration file") from None
    except IsADirectoryError:
        raise UsageError(f"{path}: is a folder, expected a calibration file (JSON from 'antiscatter calibrate')") from None
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
    if sizes is not None and (camera, projector) != tuple(tuple(int(v) for v in size) for size in sizes):
        (cw, ch), (pw, ph) = sizes
        raise UsageError(f"{path}: made for camera {camera[0]}x{camera[1]} and projector {projector[0]}x"
                         f"{projector[1]}; {user} has camera {cw}x{ch} and projector {pw}x{ph} (allowed: the "
                         "same sizes -- calibrate again at these)")
    try:
        optional = {k: (float(data[k]) if data.get(k) is not None else None)
                    for k in ("baseline_m", "camera_focal_px", "projector_focal_px")}
    except (TypeError, ValueError):
        raise UsageError(f"{path}: baseline_m, camera_focal_px and projector_focal_px must be numbers") from None
    for key, value in optional.items():
        if value is not None and not (math.isfinite(value) and (key == "baseline_m" or value > 0)):
            allowed = "a finite number (its sign: the projector's side)" if key == "baseline_m" else "a number > 0"
            raise UsageError(f"{path}: {key}: got {value}, allowed {allowed}")
    depths = [d for d, _ in planes]
    if not all(math.isfinite(d) and d > 0 for d in depths) or len(set(depths)) != len(depths):
        raise UsageError(f"{path}: planes: depth_m {depths}, allowed distinct distances > 0")
    stereo = None
    if data.get("stereo") is not None:
        s = data["stereo"]
        try:
            stereo = Stereo(_matrix(s["camera_matrix"], f"{path}: stereo.camera_matrix"),
                            np.asarray(s["camera_distortion"], np.float64),
                            _matrix(s["projector_matrix"], f"{path}: stereo.projector_matrix"),
                            np.asarray(s["projector_distortion"], np.float64),
                            _matrix(s["rotation"], f"{path}: stereo.rotation"),
                            np.asarray(s["translation"], np.float64).reshape(3), float(s["rms_px"]))
        except (KeyError, TypeError, ValueError) as exc:
            raise UsageError(f"{path}: stereo: missing or bad entry ({exc})") from None
    return Calibration(camera, projector, H, depth, planes, **optional, errors_px=tuple(data.get("errors_px", [])),
                       stereo=stereo)


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


# ------------------------------------------------------------------ full stereo calibration (a board)

def decode_dense(captures: list[np.ndarray], lit: np.ndarray, dark: np.ndarray, projector_size: tuple[int, int], *,
                 white_threshold: int = 5, black_threshold: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """Every camera pixel's projector column and row, decoded at once (float32 maps, NaN where not).

    ``captures`` are the camera images of :func:`gray_code_patterns`' stripes in their order
    (pattern, inverse, ... columns first, then rows).  Each bit is pattern > inverse; the
    bit strings are looked up in a table built from the generated patterns themselves, so
    the decoding follows OpenCV's coding exactly.  A pixel decodes when the lamp lights it
    (lit - dark > black_threshold) and every bit differs by more than white_threshold.
    """
    width, height = projector_size
    _, patterns, _, _ = gray_code_patterns(projector_size)
    columns = [k for k in range(0, len(patterns), 2) if patterns[k][0].min() != patterns[k][0].max()]
    rows = [k for k in range(0, len(patterns), 2) if k not in columns]
    grey = [_grey(c).astype(np.int16) for c in captures]
    valid = (_grey(lit).astype(np.int16) - _grey(dark).astype(np.int16)) > black_threshold

    def decode(pairs: list[int], stripes: Callable[[np.ndarray], np.ndarray], count: int) -> np.ndarray:
        """Projector index (column or row) per camera pixel, -1 where the bit string is no code."""
        code = np.zeros(grey[0].shape, np.int64)
        keys = np.zeros(count, np.int64)  # each projector index's own bit string
        for bit, k in enumerate(pairs):
            difference = grey[k] - grey[k + 1]
            valid[...] &= np.abs(difference) > white_threshold
            code |= (difference > 0).astype(np.int64) << bit
            keys |= (stripes(patterns[k]) > 127).astype(np.int64) << bit
        table = np.full(1 << len(pairs), -1, np.int64)
        table[keys] = np.arange(count)
        return table[code]

    column = decode(columns, lambda p: p[0, :], width)
    row = decode(rows, lambda p: p[:, 0], height)
    ok = valid & (column >= 0) & (row >= 0)
    return (np.where(ok, column, np.nan).astype(np.float32), np.where(ok, row, np.nan).astype(np.float32))


@dataclass(frozen=True)
class Board:
    """A printed checkerboard: ``cols`` x ``rows`` inner corners, squares ``square_m`` wide."""

    cols: int = 9
    rows: int = 6
    square_m: float = 0.04

    def object_points(self) -> np.ndarray:
        """(cols * rows, 3) float32 corner positions on the board (metres, z = 0), OpenCV's order."""
        j, i = np.mgrid[0:self.rows, 0:self.cols]
        return np.column_stack([i.ravel(), j.ravel(), np.zeros(i.size)]).astype(np.float32) * self.square_m


def board_corners(image: np.ndarray, board: Board) -> np.ndarray | None:
    """The board's inner corners in a camera image (sub-pixel, (N, 2) float32), or None."""
    grey = _grey(image)
    found, corners = cv2.findChessboardCorners(grey, (board.cols, board.rows),
                                               cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
    if not found:
        return None
    corners = cv2.cornerSubPix(grey, corners, (5, 5), (-1, -1),
                               (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3))
    return corners.reshape(-1, 2)


def projector_corners(corners: np.ndarray, column: np.ndarray, row: np.ndarray, *,
                      window: int = 15) -> np.ndarray | None:
    """Each camera corner's projector position (Moreno & Taubin 2012): a homography fitted to the
    decoded pixels within ``window`` px around the corner maps the corner itself, with sub-pixel
    precision from integer decodes.  None when a corner's neighbourhood did not decode."""
    height, width = column.shape
    out = []
    for x, y in corners.tolist():
        x0, x1 = max(int(x) - window, 0), min(int(x) + window + 1, width)
        y0, y1 = max(int(y) - window, 0), min(int(y) + window + 1, height)
        c, r = column[y0:y1, x0:x1], row[y0:y1, x0:x1]
        ok = np.isfinite(c) & np.isfinite(r)
        if ok.sum() < 0.5 * ok.size:
            return None
        ys, xs = np.nonzero(ok)
        source = np.column_stack([xs + x0, ys + y0]).astype(np.float64)
        target = np.column_stack([c[ok], r[ok]]).astype(np.float64)
        H, _ = cv2.findHomography(source, target, 0)
        if H is None:
            return None
        out.append(cv2.perspectiveTransform(np.array([[[x, y]]], np.float64), H)[0, 0])
    return np.array(out, np.float32)


@dataclass(frozen=True)
class Stereo:
    """Camera and projector as a calibrated stereo pair (OpenCV conventions: X_p = R X_c + T)."""

    camera_matrix: np.ndarray
    camera_distortion: np.ndarray
    projector_matrix: np.ndarray
    projector_distortion: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    rms_px: float

    def plane_mapping(self, depth_m: float) -> np.ndarray:
        """Camera-to-projector homography of a plane facing the camera at ``depth_m``:
        K_p (R + T n^T / d) K_c^-1 with n = (0, 0, 1) (lens distortion left out)."""
        n = np.array([[0.0, 0.0, 1.0]])
        H = self.projector_matrix @ (self.rotation + self.translation.reshape(3, 1) @ n / depth_m) \
            @ np.linalg.inv(self.camera_matrix)
        return H / H[2, 2]

    def as_dict(self) -> dict:
        return {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in vars(self).items()}


def calibrate_board(captures: list[Callable[[np.ndarray], np.ndarray]], *, board: Board,
                    camera_size: tuple[int, int], projector_size: tuple[int, int], near_m: float = 0.3,
                    far_m: float = 3.0, window: int = 15) -> Calibration:
    """Full calibration from the board at several poses (one ``capture`` per pose): camera
    intrinsics, the projector's as an inverse camera, and their relative pose (stereoCalibrate).

    The mapping for any depth follows from the pair (:meth:`Stereo.plane_mapping`); the
    working homography is the one at sqrt(near * far).
    """
    code, patterns, white, black = gray_code_patterns(projector_size)
    objects, cameras, projectors = [], [], []
    for k, capture in enumerate(captures):
        lit = capture(white)  # (a hardware rig asks for the pose here: no bar is drawn while it waits)
        corners = board_corners(lit, board)
        if corners is None:
            continue
        images = [capture(p) for p in progress(patterns, desc=f"calibrate pose {k + 1}", unit="pattern",
                                               leave=False)]
        # the board's black squares return little light: a lower lit-dark threshold than a white target's
        column, row = decode_dense(images, lit, capture(black), projector_size, black_threshold=15)
        projected = projector_corners(corners, column, row, window=window)
        if projected is None:
            continue
        objects.append(board.object_points())
        cameras.append(corners.astype(np.float32))
        projectors.append(projected)
    if len(objects) < 3:
        raise UsageError(f"calibration: the board was found and decoded in {len(objects)} pose(s); at least 3 "
                         "are needed (whole board in view and lit, tilted differently each time)")
    flags = cv2.CALIB_FIX_K3
    rms_c, Kc, Dc, _, _ = cv2.calibrateCamera(objects, cameras, camera_size, None, None, flags=flags)
    rms_p, Kp, Dp, _, _ = cv2.calibrateCamera(objects, projectors, projector_size, None, None, flags=flags)
    rms, Kc, Dc, Kp, Dp, R, T, _, _ = cv2.stereoCalibrate(objects, cameras, projectors, Kc, Dc, Kp, Dp,
                                                          camera_size, flags=cv2.CALIB_FIX_INTRINSIC)
    stereo = Stereo(Kc, Dc.ravel(), Kp, Dp.ravel(), R, T.ravel(), float(rms))
    working = math.sqrt(near_m * far_m)
    return Calibration(camera_size, projector_size, stereo.plane_mapping(working), working,
                       baseline_m=float(np.linalg.norm(T)), camera_focal_px=float(Kc[0, 0]),
                       projector_focal_px=float(Kp[0, 0]), errors_px=(float(rms_c), float(rms_p), float(rms)),
                       stereo=stereo)


class BoardRig:
    """The twin's camera looking at a checkerboard at a pose (board -> camera: ``rvec``, ``tvec``),
    lit by the projector: capture(pattern) renders the board's checker albedo times the
    pattern the projector throws on it, plus ambient light and sensor noise."""

    def __init__(self, geometry: object, rvec: np.ndarray, tvec: np.ndarray, *, board: Board = Board(),
                 noise: float = 2.0, ambient: float = 10.0, rng: np.random.Generator | None = None) -> None:
        self.rng = rng or np.random.default_rng(0)
        self.noise, self.ambient = noise, ambient
        w, h = geometry.camera_size
        fc = geometry.camera_focal
        R, _ = cv2.Rodrigues(np.asarray(rvec, np.float64))
        t = np.asarray(tvec, np.float64).reshape(3)
        normal = R[:, 2]

        def on_board(du: float, dv: float) -> tuple[np.ndarray, np.ndarray]:
            """(points on the board's plane seen through the pixels offset by du, dv; their albedo)."""
            u, v = np.meshgrid(np.arange(w, dtype=np.float64) + du, np.arange(h, dtype=np.float64) + dv)
            ray = np.stack([(u - (w - 1) / 2) / fc, (v - (h - 1) / 2) / fc, np.ones_like(u)], axis=-1)
            point = ray * ((normal @ t) / (ray @ normal))[..., None]  # along each ray to the plane
            a, b = np.moveaxis((point - t) @ R[:, :2], -1, 0) / board.square_m  # board coordinates, squares
            inside = (a >= -1) & (a <= board.cols) & (b >= -1) & (b <= board.rows)
            quiet = (a >= -2) & (a <= board.cols + 1) & (b >= -2) & (b <= board.rows + 1)
            black = ((np.floor(a) + np.floor(b)) % 2 == 0) & inside
            return point, np.where(black, 0.15, np.where(quiet, 0.9, 0.5))

        point, _ = on_board(0.0, 0.0)
        # the albedo averaged over 4 x 4 points per pixel: edges as a real camera images them
        offsets = (np.arange(4) + 0.5) / 4 - 0.5
        self.albedo = np.mean([on_board(du, dv)[1] for du in offsets for dv in offsets], axis=0).astype(np.float32)
        px, py, pz = point[..., 0] - geometry.baseline_m, point[..., 1], point[..., 2]
        fp = geometry.projector_focal
        pw, ph = geometry.projector_size
        self.map_x = (fp * px / pz + (pw - 1) / 2).astype(np.float32)
        self.map_y = (fp * py / pz + (ph - 1) / 2).astype(np.float32)

    def capture(self, pattern: np.ndarray) -> np.ndarray:
        light = cv2.remap(pattern.astype(np.float32), self.map_x, self.map_y, cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
        image = self.ambient + 0.8 * self.albedo * light + self.rng.normal(0, self.noise, light.shape)
        return np.clip(np.rint(image), 0, 255).astype(np.uint8)


def twin_board_poses(count: int = 8, *, distance_m: float = 0.8, board: Board = Board(),
                     baseline_m: float = 0.12) -> list[tuple[np.ndarray, np.ndarray]]:
    """``count`` board poses (rvec, tvec) for the twin: tilted up to 35 degrees about both axes,
    0.6-1.0 m away, centred between the camera's and the projector's axes."""
    poses = []
    centre = np.array([(board.cols - 1) * board.square_m / 2, (board.rows - 1) * board.square_m / 2, 0.0])
    for k in range(count):
        angle = 2 * np.pi * k / count
        tilt = np.radians(35.0) * np.array([np.sin(angle), np.cos(angle), 0.0]) * (0.5 + 0.5 * (k % 2))
        R, _ = cv2.Rodrigues(tilt)
        distance = distance_m + 0.2 * np.sin(3 * angle)
        target = np.array([baseline_m / 2, 0.0, distance])
        poses.append((tilt, target - R @ centre))  # the board's middle lands on the target
    return poses
