import cv2
import numpy as np
import pytest

from antiscatter.errors import UsageError
from antiscatter.sources import FolderSource, frame_files, list_frames, open_source
from conftest import numbered_frames


def _write(folder, names_and_frames):
    for name, image in names_and_frames:
        cv2.imwrite(str(folder / name), image)


def test_natural_order_and_other_files_ignored(tmp_path):
    frames = numbered_frames(4)
    _write(tmp_path, [("10.png", frames[3]), ("2.png", frames[1]), ("1.png", frames[0]),
                      ("3.png", frames[2])])
    (tmp_path / "notes.txt").write_text("x")
    (tmp_path / "a.png").write_bytes(b"not a frame name")
    (tmp_path / "5.jpg").write_bytes(b"")
    assert [p.name for p in list_frames(tmp_path)] == ["1.png", "2.png", "3.png", "10.png"]
    source = open_source(str(tmp_path))
    assert isinstance(source, FolderSource)
    read = []
    while (frame := source.read()) is not None:
        read.append(frame)
    assert [f.index for f in read] == [0, 1, 2, 3]
    for frame, expected in zip(read, frames):
        np.testing.assert_array_equal(frame.image, expected)
    assert source.size == (64, 48)


def test_loop_restarts(tmp_path):
    frames = numbered_frames(2)
    _write(tmp_path, [("0.png", frames[0]), ("1.png", frames[1])])
    source = FolderSource(tmp_path, loop=True)
    images = [source.read().image for _ in range(5)]
    np.testing.assert_array_equal(images[2], frames[0])
    np.testing.assert_array_equal(images[3], frames[1])


def test_empty_folder(tmp_path):
    (tmp_path / "readme.txt").write_text("x")
    with pytest.raises(UsageError, match=r"no frames in this folder; allowed: <int>\.png files, or images "
                                         r"named in order \(png, jpg, jpeg, tif, tiff, bmp\)"):
        open_source(str(tmp_path))


def test_images_named_in_order_are_frames_in_natural_order(tmp_path):
    # a camera's or an annotation tool's names: numbers inside names compare as numbers, any case
    frames = numbered_frames(5)
    names = ["IMG_2.JPG", "IMG_10.png", "IMG_1.tif", "img_3.bmp", "IMG_9.jpeg"]
    order = ["IMG_1.tif", "IMG_2.JPG", "img_3.bmp", "IMG_9.jpeg", "IMG_10.png"]
    for name in names:
        cv2.imwrite(str(tmp_path / name), frames[order.index(name)])
    (tmp_path / "notes.txt").write_text("x")
    (tmp_path / "sub.png").mkdir()  # a folder is not a frame
    assert [p.name for _, p in frame_files(tmp_path)] == order
    assert [n for n, _ in frame_files(tmp_path)] == [0, 1, 2, 3, 4]
    source = open_source(str(tmp_path))
    read = []
    while (frame := source.read()) is not None:
        read.append(frame)
    assert [f.index for f in read] == [0, 1, 2, 3, 4]
    np.testing.assert_array_equal(read[0].image, frames[0])  # lossless formats read back exactly
    np.testing.assert_array_equal(read[4].image, frames[4])
    assert np.abs(read[1].image.astype(int) - frames[1]).mean() < 8  # JPEG: close


def test_numbered_pngs_take_precedence_and_keep_their_numbers(tmp_path):
    frames = numbered_frames(3)
    _write(tmp_path, [("0.png", frames[0]), ("1.png", frames[1]), ("5.png", frames[2]), ("IMG_1.jpg", frames[0])])
    assert [(n, p.name) for n, p in frame_files(tmp_path)] == [(0, "0.png"), (1, "1.png"), (5, "5.png")]


def test_png_that_is_not_an_image(tmp_path):
    (tmp_path / "0.png").write_bytes(b"this is text")
    with pytest.raises(UsageError, match=r"0\.png: not a readable image"):
        open_source(str(tmp_path))


def test_bad_frame_in_the_middle_names_the_file(tmp_path):
    frames = numbered_frames(1)
    _write(tmp_path, [("0.png", frames[0])])
    (tmp_path / "1.png").write_bytes(b"broken")
    source = FolderSource(tmp_path)
    assert source.read() is not None
    with pytest.raises(UsageError, match=r"1\.png: not a readable image"):
        source.read()


def test_frame_of_other_size_rejected(tmp_path):
    _write(tmp_path, [("0.png", numbered_frames(1)[0]), ("1.png", numbered_frames(1, (32, 32))[0])])
    source = FolderSource(tmp_path)
    source.read()
    with pytest.raises(UsageError, match=r"1\.png: size 32x32 differs from the first frame's 64x48"):
        source.read()


def test_missing_path():
    with pytest.raises(UsageError, match=r"source 'no/such/dir': no such file or folder; allowed: sim, camera"):
        open_source("no/such/dir")


def test_16_bit_frames_are_scaled_by_the_first_frames_depth(tmp_path):
    # a scientific camera's 12-bit samples in 16-bit files: scaled to 8 bits by 12 bits, every
    # frame alike (OpenCV's own conversion would drop the low byte: 0-15 left)
    first = np.full((48, 64), 800, np.uint16)
    first[10, 10] = 4095
    second = np.full((48, 64), 400, np.uint16)
    cv2.imwrite(str(tmp_path / "cam_1.tif"), first)
    cv2.imwrite(str(tmp_path / "cam_2.tif"), second)
    source = open_source(str(tmp_path))
    a, b = source.read().image, source.read().image
    assert a.dtype == np.uint8 and a.shape == (48, 64, 3)
    assert a[10, 10, 0] == 255 and a[0, 0, 0] == round(800 * 255 / 4095)
    assert b[0, 0, 0] == round(400 * 255 / 4095)  # the first frame's depth, not its own
    full = np.full((48, 64), 60000, np.uint16)
    cv2.imwrite(str(tmp_path / "cam_1.tif"), full)
    assert open_source(str(tmp_path)).read().image[0, 0, 0] == round(60000 * 255 / 65535)


def test_float_frames_are_refused(tmp_path):
    cv2.imwrite(str(tmp_path / "a.tif"), np.zeros((8, 8, 3), np.float32))
    with pytest.raises(UsageError, match=r"a\.tif: float32 samples; allowed 8- or 16-bit images"):
        open_source(str(tmp_path))


def test_an_image_opencv_cannot_decode_is_one_line(tmp_path, python):
    import subprocess

    cv2.imwrite(str(tmp_path / "a.tif"), np.zeros((8, 8), np.float32))  # one float channel: OpenCV fails
    # in a process of its own: OpenCV's own messages go to the process's stderr, not Python's
    result = subprocess.run([python, "-m", "antiscatter", "run", str(tmp_path), "--output", "none"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 2 and result.stderr.strip().splitlines() == [
        f"antiscatter run: error: {tmp_path / 'a.tif'}: not a readable image"]
