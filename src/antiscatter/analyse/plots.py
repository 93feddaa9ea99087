"""The figures of ``analyse`` (matplotlib, headless): time series and size spectra."""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["plot_time_series", "plot_spectrum"]


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_time_series(path: Path, bins: dict[str, np.ndarray]) -> None:
    """Particles per litre, mean brightness and turbidity index over time, one line per file
    (the files end to end as ``ALL``, dashed)."""
    plt = _pyplot()
    figure, axes = plt.subplots(3, 1, figsize=(9, 7), sharex=False)
    names = list(dict.fromkeys(bins["file"].tolist()))
    for name in names:
        at = bins["file"] == name
        middle = (bins["start_s"][at] + bins["end_s"][at]) / 2
        style = "--" if name == "ALL" else "-"
        for axis, column in zip(axes, ("per_litre", "brightness", "turbidity_index")):
            axis.plot(middle, bins[column][at], style, marker="o", markersize=3, label=Path(name).name)
    for axis, label in zip(axes, ("particles / litre", "mean brightness (grey levels)", "turbidity index")):
        axis.set_ylabel(label)
        axis.grid(alpha=0.3)
    axes[-1].set_xlabel("time (s; ALL: the files end to end)")
    axes[0].legend(fontsize=7, loc="best")
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)


def plot_spectrum(path: Path, spectra: dict[str, np.ndarray]) -> None:
    """The normalised size spectrum (particles per litre per mm against ESD, log-log) of each file
    and of all, over the whole footage."""
    plt = _pyplot()
    figure, axis = plt.subplots(figsize=(7, 5))
    whole = spectra["bin"] == -1
    for name in dict.fromkeys(spectra["file"][whole].tolist()):
        at = whole & (spectra["file"] == name) & (spectra["count"] > 0)
        if not at.any():
            continue
        middle = np.sqrt(spectra["class_low_mm"][at] * spectra["class_high_mm"][at])
        axis.plot(middle, spectra["per_litre_per_mm"][at], "--" if name == "ALL" else "-", marker="o",
                  markersize=3, label=Path(name).name)
    axis.set_xscale("log")
    axis.set_yscale("log")
    axis.set_xlabel("equivalent spherical diameter (mm, class centre)")
    axis.set_ylabel("particles / litre / mm")
    axis.grid(alpha=0.3, which="both")
    axis.legend(fontsize=7)
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)
