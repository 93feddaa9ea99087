"""The threaded runtime: latest-frame hand-over, drops, crash propagation, both modes end to end."""

import csv
import threading
import time

import numpy as np
import pytest

from antiscatter.config import load_config
from antiscatter.errors import UsageError
from antiscatter.runtime import LatestSlot, run


def test_slow_consumer_sees_the_newest_item_and_drops_are_counted_exactly():
    slot = LatestSlot()
    for i in range(5):
        slot.put(i)
    assert slot.get() == 4
    assert slot.take_dropped() == 4
    assert slot.take_dropped() == 0
    slot.put(5)
    assert slot.get() == 5 and slot.take_dropped() == 0


def test_lossless_slot_waits_instead_of_dropping():
    slot = LatestSlot(lossless=True)
    got = []

    def consumer():
        while (item := slot.get()) is not None:
            got.append(item)
            time.sleep(0.002)

    thread = threading.Thread(target=consumer)
    thread.start()
    for i in range(20):
        slot.put(i)
    time.sleep(0.05)
    slot.close()
    thread.join(2)
    assert got == list(range(20)) and slot.take_dropped() == 0


def test_get_returns_none_when_closed_or_cancelled():
    slot = LatestSlot()
    cancel = threading.Event()
    cancel.set()
    assert slot.get(cancel) is None
    slot.close()
    assert slot.get() is None


def _config(tmp_path, mode, **run):
    return load_config(overrides={"output": {"outputs": ("none",)},
                                  "run": {"mode": mode, "metrics": str(tmp_path / f"{mode}.csv"), **run}})


@pytest.mark.parametrize("mode", ["single", "threads"])
def test_both_modes_process_every_simulator_frame(tmp_path, mode):
    import io
    summary = run(_config(tmp_path, mode, frames=50), log=io.StringIO(), out=io.StringIO())
    assert summary.frames == 50 and summary.dropped == 0
    rows = list(csv.DictReader((tmp_path / f"{mode}.csv").open()))
    assert [int(r["Frame"]) for r in rows] == list(range(50))
    assert all(int(r["Dropped Frames"]) == 0 for r in rows)


class _Exploding:
    """A source that fails on its fourth frame."""

    name, size, fps, live = "boom", (64, 48), 0.0, False

    def __init__(self):
        self.n = 0

    def read(self):
        from antiscatter.sources.base import Frame
        self.n += 1
        if self.n == 4:
            raise UsageError("boom: frame 3 is unreadable")
        return Frame(np.zeros((48, 64, 3), np.uint8), self.n - 1, time.monotonic_ns())

    def close(self):
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


@pytest.mark.parametrize("mode", ["single", "threads"])
def test_a_crash_in_any_thread_stops_the_run_with_its_error(tmp_path, monkeypatch, mode):
    import io
    from antiscatter import runtime
    monkeypatch.setattr(runtime, "_open_source", lambda config, detector: _Exploding())
    started = time.monotonic()
    with pytest.raises(UsageError, match="frame 3 is unreadable"):
        run(_config(tmp_path, mode), log=io.StringIO(), out=io.StringIO())
    assert time.monotonic() - started < 5
    rows = list(csv.reader((tmp_path / f"{mode}.csv").open()))
    assert len(rows) == 4  # header + the three good frames, written completely


def test_a_crash_in_the_detector_thread_propagates(tmp_path, monkeypatch):
    import io
    from antiscatter.detection import seed

    def broken(image):
        raise RuntimeError("detector exploded")

    monkeypatch.setattr(seed, "to_grey", broken)
    config = load_config(overrides={"output": {"outputs": ("none",)}, "detector": {"name": "seed"},
                                    "run": {"mode": "threads", "frames": 10}})
    with pytest.raises(RuntimeError, match="detector exploded"):
        run(config, log=io.StringIO(), out=io.StringIO())
    assert not [t for t in threading.enumerate() if t.name.startswith("antiscatter-")]


def test_pacing_reaches_the_asked_rate(tmp_path):
    # small frames (a few ms of work in the 20 ms period, even on a busy machine): the rate is the
    # pacing's, never faster than asked, and not slower while the work fits the period
    import io
    config = load_config(overrides={"output": {"outputs": ("none",)}, "source": {"size": "320x240"},
                                    "run": {"mode": "threads", "frames": 40, "fps": 50}})
    summary = run(config, log=io.StringIO(), out=io.StringIO())
    pacing = summary.pacing()
    assert abs(pacing["rate"] - 50) < 2.5


def test_process_controls_report_whether_they_took_effect(tmp_path):
    import io
    log = io.StringIO()
    run(_config(tmp_path, "single", frames=2, cpus="0", mlock=True), log=log, out=io.StringIO())
    text = log.getvalue()
    assert "running on CPUs [0]" in text or "warning: --cpus" in text
    assert "memory locked" in text or "warning: --mlock" in text


def test_bench_modes_reports_every_mode(cli):
    import json
    result = cli("bench", "--modes", "--frames", "15", "--sizes", "320x240", "--json")
    assert result.code == 0, result.err
    modes = json.loads(result.out)["modes"]
    assert [m["mode"] for m in modes] == ["single", "threads", "processes", "processes-pickle"]
    for m in modes:
        assert m["frames"] == 15 and m["fps"] > 0
        assert 0 < m["latency_p50_ms"] <= m["latency_p99_ms"] <= m["latency_max_ms"]


def test_bench_modes_as_on_the_vehicle_times_the_tracker_too(cli):
    import json
    plain = json.loads(cli("bench", "--modes", "--frames", "15", "--sizes", "320x240", "--json").out)["modes"]
    assert all(m["tracking_mean_ms"] is None for m in plain)  # files and the simulator: no tracking
    result = cli("bench", "--modes", "--vehicle", "--frames", "15", "--sizes", "320x240")
    assert result.code == 0, result.err
    assert "as on the vehicle: tracking with prediction" in result.out and "tracking" in result.out.splitlines()[2]
    modes = json.loads(cli("bench", "--modes", "--vehicle", "--frames", "15", "--sizes", "320x240", "--json").out)["modes"]
    for m in modes:
        assert m["frames"] == 15 and 0 < m["tracking_mean_ms"] < m["latency_max_ms"]
    wrong = cli("bench", "--vehicle", "--frames", "5")
    assert wrong.code == 2 and "--vehicle: goes with --modes" in wrong.err and "Traceback" not in wrong.err


def test_emulated_camera_blocks_until_the_next_exposure():
    from antiscatter.sources.replay import ReplaySource
    source = ReplaySource([np.zeros((4, 4), np.uint8)], frames=10, fps=200)
    stamps = [source.read().timestamp_ns for _ in range(5)]
    gaps = np.diff(stamps) / 1e6
    assert np.allclose(gaps, 5.0, atol=0.01)  # exposures on a fixed 5 ms grid
    assert source.live
    time.sleep(0.012)  # a slow reader misses two exposures, as with queue=False
    late = source.read().timestamp_ns
    assert round((late - stamps[-1]) / 5e6) >= 3


@pytest.mark.parametrize("mode", ["single", "threads"])
def test_the_detectors_learning_runs_after_the_pattern_is_out(tmp_path, monkeypatch, mode):
    # the contrast detector's background update learns for the next frames: the runtime shows
    # this frame's pattern first (off the latency path), yet detects exactly what detect() does
    # and logs the update's time with the frame
    import io

    from antiscatter import runtime
    from antiscatter.detection import make_detector
    from antiscatter.outputs.base import NullOutput
    from antiscatter.sources import open_source

    events = []
    finish, show = runtime.finish_stages, NullOutput.show
    monkeypatch.setattr(runtime, "finish_stages", lambda *a, **k: (events.append("learn"), finish(*a, **k))[1])
    monkeypatch.setattr(NullOutput, "show", lambda self, *a, **k: (events.append("show"), show(self, *a, **k))[1])
    config = load_config(overrides={"output": {"outputs": ("none",)},
                                    "run": {"mode": mode, "frames": 30, "metrics": str(tmp_path / "m.csv"),
                                            "detections": str(tmp_path / "d.csv")}})
    run(config, log=io.StringIO(), out=io.StringIO())
    assert events.count("show") == 30
    if mode == "single":
        assert events == ["show", "learn"] * 30
    else:  # the process thread learns while the output thread shows (and may run a frame or two ahead)
        assert events.count("learn") >= 30
    rows = list(csv.DictReader((tmp_path / "m.csv").open()))
    assert all(float(r["Background Update Duration (s)"]) > 0 for r in rows)
    found = list(csv.DictReader((tmp_path / "d.csv").open()))
    detector = make_detector("contrast")
    with open_source("sim") as source:
        for index in range(30):
            expected = detector.detect(source.read().image)
            mine = np.array([[float(r["x"]), float(r["y"]), float(r["radius"])] for r in found
                             if int(r["frame"]) == index]).reshape(-1, 3)
            assert np.allclose(mine, np.column_stack([expected.centres, expected.radii]), atol=1e-3), index
