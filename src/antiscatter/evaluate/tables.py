"""Reading truth and detection CSVs, with one-line errors naming the file and row."""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import UsageError

__all__ = ["FrameTruth", "read_truth", "read_detections"]


@dataclass(frozen=True)
class FrameTruth:
    """Truth of one frame: centres (N, 2), radii (N,), counted (N,) bool, labels (N,) int (the
    simulator's label image values; -1 for truth without one), ids (N,) int (-1: none)."""

    centres: np.ndarray
    radii: np.ndarray
    counted: np.ndarray
    labels: np.ndarray
    ids: np.ndarray | None = None

    @classmethod
    def empty(cls) -> "FrameTruth":
        """A frame without truth."""
        return cls(np.empty((0, 2)), np.empty(0), np.empty(0, bool), np.empty(0, np.int64), np.empty(0, np.int64))


def _rows(path: Path) -> tuple[list[str] | None, list[tuple[int, list[str]]]]:
    """(the first row, stripped -- a header, or a MOTChallenge line --, the other rows numbered
    from 2); (None, []) for an empty file.  A file that is not UTF-8 is an error naming it."""
    try:
        handle = path.open(newline="")
    except FileNotFoundError:
        raise UsageError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise UsageError(f"{path}: is a folder, expected a CSV file") from None
    with handle:
        reader = csv.reader(handle)
        try:
            header = next(reader, None)
            if header is None:
                return None, []
            return [h.strip() for h in header], list(enumerate(reader, start=2))
        except UnicodeDecodeError:
            raise UsageError(f"{path}: not UTF-8 text; allowed a UTF-8 CSV file") from None


def _index(path: Path, header: list[str], required: tuple[str, ...]) -> dict[str, int]:
    """Column name -> position; a required column missing is an error naming the file."""
    missing = [c for c in required if c not in header]
    if missing:
        raise UsageError(f"{path}: missing column {missing[0]!r} (header has: {', '.join(header)})")
    return {name: header.index(name) for name in header}


#: MOTChallenge ground truth and results, as the benchmark's devkit and annotation tools (CVAT's
#: "MOT 1.1" export) write them: no header; frame (numbered from 1), id, bb_left, bb_top,
#: bb_width, bb_height (pixels), then optionally whether the box is considered (0 = ignore it),
#: class and visibility (0..1); later columns are ignored
MOT_COLUMNS = ("frame", "id", "bb_left", "bb_top", "bb_width", "bb_height", "considered", "class", "visibility")


def _is_mot(first: list[str]) -> bool:
    """True when a file's first row is a MOTChallenge line (six or more numbers), not a header."""
    if len(first) < 6:
        return False
    try:
        [float(field) for field in first]
    except ValueError:
        return False
    return True


def _mot_rows(path: Path, first: list[str], rows: list[tuple[int, list[str]]]):
    """The boxes of a MOTChallenge file as discs: (line, frame from 0, id, x, y, radius, considered,
    visibility) -- the box's centre, and half its mean side for the radius (a particle's box
    encloses it)."""
    for line, row in [(1, first)] + rows:
        if not "".join(row).strip():
            continue
        if len(row) < 6:
            raise UsageError(f"{path} row {line}: has {len(row)} fields; a MOTChallenge line has at least 6: "
                             "frame,id,bb_left,bb_top,bb_width,bb_height")
        values = [_number(path, line, name, text.strip()) for name, text in zip(MOT_COLUMNS, row)]
        for name in ("frame", "id"):
            value = values[MOT_COLUMNS.index(name)]
            if value != int(value):
                raise UsageError(f"{path} row {line}: {name} {row[MOT_COLUMNS.index(name)].strip()!r} is not "
                                 "an integer")
        frame, ident = int(values[0]), int(values[1])
        if frame < 1:
            raise UsageError(f"{path} row {line}: frame {frame}: MOTChallenge frames are numbered from 1")
        left, top, width, height = values[2:6]
        if width < 0 or height < 0:
            raise UsageError(f"{path} row {line}: bb_width and bb_height must be >= 0; got {width:g}, {height:g}")
        considered = values[6] != 0 if len(values) > 6 else True
        visibility = values[8] if len(values) > 8 else 1.0
        yield line, frame - 1, ident, left + width / 2, top + height / 2, (width + height) / 4, considered, visibility


def _number(path: Path, line: int, name: str, text: str, *, integer: bool = False,
            non_negative: bool = False) -> float:
    try:
        value = int(text) if integer else float(text)
    except ValueError:
        kind = "an integer" if integer else "a number"
        raise UsageError(f"{path} row {line}: {name} {text!r} is not {kind}") from None
    if not integer and not math.isfinite(value):
        raise UsageError(f"{path} row {line}: {name} {text!r} is not a finite number")
    if non_negative and value < 0:
        raise UsageError(f"{path} row {line}: {name} {text!r} is negative; allowed >= 0")
    return value


#: the columns of a truth CSV -- frame, x, y, radius, id -- as the simulator names them (the
#: report's names; the first four required), and as a detections CSV does, which hand
#: annotations can use (the first three required; the id also as ``track_id``)
SIMULATOR_COLUMNS = ("Frame #", "X Position", "Y Position", "Radius", "Bubble ID")
PLAIN_COLUMNS = ("frame", "x", "y", "radius", "id")


def read_truth(path: str | Path, *, min_visibility: float = 0.5, min_snr: float = 5.0,
               frame_names: dict[str, int] | None = None) -> dict[int, FrameTruth]:
    """A truth CSV -> {frame: FrameTruth}.

    Two headers are read: the simulator's ``truth.csv`` (Bubble ID, Frame #, X Position,
    Y Position, Radius, and optionally Visibility, Label, SNR), where a particle is counted
    when its Visibility >= ``min_visibility``, its Label > 0 and its SNR >= ``min_snr``
    (columns that are absent count as satisfied); or the plain ``frame,x,y`` of a detections
    CSV, with optional ``radius`` and ``id`` (or ``track_id``, as ``run --detections`` writes)
    -- hand annotations, every row counted.  Without a radius (points clicked on particle
    centres) a detection matches within the matching's smallest distance (``--min-gate``).
    Other columns are allowed and ignored.
    ``frame_names``: file name -> frame number of the frames' folder; the plain ``frame``
    column may then name each row's image file (as annotation tools export) instead of its
    number.
    """
    path = Path(path)
    header, rows = _rows(path)
    if header is None:
        raise UsageError(f"{path}: empty; expected the header frame,x,y[,radius][,id], the simulator's "
                         "Bubble ID,Frame #,X Position,Y Position,Radius, or MOTChallenge lines")
    if _is_mot(header):
        return _mot_truth(path, header, rows, min_visibility)
    index = _index(path, header, ())
    plain = all(c in index for c in PLAIN_COLUMNS[:3])
    if not plain:
        missing = [c for c in SIMULATOR_COLUMNS[:4] if c not in index]
        if missing:
            raise UsageError(f"{path}: missing column {missing[0]!r} (header has: {', '.join(index)}); "
                             "allowed: the header frame,x,y[,radius][,id], the simulator's "
                             "Frame #,X Position,Y Position,Radius, or MOTChallenge lines without a header")
    c_frame, c_x, c_y, c_r, c_id = PLAIN_COLUMNS if plain else SIMULATOR_COLUMNS
    if plain and c_id not in index:
        c_id = "track_id"
    frames: dict[int, list] = {}
    for line, row in rows:
        if not row:
            continue
        if len(row) > len(index):
            raise UsageError(f"{path} row {line}: has {len(row)} fields, the header has {len(index)}")
        try:
            text = row[index[c_frame]].strip()
            if plain and frame_names is not None and text in frame_names:
                frame = frame_names[text]
            elif plain and frame_names is not None and not text.lstrip("-").isdigit():
                raise UsageError(f"{path} row {line}: frame {text!r} is neither a frame number nor the "
                                 "name of an image among the frames")
            else:
                frame = int(_number(path, line, c_frame, text, integer=True))
            if frame < 0:
                raise UsageError(f"{path} row {line}: {c_frame} {frame} is negative; allowed >= 0")
            x = _number(path, line, c_x, row[index[c_x]])
            y = _number(path, line, c_y, row[index[c_y]])
            r = _number(path, line, c_r, row[index[c_r]], non_negative=True) if c_r in index else 0.0
            ident = int(_number(path, line, c_id, row[index[c_id]], integer=True)) if c_id in index else -1
            if plain:  # counted; no label image goes with it (label -1)
                vis, label, snr = 1.0, -1, math.inf
            else:
                vis = float(row[index["Visibility"]]) if "Visibility" in index else 1.0
                label = int(row[index["Label"]]) if "Label" in index else 1
                snr = float(row[index["SNR"]]) if "SNR" in index else math.inf
        except IndexError:
            raise UsageError(f"{path} row {line}: has {len(row)} fields, the header has {len(index)}") from None
        except ValueError:
            raise UsageError(f"{path} row {line}: Visibility, Label or SNR is not a number") from None
        counted = plain or (vis >= min_visibility and label > 0 and snr >= min_snr)
        frames.setdefault(frame, []).append((x, y, r, counted, label, ident))
    return _frame_truth(frames)


def _mot_truth(path: Path, first: list[str], rows: list, min_visibility: float) -> dict[int, FrameTruth]:
    """read_truth of a MOTChallenge file: a box counts when it is considered and its visibility is at
    least ``min_visibility`` (the rest is neither to be found nor a false alarm)."""
    frames: dict[int, list] = {}
    for _, frame, ident, x, y, r, considered, visibility in _mot_rows(path, first, rows):
        frames.setdefault(frame, []).append((x, y, r, considered and visibility >= min_visibility, -1, ident))
    return _frame_truth(frames)


def _frame_truth(frames: dict[int, list]) -> dict[int, FrameTruth]:
    """{frame: [(x, y, radius, counted, label, id), ...]} -> {frame: FrameTruth}."""
    out = {}
    for frame, items in frames.items():
        arr = np.array([item[:3] for item in items], dtype=np.float64).reshape(-1, 3)
        out[frame] = FrameTruth(arr[:, :2], arr[:, 2], np.array([item[3] for item in items], bool),
                                np.array([item[4] for item in items], np.int64),
                                np.array([item[5] for item in items], np.int64))
    return out


def read_detections(path: str | Path, *, frames: range | None = None,
                    frames_source: str = "") -> dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """A detections CSV (``frame,x,y,radius``, optional ``track_id``, more columns allowed) or
    MOTChallenge results (another tracker's: see ``MOT_COLUMNS``; frames from 1, each box a disc)
    -> {frame: (centres, radii, track ids or -1)}.

    A header alone is valid: no detections; an empty file (no header: not written by ``run``, or cut
    short) is refused, as is a row with more fields than the header.  ``frames`` is the
    range of frames the truth covers; a detection outside it is an error naming
    the row (``frames_source`` names the truth in the message).
    """
    path = Path(path)
    header, rows = _rows(path)
    if header is None:
        raise UsageError(f"{path}: empty; expected the header frame,x,y,radius[,track_id] (a run that found "
                         "nothing writes the header alone) or MOTChallenge lines")
    mot = _is_mot(header)
    if mot:  # another tracker's MOTChallenge results: its boxes as discs, its ids
        boxes = ((line, frame, x, y, r, ident) for line, frame, ident, x, y, r, _, _ in _mot_rows(path, header, rows))
    else:
        boxes = _detection_rows(path, _index(path, header, ("frame", "x", "y", "radius")), rows)
    found: dict[int, list] = {}
    for line, frame, x, y, r, track in boxes:
        if frames is not None and frame not in frames:
            numbering = " (counted from 0: the file's MOTChallenge frame numbers less 1)" if mot else ""
            raise UsageError(f"{path} row {line}: frame {frame}{numbering} is not in {frames_source or 'the truth'} "
                             f"(frames {frames.start}..{frames.stop - 1})")
        found.setdefault(frame, []).append((x, y, r, track))
    return {f: (np.array(v)[:, :2], np.array(v)[:, 2], np.array(v)[:, 3].astype(np.int64))
            for f, v in found.items()}


def _detection_rows(path: Path, index: dict[str, int], rows: list[tuple[int, list[str]]]):
    """(line, frame, x, y, radius, track id or -1) of each row of a detections CSV."""
    for line, row in rows:
        if not row:
            continue
        if len(row) > len(index):
            raise UsageError(f"{path} row {line}: has {len(row)} fields, the header has {len(index)}")
        try:
            frame = int(_number(path, line, "frame", row[index["frame"]], integer=True))
            x = _number(path, line, "x", row[index["x"]])
            y = _number(path, line, "y", row[index["y"]])
            r = _number(path, line, "radius", row[index["radius"]], non_negative=True)
            track = (int(_number(path, line, "track_id", row[index["track_id"]], integer=True))
                     if "track_id" in index else -1)
        except IndexError:
            raise UsageError(f"{path} row {line}: has {len(row)} fields, the header has {len(index)}") from None
        yield line, frame, x, y, r, track
