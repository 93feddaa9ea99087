"""The benchmark scripts that time one part of the chain for N particles."""

import subprocess
import sys
from pathlib import Path

import pytest

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"


def test_the_tracker_benchmark_script_runs_and_reports_its_medians():
    out = subprocess.run([sys.executable, str(SCRIPTS / "bench_tracker.py"), "--particles", "20", "--frames", "15"],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "Tracker.update: median" in out.stdout and "dense Hungarian alone (20x20): median" in out.stdout


def test_the_tracker_benchmark_times_the_default_detectors_detections_in_a_scene():
    out = subprocess.run([sys.executable, str(SCRIPTS / "bench_tracker.py"), "--particles", "20", "--frames", "12",
                          "--preset", "mixed"], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    scene = [line for line in out.stdout.splitlines() if line.startswith("scene mixed (800x600, 12 frames")]
    assert len(scene) == 1 and int(scene[0].split("median ")[1].split()[0]) > 50  # the scene's particles
    assert "Tracker.update on its detections: median" in out.stdout


def test_the_tracker_benchmark_turns_down_an_unknown_preset():
    out = subprocess.run([sys.executable, str(SCRIPTS / "bench_tracker.py"), "--preset", "lava"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "--preset" in out.stderr and "lava" in out.stderr
    assert "Traceback" not in out.stderr and out.stdout == ""


@pytest.mark.parametrize("script", ["bench_tracker.py", "bench_probe.py"])
@pytest.mark.parametrize("args", [["--particles", "0"], ["--frames", "-3"], ["--frames", "many"]])
def test_the_benchmark_scripts_turn_down_counts_below_one(script, args):
    out = subprocess.run([sys.executable, str(SCRIPTS / script), *args], capture_output=True, text=True, timeout=60)
    assert out.returncode == 2
    assert "allowed an integer >= 1" in out.stderr and "Traceback" not in out.stderr
    assert out.stdout == ""


def test_the_a_b_script_times_an_earlier_commits_detector_beside_this_trees():
    # HEAD against the tree: both sides run the same frames, every width of the material reported
    out = subprocess.run([sys.executable, str(SCRIPTS / "bench_ab.py"), "HEAD", "--split", "dev", "--frames", "1"],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    lines = [line for line in out.stdout.splitlines() if "new / old" in line]
    assert [line.split()[0] for line in lines] == ["800", "1456"]
    for line in lines:
        assert float(line.rsplit(" ", 1)[1]) > 0


def test_the_threads_benchmark_compares_every_variant_with_one_thread_on_the_same_frames():
    out = subprocess.run([sys.executable, str(SCRIPTS / "bench_threads.py"), "sim:320x240:mixed", "--frames", "4",
                          "--distinct", "3"], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    rows = {line.split()[0]: line.split() for line in out.stdout.splitlines() if line[:2] in ("1 ", "cv", "ba", "bo")}
    assert set(rows) == {"1", "cv2", "bands2", "both2"} and rows["1"][4] == "1.00"
    assert "load average before" in out.stdout
