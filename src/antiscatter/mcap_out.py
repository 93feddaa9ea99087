"""The run's frames, detections, projector pattern and metrics as ROS 2 messages in an MCAP file.

ROS 2 tools (``ros2 bag``), Foxglove and the ``mcap`` CLI read the file without conversion: every
message is CDR-encoded against the ROS 2 message definition (below, as the ROS 2 packages define
them), written with the ``mcap`` and ``mcap-ros2-support`` packages (no ROS installation; ``pip
install 'antiscatter[mcap]'``).  Topics:

- ``/antiscatter/camera/image/compressed``: ``sensor_msgs/msg/CompressedImage`` (PNG, lossless)
- ``/antiscatter/detections``: ``vision_msgs/msg/Detection2DArray``, one per frame; each
  detection's ``id`` is its track id (empty when untracked), its box the particle's disc
  (centre, side = diameter, px), its one hypothesis class ``particle`` with the detector's score
- ``/antiscatter/pattern/compressed``: ``sensor_msgs/msg/CompressedImage`` (PNG) of the projector pattern
- ``/antiscatter/metrics``: ``diagnostic_msgs/msg/DiagnosticArray``, one status ``antiscatter``
  whose key/value pairs are the frame's metrics (a standard type every ROS 2 tool shows)

Every message is stamped (header and log time) with the frame's true time, the one the run's CSVs
carry: see :class:`~antiscatter.sources.base.FrameClock`.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .detections import Detections
from .errors import UsageError
from .sources.base import FrameClock

__all__ = ["McapLog", "FrameClock", "MESSAGE_DEFINITIONS", "TOPICS", "require_mcap"]

#: the topics written, by role
TOPICS = {"image": "/antiscatter/camera/image/compressed", "detections": "/antiscatter/detections",
          "pattern": "/antiscatter/pattern/compressed", "metrics": "/antiscatter/metrics"}

_SEPARATOR = "=" * 80

#: ROS 2 (Humble and later) message definitions, as their packages define them
MESSAGE_DEFINITIONS: dict[str, str] = {
    "builtin_interfaces/Time": "int32 sec\nuint32 nanosec\n",
    "std_msgs/Header": "builtin_interfaces/Time stamp\nstring frame_id\n",
    "sensor_msgs/CompressedImage": "std_msgs/Header header\nstring format\nuint8[] data\n",
    "geometry_msgs/Point": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/Quaternion": "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n",
    "geometry_msgs/Pose": "Point position\nQuaternion orientation\n",
    "geometry_msgs/PoseWithCovariance": "Pose pose\nfloat64[36] covariance\n",
    "vision_msgs/Point2D": "float64 x\nfloat64 y\n",
    "vision_msgs/Pose2D": "vision_msgs/Point2D position\nfloat64 theta\n",
    "vision_msgs/BoundingBox2D": "vision_msgs/Pose2D center\nfloat64 size_x\nfloat64 size_y\n",
    "vision_msgs/ObjectHypothesis": "string class_id\nfloat64 score\n",
    "vision_msgs/ObjectHypothesisWithPose": "ObjectHypothesis hypothesis\n"
                                            "geometry_msgs/PoseWithCovariance pose\n",
    "vision_msgs/Detection2D": "std_msgs/Header header\nObjectHypothesisWithPose[] results\n"
                               "BoundingBox2D bbox\nstring id\n",
    "vision_msgs/Detection2DArray": "std_msgs/Header header\nDetection2D[] detections\n",
    "diagnostic_msgs/KeyValue": "string key\nstring value\n",
    "diagnostic_msgs/DiagnosticStatus": "byte OK=0\nbyte WARN=1\nbyte ERROR=2\nbyte STALE=3\nbyte level\n"
                                        "string name\nstring message\nstring hardware_id\nKeyValue[] values\n",
    "diagnostic_msgs/DiagnosticArray": "std_msgs/Header header\nDiagnosticStatus[] status\n",
}

#: each written type's dependencies, in the order ROS 2 lists them after the main definition
_DEPENDENCIES = {
    "sensor_msgs/CompressedImage": ("std_msgs/Header", "builtin_interfaces/Time"),
    "vision_msgs/Detection2DArray": (
        "std_msgs/Header", "builtin_interfaces/Time", "vision_msgs/Detection2D",
        "vision_msgs/ObjectHypothesisWithPose", "vision_msgs/ObjectHypothesis", "geometry_msgs/PoseWithCovariance",
        "geometry_msgs/Pose", "geometry_msgs/Point", "geometry_msgs/Quaternion", "vision_msgs/BoundingBox2D",
        "vision_msgs/Pose2D", "vision_msgs/Point2D"),
    "diagnostic_msgs/DiagnosticArray": ("std_msgs/Header", "builtin_interfaces/Time",
                                        "diagnostic_msgs/DiagnosticStatus", "diagnostic_msgs/KeyValue"),
}

_IDENTITY_POSE = {"pose": {"position": {"x": 0.0, "y": 0.0, "z": 0.0},
                           "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}},
                  "covariance": [0.0] * 36}


def schema_text(name: str) -> str:
    """The concatenated ROS 2 definition of ``name`` with its dependencies (the rosbag2 form)."""
    parts = [MESSAGE_DEFINITIONS[name]]
    for dependency in _DEPENDENCIES.get(name, ()):
        parts.append(f"{_SEPARATOR}\nMSG: {dependency}\n{MESSAGE_DEFINITIONS[dependency]}")
    return "\n".join(parts)


def require_mcap() -> None:
    """A one-line UsageError naming the install command when the ``mcap`` extra is missing."""
    try:
        import mcap  # noqa: F401
        import mcap_ros2.writer  # noqa: F401
    except ImportError:
        raise UsageError("--mcap needs the mcap packages: pip install 'antiscatter[mcap]'") from None


def _stamp(ns: int) -> dict[str, int]:
    return {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}


def _png(image: np.ndarray) -> bytes:
    """Lossless PNG bytes of a grey or BGR uint8 image (fastest compression: the log is off the latency path)."""
    import cv2

    ok, data = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        raise ValueError(f"image of shape {image.shape}: cannot be encoded as PNG")
    return data.tobytes()


class McapLog:
    """Frames, detections, patterns and metrics as ROS 2 messages in one MCAP file.

    Parameters
    ----------
    path : str or Path
        The ``.mcap`` file to write (replaced).
    frame_id : str
        ``header.frame_id`` of every message, the camera's frame (default ``camera``).

    A context manager; :meth:`close` finishes the file (its summary and index), so it opens in
    every MCAP tool however the run ended.
    """

    def __init__(self, path: str | Path, *, frame_id: str = "camera") -> None:
        require_mcap()
        from mcap_ros2.writer import Writer

        self.path = Path(path)
        self.frame_id = frame_id
        self._file = self.path.open("wb")
        self._writer = Writer(self._file)
        self._schemas = {name: self._writer.register_msgdef(name.replace("/", "/msg/", 1), schema_text(name))
                         for name in _DEPENDENCIES}
        self._sequence = 0
        self.messages = 0

    def _header(self, stamp_ns: int) -> dict[str, Any]:
        return {"stamp": _stamp(stamp_ns), "frame_id": self.frame_id}

    def _put(self, role: str, schema: str, message: dict, stamp_ns: int) -> None:
        self._writer.write_message(TOPICS[role], self._schemas[schema], message, log_time=stamp_ns,
                                   publish_time=stamp_ns, sequence=self._sequence)
        self.messages += 1

    def write(self, stamp_ns: int, *, image: np.ndarray | None = None, detections: Detections | None = None,
              track_ids: np.ndarray | None = None, pattern: np.ndarray | None = None,
              metrics: Mapping[str, float | int | str] | None = None) -> None:
        """One frame's messages, each stamped ``stamp_ns`` (UNIX ns); what is None is not written.

        image, pattern: (H, W) or (H, W, 3) uint8; detections: the frame's particles (px);
        track_ids: (N,) int64 track id per detection (-1 untracked; default: the detections' own);
        metrics: the frame's figures by name (seconds, counts).
        """
        header = self._header(stamp_ns)
        if image is not None:
            self._put("image", "sensor_msgs/CompressedImage",
                      {"header": header, "format": "png", "data": _png(image)}, stamp_ns)
        if detections is not None:
            ids = detections.track_ids if track_ids is None else np.asarray(track_ids, np.int64)
            items = []
            for (x, y), r, score, track in zip(detections.centres.tolist(), detections.radii.tolist(),
                                               detections.scores.tolist(), ids.tolist()):
                items.append({
                    "header": header,
                    "results": [{"hypothesis": {"class_id": "particle",
                                                "score": 0.0 if math.isnan(score) else score},
                                 "pose": _IDENTITY_POSE}],
                    "bbox": {"center": {"position": {"x": x, "y": y}, "theta": 0.0},
                             "size_x": 2 * r, "size_y": 2 * r},
                    "id": "" if track < 0 else str(track)})
            self._put("detections", "vision_msgs/Detection2DArray", {"header": header, "detections": items},
                      stamp_ns)
        if pattern is not None:
            self._put("pattern", "sensor_msgs/CompressedImage",
                      {"header": header, "format": "png", "data": _png(pattern)}, stamp_ns)
        if metrics is not None:
            values = [{"key": key, "value": f"{value:.9g}" if isinstance(value, float) else str(value)}
                      for key, value in metrics.items()]
            self._put("metrics", "diagnostic_msgs/DiagnosticArray",
                      {"header": header, "status": [{"level": 0, "name": "antiscatter", "message": "",
                                                     "hardware_id": self.frame_id, "values": values}]}, stamp_ns)
        self._sequence += 1

    def close(self) -> None:
        """Finish the file (summary, index): it opens in every MCAP tool."""
        if self._file.closed:
            return
        try:
            self._writer.finish()
        finally:
            self._file.close()

    def __enter__(self) -> "McapLog":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
