"""MCAP output of ``run`` and ``record``: read back with the same libraries, every message checked."""

from __future__ import annotations

import csv
import sys
from collections import Counter
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from conftest import draw_discs, write_ffv1

pytest.importorskip("mcap_ros2")
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from antiscatter.mcap_out import TOPICS, FrameClock

FPS = 30


@pytest.fixture
def video(tmp_path):
    """12 frames of 3 discs drifting right, 30 frames a second."""
    frames = [draw_discs((160, 120), [(30 + 2 * i, 40, 4), (80 + 2 * i, 70, 6), (120, 30 + i, 3)], background=20,
                         value=210) for i in range(12)]
    path = tmp_path / "v.mkv"
    write_ffv1(path, frames, fps=FPS)
    return path, frames


def by_topic(path) -> dict[str, list]:
    """Every message of the file, decoded (mcap_ros2's decoder), by topic in log-time order."""
    messages: dict[str, list] = {}
    with open(path, "rb") as handle:
        reader = make_reader(handle, decoder_factories=[DecoderFactory()])
        for _, channel, message, ros_msg in reader.iter_decoded_messages(log_time_order=True):
            messages.setdefault(channel.topic, []).append(SimpleNamespace(log_time_ns=message.log_time,
                                                                          ros_msg=ros_msg))
    return messages


def decode_png(message) -> np.ndarray:
    assert message.ros_msg.format == "png"
    return cv2.imdecode(np.frombuffer(bytes(message.ros_msg.data), np.uint8), cv2.IMREAD_UNCHANGED)


def test_run_writes_every_frame_as_ros2_messages(video, tmp_path, cli):
    path, frames = video
    out = tmp_path / "run.mcap"
    result = cli("run", str(path), "--output", "none", "--track", "--detections", str(tmp_path / "d.csv"),
                 "--mcap", str(out))
    assert result.code == 0, result.err
    with out.open("rb") as handle:  # the plain mcap reader: a whole file with its summary
        reader = make_reader(handle)
        summary = reader.get_summary()
        assert reader.get_header().profile == "ros2"
        assert summary.statistics.message_count == 4 * len(frames)
        assert {s.name for s in summary.schemas.values()} == {
            "sensor_msgs/msg/CompressedImage", "vision_msgs/msg/Detection2DArray", "diagnostic_msgs/msg/DiagnosticArray"}
        assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
        assert {c.message_encoding for c in summary.channels.values()} == {"cdr"}
    messages = by_topic(out)
    assert Counter({t: len(v) for t, v in messages.items()}) == Counter({t: len(frames) for t in TOPICS.values()})
    # stamped with the frame's time in the file (its pts: 1/30 s apart in Matroska's 1 ms ticks, from 0),
    # the time the CSVs carry; header = log time
    import av

    with av.open(str(path)) as container:
        pts_ns = [round(f.pts * f.time_base * 10 ** 9) for f in container.decode(video=0)]
    assert pts_ns[:4] == [0, 33_000_000, 67_000_000, 100_000_000]
    for topic in TOPICS.values():
        times = np.array([m.log_time_ns for m in messages[topic]])
        np.testing.assert_array_equal(times, pts_ns)
        for m in messages[topic]:
            stamp = m.ros_msg.header.stamp
            assert stamp.sec * 1_000_000_000 + stamp.nanosec == m.log_time_ns
    images = messages[TOPICS["image"]]
    for message, frame in zip(images, frames):
        np.testing.assert_array_equal(decode_png(message), frame)  # lossless
    rows = list(csv.DictReader((tmp_path / "d.csv").open()))
    detections = messages[TOPICS["detections"]]
    for index, message in enumerate(detections):
        mine = [r for r in rows if int(r["frame"]) == index]
        found = message.ros_msg.detections
        assert len(found) == len(mine) == 3
        for d, row in zip(found, mine):
            assert d.bbox.center.position.x == pytest.approx(float(row["x"]), abs=5e-4)
            assert d.bbox.center.position.y == pytest.approx(float(row["y"]), abs=5e-4)
            assert d.bbox.size_x == pytest.approx(2 * float(row["radius"]), abs=1e-3)
            assert d.id == ("" if int(row["track_id"]) < 0 else row["track_id"])
            assert d.results[0].hypothesis.class_id == "particle"
    assert sorted({d.id for d in detections[-1].ros_msg.detections}) != [""]  # confirmed tracks carry ids
    pattern = decode_png(messages[TOPICS["pattern"]][0])
    assert pattern.shape == (800, 1280) and pattern.max() == 255 and pattern.min() == 0  # lit, with holes
    for index, message in enumerate(messages[TOPICS["metrics"]]):
        values = {kv.key: kv.value for kv in message.ros_msg.status[0].values}
        assert values["Frame"] == str(index) and values["Particles"] == "3"
        assert float(values["Total frame processing time (s)"]) > 0


def test_record_writes_every_recorded_frame(tmp_path, cli):
    out = tmp_path / "r.mcap"
    result = cli("record", str(tmp_path / "r.mkv"), "--source", "sim", "--size", "160x120", "--frames", "6",
                 "--fps", "0", "--mcap", str(out))
    assert result.code == 0, result.err
    import av

    with av.open(str(tmp_path / "r.mkv")) as container:
        recorded = [f.to_ndarray(format="bgr24") for f in container.decode(video=0)]
    messages = by_topic(out)
    assert sorted(messages) == sorted([TOPICS["image"], TOPICS["metrics"]])
    images = messages[TOPICS["image"]]
    assert len(images) == len(recorded) == 6
    for message, frame in zip(images, recorded):
        image = decode_png(message)
        np.testing.assert_array_equal(image if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR), frame)
    times = np.array([m.log_time_ns for m in images])
    from antiscatter.sources.simulated import SimulatorSource

    fps = SimulatorSource(size=(160, 120)).fps  # --fps 0: stamped at the simulator's own rate
    np.testing.assert_allclose(np.diff(times), 1e9 / fps, atol=1)
    recorded_counts = [{kv.key: kv.value for kv in m.ros_msg.status[0].values}["Recorded"]
                       for m in messages[TOPICS["metrics"]]]
    assert recorded_counts == ["1", "2", "3", "4", "5", "6"]


def test_live_frames_keep_their_capture_times():
    clock = FrameClock(live=True, interval_s=0.0)
    first, second = SimpleNamespace(timestamp_ns=5_000_000_000, index=0), SimpleNamespace(timestamp_ns=5_016_700_000,
                                                                                          index=1)
    assert clock.stamp_ns(second) - clock.stamp_ns(first) == 16_700_000
    assert abs(clock.stamp_ns(first) - (5_000_000_000 + clock.offset_ns)) == 0


def test_frame_clock_bad_interval():
    with pytest.raises(ValueError) as info:
        FrameClock(live=False, interval_s=0.0)
    assert str(info.value) == "interval_s: got 0.0, allowed a number > 0 for a source that is not live"


def test_bad_mcap_path_is_refused_before_any_work(video, tmp_path, cli):
    path, _ = video
    result = cli("run", str(path), "--output", "none", "--mcap", str(tmp_path / "out.bag"))
    assert result.code == 2 and "--mcap" in result.err and "allowed a file ending in .mcap" in result.err
    assert not (tmp_path / "out.bag").exists()
    result = cli("record", str(tmp_path / "r.mkv"), "--frames", "2", "--mcap", str(tmp_path / "nowhere" / "r.mcap"))
    assert result.code == 2 and "does not exist" in result.err and not (tmp_path / "r.mkv").exists()


def test_missing_extra_names_the_install_command(video, tmp_path, cli, monkeypatch):
    path, _ = video
    monkeypatch.setitem(sys.modules, "mcap_ros2.writer", None)  # as if the package were not installed
    result = cli("run", str(path), "--output", "none", "--mcap", str(tmp_path / "o.mcap"))
    assert result.code == 2
    assert "--mcap needs the mcap packages: pip install 'antiscatter[mcap]'" in result.err
