"""The volume model of ``analyse``: how many litres a frame images and how large a pixel is.

The camera images a rectangular frustum: its horizontal and vertical fields of view between a
near and a far distance (the particles counted lie there: closer ones are out of focus or
shadowed by the housing, farther ones too dark under the lamp).  Its volume is

    V = 4 tan(hfov / 2) tan(vfov / 2) (far^3 - near^3) / 3      (cubic metres; x 1000 litres)

and a pixel at the reference distance d spans 2 d tan(hfov / 2) / width metres.  A particle's
equivalent-spherical diameter (ESD) is its detected diameter in pixels times that.  Size classes
are the UVP's: log-spaced, each 2^(1/3) times the last, on the grid 0.001 mm * 2^(k/3) (so 1.02,
1.29, 1.63, 2.05 ... mm).  Why this model: docs/decisions/006-analyse-and-mcap.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["VolumeModel", "frustum_litres", "metres_per_pixel", "esd_classes", "UVP_STEP", "UVP_BASE_MM"]

#: ratio of one UVP size class's bounds
UVP_STEP = 2.0 ** (1.0 / 3.0)
#: the UVP class grid's origin, mm: bounds are UVP_BASE_MM * UVP_STEP ** k
UVP_BASE_MM = 0.001


def frustum_litres(hfov_deg: float, vfov_deg: float, near_m: float, far_m: float) -> float:
    """Litres inside the camera's field of view (degrees, each side) between near_m and far_m (metres)."""
    tx = math.tan(math.radians(hfov_deg) / 2)
    ty = math.tan(math.radians(vfov_deg) / 2)
    return 4 * tx * ty * (far_m ** 3 - near_m ** 3) / 3 * 1000.0


def metres_per_pixel(hfov_deg: float, width_px: int, distance_m: float) -> float:
    """Metres a pixel spans at ``distance_m`` for a frame ``width_px`` wide seeing ``hfov_deg``."""
    return 2 * distance_m * math.tan(math.radians(hfov_deg) / 2) / width_px


def esd_classes(low_mm: float, high_mm: float) -> np.ndarray:
    """(C + 1,) bounds, mm, of the UVP classes covering ``low_mm`` .. ``high_mm`` (whole classes)."""
    if not (0 < low_mm < high_mm and math.isfinite(high_mm)):
        raise ValueError(f"classes: got {low_mm:g}..{high_mm:g} mm, allowed 0 < low < high")
    k0 = math.floor(3 * math.log2(low_mm / UVP_BASE_MM) + 1e-9)
    k1 = math.ceil(3 * math.log2(high_mm / UVP_BASE_MM) - 1e-9)
    return UVP_BASE_MM * UVP_STEP ** np.arange(k0, max(k1, k0 + 1) + 1)


@dataclass(frozen=True)
class VolumeModel:
    """The camera's view and the depth range counted; a bad value raises ValueError naming it.

    hfov_deg: horizontal field of view, degrees (default 63: the IMX296 behind a 6 mm lens, as the twin).
    vfov_deg: vertical field of view, degrees; 0 = from hfov and the frame's aspect (default 0).
    near_m, far_m: the depth range whose particles are counted, metres (default 0.3 .. 1.5: the lamp's
        useful reach in turbid water; set your own).
    reference_m: distance at which pixels are converted to millimetres; 0 = the range's middle (default 0).
    """

    hfov_deg: float = 63.0
    vfov_deg: float = 0.0
    near_m: float = 0.3
    far_m: float = 1.5
    reference_m: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.hfov_deg) and 0 < self.hfov_deg < 180):
            raise ValueError(f"hfov_deg: got {self.hfov_deg}, allowed 0 < hfov_deg < 180")
        if not (math.isfinite(self.vfov_deg) and 0 <= self.vfov_deg < 180):
            raise ValueError(f"vfov_deg: got {self.vfov_deg}, allowed 0 (from the aspect) or 0 < vfov_deg < 180")
        if not (math.isfinite(self.near_m) and math.isfinite(self.far_m) and 0 <= self.near_m < self.far_m):
            raise ValueError(f"near_m, far_m: got {self.near_m}, {self.far_m}, allowed 0 <= near_m < far_m")
        if not (math.isfinite(self.reference_m) and self.reference_m >= 0):
            raise ValueError(f"reference_m: got {self.reference_m}, allowed >= 0 (0 = the range's middle)")

    def vfov_for(self, width_px: int, height_px: int) -> float:
        """The vertical field of view, degrees, for frames of this size."""
        if self.vfov_deg:
            return self.vfov_deg
        return math.degrees(2 * math.atan(math.tan(math.radians(self.hfov_deg) / 2) * height_px / width_px))

    def litres(self, width_px: int, height_px: int) -> float:
        """Litres one frame of this size images."""
        return frustum_litres(self.hfov_deg, self.vfov_for(width_px, height_px), self.near_m, self.far_m)

    def mm_per_pixel(self, width_px: int) -> float:
        """Millimetres a pixel spans at the reference distance, for frames ``width_px`` wide."""
        distance = self.reference_m or (self.near_m + self.far_m) / 2
        return metres_per_pixel(self.hfov_deg, width_px, distance) * 1000.0
