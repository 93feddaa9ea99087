"""The per-frame step run and the twin share (antiscatter.system)."""

import collections
import types

import numpy as np
import pytest

from antiscatter.detections import Detections
from antiscatter.detection import make_detector
from antiscatter.system import Exposure, LoopSettings, System, make_tracker


# times in binary fractions of a second (a 64 Hz camera, a 128 Hz projector, 1/256 s exposures), so
# run's integer nanoseconds and the twin's float seconds are the same instants exactly
CAMERA_HZ, PROJECTOR_HZ, EXPOSURE_S = 64.0, 128.0, 1 / 256
SIZE = (320, 240)


def _twin_steps(monkeypatch, strategy, frames):
    """The twin's loop (co-located, the camera locked to the projector, prediction, 5 ms): each
    step's frame, capture and light-on times, and the pattern and exposure light it drew."""
    import antiscatter.twin as twin

    real, steps = twin._twin_system, []

    def recording(*args, **kwargs):
        system = real(*args, **kwargs)
        analyse, render = system.analyse, system.render

        def analyse_and_record(image, captured_s, **options):
            steps.append({"image": image.copy(), "captured": captured_s, **options})
            return analyse(image, captured_s, **options)

        def render_and_record(step):
            step = render(step)
            steps[-1]["pattern"] = step.pattern.copy()
            steps[-1]["exposure"] = None if step.exposure is None else step.exposure.copy()
            return step

        system.analyse, system.render = analyse_and_record, render_and_record
        return system

    monkeypatch.setattr(twin, "_twin_system", recording)
    geometry = twin.TwinGeometry(camera_size=SIZE, baseline_m=0.0, camera_hz=CAMERA_HZ, projector_hz=PROJECTOR_HZ,
                                 exposure_s=EXPOSURE_S)
    twin.simulate_loop(twin.TwinRun("contrast", "calibrated", strategy, predict=True), geometry=geometry,
                       frames=frames, latency_ms=5.0, scene=twin.twin_scene(geometry, "mixed", 3))
    return steps, geometry


@pytest.mark.parametrize("strategy", ["dim", "pulse"])
def test_run_and_the_twin_draw_the_same_patterns_from_the_same_frames_and_light(strategy, monkeypatch):
    # the twin's frames replayed through run's pipeline (its System built from run's config, its
    # exposure bookkeeping in emit): every pattern, and every pulse's exposure light, the same
    from antiscatter import runtime
    from antiscatter.config import load_config
    from antiscatter.sources.base import Frame
    from antiscatter.stats import RunningStats

    frames = 30
    steps, geometry = _twin_steps(monkeypatch, strategy, frames)
    assert len(steps) == frames  # the locked camera: every frame read, each under the last frame's light
    mapping = geometry.plane_mapping(geometry.working_depth_m)
    config = load_config(overrides={
        "light": {"strategy": strategy, "levels": "adaptive", "compensate": True},
        "track": {"enabled": True, "predict": True},
        "pattern": {"width": geometry.projector_size[0], "height": geometry.projector_size[1],
                    "mapping": tuple(map(tuple, mapping.tolist())), "refresh_hz": PROJECTOR_HZ},
        "output": {"outputs": ("none",)}})
    detector = make_detector(config.detector.name, config.detector_params)
    summary = runtime.RunSummary(durations=collections.defaultdict(RunningStats))
    camera = types.SimpleNamespace(size=SIZE, live=True, fps=None)
    pipeline = runtime._Pipeline(config, detector, make_tracker(config.track), camera, None, [], None, None,
                                 runtime.metrics_columns(detector), summary, buffers=1)
    holes = 0
    for k, seen in enumerate(steps):
        frame = Frame(seen["image"], k, round(seen["captured"] * 1e9), round(seen["exposure_s"] * 1e9))
        pipeline.pattern_on_ns = round(seen["on_s"] * 1e9)  # when the twin put its pattern on
        rec = pipeline.process(frame, 0, 0)
        np.testing.assert_array_equal(rec.pattern, seen["pattern"], err_msg=f"frame {k}")
        if strategy == "pulse":
            np.testing.assert_array_equal(rec.exposure, seen["exposure"], err_msg=f"frame {k}")
        holes += int((rec.pattern < 255).sum() > 0)
        pipeline.emit(rec, 0)
    assert holes >= frames - 3  # (the first frames find no particle yet)


def _system(**settings):
    return System(make_detector("seed"), None, mapping=np.eye(3), camera_size=(200, 100), projector_size=(200, 100),
                  settings=LoopSettings(**settings))


def test_holes_at_the_dim_level_and_lifted_for_a_pulse():
    found = Detections(np.array([[50.0, 40.0]]), np.array([6.0]))
    dim = _system(strategy="dim", dim_level=0.2, grow=0.0)
    step = dim.render(dim.analyse(np.zeros((100, 200), np.uint8), 0.0, found=found, stage_ns=[]))
    assert step.pattern[40, 50] == 51 and step.pattern[40, 80] == 255  # 0.2 of 255 in the hole, full beside it
    pulse = _system(strategy="pulse", dim_level=0.2, grow=0.0)
    step = pulse.render(pulse.analyse(np.zeros((100, 200), np.uint8), 0.0, found=found, stage_ns=[]))
    assert step.pattern[40, 50] == 0  # dark between exposures ...
    assert pulse.lift(step, step.pattern)[40, 50] == 51  # ... lifted while the camera exposes


def test_a_flash_leaves_no_track_unlit_and_an_off_lamp_no_probe():
    flash = _system(strategy="flash", flash_level=0.25)
    assert flash.flash_image.shape == (100, 200) and flash.flash_image[0, 0] == 64
    step = flash.render(flash.analyse(np.zeros((100, 200), np.uint8), 0.0, found=Detections(
        np.array([[50.0, 40.0]]), np.array([6.0]), track_ids=np.array([7])), stage_ns=[]))
    assert flash.made(step, step.pattern).unlit_ids is None
    assert flash.made(step, None) == Exposure(None, None, None, {})
    assert flash.made(step, step.pattern, pattern=True).unlit_ids.tolist() == [7]  # under the pattern: dark


def test_the_measured_latency_is_a_running_mean():
    system = _system()
    system.observe_latency(0.010)
    assert system.timing.latency == pytest.approx(0.010)
    system.observe_latency(0.020)
    assert system.timing.latency == pytest.approx(0.011)


def test_a_changed_level_or_detector_applies_from_the_next_frame_only():
    found = Detections(np.array([[50.0, 40.0]]), np.array([6.0]))
    frame = np.zeros((100, 200), np.uint8)
    for strategy, lifted in (("dim", False), ("pulse", True)):
        system = _system(strategy=strategy, dim_level=0.2, grow=0.0)
        assert system.level == pytest.approx(51 / 255)
        step = system.analyse(frame, 0.0, found=found, stage_ns=[])
        system.change(level=0.5)  # while a frame is under way: that frame keeps its level
        step = system.render(step)
        shown = system.lift(step, step.pattern) if lifted else step.pattern
        assert shown[40, 50] == 51
        step = system.render(system.analyse(frame, 0.02, found=found, stage_ns=[]))
        shown = system.lift(step, step.pattern) if lifted else step.pattern
        assert shown[40, 50] == 128 and system.level == pytest.approx(128 / 255)
    assert _system(strategy="none").level is None  # dark holes: no level to change
    system = _system()
    old, new = system.detector, make_detector("contrast")
    system.change(detector=new)
    assert system.detector is old
    step = system.analyse(frame, 0.0)
    assert system.detector is new and step.detector is new  # its deferred stages are the new one's


def test_a_changed_ceiling_holds_every_tracks_level_under_it():
    from antiscatter.levels import HoleLevels

    levels = HoleLevels(0.5, floor=0.05)
    levels.ids, levels.level, levels.least = np.array([1, 2]), np.array([0.5, 0.1]), np.array([0.2, 0.0])
    levels.set_ceiling(0.15)
    assert levels.ceiling == 0.15 and levels.level.tolist() == [0.15, 0.1] and levels.least.tolist() == [0.15, 0.0]
    levels.set_ceiling(0.0)  # never under the floor
    assert levels.ceiling == 0.05
