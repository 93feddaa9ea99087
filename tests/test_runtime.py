import csv

import numpy as np

from antiscatter.config import load_config
from antiscatter.detection import make_detector
from antiscatter.runtime import REPORT_COLUMNS, Pacer, metrics_columns, run

SPEC_COLUMNS = [
    "Capture Duration (s)", "Greyscale Conversion Duration (s)", "Gaussian Blur Duration (s)",
    "Histogram Equalisation Duration (s)", "Binary Thresholding Duration (s)",
    "Canny Algorithm Duration (s)", "CV2 findContours() Duration (s)",
    "CV2 minEnclosingCircle() Duration (s)", "Number of MECs on screen",
    "Total frame processing time (s)",
]


def test_metrics_header_starts_with_the_reports_columns():
    assert list(REPORT_COLUMNS) == SPEC_COLUMNS
    assert metrics_columns(make_detector("seed"))[:10] == SPEC_COLUMNS


class FakeClock:
    def __init__(self):
        self.now = 0
        self.sleeps = []

    def clock(self):
        return self.now

    def sleep(self, seconds):
        self.sleeps.append(seconds)
        self.now += int(round(seconds * 1e9))


def test_pacer_is_drift_free():
    fake = FakeClock()
    pacer = Pacer(100.0, clock=fake.clock, sleep=fake.sleep)
    released = []
    for work_ns in [3_000_000, 7_000_000, 1_000_000, 9_000_000, 2_000_000]:
        pacer.wait()
        released.append(fake.now)
        fake.now += work_ns  # the frame's processing time
    assert released == [0, 10_000_000, 20_000_000, 30_000_000, 40_000_000]


def test_pacer_restarts_after_falling_behind():
    fake = FakeClock()
    pacer = Pacer(100.0, clock=fake.clock, sleep=fake.sleep)
    pacer.wait()
    fake.now += 35_000_000  # a stall of 3.5 periods
    pacer.wait()
    released = fake.now
    pacer.wait()
    assert fake.now - released == 10_000_000  # no burst of catch-up frames


def test_run_on_the_simulator_writes_metrics_and_detections(tmp_path):
    metrics, detections = tmp_path / "m.csv", tmp_path / "d.csv"
    config = load_config(overrides={"output": {"outputs": ("none",)},
                                    "run": {"frames": 40, "metrics": str(metrics),
                                            "detections": str(detections)}})
    import io
    out = io.StringIO()
    summary = run(config, log=io.StringIO(), out=out)
    assert summary.frames == 40 and summary.stop_reason == "frame limit 40"
    rows = list(csv.DictReader(metrics.open()))
    assert len(rows) == 40
    assert [int(r["Frame"]) for r in rows] == list(range(40))
    assert all(float(r["Total frame processing time (s)"]) > 0 for r in rows)
    assert all(float(r["Histogram Equalisation Duration (s)"]) == 0 for r in rows)
    det = list(csv.DictReader(detections.open()))
    assert det and list(det[0]) == ["frame", "x", "y", "radius"]
    per_frame = np.bincount([int(r["frame"]) for r in det], minlength=40)
    assert per_frame.tolist() == [int(r["Number of MECs on screen"]) for r in rows]
    text = out.getvalue()
    assert "Connected Components" in text and "frames per second" in text


def test_run_says_what_the_configuration_decided_for_it():
    import dataclasses
    import io

    config = load_config(overrides={"output": {"outputs": ("none",)}, "run": {"frames": 2}})
    log = io.StringIO()
    run(dataclasses.replace(config, notes=("strategy auto took dim holes",)), log=log, out=io.StringIO())
    assert "note: strategy auto took dim holes\n" in log.getvalue()
