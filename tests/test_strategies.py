"""The light strategies' registry (antiscatter.strategies)."""

import numpy as np
import pytest

from antiscatter import strategies
from antiscatter.strategies import Strategy, register_strategy, strategy_entry, strategy_names


def test_the_five_strategies_and_what_each_does():
    assert strategy_names() == ("none", "dim", "pulse", "flash", "coast")
    assert [strategy_entry(n).exposing for n in strategy_names()] == [False, False, True, True, False]
    assert [n for n in strategy_names() if strategy_entry(n).visible] == ["dim", "pulse"]
    assert not strategy_entry("flash").unlit and strategy_entry("coast").tracks
    assert (strategy_entry("dim").rest, strategy_entry("pulse").rest) == (2, 1)


def test_bad_names_and_fields_are_refused():
    with pytest.raises(ValueError, match=r"^strategy: got 'strobe', allowed none, dim, pulse, flash, coast$"):
        strategy_entry("strobe")
    with pytest.raises(ValueError, match=r"^hole: got 'grey', allowed dark, dim$"):
        Strategy("x", hole="grey")
    with pytest.raises(ValueError, match=r"^strategy 'dim': the name is taken$"):
        register_strategy(Strategy("dim"))


def test_a_new_strategy_is_one_entry_for_config_twin_and_system(monkeypatch):
    # dim holes that are also lifted while the camera exposes: registered, the config, the twin and
    # the System take it by name
    from antiscatter.config import LightConfig
    from antiscatter.detection import make_detector
    from antiscatter.system import LoopSettings, System
    from antiscatter.twin import TwinRun

    monkeypatch.setattr(strategies, "STRATEGY_REGISTRY", dict(strategies.STRATEGY_REGISTRY))
    register_strategy(Strategy("glow", hole="dim", exposure="lifted", visible=True))
    assert LightConfig(strategy="glow").strategy == "glow"
    assert TwinRun(strategy="glow", mapping="probe").strategy == "glow"  # visible: it can be probed
    system = System(make_detector("seed"), mapping=np.eye(3), camera_size=(64, 48), projector_size=(64, 48),
                    settings=LoopSettings(strategy="glow", dim_level=0.2))
    assert (system.hole_level, system.pulse_level, system.flash_image) == (51, 51, None)
