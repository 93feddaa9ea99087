"""The lossless recorder and `antiscatter record`."""

import os
import re
import signal
import subprocess
import sys
import time
from types import SimpleNamespace

import av
import numpy as np
import pytest

from antiscatter.errors import UsageError
from antiscatter.record import Recorder, RecorderFull, pixel_format

from conftest import PanelProcess


def decode(path, fmt):
    with av.open(str(path)) as container:
        return [f.to_ndarray(format=fmt) for f in container.decode(video=0)]


@pytest.mark.parametrize("shape, fmt, pix", [((48, 64), "gray", "gray"), ((48, 64, 3), "bgr24", "bgr0")])
def test_lossless_round_trip_grey_and_colour(tmp_path, shape, fmt, pix):
    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 256, shape, dtype=np.uint8) for _ in range(25)]
    assert pixel_format(frames[0]) == (fmt, pix)
    recorder = Recorder(tmp_path / "r.mkv", fps=60)
    for f in frames:
        recorder.write(f)
        f[...] = 0  # the caller reuses its buffer: the recorder kept its own copy
    summary = recorder.close()
    assert summary["frames"] == 25 and summary["dropped"] == 0
    rng = np.random.default_rng(0)
    expected = [rng.integers(0, 256, shape, dtype=np.uint8) for _ in range(25)]
    got = decode(tmp_path / "r.mkv", fmt)
    assert len(got) == 25
    for a, b in zip(got, expected):
        np.testing.assert_array_equal(a, b)
    with av.open(str(tmp_path / "r.mkv")) as container:
        assert container.streams.video[0].codec_context.name == "ffv1"
        assert container.streams.video[0].format.name == pix


def test_full_buffer_spills_to_disk_in_order(tmp_path):
    frames = [np.full((32, 32), i, np.uint8) for i in range(40)]
    recorder = Recorder(tmp_path / "s.mkv", buffer_bytes=32 * 32 * 2)  # room for two frames
    for f in frames:
        recorder.write(f)
    summary = recorder.close()
    assert summary["frames"] == 40 and summary["dropped"] == 0 and summary["spilled"] > 0
    assert [int(f[0, 0]) for f in decode(tmp_path / "s.mkv", "gray")] == list(range(40))


def test_full_buffer_can_stop_recording_with_a_message(tmp_path):
    recorder = Recorder(tmp_path / "t.mkv", buffer_bytes=100, overflow="stop")  # smaller than one frame
    with pytest.raises(RecorderFull, match="frame buffer is full .* recording stopped after 0 frames"):
        recorder.write(np.zeros((32, 32), np.uint8))
    recorder.close()


def test_bad_paths(tmp_path):
    with pytest.raises(UsageError, match=r"allowed a \.mkv file"):
        Recorder(tmp_path / "x.mp4")
    with pytest.raises(UsageError, match="does not exist"):
        Recorder(tmp_path / "no" / "x.mkv")


def test_record_command_and_playback(tmp_path, cli):
    result = cli("record", str(tmp_path / "sim.mkv"), "--source", "sim", "--frames", "30", "--fps", "0")
    assert result.code == 0, result.err
    assert "recorded 30 of 30 captured frames" in result.out and "dropped 0" in result.out
    assert len(decode(tmp_path / "sim.mkv", "bgr24")) == 30
    play = cli("run", str(tmp_path / "sim.mkv"), "--output", "none", "--detections", str(tmp_path / "d.csv"))
    assert play.code == 0 and "frames: 30 (source ended)" in play.out


def test_ctrl_c_mid_recording_leaves_a_playable_file_with_every_captured_frame(tmp_path):
    # interrupted 2 s after it says it has started (not 2 s after launch: on a loaded machine the
    # interpreter's start-up alone took most of that, and 21 frames were captured)
    proc = subprocess.Popen([sys.executable, "-m", "antiscatter", "record", "r.mkv", "--source", "sim",
                             "--fps", "60"], cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    first = proc.stderr.readline()  # the log
    assert first.startswith("antiscatter record: "), first
    time.sleep(2.0)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 130, err
    match = re.search(r"recorded (\d+) of (\d+) captured frames", out)
    recorded, captured = int(match.group(1)), int(match.group(2))
    assert recorded == captured > 30
    assert len(decode(tmp_path / "r.mkv", "bgr24")) == captured


def test_record_bad_input(tmp_path, cli):
    result = cli("record", str(tmp_path / "r.mkv"), "--source", str(tmp_path / "missing.mkv"))
    assert result.code == 2 and "no such file or folder" in result.err
    result = cli("record", str(tmp_path / "r.mkv"), "--fps", "-1")
    assert result.code == 2 and "--fps -1.0: allowed a number >= 0" in result.err
    result = cli("record", str(tmp_path / "r.mkv"), "--seconds", "nan")  # not a time: it used to pass
    assert result.code == 2 and "--seconds nan: allowed a number >= 0" in result.err
    assert not (tmp_path / "r.mkv").exists()


def test_record_panel_pauses_and_stops(tmp_path):
    with PanelProcess(["record", "r.mkv", "--source", "sim", "--fps", "30"], tmp_path) as panel:
        proc, post = panel.proc, panel.post
        time.sleep(1.0)
        assert post("record") == "recording off"  # paused
        time.sleep(0.5)
        stats = panel.stats()
        assert stats["recording"] == "no" and stats["captured"] > stats["recorded"] - 1
        assert post("light") == "light off"
        post("stop")
        out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    match = re.search(r"recorded (\d+) of (\d+) captured frames", out)
    recorded, captured = int(match.group(1)), int(match.group(2))
    assert 0 < recorded < captured  # the pause was honoured
    assert len(decode(tmp_path / "r.mkv", "bgr24")) == recorded


# ---------------------------------------------------------------- true time (issue 50)

def read_times(path):
    """(pts ticks, time base) of every frame of a recording, read back with PyAV."""
    with av.open(str(path)) as container:
        frames = list(container.decode(video=0))
    return [f.pts for f in frames], frames[0].time_base


def sidecar_rows(path):
    import csv

    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def test_recording_keeps_irregular_times_as_its_timestamps_and_in_its_sidecar(tmp_path):
    from fractions import Fraction

    from antiscatter.record import SIDECAR_COLUMNS, sidecar_path

    start = 12_345_678_000_000  # a monotonic clock's ns, hours after boot
    gaps_ms = [0, 16, 17, 50, 3, 100, 16, 1000, 1]  # dropped frames, a stall, a burst
    times = [start + 1_000_000 * sum(gaps_ms[:i + 1]) for i in range(len(gaps_ms))]
    exposures = [4_000_000, 4_000_000, 2_500_000, 1_000, 0, 16_000_000, 8_000_000, 4_000_000, 4_000_000]
    gains = [1.0, 1.0, 2.5, 64.0, 0.0, 1.0, 8.0, 1.5, 1.0]
    recorder = Recorder(tmp_path / "t.mkv", fps=60, unix_offset_ns=1_700_000_000_000_000_000)
    for i, (t, e, g) in enumerate(zip(times, exposures, gains)):
        recorder.write(np.full((24, 32), i, np.uint8), time_ns=t, exposure_ns=e, analogue_gain=g)
    assert recorder.close()["frames"] == len(times)
    pts, base = read_times(tmp_path / "t.mkv")
    assert base == Fraction(1, 1000)
    assert [p * base for p in pts] == [Fraction(t - start, 10 ** 9) for t in times]  # exactly, from the first
    assert sidecar_path(tmp_path / "t.mkv") == tmp_path / "t.frames.csv"
    rows = sidecar_rows(tmp_path / "t.frames.csv")
    assert list(rows[0]) == list(SIDECAR_COLUMNS)
    assert [int(r["frame"]) for r in rows] == list(range(len(times)))
    assert [int(r["pts"]) for r in rows] == pts
    assert [int(r["time_ns"]) for r in rows] == times
    assert [int(r["unix_time_ns"]) for r in rows] == [t + 1_700_000_000_000_000_000 for t in times]
    assert [r["exposure_us"] for r in rows] == ["4000", "4000", "2500", "1", "", "16000", "8000", "4000", "4000"]
    assert [r["analogue_gain"] for r in rows] == ["1", "1", "2.5", "64", "", "1", "8", "1.5", "1"]


def test_timestamps_finer_than_a_millisecond_round_and_never_run_backwards(tmp_path):
    # Matroska (FFmpeg's muxer) keeps 1 ms ticks: the sidecar keeps the ns; a clock that steps back
    # or stands still gives the next tick, so every frame is kept in order
    times = [5_000_000_000, 5_016_666_667, 5_033_499_999, 5_033_500_001, 5_020_000_000, 5_050_000_000]
    recorder = Recorder(tmp_path / "r.mkv")
    for i, t in enumerate(times):
        recorder.write(np.full((16, 16), i, np.uint8), time_ns=t)
    recorder.close()
    pts, _ = read_times(tmp_path / "r.mkv")
    assert pts == [0, 17, 33, 34, 35, 50]
    rows = sidecar_rows(tmp_path / "r.frames.csv")
    assert [int(r["time_ns"]) for r in rows] == times and [r["unix_time_ns"] for r in rows] == [""] * 6
    assert [int(f[0, 0]) for f in decode(tmp_path / "r.mkv", "gray")] == list(range(6))


def test_frames_without_times_are_at_the_nominal_rate(tmp_path):
    recorder = Recorder(tmp_path / "c.mkv", fps=25)
    for i in range(5):
        recorder.write(np.zeros((16, 16), np.uint8))
    recorder.close()
    assert read_times(tmp_path / "c.mkv")[0] == [0, 40, 80, 120, 160]
    assert [int(r["time_ns"]) for r in sidecar_rows(tmp_path / "c.frames.csv")] == [i * 40_000_000 for i in range(5)]


def test_a_recording_that_takes_no_frame_leaves_no_sidecar(tmp_path):
    Recorder(tmp_path / "n.mkv").close()
    assert not (tmp_path / "n.frames.csv").exists()


class SimulatedCamera:
    """Picamera2 as ``CameraSource`` uses it, handing out the simulator's frames (their grey as the
    Y plane) with a known, irregular sensor clock, exposure and gain."""

    stamps = [7_000_000_000_000 + ns for ns in (0, 16_666_667, 33_333_334, 66_671_002, 83_337_000, 183_337_000,
                                                200_003_667, 216_670_334)]  # drops, a stall, jitter
    exposures_us = [4000, 4000, 3217, 12001, 999, 4000, 16000, 4000]  # automatic exposure at work
    gains = [1.0, 1.0, 1.25, 3.5, 1.0, 1.0, 7.75, 1.0]
    frames: list = []

    def __init__(self):
        from antiscatter.sources.simulated import SimulatorSource

        self.sim = SimulatorSource(size=(160, 120), seed=3)
        self.count = 0

    def create_video_configuration(self, main, buffer_count, queue, controls):
        return {"main": main}

    def configure(self, config):
        self.size = config["main"]["size"]

    def start(self):
        pass

    def capture_request(self):
        import cv2

        grey = cv2.cvtColor(self.sim.read().image, cv2.COLOR_BGR2GRAY)
        SimulatedCamera.frames.append(grey)
        i, self.count = self.count, self.count + 1
        image = np.vstack([grey, np.full((grey.shape[0] // 2, grey.shape[1]), 128, np.uint8)])  # YUV420's Y, then UV
        metadata = {"SensorTimestamp": self.stamps[i], "ExposureTime": self.exposures_us[i],
                    "AnalogueGain": self.gains[i]}
        return SimpleNamespace(make_array=lambda name: image, get_metadata=lambda: metadata, release=lambda: None)

    def stop(self):
        pass

    def close(self):
        pass


def test_a_camera_recording_keeps_the_sensor_times_exposures_and_gains(tmp_path, cli, monkeypatch):
    """``record --source camera`` end to end (the real CameraSource, a fake Picamera2 with a known clock):
    the file's timestamps are the sensor's, from the first frame; the sidecar has them to the ns."""
    from fractions import Fraction
    import time as clock

    module = SimpleNamespace(Picamera2=SimulatedCamera, MappedArray=None)
    monkeypatch.setitem(sys.modules, "picamera2", module)
    SimulatedCamera.frames = []
    result = cli("record", str(tmp_path / "cam.mkv"), "--source", "camera", "--size", "160x120", "--frames", "8")
    assert result.code == 0, result.err
    assert "recorded 8 of 8 captured frames" in result.out
    # each frame's time is the middle of its exposure: SensorTimestamp (its end) less half ExposureTime
    middles = [s - e * 1000 // 2 for s, e in zip(SimulatedCamera.stamps, SimulatedCamera.exposures_us)]
    pts, base = read_times(tmp_path / "cam.mkv")
    assert pts == [round(Fraction(m - middles[0], 10 ** 6)) for m in middles]  # ms ticks from the first
    assert pts == [0, 17, 34, 63, 85, 183, 194, 217]
    got = decode(tmp_path / "cam.mkv", "gray")
    assert len(got) == 8
    for a, b in zip(got, SimulatedCamera.frames):
        np.testing.assert_array_equal(a, b)  # lossless
    rows = sidecar_rows(tmp_path / "cam.frames.csv")
    assert [int(r["time_ns"]) for r in rows] == middles
    assert [int(r["pts"]) for r in rows] == pts
    assert [float(r["exposure_us"]) for r in rows] == SimulatedCamera.exposures_us
    assert [float(r["analogue_gain"]) for r in rows] == SimulatedCamera.gains
    offsets = {int(r["unix_time_ns"]) - int(r["time_ns"]) for r in rows}  # one mapping to UNIX time
    assert len(offsets) == 1
    assert abs(offsets.pop() - (clock.time_ns() - clock.monotonic_ns())) < 5e9


def test_record_refuses_to_overwrite_a_sidecar(tmp_path, cli):
    (tmp_path / "x.frames.csv").write_text("kept\n")
    result = cli("record", str(tmp_path / "x.mkv"), "--frames", "2", "--fps", "0")
    assert result.code == 2
    assert (tmp_path / "x.frames.csv").read_text() == "kept\n" and not (tmp_path / "x.mkv").exists()
    assert result.err.strip().count("\n") == 0 and "x.frames.csv" in result.err
