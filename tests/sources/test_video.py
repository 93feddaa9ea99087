from fractions import Fraction

import numpy as np
import pytest

from antiscatter.errors import UsageError
from antiscatter.sources import VideoSource, open_source, parse_crop
from conftest import numbered_frames, write_ffv1, write_vfr


@pytest.fixture
def video(tmp_path):
    frames = numbered_frames(5, (64, 48))
    path = tmp_path / "clip.mkv"
    write_ffv1(path, frames)
    return path, frames


def test_ffv1_frames_decode_exactly(video):
    path, frames = video
    source = open_source(str(path))
    assert isinstance(source, VideoSource)
    assert source.size == (64, 48)
    got = []
    while (frame := source.read()) is not None:
        got.append(frame.image.copy())
    assert len(got) == 5
    for a, b in zip(got, frames):
        np.testing.assert_array_equal(a, b)


def test_crop_keeps_the_named_columns_and_rows(video):
    path, frames = video
    source = open_source(str(path), crop=parse_crop("10:40,5:25"))
    assert source.size == (30, 20)
    frame = source.read()
    assert frame.image.shape == (20, 30, 3)
    np.testing.assert_array_equal(frame.image, frames[0][5:25, 10:40])


def test_loop_plays_again(video):
    path, frames = video
    source = open_source(str(path), loop=True)
    images = [source.read().image.copy() for _ in range(12)]
    np.testing.assert_array_equal(images[5], frames[0])
    np.testing.assert_array_equal(images[11], frames[1])
    assert source.read().index == 12


def test_crop_outside_the_frame(video):
    path, _ = video
    with pytest.raises(UsageError, match=r"--crop 10:80,0:20: outside the 64x48 frame of .*clip\.mkv "
                                         r"\(allowed X1 <= 64, Y1 <= 48\)"):
        open_source(str(path), crop=parse_crop("10:80,0:20"))


@pytest.mark.parametrize("text", ["1:2", "a:b,c:d", "5:3,0:10", "0:10,-1:5"])
def test_bad_crop_text(text):
    with pytest.raises(UsageError, match="--crop"):
        parse_crop(text)


def test_file_that_is_not_a_video(tmp_path):
    path = tmp_path / "junk.mkv"
    path.write_bytes(b"\x00" * 100)
    with pytest.raises(UsageError, match=r"junk\.mkv: cannot be (opened|decoded) as a video"):
        open_source(str(path))


# ---------------------------------------------------------------- true time (issue 50)

VFR_PTS = [0, 10, 45, 46, 120, 133, 500, 517]  # ms: irregular, a stall, a burst


@pytest.mark.parametrize("name, codec, base", [("vfr.mkv", "ffv1", Fraction(1, 1000)),
                                               ("vfr.mp4", "libx264", Fraction(1, 90000))])
def test_each_frame_keeps_its_presentation_time(tmp_path, name, codec, base):
    frames = numbered_frames(len(VFR_PTS), (64, 48))
    ticks = [int(ms * Fraction(1, 1000) / base) for ms in VFR_PTS]
    write_vfr(tmp_path / name, frames, ticks, base, codec)
    with open_source(str(tmp_path / name)) as source:
        got = list(iter(source.read, None))
    assert [f.media_time_ns for f in got] == [ms * 1_000_000 for ms in VFR_PTS]
    assert [f.index for f in got] == list(range(len(VFR_PTS)))
    assert source.damaged == ""  # the nominal rate's count (30/s over 0.5 s) is not a cut


def test_a_looped_file_goes_on_in_time(tmp_path):
    frames = numbered_frames(3, (64, 48))
    write_vfr(tmp_path / "l.mkv", frames, [100, 130, 200])  # starts at 100 ms, as a cut-out clip may
    with open_source(str(tmp_path / "l.mkv"), loop=True) as source:
        times = [source.read().media_time_ns // 1_000_000 for _ in range(7)]
    # the next pass starts a nominal period (30/s: 33 ms) after the last frame, the clip's own spacing kept
    assert times == [100, 130, 200, 233, 263, 333, 366]


def test_a_file_cut_short_is_still_reported(tmp_path):
    path = tmp_path / "c.mkv"
    write_ffv1(path, numbered_frames(60, (64, 48)))
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with open_source(str(path)) as source:
        count = len(list(iter(source.read, None)))
    assert 0 < count < 60
    assert source.damaged.endswith(f"ended after {count} of the 60 frames its container declares (cut short or "
                                   "damaged); the frames read were used")


def test_simulator_frames_are_on_the_scene_clock():
    with open_source("sim", size=(96, 64)) as source:
        frames = [source.read() for _ in range(4)]
    assert [f.media_time_ns for f in frames] == [round(i * 1e9 / source.fps) for i in range(4)]
