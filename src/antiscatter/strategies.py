"""Light strategies: what the lamp does against the closed-loop catch (a particle dark in its hole
is lost by the next frame's detector), a role picked by name from one registry like the detectors'.

A strategy says what light a hole leaves between exposures, what light each exposure is taken
under, and whether the tracks whose holes an exposure holds are unlit then.  ``run``'s config,
the :class:`~antiscatter.system.System` and the twin read these entries; a new strategy is one
:class:`Strategy` and its :func:`register_strategy`.
"""

from __future__ import annotations

from dataclasses import dataclass

from .levels import DIM_REST, REST

__all__ = ["Strategy", "STRATEGY_REGISTRY", "register_strategy", "strategy_entry", "strategy_names"]

#: what a hole leaves its particle between exposures: no light, or ``dim_level``
HOLES = ("dark", "dim")
#: what an exposure is taken under: the pattern as shown, the pattern with its holes lifted to
#: ``dim_level`` (in the exposure's refresh only), or a uniform ``flash_level`` frame
EXPOSURES = ("pattern", "lifted", "flash")


@dataclass(frozen=True)
class Strategy:
    """One light strategy.

    name: its name in the config, the CLI and the twin.
    hole: ``dark`` or ``dim`` (``HOLES``): a hole's light between exposures.
    exposure: ``pattern``, ``lifted`` or ``flash`` (``EXPOSURES``): the light each exposure gets;
        other than ``pattern`` the exposure's light and the capture take turns (run's mode single).
    visible: a particle under its hole stays visible to the camera, so each hole's own level
        (adaptive levels) and depth probing can be judged by it.
    unlit: the tracks whose holes an exposure holds are unlit in it (False: the flash lights all).
    tracks: needs the tracker (its holes follow particles gone dark).
    rest: adaptive levels: frames a confirmed track's hole stays dark after each look (default).
    """

    name: str
    hole: str = "dark"
    exposure: str = "pattern"
    visible: bool = False
    unlit: bool = True
    tracks: bool = False
    rest: int = REST

    def __post_init__(self) -> None:
        if self.hole not in HOLES:
            raise ValueError(f"hole: got {self.hole!r}, allowed {', '.join(HOLES)}")
        if self.exposure not in EXPOSURES:
            raise ValueError(f"exposure: got {self.exposure!r}, allowed {', '.join(EXPOSURES)}")

    @property
    def exposing(self) -> bool:
        """The exposure has a light of its own (lifted holes or a flash): mode single only."""
        return self.exposure != "pattern"


#: every strategy by name, in the order the CLI lists them
STRATEGY_REGISTRY: dict[str, Strategy] = {}


def register_strategy(strategy: Strategy) -> Strategy:
    """Add ``strategy`` to the registry (ValueError if its name is taken); returns it."""
    if strategy.name in STRATEGY_REGISTRY or strategy.name == "auto":
        raise ValueError(f"strategy {strategy.name!r}: the name is taken")
    STRATEGY_REGISTRY[strategy.name] = strategy
    return strategy


def strategy_names() -> tuple[str, ...]:
    """The registered strategies' names."""
    return tuple(STRATEGY_REGISTRY)


def strategies_that(what: str) -> str:
    """The registered strategies whose attribute ``what`` is true, as ``a, b or c`` (for messages)."""
    names = [s.name for s in STRATEGY_REGISTRY.values() if getattr(s, what)]
    return " or ".join((", ".join(names[:-1]), names[-1])) if len(names) > 1 else "".join(names)


def strategy_entry(name: str) -> Strategy:
    """The strategy called ``name``; ValueError naming the allowed ones otherwise."""
    try:
        return STRATEGY_REGISTRY[name]
    except KeyError:
        raise ValueError(f"strategy: got {name!r}, allowed {', '.join(STRATEGY_REGISTRY)}") from None


register_strategy(Strategy("none"))  # holes from this frame's detections, dark
register_strategy(Strategy("dim", hole="dim", visible=True, rest=DIM_REST))  # darkened particles stay visible
register_strategy(Strategy("pulse", exposure="lifted", visible=True))  # dim only while the camera exposes
register_strategy(Strategy("flash", exposure="flash", unlit=False))  # a uniform flash for each exposure
register_strategy(Strategy("coast", tracks=True))  # tracked holes stay on particles gone dark
