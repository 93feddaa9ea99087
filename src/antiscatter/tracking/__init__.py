"""Tracking and latency-compensated prediction: put the holes where the particles will be.

:class:`Tracker` is the one stateful object: call ``update(detections,
timestamp)`` every frame, even with none; ask ``holes(at)`` for where the
particles will be when the light is on, or ``snapshot()`` for a frozen
:class:`Prediction` that gives holes for each projector refresh's own time.
"""

from .kalman import Prediction, Tracker, Tracks

__all__ = ["Tracker", "Tracks", "Prediction"]
