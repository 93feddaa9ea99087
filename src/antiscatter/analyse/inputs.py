"""The inputs of ``analyse``: files named, globbed or listed; each probed once and cut into chunks.

A video is probed by demuxing its packets (no decoding): every frame's presentation time and
which frames are keyframes, so a chunk can seek straight to its first frame.  A frame folder is
listed as :func:`~antiscatter.sources.folder.frame_files` lists it.  Frames are numbered from 0
in presentation order in both.
"""

from __future__ import annotations

import glob
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from ..errors import UsageError
from ..sources.folder import frame_files, read_frame

__all__ = ["Input", "Chunk", "Skipped", "expand_inputs", "probe", "plan_chunks", "read_chunk"]


@dataclass(frozen=True)
class Input:
    """One readable file or folder.

    path: the video file or frame folder; kind: ``video`` or ``folder``.
    times_s: (F,) float64 seconds of each frame from the first (a video's pts * time_base; a
        folder's index / fps).
    keyframes: (K,) int64 frame indices a chunk may start at (every frame of a folder).
    pts: (F,) int64 presentation times in the stream's time base (video; empty for a folder).
    bits: a folder's sample depth, from its first frame, so every chunk scales its frames alike.
    stamp: (size, mtime_ns) of each file read, so a changed input is analysed again.
    damaged: why a video holds fewer frames than its container declares (cut short), "" otherwise.
    """

    path: Path
    kind: str
    times_s: np.ndarray
    keyframes: np.ndarray
    pts: np.ndarray
    bits: int
    stamp: tuple[int, ...]
    damaged: str = ""

    @property
    def frames(self) -> int:
        return len(self.times_s)


@dataclass(frozen=True)
class Chunk:
    """Frames ``start`` .. ``stop - 1`` of ``source``; ``start`` is a keyframe."""

    source: Input
    start: int
    stop: int


@dataclass(frozen=True)
class Skipped:
    """An input that could not be read: its path and why (one line)."""

    path: Path
    reason: str


def expand_inputs(specs: list[str] | tuple[str, ...]) -> list[Path]:
    """Paths from the command line: files, folders, globs (``dives/*.mkv``) and ``@list.txt`` (one
    entry a line, each of these kinds; blank lines and ``#`` comments skipped), in order, each once.

    A missing file, a glob matching nothing or an unreadable list is a UsageError naming it.
    """
    paths: list[Path] = []
    for spec in specs:
        for item in _expand(spec, depth=0):
            if item not in paths:
                paths.append(item)
    if not paths:
        raise UsageError("no inputs given; allowed: video files, frame folders, globs, @list.txt")
    return paths


def _expand(spec: str, depth: int) -> Iterator[Path]:
    if spec.startswith("@"):
        listing = Path(spec[1:])
        if depth > 0:
            raise UsageError(f"{spec}: a list file inside a list file; allowed: paths and globs")
        try:
            lines = listing.read_text().splitlines()
        except (OSError, UnicodeDecodeError) as exc:
            raise UsageError(f"{spec}: cannot read the list file ({getattr(exc, 'strerror', None) or exc})") from None
        for line in lines:
            line = line.strip()
            if line and not line.startswith("#"):
                entry = line if Path(line).is_absolute() else str(listing.parent / line)
                yield from _expand(entry, depth + 1)
        return
    if glob.has_magic(spec):
        matches = sorted(glob.glob(spec))
        if not matches:
            raise UsageError(f"{spec}: the pattern matches no file or folder")
        yield from (Path(m) for m in matches)
        return
    path = Path(spec)
    if not path.exists():
        raise UsageError(f"{spec}: no such file or folder")
    yield path


def _stamp(path: Path) -> tuple[int, int]:
    info = path.stat()
    return info.st_size, info.st_mtime_ns


def probe(path: Path, *, fps: float) -> Input:
    """Probe ``path`` (a video file or a frame folder; ``fps``: a folder's frame rate, frames a second).

    Raises ValueError with a one-line reason when it cannot be read (not a video, no frames,
    damaged headers); the caller reports it and goes on.
    """
    if path.is_dir():
        files = [p for _, p in frame_files(path)]
        if not files:
            raise ValueError("no frames in this folder")
        try:
            _, bits = read_frame(files[0])
        except UsageError as exc:
            raise ValueError(str(exc)) from None
        count = len(files)
        stamp = tuple(v for p in files for v in _stamp(p))
        return Input(path, "folder", np.arange(count) / fps, np.arange(count, dtype=np.int64),
                     np.empty(0, np.int64), bits, stamp)
    import av

    try:
        with av.open(str(path)) as container:
            if not container.streams.video:
                raise ValueError("no video stream")
            stream = container.streams.video[0]
            pts, keys = [], []
            for packet in container.demux(stream):
                if packet.pts is None or packet.size == 0:
                    continue
                pts.append(packet.pts)
                keys.append(packet.is_keyframe)
            base = float(stream.time_base)
            declared = stream.frames or (round(container.duration / 1e6 * float(stream.average_rate))
                                         if container.duration and stream.average_rate else 0)
    except (av.FFmpegError, OSError) as exc:
        raise ValueError(f"cannot be read as a video ({_reason(exc)})") from None
    if not pts:
        raise ValueError("no video frames")
    order = np.argsort(np.asarray(pts, np.int64), kind="stable")
    pts_sorted = np.asarray(pts, np.int64)[order]
    keyframes = np.flatnonzero(np.asarray(keys, bool)[order]).astype(np.int64)
    if len(keyframes) == 0 or keyframes[0] != 0:
        keyframes = np.concatenate([[0], keyframes]).astype(np.int64)
    times = (pts_sorted - pts_sorted[0]) * base
    damaged = ""
    if len(pts) < declared - 1:  # one frame's rounding allowed, as the video source does
        damaged = (f"ended after {len(pts)} of the {declared} frames its container declares (cut short or "
                   "damaged); the frames read were used")
    return Input(path, "video", times, keyframes, pts_sorted, 8, _stamp(path), damaged)


def _reason(exc: BaseException) -> str:
    text = getattr(exc, "strerror", None) or str(exc)
    return text.splitlines()[0] if text else type(exc).__name__


def plan_chunks(source: Input, chunk_frames: int) -> list[Chunk]:
    """Cut ``source`` into chunks of about ``chunk_frames`` frames, each starting at a keyframe (the
    first keyframe at or after every multiple of ``chunk_frames``), so every chunk decodes alone."""
    if chunk_frames < 1:
        raise ValueError(f"chunk_frames: got {chunk_frames}, allowed >= 1")
    starts = [0]
    for target in range(chunk_frames, source.frames, chunk_frames):
        at = int(np.searchsorted(source.keyframes, target))
        if at < len(source.keyframes) and source.keyframes[at] > starts[-1]:
            starts.append(int(source.keyframes[at]))
    starts = sorted(set(starts))
    stops = starts[1:] + [source.frames]
    return [Chunk(source, a, b) for a, b in zip(starts, stops) if b > a]


def read_chunk(chunk: Chunk) -> Iterator[tuple[int, np.ndarray]]:
    """(frame index, image) of each frame of ``chunk`` in order: (H, W) grey or (H, W, 3) BGR uint8.

    A video is sought to the chunk's keyframe with PyAV and decoded to its last frame; a frame
    missing from the decoded stream raises ValueError naming it.
    """
    source = chunk.source
    if source.kind == "folder":
        files = [p for _, p in frame_files(source.path)]
        for index in range(chunk.start, chunk.stop):
            try:
                image, _ = read_frame(files[index], source.bits)
            except UsageError as exc:
                raise ValueError(str(exc)) from None
            yield index, image
        return
    import av

    index_of = {int(p): i for i, p in enumerate(source.pts.tolist())}
    expected = chunk.start
    with av.open(str(source.path)) as container:
        stream = container.streams.video[0]
        stream.codec_context.thread_count = 1  # one core a task: the scheduler runs one task per core
        first = int(source.pts[chunk.start])
        if chunk.start > 0:
            container.seek(first, stream=stream, backward=True, any_frame=False)
        try:
            for frame in container.decode(stream):
                if frame.pts is None:
                    continue
                index = index_of.get(int(frame.pts))
                if index is None or index < chunk.start:
                    continue
                if index >= chunk.stop:
                    break
                if index != expected:
                    raise ValueError(f"frame {expected} could not be decoded (the stream went on at frame {index})")
                grey = frame.format.name in ("gray", "gray8", "y8")
                yield index, frame.to_ndarray(format="gray" if grey else "bgr24")
                expected += 1
        except av.FFmpegError as exc:
            raise ValueError(f"frame {expected} could not be decoded ({_reason(exc)})") from None
    if expected < chunk.stop:
        raise ValueError(f"frames {expected}..{chunk.stop - 1} could not be decoded (the file ended early)")


def frame_rate(source: Input) -> float:
    """Frames a second over the source (its frames over its span; NaN with one frame)."""
    if source.frames < 2:
        return math.nan
    return (source.frames - 1) / float(source.times_s[-1] - source.times_s[0])
