import av
import cv2
import numpy as np
import pytest

from antiscatter.detections import Detections
from antiscatter.errors import UsageError
from antiscatter.outputs import NullOutput, open_output
from antiscatter.sources.base import Frame


def frames_and_patterns(n, size=(40, 24)):
    rng = np.random.default_rng(3)
    for i in range(n):
        pattern = rng.integers(0, 256, (size[1], size[0]), dtype=np.uint8)
        yield Frame(np.zeros((4, 4, 3), np.uint8), i, 0), pattern


def test_ffv1_video_round_trip_is_exact(tmp_path):
    path = tmp_path / "patterns.mkv"
    written = []
    with open_output(f"files:{path}", fps=60) as out:
        for frame, pattern in frames_and_patterns(6):
            out.show(pattern, frame, Detections.empty())
            written.append(pattern)
    with av.open(str(path)) as container:
        decoded = [f.to_ndarray(format="gray") for f in container.decode(video=0)]
    assert len(decoded) == 6
    for a, b in zip(decoded, written):
        np.testing.assert_array_equal(a, b)


def test_png_folder(tmp_path):
    folder = tmp_path / "pats"
    with open_output(f"files:{folder}") as out:
        for frame, pattern in frames_and_patterns(3):
            out.show(pattern, frame, Detections.empty())
            last = pattern
    assert sorted(p.name for p in folder.iterdir()) == ["0.png", "1.png", "2.png"]
    np.testing.assert_array_equal(cv2.imread(str(folder / "2.png"), cv2.IMREAD_UNCHANGED), last)


def test_output_names():
    assert isinstance(open_output("none"), NullOutput)
    with pytest.raises(UsageError, match="unknown output 'projector'; allowed: framebuffer"):
        open_output("projector")
    with pytest.raises(UsageError, match=r"output 'files' needs a target: files:DIR or files:NAME\.mkv"):
        open_output("files")


def test_video_in_missing_folder(tmp_path):
    with pytest.raises(UsageError, match="does not exist"):
        open_output(f"files:{tmp_path / 'nope' / 'a.mkv'}")


def test_window_without_display(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(UsageError, match=r"output 'window' needs a display \(DISPLAY is not set\)"):
        open_output("window")
    assert isinstance(open_output("auto"), NullOutput)
