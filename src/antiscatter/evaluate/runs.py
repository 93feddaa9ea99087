"""Evaluation drivers: CSV pairs, simulator folders, in-memory scenarios, real image pairs."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

import cv2
import numpy as np

from ..console import progress
from ..detection import Detector
from ..errors import UsageError
from ..simulate import make_scene
from .metrics import FrameScore, score_frame
from ..sources.folder import frame_files, no_frames, read_frame
from ..sources.video import VideoSource
from .reference import reference_truth
from .tables import FrameTruth, read_detections, read_truth

__all__ = ["Matching", "evaluate_csv", "evaluate_folder", "evaluate_source", "evaluate_source_tracking",
           "evaluate_scenario", "evaluate_pairs", "scenario_frames", "source_truth_frames"]


@dataclass(frozen=True)
class Matching:
    """How truth is counted and matched.

    min_gate, gate_scale: a detection matches when its centre is within
        max(gate_scale * truth radius, min_gate) pixels.
    min_visibility, min_snr: truth below these is neither to be found nor a false alarm.
    margin: pixels added to each hole's radius for the pixel metrics.
    """

    min_gate: float = 2.0
    gate_scale: float = 1.0
    min_visibility: float = 0.5
    min_snr: float = 5.0
    margin: float = 0.0

    def __post_init__(self) -> None:
        for name in ("min_gate", "gate_scale", "min_visibility", "margin", "min_snr"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):  # NaN passed and made every figure NaN or 1
                raise UsageError(f"--{name.replace('_', '-')}: got {value}, allowed a number >= 0")
        if self.min_visibility > 1:
            raise UsageError(f"--min-visibility: got {self.min_visibility}, allowed 0..1 (a share of the particle)")


def _score(frame: int, truth: FrameTruth | None, centres: np.ndarray, radii: np.ndarray, m: Matching,
           masks: tuple[np.ndarray, np.ndarray] | None = None) -> FrameScore:
    if truth is None:
        truth = FrameTruth.empty()
    particle, ignore = masks if masks is not None else (None, None)
    return score_frame(frame, truth.centres, truth.radii, truth.counted, centres, radii,
                       min_gate=m.min_gate, gate_scale=m.gate_scale, particle_mask=particle,
                       ignore_mask=ignore, margin=m.margin)


def _label_masks(labels: np.ndarray, truth: FrameTruth | None, path: Any = "") -> tuple[np.ndarray, np.ndarray]:
    counted_labels = truth.labels[truth.counted & (truth.labels > 0)] if truth is not None else np.empty(0)
    lut = np.zeros(int(labels.max()) + 1 if labels.size else 1, bool)
    lut[counted_labels[counted_labels < len(lut)]] = True
    particle = lut[labels]
    return particle, (labels > 0) & ~particle


_NO_DETECTIONS = (np.empty((0, 2)), np.empty(0), np.empty(0, np.int64))


def read_csv_pair(truth_path: Path, detections_path: Path, m: Matching):
    """(truth per frame, detections per frame, frame range) of a truth CSV and a detections CSV."""
    truth = read_truth(truth_path, min_visibility=m.min_visibility, min_snr=m.min_snr)
    frames = range(0, max(truth) + 1) if truth else range(0)
    found = read_detections(detections_path, frames=frames, frames_source=str(truth_path))
    return truth, found, frames


def score_csv_pair(truth: dict, found: dict, frames: range, m: Matching) -> list[FrameScore]:
    """Per-frame scores of what :func:`read_csv_pair` read."""
    return [_score(f, truth.get(f), *found.get(f, _NO_DETECTIONS)[:2], m) for f in frames]


def evaluate_csv(truth_path: Path, detections_path: Path, m: Matching) -> list[FrameScore]:
    """Score a detections CSV against a truth CSV, frame by frame (0 .. last truth frame)."""
    return score_csv_pair(*read_csv_pair(truth_path, detections_path, m), m)


def source_truth_frames(source: Path, m: Matching, truth_path: Path | None = None, limit: int | None = None):
    """(frame number, image, FrameTruth or None, label image path or None) of a folder of frames
    or a video file, with its truth: ``truth_path``, else the folder's ``truth.csv`` (a
    simulator output folder).  Frames are numbered as :func:`~antiscatter.sources.folder.frame_files`
    does for a folder (``<int>.png`` by name, other images 0, 1, ... in order) and from 0 in
    decoding order for a video (a folder's truth may name its frames by file name instead);
    ``limit``: the first so many frames only.  Label images
    (``masks/<frame file>``) only with the simulator's truth."""
    if truth_path is None:
        truth_path = source / "truth.csv"
        if not source.is_dir() or not truth_path.is_file():
            raise UsageError(f"{source}: no truth.csv (expected an 'antiscatter simulate' output folder, "
                             "or give --truth CSV)")
    files = frame_files(source) if source.is_dir() else None
    if files is not None and not files:
        raise no_frames(source)
    names = {path.name: number for number, path in files} if files else None
    truth = read_truth(truth_path, min_visibility=m.min_visibility, min_snr=m.min_snr, frame_names=names)
    labelled = not any((t.labels < 0).any() for t in truth.values())
    last = max(truth) if truth else -1
    if files is not None:
        files = files[:limit] if limit else files
        if last > files[-1][0] and not limit:
            raise UsageError(f"{truth_path}: frame {last} is beyond the last frame of {source} "
                             f"({files[-1][0]})")
        bits = None  # every frame scaled as the first (16-bit files)
        for number, path in files:
            mask = source / "masks" / path.name if labelled else None
            image, bits = read_frame(path, bits)
            yield number, image, truth.get(number), mask if mask is not None and mask.is_file() else None
        return
    video = VideoSource(source)
    try:
        number = 0
        while (not limit or number < limit) and (frame := video.read()) is not None:
            yield number, frame.image, truth.get(number), None
            number += 1
    finally:
        video.close()
    if last >= number and not limit:
        raise UsageError(f"{truth_path}: frame {last} is beyond the last frame of {source} ({number - 1})")


def _frame_count(source: Path, limit: int | None) -> int | None:
    """The frames :func:`source_truth_frames` gives, for a progress bar: a folder's, a video's declared
    count (None when its container does not say), at most ``limit``."""
    if source.is_dir():
        count = len(frame_files(source))
    else:
        capture = cv2.VideoCapture(str(source))
        count = int(capture.get(cv2.CAP_PROP_FRAME_COUNT)) if capture.isOpened() else 0
        capture.release()
        if count <= 0:
            return limit
    return min(count, limit) if limit else count


def evaluate_source(source: Path, detector: Detector, m: Matching, truth_path: Path | None = None,
                    limit: int | None = None) -> list[FrameScore]:
    """Run ``detector`` on a folder of frames or a video file and score it against its truth
    (:func:`source_truth_frames`); pixel metrics where a simulator folder has masks/."""
    scores = []
    detector.reset()
    for frame, image, truth, mask_path in progress(source_truth_frames(source, m, truth_path, limit),
                                                   total=_frame_count(source, limit),
                                                   desc=f"evaluate {detector.name}", leave=False):
        masks = None
        if mask_path is not None:
            labels = cv2.imread(str(mask_path), cv2.IMREAD_UNCHANGED)
            if labels is None:
                raise UsageError(f"{mask_path}: not a readable mask image")
            if labels.shape[:2] != image.shape[:2]:
                raise UsageError(f"{mask_path}: mask is {labels.shape[1]}x{labels.shape[0]}, "
                                 f"frame is {image.shape[1]}x{image.shape[0]}")
            masks = _label_masks(labels, truth)
        found = detector.detect(image)
        scores.append(_score(frame, truth, found.centres, found.radii, m, masks))
    return scores


def evaluate_source_tracking(source: Path, detector: Detector, m: Matching, truth_path: Path | None = None, *,
                             fps: float | None = None, limit: int | None = None) -> dict[str, Any]:
    """:func:`evaluate_tracking` on a folder of frames or a video file with truth ids
    (:func:`source_truth_frames`); ``fps``: the frame rate the tracker assumes (None: the
    video's, else 60)."""
    if fps is None:
        fps = 60.0
        if source.is_file():
            with VideoSource(source) as video:
                fps = video.fps or fps
    empty = FrameTruth.empty()

    def frames():
        for number, image, truth, _ in source_truth_frames(source, m, truth_path, limit):
            truth = truth if truth is not None else empty
            if (truth.ids < 0).any():
                raise UsageError(f"{truth_path or source / 'truth.csv'}: tracking figures need particle ids "
                                 "(an 'id' column, or the simulator's 'Bubble ID')")
            yield number, image, truth
    return evaluate_tracking(frames(), detector, m, fps=fps)


def evaluate_folder(folder: Path, detector: Detector, m: Matching) -> list[FrameScore]:
    """Run ``detector`` on a simulator output folder; pixel metrics where masks/ exist."""
    return evaluate_source(folder, detector, m)


def scenario_frames(preset: str, size: tuple[int, int], frames: int,
                    seed: int) -> Iterator[tuple[int, np.ndarray, np.ndarray, Any]]:
    """(frame, image, labels, truth) of a scenario, generated in memory."""
    scene = make_scene(preset, rng=np.random.default_rng(seed), size=size)
    labels = np.zeros((scene.size[1], scene.size[0]), np.uint16)
    for index in range(frames):
        if index:
            scene.step()
        image = scene.render(labels=labels)
        yield index, image, labels, scene.truth()


def truth_of(scene_truth: Any, m: Matching) -> FrameTruth:
    """A simulator Truth as FrameTruth with the counting rule applied."""
    counted = (scene_truth.visibility >= m.min_visibility) & (scene_truth.labels > 0) & (scene_truth.snr >= m.min_snr)
    return FrameTruth(scene_truth.centres, scene_truth.radii, counted, scene_truth.labels.astype(np.int64),
                      scene_truth.ids.astype(np.int64))


def evaluate_scenario(preset: str, size: tuple[int, int], frames: int, seed: int,
                      detectors: dict[str, Detector], m: Matching) -> dict[str, list[FrameScore]]:
    """Every detector on the same in-memory scenario frames."""
    scores: dict[str, list[FrameScore]] = {name: [] for name in detectors}
    for detector in detectors.values():
        detector.reset()  # a new scene: nothing learnt carries over
    for index, image, labels, scene_truth in progress(scenario_frames(preset, size, frames, seed), total=frames,
                                                      desc=f"evaluate {preset}", leave=False):
        truth = truth_of(scene_truth, m)
        masks = _label_masks(labels, truth)
        for name, detector in detectors.items():
            found = detector.detect(image)
            scores[name].append(_score(index, truth, found.centres, found.radii, m, masks))
    return scores


def evaluate_pairs(pairs: list[tuple[Path, Path]], detector: Detector, m: Matching, *,
                   rise: float = 20.0, min_area: int = 3) -> list[FrameScore]:
    """Score ``detector`` on real degraded images against truth from their clean references."""
    scores = []
    for index, (degraded_path, clean_path) in enumerate(progress(pairs, desc=f"evaluate {detector.name}", unit="pair",
                                                                 leave=False)):
        degraded, bits = read_frame(degraded_path)
        clean, _ = read_frame(clean_path, bits)  # a 16-bit pair scaled alike
        try:
            centres, radii, particle, small = reference_truth(degraded, clean, rise=rise, min_area=min_area)
        except ValueError as exc:
            raise UsageError(f"{degraded_path}: {exc} ({clean_path})") from None
        truth = FrameTruth(centres, radii, np.ones(len(radii), bool), np.arange(1, len(radii) + 1))
        detector.reset()  # unrelated images: nothing learnt carries over
        found = detector.detect(degraded)
        scores.append(_score(index, truth, found.centres, found.radii, m, (particle, small)))
    return scores


def evaluate_tracking(frames_iter, detector: Detector, m: Matching, *, fps: float) -> dict[str, Any]:
    """Run ``detector`` and a :class:`~antiscatter.tracking.Tracker` over (index, image, truth) frames.

    Returns {"tracking": MOTA, IDF1, switches..., "tracking_isolated": the same over the particles
    that overlap no other (the others neither to be found nor false alarms), "prediction": error
    at +1, +2, +3 frames}.
    """
    from ..assignment import gates as _gates, match as _match
    from ..system import make_tracker
    from .tracking import PredictionError, TrackingScore, isolated

    detector.reset()
    tracker = make_tracker()
    score = TrackingScore(min_gate=m.min_gate, gate_scale=m.gate_scale)
    alone = TrackingScore(min_gate=m.min_gate, gate_scale=m.gate_scale)  # particles that overlap none
    prediction = PredictionError()
    dt = 1.0 / fps
    for index, image, truth in progress(frames_iter, desc="tracking", leave=False):
        found = detector.detect(image)
        if tracker.timestamp is None:  # the first frame: its motion settings are for 800 px wide ones
            tracker.set_frame_size((image.shape[1], image.shape[0]))
        tracks = tracker.update(found, index * dt)
        score.add(truth.ids, truth.centres, truth.radii, truth.counted, found.centres, tracks.detection_ids)
        alone.add(truth.ids, truth.centres, truth.radii, truth.counted & isolated(truth.centres, truth.radii),
                  found.centres, tracks.detection_ids)
        # predictions of confirmed tracks, attributed to the particle their detection matched
        pairs, _, _ = _match(truth.centres, _gates(truth.radii, min_gate=m.min_gate, scale=m.gate_scale),
                             found.centres)
        row = {int(i): n for n, i in enumerate(tracks.ids.tolist())}
        predictions = {}
        for t, d in pairs.tolist():
            n = row.get(int(tracks.detection_ids[d]))
            if n is None or not tracks.confirmed[n] or not truth.counted[t]:
                continue
            predictions[int(truth.ids[t])] = [(k, tracks.centres[n] + tracks.velocities[n] * k * dt)
                                              for k in prediction.horizons]
        prediction.add(index, truth.ids, truth.centres, predictions)
    return {"tracking": score.summary(), "tracking_isolated": alone.summary(), "prediction": prediction.summary()}


def scenario_truth_frames(preset: str, size: tuple[int, int], frames: int, seed: int, m: Matching):
    """(index, image, FrameTruth) of a scenario, for :func:`evaluate_tracking`."""
    for index, image, _labels, scene_truth in scenario_frames(preset, size, frames, seed):
        yield index, image, truth_of(scene_truth, m)
