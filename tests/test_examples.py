"""Every file in examples/ runs as its header says (small frame counts: a few seconds in all)."""

from __future__ import annotations

import csv
import re
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np

from antiscatter.config import load_config

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def test_every_example_has_a_test():
    tested = {"detect_one_image.py", "frames-folder.toml", "simulator-dim.toml", "vehicle.toml"}
    assert {p.name for p in EXAMPLES.iterdir() if not p.name.startswith(".")} == tested


def test_detect_one_image_finds_the_simulated_particles_and_draws_the_pattern(tmp_path):
    pattern = tmp_path / "pattern.png"
    done = subprocess.run([sys.executable, str(EXAMPLES / "detect_one_image.py"), "--pattern", str(pattern)],
                          capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    found = int(re.search(r"^(\d+) particles in the 800x600 image$", done.stdout, re.M).group(1))
    drawn = int(re.search(r"^the simulator drew (\d+) visible particles$", done.stdout, re.M).group(1))
    assert 0.8 * drawn <= found <= 1.1 * drawn, done.stdout
    image = cv2.imread(str(pattern), cv2.IMREAD_UNCHANGED)
    assert image.shape == (800, 1280) and set(map(int, image.ravel()[::97])) <= {0, 255}


def test_detect_one_image_on_a_file_and_on_a_non_image(tmp_path):
    frame = tmp_path / "frame.png"
    image = np.full((600, 800, 3), 20, np.uint8)
    cv2.circle(image, (400, 300), 6, (255, 255, 255), -1)
    cv2.imwrite(str(frame), image)
    done = subprocess.run([sys.executable, str(EXAMPLES / "detect_one_image.py"), str(frame)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("1 particles in the 800x600 image\n  at x   400.0 px, y   300.0 px")
    (tmp_path / "notes.png").write_text("not a picture")
    done = subprocess.run([sys.executable, str(EXAMPLES / "detect_one_image.py"), str(tmp_path / "notes.png")],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and done.stderr == f"{tmp_path / 'notes.png'}: not an image file\n"


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as fh:
        return list(csv.DictReader(fh))


def test_frames_folder_config(tmp_path, cli, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert cli("simulate", "frames", "--preset", "snow", "--frames", "8").code == 0
    result = cli("run", "--config", str(EXAMPLES / "frames-folder.toml"), "--fps", "0")
    assert result.code == 0, result.err
    assert sorted(p.name for p in (tmp_path / "patterns").glob("*.png")) == sorted(f"{i}.png" for i in range(8))
    assert len(_rows(tmp_path / "metrics.csv")) == 8
    assert {row["frame"] for row in _rows(tmp_path / "detections.csv")} == {str(i) for i in range(8)}


def test_simulator_dim_config(tmp_path, cli, monkeypatch):
    monkeypatch.chdir(tmp_path)
    config = load_config(EXAMPLES / "simulator-dim.toml")
    assert (config.light.strategy, config.track.enabled, config.source.preset) == ("dim", True, "snow")
    result = cli("run", "--config", str(EXAMPLES / "simulator-dim.toml"), "--frames", "12")
    assert result.code == 0, result.err
    assert len(_rows(tmp_path / "metrics.csv")) == 12


def test_vehicle_config_parses_and_makes_a_service_unit(cli):
    config = load_config(EXAMPLES / "vehicle.toml")
    assert (config.source.spec, config.output.outputs, config.run.rt_priority, config.run.mlock) == \
        ("camera", ("kms",), 50, True)
    result = cli("service", "install", "--config", str(EXAMPLES / "vehicle.toml"), "--dry-run")
    assert result.code == 0, result.err
    assert f"run --config {EXAMPLES / 'vehicle.toml'}\n" in result.out
