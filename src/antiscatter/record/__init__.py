"""Lossless recording: frames into a bounded RAM buffer, FFV1 in Matroska encoded in a worker thread."""

from .recorder import SIDECAR_COLUMNS, TIME_BASE, Recorder, RecorderFull, pixel_format, sidecar_path

__all__ = ["Recorder", "RecorderFull", "pixel_format", "sidecar_path", "SIDECAR_COLUMNS", "TIME_BASE"]
