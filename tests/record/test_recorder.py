"""The lossless recorder and `antiscatter record`."""

import os
import re
import signal
import subprocess
import sys
import time

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
