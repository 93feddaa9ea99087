"""Tracking and latency-compensated prediction: put the holes where the particles will be.

:class:`Tracker` is the one stateful object: call ``update(detections,
timestamp)`` every frame, even with none; ask ``holes(at)`` for where the
particles will be when the light is on, or ``snapshot()`` for a frozen
:class:`Prediction` that gives holes for any later time.  ``run`` and the twin draw a pattern's
holes for the middle of the time it stays on (``PREDICT_AHEAD`` of a frame period after it goes on).
"""

from .kalman import PREDICT_AHEAD, Prediction, Tracker, Tracks

__all__ = ["Tracker", "Tracks", "Prediction", "PREDICT_AHEAD"]
