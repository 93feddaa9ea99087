"""``antiscatter analyse``: survey footage measured at scale on Dask -- particle counts, abundance
per litre, UVP-style size spectra, brightness and turbidity, binned in time.

Stages, one module each: :mod:`.inputs` (files, globs, lists; probing; chunks at keyframes),
:mod:`.work` (one chunk through the detector, resumable results), :mod:`.volume` (the volume
and pixel-size model), :mod:`.tables` (Parquet tables and the summary), :mod:`.plots`, and
:mod:`.command` (the Dask run).  Dask, pyarrow and matplotlib are imported only when a
run starts (``pip install 'antiscatter[analysis]'``).
"""

from __future__ import annotations

from .volume import VolumeModel, esd_classes, frustum_litres, metres_per_pixel

__all__ = ["AnalyseRequest", "analyse", "VolumeModel", "esd_classes", "frustum_litres", "metres_per_pixel",
           "EXIT_SKIPPED"]


def __getattr__(name: str):
    if name in ("AnalyseRequest", "analyse", "EXIT_SKIPPED"):
        from . import command

        return getattr(command, name)
    raise AttributeError(name)
