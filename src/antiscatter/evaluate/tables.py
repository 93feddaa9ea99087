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


def _rows(path: Path, required: tuple[str, ...]):
    try:
        handle = path.open(newline="")
    except FileNotFoundError:
        raise UsageError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise UsageError(f"{path}: is a folder, expected a CSV file") from None
    with handle:
        reader = csv.reader(handle)
        header = next(reader, None)
        if header is None:
            return None, iter(())
        header = [h.strip() for h in header]
        missing = [c for c in required if c not in header]
        if missing:
            raise UsageError(f"{path}: missing column {missing[0]!r} (header has: {', '.join(header)})")
        index = {name: header.index(name) for name in header}
        rows = list(enumerate(reader, start=2))
    return index, iter(rows)


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
    index, rows = _rows(path, ())
    if index is None:
        raise UsageError(f"{path}: empty; expected the header frame,x,y[,radius][,id] or the simulator's "
                         "Bubble ID,Frame #,X Position,Y Position,Radius")
    plain = all(c in index for c in PLAIN_COLUMNS[:3])
    if not plain:
        missing = [c for c in SIMULATOR_COLUMNS[:4] if c not in index]
        if missing:
            raise UsageError(f"{path}: missing column {missing[0]!r} (header has: {', '.join(index)}); "
                             "allowed headers: frame,x,y[,radius][,id] or the simulator's "
                             "Frame #,X Position,Y Position,Radius")
    c_frame, c_x, c_y, c_r, c_id = PLAIN_COLUMNS if plain else SIMULATOR_COLUMNS
    if plain and c_id not in index:
        c_id = "track_id"
    frames: dict[int, list] = {}
    for line, row in rows:
        if not row:
            continue
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
    out = {}
    for frame, items in frames.items():
        arr = np.array([item[:3] for item in items], dtype=np.float64).reshape(-1, 3)
        out[frame] = FrameTruth(arr[:, :2], arr[:, 2], np.array([item[3] for item in items], bool),
                                np.array([item[4] for item in items], np.int64),
                                np.array([item[5] for item in items], np.int64))
    return out


def read_detections(path: str | Path, *, frames: range | None = None,
                    frames_source: str = "") -> dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """A detections CSV (``frame,x,y,radius``, optional ``track_id``, more columns allowed)
    -> {frame: (centres, radii, track ids or -1)}.

    An empty file (or a header alone) is valid: no detections.  ``frames`` is the
    range of frames the truth covers; a detection outside it is an error naming
    the row (``frames_source`` names the truth in the message).
    """
    path = Path(path)
    if path.exists() and path.is_file() and path.stat().st_size == 0:
        return {}
    index, rows = _rows(path, ("frame", "x", "y", "radius"))
    if index is None:
        return {}
    found: dict[int, list] = {}
    for line, row in rows:
        if not row:
            continue
        try:
            frame = int(_number(path, line, "frame", row[index["frame"]], integer=True))
            x = _number(path, line, "x", row[index["x"]])
            y = _number(path, line, "y", row[index["y"]])
            r = _number(path, line, "radius", row[index["radius"]], non_negative=True)
            track = (int(_number(path, line, "track_id", row[index["track_id"]], integer=True))
                     if "track_id" in index else -1)
        except IndexError:
            raise UsageError(f"{path} row {line}: has {len(row)} fields, the header has {len(index)}") from None
        if frames is not None and frame not in frames:
            raise UsageError(f"{path} row {line}: frame {frame} is not in {frames_source or 'the truth'} "
                             f"(frames {frames.start}..{frames.stop - 1})")
        found.setdefault(frame, []).append((x, y, r, track))
    return {f: (np.array(v)[:, :2], np.array(v)[:, 2], np.array(v)[:, 3].astype(np.int64))
            for f, v in found.items()}
