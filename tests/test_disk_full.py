"""A full disk stops a run with one line and leaves every file whole up to its last row or frame.

First with fake writers that raise ENOSPC (no privilege needed), then on a real small tmpfs
(skipped where mounting is not permitted).  After each: every CSV parses with the header's field
count on every row, every MKV decodes to the last frame the message reports.
"""

import errno
import os
import re
import subprocess
import tempfile
from pathlib import Path

import av
import numpy as np
import pytest

from antiscatter import writing
from conftest import csv_rows, mkv_frames

from antiscatter.errors import WriteError
from antiscatter.record import Recorder

ENOSPC = OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
REAL_TEMPORARY_FILE = tempfile.TemporaryFile


def one_error_line(result):
    """The command's one error line (the run's start-up banner may precede it); no traceback."""
    assert "Traceback" not in result.err, result.err
    errors = [line for line in result.err.splitlines() if ": error: " in line]
    assert len(errors) == 1 and result.err.strip().splitlines()[-1] == errors[0], result.err
    return errors[0]


# ----------------------------------------------------------------- fake writers


class FullDisk:
    """``os`` with a disk of ``room`` bytes shared by every file: a write past it is cut short,
    the next raises ENOSPC (as a real file system does)."""

    def __init__(self, room: int) -> None:
        self.room = room

    def __getattr__(self, name):
        return getattr(os, name)

    def write(self, fd, data):
        if self.room <= 0:
            raise ENOSPC
        n = min(len(data), self.room)
        self.room -= n
        return os.write(fd, bytes(data[:n]))


@pytest.mark.parametrize("room", [0, 100, 5_000, 20_000])
def test_csv_file_keeps_whole_rows_when_the_disk_fills(tmp_path, monkeypatch, room):
    monkeypatch.setattr(writing, "os", FullDisk(room))
    path = tmp_path / "c.csv"
    written = 0
    with pytest.raises(WriteError, match="No space left on device; stopped, ") as caught:
        with writing.CsvFile(path, ["frame", "x", "y"]) as out:
            for i in range(10_000):
                out.writerows([(i, f"{i * 0.5:.3f}", f"{i * 0.25:.3f}")] * 3)
                written += 3
    rows = csv_rows(path) if path.stat().st_size else []
    kept = max(0, len(rows) - 1)
    assert kept <= written + 3 and path.stat().st_size <= room
    if rows:
        assert f"the file holds the header and {kept} whole rows" in str(caught.value)
        assert [int(r[0]) for r in rows[1:]] == [i // 3 for i in range(kept)]
    else:
        assert "the file is empty" in str(caught.value)


def test_run_stops_with_whole_csvs_when_the_disk_fills(tmp_path, cli, monkeypatch):
    monkeypatch.setattr(writing, "os", FullDisk(30_000))
    result = cli("run", "--frames", "5000", "--size", "160x120", "--output", "none",
                 "--metrics", str(tmp_path / "m.csv"), "--detections", str(tmp_path / "d.csv"))
    assert result.code == 1
    line = one_error_line(result)
    assert "No space left on device; stopped, the file holds the header and" in line
    metrics, detections = csv_rows(tmp_path / "m.csv"), csv_rows(tmp_path / "d.csv")
    failed = metrics if "m.csv" in line else detections
    assert f"the header and {len(failed) - 1} whole rows" in line
    assert 0 < len(metrics) - 1 < 5000


class FullContainer:
    """A PyAV output container whose disk fills after ``room`` packets: mux raises ENOSPC."""

    def __init__(self, inner, room: int) -> None:
        self._inner, self._room = inner, room

    def __getattr__(self, name):
        return getattr(self._inner, name)

    def mux(self, packet):
        if self._room <= 0:
            raise ENOSPC
        self._room -= 1
        self._inner.mux(packet)


@pytest.fixture
def full_video(monkeypatch):
    """Output videos opened from here on fill their disk after ``room`` packets."""
    real_open = av.open

    def install(room: int) -> None:
        def opened(path, mode="r", **kwargs):
            container = real_open(path, mode, **kwargs)
            return FullContainer(container, room) if mode == "w" else container
        monkeypatch.setattr(av, "open", opened)
    return install


def test_run_pattern_video_is_closed_and_readable_when_the_disk_fills(tmp_path, cli, full_video):
    full_video(25)
    result = cli("run", "--frames", "200", "--size", "160x120", "--projector-size", "160x100",
                 "--output", f"files:{tmp_path / 'p.mkv'}", "--metrics", str(tmp_path / "m.csv"))
    assert result.code == 1
    line = one_error_line(result)
    kept = int(re.search(r"the video holds (\d+) of (\d+) patterns", line).group(1))
    assert kept == mkv_frames(tmp_path / "p.mkv") == 25  # every packet muxed before it, finalised
    assert len(csv_rows(tmp_path / "m.csv")) - 1 >= kept


def test_record_prints_its_summary_with_the_frames_written_when_the_disk_fills(tmp_path, cli, full_video):
    full_video(30)
    result = cli("record", str(tmp_path / "r.mkv"), "--frames", "500", "--fps", "0", "--size", "160x120")
    assert result.code == 1
    line = one_error_line(result)
    kept = int(re.search(r"the file holds (\d+) of the (\d+) frames taken", line).group(1))
    assert kept == mkv_frames(tmp_path / "r.mkv") == 30
    assert re.search(rf"^recorded {kept} of \d+ captured frames .*\(write failed\)", result.out, re.M), result.out


class FullSpill:
    """A spill file whose disk (TMPDIR) holds ``room`` bytes."""

    def __init__(self, room: int, **kwargs) -> None:
        self._file, self._room = REAL_TEMPORARY_FILE(**kwargs), room

    def __getattr__(self, name):
        return getattr(self._file, name)

    def write(self, data):
        if len(data) > self._room:
            self._file.write(data[:self._room])  # cut short, as a full disk does
            self._room = 0
            raise ENOSPC
        self._room -= len(data)
        return self._file.write(data)


def _fill_recorder(recorder, frames=400):
    """Write numbered frames until the recorder refuses one; the frames it took."""
    for i in range(frames):
        try:
            recorder.write(np.full((128, 128), i % 256, np.uint8) ^ np.eye(128, dtype=np.uint8))
        except WriteError as exc:
            return i, exc
    pytest.fail("the spill never filled")


def test_spill_filling_tmpdir_stops_recording_with_the_frames_taken(tmp_path, monkeypatch):
    from antiscatter.record import recorder as recorder_module

    monkeypatch.setattr(recorder_module.tempfile, "TemporaryFile", lambda **kw: FullSpill(3 * 128 * 128 + 100, **kw))
    recorder = Recorder(tmp_path / "s.mkv", buffer_bytes=128 * 128)  # one frame in RAM, then the spill
    taken, error = _fill_recorder(recorder)
    assert "No space left on device; stopped, recording stopped after" in str(error)
    summary = recorder.close()
    assert summary["frames"] == taken == recorder.frames_in and summary["spilled"] >= 1
    with av.open(str(tmp_path / "s.mkv")) as container:
        values = [int(f.to_ndarray(format="gray")[0, 1]) for f in container.decode(video=0)]
    assert values == list(range(taken))  # in order, none lost, the refused one not half there


# ----------------------------------------------------------------- a real small disk


@pytest.fixture
def small_disk(tmp_path):
    """Mount a tmpfs of the given size (``small_disk("64k")``); unmounted afterwards."""
    mounts = []

    def mount(size: str) -> Path:
        folder = tmp_path / f"disk{len(mounts)}"
        folder.mkdir()
        done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(folder)],
                              capture_output=True, text=True)
        if done.returncode:
            pytest.skip("mounting a small tmpfs needs root or CAP_SYS_ADMIN, not available here "
                        f"({done.stderr.strip() or done.returncode}); the fake-writer tests cover the same paths")
        mounts.append(folder)
        return folder
    yield mount
    for folder in mounts:
        subprocess.run(["umount", str(folder)], capture_output=True)


@pytest.mark.parametrize("flag, target, size, frames", [
    ("--metrics", "m.csv", "16k", "160x120"),
    ("--detections", "d.csv", "8k", "800x600"),  # (the report's bubbles: several particles a frame)
    ("--output", "files:p.mkv", "16k", "160x120"),
    ("--output", "files:pat", "48k", "160x120"),
])
def test_run_on_a_full_tmpfs_leaves_whole_files(cli, small_disk, flag, target, size, frames):
    disk = small_disk(size)
    kind, _, name = target.rpartition(":")
    value = f"{kind}:{disk / name}" if kind else str(disk / name)
    result = cli("run", "--frames", "20000", "--size", frames, "--projector-size", "160x100",
                 "--output", "none", flag, value)
    assert result.code == 1
    line = one_error_line(result)
    assert "No space left on device; stopped" in line
    path = disk / name
    if name.endswith(".csv"):
        assert f"the header and {len(csv_rows(path)) - 1} whole rows" in line
    elif name.endswith(".mkv"):
        kept = int(re.search(r"the video holds (\d+) of", line).group(1))
        assert kept > 0 and mkv_frames(path) == kept
    else:
        import cv2

        pngs = sorted(path.glob("*.png"))
        assert pngs and all(cv2.imread(str(p)) is not None for p in pngs)
        assert f"holds the {len(pngs)} images before it" in line


def test_record_on_a_full_tmpfs_reports_the_frames_on_disk(cli, small_disk):
    disk = small_disk("512k")
    result = cli("record", str(disk / "r.mkv"), "--frames", "5000", "--fps", "0", "--size", "160x120")
    assert result.code == 1
    line = one_error_line(result)
    kept = int(re.search(r"the file holds (\d+) of", line).group(1))
    assert kept > 0 and mkv_frames(disk / "r.mkv") == kept
    assert f"recorded {kept} of" in result.out


def test_spill_on_a_full_tmpfs_keeps_the_frames_taken(tmp_path, small_disk, monkeypatch):
    monkeypatch.setattr(tempfile, "tempdir", str(small_disk("128k")))
    recorder = Recorder(tmp_path / "s.mkv", buffer_bytes=128 * 128)
    taken, error = _fill_recorder(recorder)
    assert "the spill file in" in str(error)
    assert recorder.close()["frames"] == taken == mkv_frames(tmp_path / "s.mkv")


def test_simulate_on_a_full_tmpfs_leaves_nothing_half_written(cli, small_disk):
    out = small_disk("128k") / "out"
    result = cli("simulate", str(out), "--frames", "200", "--size", "160x120")
    assert result.code == 1
    assert "No space left on device; stopped, nothing written (the partial output removed)" in one_error_line(result)
    assert list(out.iterdir()) == []
