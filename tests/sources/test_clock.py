"""Which clock a frame's time is on (sources/base.py): the one rule the CSVs, MCAP, tracker and recorder share."""

import time

import numpy as np
import pytest

from antiscatter.sources.base import Frame, FrameClock, frame_time_ns, seconds_text

IMAGE = np.zeros((8, 8), np.uint8)


def test_a_file_or_the_simulator_keeps_its_own_time_and_a_folder_is_timed_by_its_index():
    clock = FrameClock(live=False, interval_s=1 / 60)
    video = Frame(IMAGE, 3, timestamp_ns=123, media_time_ns=45_000_000)  # read at 123 ns, shown at 45 ms
    folder = Frame(IMAGE, 3, timestamp_ns=123)
    assert clock.source_ns(video) == clock.stamp_ns(video) == 45_000_000
    assert clock.source_ns(folder) == clock.stamp_ns(folder) == frame_time_ns(folder, 1e9 / 60) == 50_000_000


def test_a_live_source_is_on_the_monotonic_clock_written_as_unix_time():
    before = time.time_ns() - time.monotonic_ns()
    clock = FrameClock(live=True, interval_s=0.0)
    after = time.time_ns() - time.monotonic_ns()
    frame = Frame(IMAGE, 0, timestamp_ns=7_000_000_000_000, exposure_ns=4_000_000, media_time_ns=7_000_000_000_000)
    assert clock.source_ns(frame) == 7_000_000_000_000
    assert clock.stamp_ns(frame) - 7_000_000_000_000 == clock.offset_ns
    assert min(before, after) - 1_000_000 <= clock.offset_ns <= max(before, after) + 1_000_000


@pytest.mark.parametrize("ns, text", [(0, "0.000000000"), (45_000_000, "0.045000000"),
                                      (1_733_621_012_016_666_667, "1733621012.016666667"),
                                      (-1_500_000_000, "-1.500000000")])
def test_seconds_are_written_exactly(ns, text):
    assert seconds_text(ns) == text
