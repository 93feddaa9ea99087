"""Truth from real images: a degraded frame and its clean reference.

The particle mask is ``max over channels |degraded - clean| > rise``; each
8-connected region of at least ``min_area`` pixels is one particle (its centroid
and equivalent radius are the truth).  This is how the MSRB images in
``shared/data/msrb`` are scored (overlapping particles merge into one region).
"""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np

from ..errors import UsageError

__all__ = ["reference_truth", "pair_files", "msrb_pairs"]


def reference_truth(degraded: np.ndarray, clean: np.ndarray, *, rise: float = 20.0,
                    min_area: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(centres (N, 2), radii (N,), particle mask (H, W) bool, small-region mask (H, W) bool)."""
    if degraded.shape != clean.shape:
        raise ValueError(f"size mismatch: degraded {degraded.shape[1]}x{degraded.shape[0]}, "
                         f"clean {clean.shape[1]}x{clean.shape[0]}")
    diff = cv2.absdiff(degraded, clean)
    if diff.ndim == 3:
        diff = diff.max(axis=2)
    mask = (diff > rise).astype(np.uint8)
    n, labels, stats, centroids = cv2.connectedComponentsWithStats(mask, connectivity=8)
    areas = stats[1:, cv2.CC_STAT_AREA]
    keep = np.flatnonzero(areas >= min_area) + 1
    big = np.zeros(n, bool)
    big[keep] = True
    particle = big[labels] & (labels > 0)
    small = (labels > 0) & ~particle
    return centroids[keep].astype(np.float64), np.sqrt(areas[keep - 1] / np.pi), particle, small


def pair_files(degraded: Path, clean: Path) -> list[tuple[Path, Path]]:
    """Pairs from two files, or from two folders by equal file names."""
    if not degraded.exists():
        raise UsageError(f"--degraded {degraded}: no such file or folder")
    if not clean.exists():
        raise UsageError(f"--clean {clean}: no such file or folder")
    if degraded.is_file() and clean.is_file():
        return [(degraded, clean)]
    if degraded.is_dir() and clean.is_dir():
        names = sorted(p.name for p in degraded.iterdir() if p.suffix.lower() in (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff"))
        pairs = [(degraded / n, clean / n) for n in names if (clean / n).is_file()]
        if not pairs:
            raise UsageError(f"--degraded {degraded} and --clean {clean}: no image names in common")
        return pairs
    raise UsageError("--degraded and --clean must both be files or both be folders")


_MSRB = re.compile(r"^(.+)_orig\.png$")


def msrb_pairs(folder: Path) -> list[tuple[str, Path, Path]]:
    """(name, degraded, clean) for every ``<id>_taskN.png`` beside an ``<id>_orig.png``."""
    out = []
    for clean in sorted(folder.glob("*_orig.png")):
        stem = _MSRB.match(clean.name).group(1)
        for degraded in sorted(folder.glob(f"{stem}_task*.png")):
            out.append((degraded.stem, degraded, clean))
    return out
