import csv

import numpy as np

from antiscatter.config import load_config
from antiscatter.detection import make_detector
from antiscatter.runtime import REPORT_COLUMNS, Pacer, metrics_columns, run
from antiscatter.sources.base import seconds_text

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
    assert det and list(det[0]) == ["frame", "time", "x", "y", "radius"]
    # the frames' time: the simulator's scene time (frame i at i / fps), in both CSVs
    fps = round(1 / float(rows[1]["Frame Time (s)"]))
    assert [r["Frame Time (s)"] for r in rows] == [seconds_text(round(i * 1e9 / fps)) for i in range(40)]
    assert all(r["time"] == rows[int(r["frame"])]["Frame Time (s)"] for r in det)
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


# ---------------------------------------------------------------- true time (issue 50)

#: ms between the frames of a variable-rate file: a camera that dropped frames, a stall, bursts
VFR_GAPS_MS = [10, 60, 15, 50, 10, 70, 20, 10, 60, 15, 40, 10, 80, 20, 10, 60, 15, 50, 10, 60, 25, 10, 70, 15]


def test_a_variable_rate_video_keeps_its_times_in_the_csvs_and_tracks_by_them(tmp_path, cli):
    """Two discs crossing at 500 px/s in a file whose frames are 10-80 ms apart: the CSVs carry each
    frame's presentation time, and tracked by those times each disc keeps one id (timed by frame index
    over the nominal rate, as before, the discs went through 11 and 9 ids)."""
    from conftest import draw_discs, write_vfr

    pts = np.concatenate([[0], np.cumsum(VFR_GAPS_MS)]).tolist()
    frames = [draw_discs((480, 120), [(20 + 0.5 * t, 60, 4), (460 - 0.5 * t, 40, 3)], background=20, value=230)
              for t in pts]
    write_vfr(tmp_path / "v.mkv", frames, pts)
    result = cli("run", str(tmp_path / "v.mkv"), "--output", "none", "--track", "--detections",
                 str(tmp_path / "d.csv"), "--metrics", str(tmp_path / "m.csv"))
    assert result.code == 0, result.err
    with open(tmp_path / "d.csv", newline="") as handle:
        reader = csv.reader(handle)
        assert next(reader) == ["frame", "time", "x", "y", "radius", "track_id"]
        rows = list(reader)
    assert len(rows) == 2 * len(pts)
    assert [(int(r[0]), r[1]) for r in rows] == [(i, f"0.{t:03d}000000") for i, t in enumerate(pts) for _ in (0, 1)]
    metrics = list(csv.DictReader(open(tmp_path / "m.csv", newline="")))
    assert [m["Frame Time (s)"] for m in metrics] == [f"0.{t:03d}000000" for t in pts]
    left = {r[5] for r in rows if float(r[2]) < 20 + 0.5 * int(r[1][2:5]) + 5
            and float(r[2]) > 20 + 0.5 * int(r[1][2:5]) - 5}  # the disc moving right
    right = {r[5] for r in rows} - left
    assert len(left) == 1 and len(right) == 1, (len(left), len(right))


def test_the_csv_columns_are_documented():
    """docs/commands/run.md names the detections header and the metrics' frame time as written."""
    from pathlib import Path

    text = (Path(__file__).parents[1] / "docs" / "commands" / "run.md").read_text()
    assert "`frame,time,x,y,radius`" in text and "`Frame Time (s)`" in text
    assert "Frame Time (s)" in metrics_columns(make_detector("contrast"))


def test_a_panel_recording_never_takes_a_name_whose_sidecar_exists(tmp_path):
    from antiscatter.runtime import claim_recording_path

    (tmp_path / "rec.frames.csv").write_text("an earlier recording's times\n")
    assert claim_recording_path(tmp_path / "rec.mkv") == tmp_path / "rec-2.mkv"
    assert not (tmp_path / "rec.mkv").exists() and (tmp_path / "rec-2.mkv").exists()
