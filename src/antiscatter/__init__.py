"""antiscatter: underwater lighting that avoids the particles in the water.

The pipeline reads sources -> detection -> pattern -> outputs; ``simulate``
makes scenes with ground truth.  The command line is :mod:`antiscatter.cli`.
"""

from __future__ import annotations

__version__ = "0.1.0"

from .detections import Detections  # noqa: E402

__all__ = ["Detections", "__version__"]
