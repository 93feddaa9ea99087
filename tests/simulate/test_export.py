"""``antiscatter simulate``: files, determinism, FFV1 round trip, catalogue, bad input."""

import csv

import av
import cv2
import numpy as np
import pytest

from antiscatter.simulate import PRESETS
from antiscatter.simulate.catalogue import load_catalogue
from antiscatter.simulate.export import SimulationRequest, simulate


def test_seed_preset_writes_frames_and_the_reports_truth_header(tmp_path, cli):
    result = cli("simulate", str(tmp_path / "out"), "--preset", "seed", "--frames", "12", "--seed", "1")
    assert result.code == 0, result.err
    out = tmp_path / "out"
    assert sorted(int(p.stem) for p in out.glob("*.png")) == list(range(12))
    rows = list(csv.reader((out / "truth.csv").open()))
    assert rows[0][:5] == ["Bubble ID", "Frame #", "X Position", "Y Position", "Radius"]
    assert len(rows) == 1 + 12 * 300
    image = cv2.imread(str(out / "0.png"))
    assert image.shape == (600, 800, 3)
    assert not list(out.glob(".partial-*"))


def test_same_seed_same_bytes(tmp_path):
    for name in ("a", "b"):
        simulate(SimulationRequest(out=tmp_path / name, preset="mixed", frames=3, seed=7, size=(160, 120),
                                   masks=True))
    for path in (tmp_path / "a").rglob("*"):
        if path.is_file():
            assert path.read_bytes() == (tmp_path / "b" / path.relative_to(tmp_path / "a")).read_bytes(), path
    simulate(SimulationRequest(out=tmp_path / "c", preset="mixed", frames=3, seed=8, size=(160, 120)))
    assert (tmp_path / "a" / "2.png").read_bytes() != (tmp_path / "c" / "2.png").read_bytes()


def test_masks_are_16_bit_labels_that_truth_maps(tmp_path):
    simulate(SimulationRequest(out=tmp_path, preset="dense", frames=2, seed=1, size=(320, 240), masks=True))
    mask = cv2.imread(str(tmp_path / "masks" / "1.png"), cv2.IMREAD_UNCHANGED)
    assert mask.dtype == np.uint16 and mask.shape == (240, 320)
    rows = [r for r in csv.DictReader((tmp_path / "truth.csv").open()) if r["Frame #"] == "1"]
    labels = {int(r["Label"]) for r in rows} - {0}
    assert set(np.unique(mask).tolist()) - {0} == labels
    assert len(labels) > 50


def test_ffv1_video_round_trip_is_bit_exact(tmp_path):
    simulate(SimulationRequest(out=tmp_path / "png", preset="textured", frames=4, seed=2, size=(200, 150)))
    simulate(SimulationRequest(out=tmp_path / "vid", preset="textured", frames=4, seed=2, size=(200, 150),
                               video=tmp_path / "vid" / "frames.mkv"))
    assert not list((tmp_path / "vid").glob("*.png"))
    with av.open(str(tmp_path / "vid" / "frames.mkv")) as container:
        decoded = [f.to_ndarray(format="bgr24") for f in container.decode(video=0)]
    assert len(decoded) == 4
    for i, image in enumerate(decoded):
        np.testing.assert_array_equal(image, cv2.imread(str(tmp_path / "png" / f"{i}.png")))
    assert (tmp_path / "png" / "truth.csv").read_bytes() == (tmp_path / "vid" / "truth.csv").read_bytes()


def test_user_background_image(tmp_path):
    photo = np.zeros((90, 120, 3), np.uint8)
    photo[:, 60:] = 255
    cv2.imwrite(str(tmp_path / "bg.png"), photo)
    simulate(SimulationRequest(out=tmp_path / "o", preset="snow", frames=1, seed=0, size=(240, 180),
                               background=str(tmp_path / "bg.png")))
    image = cv2.imread(str(tmp_path / "o" / "0.png")).astype(float)
    assert image[:, 150:].mean() > image[:, :90].mean() + 10  # the bright half shows through, dimmed
    assert image.max() < 255 or image[:, 150:].mean() < 200


def test_failure_mid_run_leaves_nothing_that_looks_complete(tmp_path, monkeypatch):
    from antiscatter.simulate import scene as scene_module

    calls = {"n": 0}
    original = scene_module.RealisticScene.render

    def failing(self, labels=None):
        calls["n"] += 1
        if calls["n"] == 3:
            raise OSError("disk full")
        return original(self, labels=labels)

    monkeypatch.setattr(scene_module.RealisticScene, "render", failing)
    with pytest.raises(OSError):
        simulate(SimulationRequest(out=tmp_path, preset="sand", frames=5, seed=0, size=(100, 80)))
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("args, message", [
    (["--preset", "storm"], "unknown preset 'storm'; allowed: seed, bubbles"),
    (["--frames", "0"], "--frames 0: allowed a positive number of frames"),
    (["--frames", "-5"], "--frames -5: allowed a positive number of frames"),
    (["--size", "0x100"], "--size: got '0x100', allowed positive WIDTHxHEIGHT"),
    (["--size", "big"], "--size: got 'big', allowed WIDTHxHEIGHT"),
    (["--preset", "snow", "--background", "nope.png"], "--background nope.png: no such file"),
    (["--scenario", "moon"], "unknown scenario 'moon'"),
    (["--video", "x.mp4"], "--video x.mp4: allowed a .mkv file"),
])
def test_bad_input(tmp_path, cli, args, message):
    result = cli("simulate", str(tmp_path / "o"), *args)
    assert result.code == 2
    assert len(result.err.strip().splitlines()) == 1
    assert message in result.err
    assert not (tmp_path / "o" / "truth.csv").exists()


def test_unreadable_background(tmp_path, cli):
    (tmp_path / "bg.png").write_text("not an image")
    result = cli("simulate", str(tmp_path / "o"), "--preset", "snow", "--background", str(tmp_path / "bg.png"))
    assert result.code == 2 and "not a readable image or video" in result.err


def test_refuses_to_overwrite_frames_without_flag(tmp_path, cli):
    assert cli("simulate", str(tmp_path), "--frames", "2").code == 0
    first = (tmp_path / "1.png").read_bytes()
    result = cli("simulate", str(tmp_path), "--frames", "2", "--seed", "5")
    assert result.code == 2 and "already holds frames or truth.csv; use --overwrite" in result.err
    assert (tmp_path / "1.png").read_bytes() == first
    assert cli("simulate", str(tmp_path), "--frames", "1", "--seed", "5", "--overwrite").code == 0
    assert sorted(p.name for p in tmp_path.glob("*.png")) == ["0.png"]


def test_catalogue_names_every_preset_once_and_is_versioned(cli):
    version, scenarios = load_catalogue()
    assert isinstance(version, int) and version >= 1
    assert {s.preset for s in scenarios.values()} == set(PRESETS)
    result = cli("simulate", "--list")
    assert result.code == 0 and "fullres" in result.out and "catalogue version" in result.out


def test_scenario_runs(tmp_path, cli):
    result = cli("simulate", str(tmp_path), "--scenario", "bubbles", "--frames", "2")
    assert result.code == 0, result.err
    assert "preset bubbles (seed 1)" in result.out


def test_sim_source_serves_realistic_presets(tmp_path, cli):
    result = cli("run", "--preset", "textured", "--frames", "3", "--output", "none",
                 "--detections", str(tmp_path / "d.csv"))
    assert result.code == 0, result.err
    assert "source sim (800x600)" in result.err
