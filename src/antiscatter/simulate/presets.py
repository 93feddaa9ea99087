"""The realistic presets: named SceneConfigs with their default frame size.

Particle populations are modelled on what a lamp-lit camera sees 0.3-2.5 m in
front of an underwater vehicle: bubbles 1-4 mm in radius rising at 0.15-0.3 m/s
(and wobbling); marine snow flakes 0.5-4 mm, dim and semi-transparent, sinking
at 1-3 cm/s in a drifting current; sand grains 0.2-0.8 mm thrown across the view
at 0.3-1 m/s by a thruster wash (albedo above 1: quartz grains glint).
"""

from __future__ import annotations

from dataclasses import replace

from .scene import KindConfig, SceneConfig

__all__ = ["REALISTIC", "BUBBLES", "SNOW", "SAND"]

BUBBLES = KindConfig(count=120, size_mm=(1.0, 4.0), depth_m=(0.3, 1.5), speed=(0.15, 0.3),
                     direction_deg=-90.0, spread_deg=8.0, albedo=(0.7, 1.0), colour=(1.0, 0.97, 0.9),
                     wobble=0.06, wobble_hz=3.0, growth=0.03)
SNOW = KindConfig(count=250, size_mm=(0.5, 4.0), depth_m=(0.3, 2.0), speed=(0.01, 0.03),
                  direction_deg=90.0, spread_deg=30.0, albedo=(0.25, 0.6), colour=(0.8, 0.95, 1.0),
                  wobble=0.01, wobble_hz=0.5, spin=1.5)
SAND = KindConfig(count=250, size_mm=(0.2, 0.8), depth_m=(0.3, 1.2), speed=(0.3, 1.0),
                  direction_deg=15.0, spread_deg=20.0, albedo=(1.5, 4.0), colour=(0.75, 0.9, 1.0))

_BASE = SceneConfig()

#: name -> (SceneConfig, default (width, height), one-line summary)
REALISTIC: dict[str, tuple[SceneConfig, tuple[int, int], str]] = {
    "bubbles": (replace(_BASE, bubbles=BUBBLES, background="water"), (800, 600),
                "rising bubbles with bright rims and highlights in open water"),
    "snow": (replace(_BASE, snow=SNOW, background="water", current=(0.04, 0.0)), (800, 600),
             "dim, irregular marine snow sinking in a drifting current"),
    "sand": (replace(_BASE, sand=SAND, background="seabed", background_level=70.0), (800, 600),
             "small fast sand grains over the seabed after a thruster wash"),
    "mixed": (replace(_BASE, bubbles=replace(BUBBLES, count=60), snow=replace(SNOW, count=150),
                      sand=replace(SAND, count=100), background="seabed", background_level=60.0,
                      current=(0.02, 0.0)), (800, 600),
              "bubbles, snow and sand together over the seabed"),
    "survey": (replace(_BASE, bubbles=replace(BUBBLES, count=60), snow=replace(SNOW, count=150),
                       sand=replace(SAND, count=100), background="seabed", background_level=60.0,
                       current=(0.02, 0.0), vehicle_m_s=(0.25, 0.0, 0.0), yaw_deg_s=4.0, ground_m=2.5), (800, 600),
               "the mixed scene from a vehicle surveying the seabed 2.5 m away: moving sideways at "
               "0.25 m/s and turning 4 degrees a second"),
    "textured": (replace(_BASE, bubbles=replace(BUBBLES, count=80), snow=replace(SNOW, count=120),
                         background="padding", background_level=170.0), (800, 600),
                 "particles in front of bright quilted tank padding (the report's failure case)"),
    "dense": (replace(_BASE, bubbles=replace(BUBBLES, count=250), snow=replace(SNOW, count=600),
                      sand=replace(SAND, count=500), background="water", current=(0.02, 0.0)), (800, 600),
              "a thick cloud of all kinds with many overlaps"),
    "fullres": (replace(_BASE, bubbles=replace(BUBBLES, count=60), snow=replace(SNOW, count=150),
                        sand=replace(SAND, count=100), background="seabed", background_level=60.0,
                        current=(0.02, 0.0)), (1456, 1088),
                "the mixed scene at the IMX296's full 1456x1088"),
}
