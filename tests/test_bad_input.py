"""Bad input across every command, as one table: each row is a command line, the exit code and the
message fragment it must give, and the files it must leave or must not write.

Bad input is one line on stderr naming the file, key or value and what is allowed, exit code 2,
no traceback and nothing written.  Rows run the CLI in-process; the few that check what a library
prints on the process's own stderr (FFmpeg, numpy warnings) or need a stdin without a terminal
run it in a subprocess.
"""

from __future__ import annotations

import resource
import subprocess
import sys
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import pytest

from conftest import draw_discs, run_cli, write_ffv1

HUGE = "100000x100000"


@pytest.fixture(scope="module")
def fx(tmp_path_factory) -> Path:
    """The bad (and a few good) input files every row may name as ``{fx}/...``."""
    d = tmp_path_factory.mktemp("fx")
    (d / "latin1.toml").write_bytes(b"[run]\n# caf\xe9\nframes = 3\n")
    (d / "ten.toml").write_text('[run]\nframes = "ten"\n')
    (d / "threads.toml").write_text("[run]\nthreads = 0\n")
    (d / "seed.toml").write_text('[detector]\nname = "seed"\n[detector.seed]\nthreshold = "high"\n')
    (d / "latin1.csv").write_bytes(b"frame,x,y,radius\n0,1,2,3 # caf\xe9\n")
    (d / "truth.csv").write_text("frame,x,y,radius\n0,10,10,3\n1,20,20,3\n")
    (d / "empty.csv").write_bytes(b"")
    (d / "extra.csv").write_text("frame,x,y,radius\n0,10,10,3,99\n")
    (d / "empty.txt").write_bytes(b"")
    (d / "caldir").mkdir()
    image = draw_discs((64, 48), [(20, 20, 4)])
    (d / "mixed").mkdir()
    cv2.imwrite(str(d / "mixed" / "0.png"), image)
    cv2.imwrite(str(d / "mixed" / "1.png"), image.astype(np.uint16) * 256)
    write_ffv1(d / "full.mkv", [draw_discs((64, 48), [(10 + 2 * i, 20, 4)]) for i in range(30)])
    data = (d / "full.mkv").read_bytes()
    (d / "trunc.mkv").write_bytes(data[: len(data) * 2 // 3])
    (d / "garbage.mkv").write_bytes(b"\x1aE\xdf\xa3" + bytes(range(256)) * 8)
    return d


def folder_named(name: str):
    """A setup: a folder of one frame named like a source keyword, in the current folder."""
    def setup(cwd: Path) -> None:
        (cwd / name).mkdir()
        cv2.imwrite(str(cwd / name / "0.png"), draw_discs((64, 48), [(20, 20, 4)]))
    return setup


@dataclass
class Row:
    argv: list[str]
    code: int
    fragment: str
    absent: tuple[str, ...] = ()  # files (in the current folder) that must not be written
    left: tuple[str, ...] = ()  # files that must be there afterwards
    setup: object = None  # cwd -> None, run before the command
    fresh: bool = False  # in a subprocess, stdin not a terminal: the process's own stderr is checked
    extra: dict = field(default_factory=dict)


RUN = ["--frames", "1", "--output", "none", "--metrics", "m.csv"]

ROWS = {
    # huge sizes: one limit (check_frame_size) before anything is allocated
    "run huge size": Row(["run", "--size", HUGE, *RUN], 2, f"source sim: frames of {HUGE} px: too large", ("m.csv",)),
    "simulate huge size": Row(["simulate", "out", "--size", HUGE, "--frames", "1"], 2,
                              f"--size: frames of {HUGE} px: too large", ("out",)),
    "record huge size": Row(["record", "r.mkv", "--size", HUGE, "--frames", "1"], 2,
                            f"source sim: frames of {HUGE} px: too large", ("r.mkv",)),
    "twin huge size": Row(["twin", "--size", HUGE, "--frames", "1", "--plot", "t.png"], 2,
                          f"--size: camera frames of {HUGE} px: too large", ("t.png",)),
    "bench huge size": Row(["bench", "--sizes", HUGE, "--frames", "1", "--plot", "b.png"], 2,
                           f"--sizes: frames of {HUGE} px: too large", ("b.png",)),
    "calibrate huge size": Row(["calibrate", "c.json", "--twin", "--size", HUGE], 2,
                               f"--size: frames of {HUGE} px: too large", ("c.json",)),
    "calibrate huge projector": Row(["calibrate", "c.json", "--twin", "--projector-size", HUGE], 2,
                                    f"--projector-size {HUGE}: too large, allowed each side 1..16384", ("c.json",)),
    "bench threads 100000": Row(["bench", "--threads", "100000", "--frames", "1", "--sizes", "64x48"], 2,
                                "--threads 100000: allowed 1.."),
    "run threads 0": Row(["run", "--threads", "0", "--frames", "1", "--output", "none", "--detections", "d.csv"], 2,
                         "--threads 0: allowed 1..", ("d.csv",)),
    "run threads 100000": Row(["run", "--threads", "100000", "--frames", "1", "--output", "none"], 2,
                              "--threads 100000: allowed 1.."),
    "run config threads 0": Row(["run", "--config", "{fx}/threads.toml", "--frames", "1", "--output", "none"], 2,
                                "threads.toml: run.threads: got 0, allowed 1.."),
    # tiny sizes: one minimum for every command
    "record 1x1": Row(["record", "r.mkv", "--size", "1x1", "--frames", "1"], 2,
                      "source sim: frames of 1x1 px: too small, allowed at least 8x8", ("r.mkv",)),
    "simulate 1x1": Row(["simulate", "out", "--size", "1x1", "--frames", "1"], 2,
                        "--size: frames of 1x1 px: too small, allowed at least 8x8", ("out",)),
    "run 1x1": Row(["run", "--size", "1x1", *RUN], 2, "frames of 1x1 px: too small, allowed at least 8x8", ("m.csv",)),
    "twin 4x4": Row(["twin", "--size", "4x4", "--frames", "1"], 2, "frames of 4x4 px: too small"),
    "bench 4x4": Row(["bench", "--sizes", "4x4", "--frames", "1"], 2, "frames of 4x4 px: too small"),
    "calibrate 4x4": Row(["calibrate", "c.json", "--twin", "--size", "4x4"], 2, "frames of 4x4 px: too small",
                         ("c.json",)),
    # files that are not UTF-8, folders for files
    "run latin-1 toml": Row(["run", "--config", "{fx}/latin1.toml", *RUN], 2,
                            "latin1.toml: not UTF-8 text (byte 11); allowed a UTF-8 TOML config file", ("m.csv",)),
    "simulate latin-1 catalogue": Row(["simulate", "out", "--catalogue", "{fx}/latin1.toml"], 2,
                                      "latin1.toml: cannot read the scenario catalogue", ("out",)),
    "evaluate latin-1 detections": Row(["evaluate", "--truth", "{fx}/truth.csv", "--detections", "{fx}/latin1.csv",
                                        "--csv", "e.csv"], 2, "latin1.csv: not UTF-8 text", ("e.csv",)),
    "evaluate latin-1 truth": Row(["evaluate", "--truth", "{fx}/latin1.csv", "--detections", "{fx}/truth.csv"], 2,
                                  "latin1.csv: not UTF-8 text"),
    "run calibration folder": Row(["run", "--calibration", "{fx}/caldir", *RUN], 2,
                                  "caldir: is a folder, expected a calibration file", ("m.csv",)),
    "twin calibration folder": Row(["twin", "--calibration", "{fx}/caldir", "--frames", "1"], 2,
                                   "caldir: is a folder, expected a calibration file"),
    "run mapping empty (numpy warning)": Row(["run", "--mapping", "{fx}/empty.txt", *RUN], 2,
                                             "empty.txt: got a 0x1 matrix, expected 3x3", ("m.csv",), fresh=True),
    # calibrate's numbers and its terminal
    "calibrate hfov 0": Row(["calibrate", "c.json", "--twin", "--hfov-deg", "0"], 2,
                            "--hfov-deg: got 0.0, allowed 0 < hfov < 180 degrees", ("c.json",)),
    "calibrate hfov 180": Row(["calibrate", "c.json", "--twin", "--hfov-deg", "180"], 2,
                              "--hfov-deg: got 180.0, allowed 0 < hfov < 180 degrees", ("c.json",)),
    "calibrate baseline nan": Row(["calibrate", "c.json", "--twin", "--baseline-m", "nan"], 2,
                                  "--baseline-m: got nan, allowed a number >= 0", ("c.json",)),
    "calibrate depths inf": Row(["calibrate", "c.json", "--twin", "--depths", "0.5,inf"], 2,
                                "--depths '0.5,inf': allowed distinct positive distances", ("c.json",)),
    "calibrate without a terminal": Row(["calibrate", "c.json", "--source", "sim", "--output", "none"], 2,
                                        "needs an interactive terminal on stdin", ("c.json",), fresh=True),
    # silently accepted before
    "run mixed 8/16-bit folder": Row(["run", "{fx}/mixed", *RUN], 2,
                                     "mixed/1.png: a 16-bit image where the frames before it are 8-bit", ("m.csv",)),
    "run empty source": Row(["run", "", *RUN], 2, "source.spec: got '', allowed sim, camera", ("m.csv",)),
    "record empty source": Row(["record", "r.mkv", "--source", "", "--frames", "1"], 2, "source '': empty",
                               ("r.mkv",)),
    "run sim with a folder sim": Row(["run", "sim", *RUN], 2, "source 'sim': ambiguous, a folder named sim is in "
                                     "this folder; write ./sim for the folder or sim: for the simulator",
                                     ("m.csv",), ("sim",), setup=folder_named("sim")),
    "run sim: with a folder sim": Row(["run", "sim:", "--size", "64x48", *RUN], 0, "source sim: (64x48)",
                                      left=("m.csv", "sim"), setup=folder_named("sim")),
    "run ./sim with a folder sim": Row(["run", "./sim", *RUN], 0, "source ./sim (64x48)", left=("m.csv",),
                                       setup=folder_named("sim")),
    "run camera with a folder camera": Row(["run", "camera", *RUN], 2, "source 'camera': ambiguous, a folder named "
                                           "camera", ("m.csv",), setup=folder_named("camera")),
    "run cpus 99": Row(["run", "--cpus", "99", *RUN], 2, "run.cpus: got '99', allowed CPU numbers 0..", ("m.csv",)),
    "run margin 1e12": Row(["run", "--margin", "1e12", *RUN], 2, "pattern.margin: got 1e+12, allowed 0..1280 px",
                           ("m.csv",)),
    "record camera gain 100": Row(["record", "r.mkv", "--camera-gain", "100", "--frames", "1"], 2,
                                  "camera gain: goes with a fixed exposure", ("r.mkv",)),
    "record camera gain 100 exposed": Row(["record", "r.mkv", "--camera-exposure-ms", "4", "--camera-gain", "100",
                                           "--frames", "1"], 2, "camera gain 100.0: allowed 1", ("r.mkv",)),
    "config value hidden by a flag": Row(["run", "--config", "{fx}/ten.toml", *RUN], 2,
                                         "ten.toml: run.frames: got 'ten', allowed an integer", ("m.csv",)),
    "config parameter hidden by --param": Row(["run", "--config", "{fx}/seed.toml", "-p", "threshold=100", *RUN], 2,
                                              "seed.toml: detector.seed.threshold: got 'high'", ("m.csv",)),
    "evaluate zero-byte detections": Row(["evaluate", "--truth", "{fx}/truth.csv", "--detections", "{fx}/empty.csv"],
                                         2, "empty.csv: empty; expected the header frame,x,y,radius"),
    "evaluate detections with extra fields": Row(["evaluate", "--truth", "{fx}/truth.csv", "--detections",
                                                  "{fx}/extra.csv"], 2, "extra.csv row 2: has 5 fields, the header has 4"),
    "evaluate truth with extra fields": Row(["evaluate", "--truth", "{fx}/extra.csv", "--detections",
                                             "{fx}/truth.csv"], 2, "extra.csv row 2: has 5 fields, the header has 4"),
    "run truncated video": Row(["run", "{fx}/trunc.mkv", "--output", "none", "--metrics", "m.csv"], 3,
                               "of the 30 frames its container declares (cut short or damaged)", left=("m.csv",),
                               fresh=True),
    "run whole video": Row(["run", "{fx}/full.mkv", "--output", "none", "--metrics", "m.csv"], 0,
                           "frames: 30 (source ended)", left=("m.csv",)),
    # library log lines before a one-line error
    "run garbage video (FFmpeg log)": Row(["run", "{fx}/garbage.mkv", *RUN], 2,
                                          "garbage.mkv: cannot be opened as a video", ("m.csv",), fresh=True),
    "simulate garbage background (FFmpeg log)": Row(["simulate", "out", "--preset", "textured", "--frames", "1",
                                                     "--background", "{fx}/garbage.mkv"], 2,
                                                    "garbage.mkv: not a readable image or video", ("out",), fresh=True),
}


@contextmanager
def memory_capped(extra: int = 8 << 30):
    """The process's address space capped at its present size plus ``extra`` bytes while a row runs
    in-process: a size that slipped past its check fails with MemoryError, not the machine's OOM killer."""
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    with open("/proc/self/statm") as handle:
        used = int(handle.read().split()[0]) * resource.getpagesize()
    cap = used + extra if hard == resource.RLIM_INFINITY else min(used + extra, hard)
    resource.setrlimit(resource.RLIMIT_AS, (cap, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


@pytest.mark.parametrize("name", list(ROWS))
def test_bad_input(name, fx, tmp_path, monkeypatch):
    row = ROWS[name]
    argv = [a.replace("{fx}", str(fx)) for a in row.argv]
    if row.setup is not None:
        row.setup(tmp_path)
    if row.fresh:
        done = subprocess.run([sys.executable, "-m", "antiscatter", *argv], cwd=tmp_path, stdin=subprocess.DEVNULL,
                              capture_output=True, text=True, timeout=60,
                              preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_AS, (12 << 30, 12 << 30)))
        code, out, err = done.returncode, done.stdout, done.stderr
    else:
        monkeypatch.chdir(tmp_path)
        with memory_capped():
            result = run_cli(*argv)
        code, out, err = result.code, result.out, result.err
    assert code == row.code, err
    assert row.fragment in out + err
    assert "Traceback" not in err
    if row.code == 2:  # one line, naming what is wrong; nothing before it (library logs, warnings)
        assert err.count("\n") == 1 and err.startswith(f"antiscatter {argv[0]}: error: "), err
    for path in row.absent:
        assert not (tmp_path / path).exists(), path
    for path in row.left:
        assert (tmp_path / path).exists(), path


def test_a_cut_short_video_warns_in_one_line_and_keeps_every_frame_read(fx, tmp_path):
    done = subprocess.run([sys.executable, "-m", "antiscatter", "run", str(fx / "trunc.mkv"), "--output", "none",
                           "--metrics", "m.csv"], cwd=tmp_path, capture_output=True, text=True, timeout=60)
    assert done.returncode == 3
    lines = done.stderr.splitlines()
    assert len(lines) == 2 and lines[1].startswith(f"warning: {fx / 'trunc.mkv'}: ended after ")  # no FFmpeg line
    read = int(lines[1].split("ended after ")[1].split()[0])
    assert 0 < read < 30
    assert len((tmp_path / "m.csv").read_text().splitlines()) == read + 1  # the header and every frame read
