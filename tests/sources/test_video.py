import numpy as np
import pytest

from antiscatter.errors import UsageError
from antiscatter.sources import VideoSource, open_source, parse_crop
from conftest import numbered_frames, write_ffv1


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
