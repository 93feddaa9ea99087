"""Lossless recording: frames into a bounded RAM buffer, FFV1 in Matroska encoded in a worker thread."""

from .recorder import Recorder, RecorderFull, pixel_format

__all__ = ["Recorder", "RecorderFull", "pixel_format"]
