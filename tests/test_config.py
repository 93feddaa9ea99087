import numpy as np
import pytest

from antiscatter.config import Config, load_config, parse_param
from antiscatter.detection.seed import SeedParams
from antiscatter.errors import UsageError


def write(tmp_path, text):
    path = tmp_path / "run.toml"
    path.write_text(text)
    return path


def test_defaults():
    config = load_config()
    assert isinstance(config, Config)
    assert config.source.spec == "sim"
    assert config.detector.name == "contrast"
    from antiscatter.detection.contrast import ContrastParams
    assert config.detector_params == ContrastParams()
    assert (config.pattern.width, config.pattern.height) == (1280, 800)
    assert config.output.outputs == ("auto",)


def test_toml_fills_every_section_and_flags_win(tmp_path):
    path = write(tmp_path, """
[source]
spec = "frames"
loop = true
[detector]
name = "seed"
[detector.seed]
threshold = 180
equalise = false
[pattern]
width = 640
height = 400
margin = 2
mapping = [[2, 0, 1], [0, 2, 0], [0, 0, 1]]
[output]
outputs = ["none", "files:x.mkv"]
[run]
frames = 10
fps = 30
""")
    config = load_config(path, {"run": {"frames": 20, "fps": None}})
    assert config.source.spec == "frames" and config.source.loop is True
    assert config.detector_params.threshold == 180
    assert config.pattern.margin == 2.0
    np.testing.assert_array_equal(config.pattern.matrix(), [[2, 0, 1], [0, 2, 0], [0, 0, 1]])
    assert config.output.outputs == ("none", "files:x.mkv")
    assert config.run.frames == 20 and config.run.fps == 30.0


@pytest.mark.parametrize("text, message", [
    ("[run]\nframez = 3\n", "run.toml: unknown key run.framez; allowed: frames, fps, nice, metrics, detections"),
    ("[run]\nframes = 'ten'\n", "run.toml: run.frames: got 'ten', allowed an integer"),
    ("[run]\nframes = -1\n", "run.toml: run.frames: got -1, allowed >= 0 (0 = no limit)"),
    ("[run]\nnice = -40\n", "run.toml: run.nice: got -40, allowed -20..19"),
    ("[source]\nloop = 1\n", "run.toml: source.loop: got 1, allowed true or false"),
    ("[source]\nsize = '800by600'\n", "run.toml: source.size: got '800by600', allowed WIDTHxHEIGHT, e.g. 800x600"),
    ("[pattern]\nmapping = [[1, 0], [0, 1]]\n", "run.toml: pattern.mapping: got [[1, 0], [0, 1]], allowed a 3x3 matrix of finite numbers"),
    ("[pattern]\nmargin = -1\n", "run.toml: pattern.margin: got -1.0, allowed a number >= 0"),
    ("[pattern]\nrefresh_hz = 0\n", "run.toml: pattern.refresh_hz: got 0.0, allowed a number of refreshes a second > 0"),
    ("[pattern]\nrefresh_hz = nan\n", "run.toml: pattern.refresh_hz: got nan, allowed a number of refreshes a second > 0"),
    ("[detector]\nname = 'seed'\n[detector.seed]\nthreshold = 300\n", "run.toml: detector.seed.threshold: got 300, allowed 0..255"),
    ("[detector]\nname = 'seed'\n[detector.seed]\ncolour = 1\n", "run.toml: unknown key detector.seed.colour; allowed: threshold, blur_kernel, canny_sigma, equalise"),
    ("[detector.contrast]\nk = -1\n", "run.toml: detector.contrast.k: got -1.0, allowed a number > 0"),
    ("[track]\nrevive_frames = -2\n", "run.toml: track.revive_frames: got -2, allowed >= 0 (0 = off)"),
    ("[track]\nmerge_reach = -0.5\n", "run.toml: track.merge_reach: got -0.5, allowed a number >= 0 (0 = off)"),
    ("[track]\nflux_ratio = 0.5\n", "run.toml: track.flux_ratio: got 0.5, allowed 0 (off) or a number >= 1"),
    ("[track]\nfar_bright = 0.5\n", "run.toml: track.far_bright: got 0.5, allowed 0 (off) or a number >= 1"),
    ("[track]\naccel_floor = 0\n", "run.toml: track.accel_floor: got 0.0, allowed a share of the noise, > 0 and <= 1"),
    ("[track]\nmiss_cost = -1\n", "run.toml: track.miss_cost: got -1.0, allowed a distance in px >= 0 (0 = the most matches first)"),
    ("[track]\nflux_cost = -1\n", "run.toml: track.flux_cost: got -1.0, allowed a distance in px >= 0 (0 = distance alone)"),
    ("[light]\nrest = -1\n", "run.toml: light.rest: got -1, allowed a whole number of frames >= 0"),
    ("[light]\nrest = 1.5\n", "run.toml: light.rest: got 1.5, allowed an integer"),
    ("[track]\nmax_misses = 6\nkeep_misses = 4\n", "run.toml: track.keep_misses: got 4, allowed >= max_misses (6)"),
    ("[detector.fancy]\nx = 1\n", "run.toml: unknown section [detector.fancy]; allowed: detector.contrast, detector.seed"),
    ("[detector]\nname = 'fancy'\n", "unknown detector 'fancy'; allowed: contrast, seed"),
    ("[lamp]\nx = 1\n", "run.toml: unknown section [lamp]; allowed: source, detector, pattern, output, run"),
    ("[run\n", "run.toml: not valid TOML"),
])
def test_bad_config_rejected_with_key_value_and_allowed(tmp_path, text, message):
    path = write(tmp_path, text)
    with pytest.raises(UsageError) as info:
        load_config(path)
    assert str(info.value).replace(str(tmp_path) + "/", "").startswith(message)


def test_missing_config_file(tmp_path):
    with pytest.raises(UsageError, match="nope.toml: no such config file"):
        load_config(tmp_path / "nope.toml")


def test_parse_param_types():
    assert parse_param("threshold=180", SeedParams, detector="seed") == ("threshold", 180)
    assert parse_param("equalise=true", SeedParams, detector="seed") == ("equalise", True)
    assert parse_param("canny-sigma=0.33", SeedParams, detector="seed") == ("canny_sigma", 0.33)
    with pytest.raises(UsageError, match="detector.seed.threshold: got 'high', allowed an integer"):
        parse_param("threshold=high", SeedParams, detector="seed")
    with pytest.raises(UsageError, match="unknown key detector.seed.speed"):
        parse_param("speed=3", SeedParams, detector="seed")
    with pytest.raises(UsageError, match="expected KEY=VALUE"):
        parse_param("threshold", SeedParams, detector="seed")


def test_rest_defaults_to_the_strategys_own():
    from antiscatter.config import load_config

    assert load_config(overrides={"light": {"strategy": "dim"}}).light.rest == 2
    assert load_config(overrides={"light": {"strategy": "pulse"}}).light.rest == 1
    assert load_config(overrides={"light": {"strategy": "dim", "rest": 1}}).light.rest == 1


def test_the_camera_lock_and_what_it_needs():
    locked = {"spec": "camera", "camera_lock": True, "camera_exposure_ms": 4.0}
    kms = {"outputs": ("kms",)}
    config = load_config(overrides={"source": locked, "output": kms})
    assert config.source.camera_lock and config.light.strategy == "pulse"  # auto: pulsed holes when locked
    assert load_config(overrides={"source": {"spec": "camera"}}).light.strategy == "dim"  # free-running: dim
    flash = load_config(overrides={"source": locked, "output": kms, "light": {"strategy": "flash"}})
    assert flash.light.strategy == "flash"
    cases = [
        ({"source": {**locked, "spec": "sim"}, "output": kms}, r"locks the camera \(source camera\), got source 'sim'"),
        ({"source": locked, "output": {"outputs": ("framebuffer",)}}, "needs output kms"),
        ({"source": locked, "output": kms, "light": {"strategy": "dim"}}, "times the pulse or the flash to the exposure: needs light.strategy pulse or flash, got dim"),
        ({"source": {**locked, "camera_exposure_ms": 0.0}, "output": kms},
         "needs a fixed camera_exposure_ms inside one projector refresh .* got automatic"),
        ({"source": {**locked, "camera_exposure_ms": 10.0}, "output": kms},
         r"needs a fixed camera_exposure_ms inside one projector refresh \(0 < exposure <= 8.33 ms at 120 Hz\), "
         "got 10"),
        ({"source": {**locked, "camera_fps": 50.0}, "output": kms},
         "needs the camera's frame period a whole number of projector refreshes, got camera_fps 50 with "
         "pattern.refresh_hz 120"),
    ]
    for overrides, message in cases:
        with pytest.raises(UsageError, match="source.camera_lock: " + message):
            load_config(overrides=overrides)


def test_the_display_lag_is_a_time_in_ms():
    assert load_config(overrides={"pattern": {"display_lag_ms": 8.3}}).pattern.display_lag_ms == 8.3
    for bad in (-1.0, float("nan"), 5000.0):
        with pytest.raises(UsageError, match=f"pattern.display_lag_ms: got {bad}, allowed 0..1000 ms"):
            load_config(overrides={"pattern": {"display_lag_ms": bad}})


def test_auto_takes_dim_holes_without_the_lock_when_no_light_can_reach_the_next_exposure():
    # 60 Hz camera, 120 Hz projector, 4 ms exposures: a light reaches the next exposure -- a frame
    # ahead at the latest -- while the display lags less than 16.67 - (8.33 + 4) / 2 - 1 = 9.5 ms;
    # the light after the pattern, for the exposure after the next, while it lags at most
    # 33.33 - (25 + 4) / 2 - 1 - 5 = 12.83 ms (5 ms of processing)
    locked = {"spec": "camera", "camera_lock": True, "camera_exposure_ms": 4.0}
    kms = {"outputs": ("kms",)}

    def config(lag, **light):
        return load_config(overrides={"source": locked, "output": kms, "pattern": {"display_lag_ms": lag},
                                      "light": light})

    for lag in (1000 / 120, 9.4, 9.6, 12.0, 12.8):
        reached = config(lag)
        assert reached.light.strategy == "pulse" and reached.source.camera_lock and reached.notes == (), lag
    longer = config(12.9)
    assert longer.light.strategy == "dim" and not longer.source.camera_lock
    assert len(longer.notes) == 1 and "pattern.display_lag_ms 12.9: no exposure light can reach" in longer.notes[0]
    asked = config(14.0, strategy="pulse")  # asked for: the lock stays, the run says what it read
    assert asked.light.strategy == "pulse" and asked.source.camera_lock and asked.notes == ()
    # a camera frame period of three refreshes (40 Hz) reaches further: 50 - 14.5 - 6 = 29.5 ms
    slower = load_config(overrides={"source": {**locked, "camera_fps": 40.0}, "output": kms,
                                    "pattern": {"display_lag_ms": 29.0}})
    assert slower.light.strategy == "pulse" and slower.source.camera_lock
    with pytest.raises(UsageError, match="source.camera_lock: needs a fixed camera_exposure_ms"):
        load_config(overrides={"source": {**locked, "camera_exposure_ms": 0.0}, "output": kms,
                               "pattern": {"display_lag_ms": 12.0}})
