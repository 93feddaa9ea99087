"""The scenario catalogue: named (preset, size, frames, seed) kept in the repository.

Evaluation and benchmarks measure every detector on these same scenes.  The
catalogue file is versioned: change ``version`` when a scenario changes.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from ..detection import check_frame_size
from ..errors import UsageError

__all__ = ["Scenario", "load_catalogue"]


@dataclass(frozen=True)
class Scenario:
    """One catalogued scene: preset, size (width, height), frames and seed."""

    name: str
    preset: str
    size: tuple[int, int]
    frames: int
    seed: int


def load_catalogue(path: str | Path | None = None) -> tuple[int, dict[str, Scenario]]:
    """(version, {name: Scenario}) from ``path`` or the packaged ``scenarios.toml``."""
    from . import PRESETS

    if path is None:
        text = resources.files(__package__).joinpath("scenarios.toml").read_text()
        where = "scenarios.toml"
    else:
        try:
            text = Path(path).read_text()
        except (OSError, UnicodeDecodeError):
            raise UsageError(f"{path}: cannot read the scenario catalogue (allowed a UTF-8 TOML file)") from None
        where = str(path)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise UsageError(f"{where}: not valid TOML ({exc})") from None
    version = data.get("version")
    if not isinstance(version, int):
        raise UsageError(f"{where}: needs an integer 'version'")
    scenarios = {}
    for name, entry in data.get("scenario", {}).items():
        unknown = set(entry) - {"preset", "size", "frames", "seed"}
        if unknown:
            raise UsageError(f"{where}: unknown key scenario.{name}.{sorted(unknown)[0]}; "
                             "allowed: preset, size, frames, seed")
        preset = entry.get("preset")
        if preset not in PRESETS:
            raise UsageError(f"{where}: scenario.{name}.preset: got {preset!r}, allowed: {', '.join(PRESETS)}")
        try:
            w, h = (int(v) for v in str(entry["size"]).lower().split("x"))
            frames, seed = int(entry["frames"]), int(entry["seed"])
        except (KeyError, ValueError):
            raise UsageError(f"{where}: scenario.{name} needs size = 'WxH', frames and seed") from None
        check_frame_size(w, h, what=f"{where}: scenario.{name}.size: frames", error=UsageError)
        scenarios[name] = Scenario(name, preset, (w, h), frames, seed)
    return version, scenarios
