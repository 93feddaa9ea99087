"""Every writer checks its path before any work, never overwrites a recording, and leaves whole files on signals.

A table of cases: the command, the exit code, a fragment of its one-line message, and the files
it must leave (absent, untouched, or valid: every CSV parses with the header's field count, every
MKV decodes to its last frame).
"""

import os
import signal
import subprocess
import sys
import time

import pytest

from conftest import csv_rows, mkv_frames

from antiscatter.errors import UsageError, check_output_folder, check_output_path

OLD = b"old,content\r\n1,2\r\n"


def check_files(tmp_path, files):
    """``files``: path (under tmp_path) -> "absent", "old" (left as it was), "csv", or ("mkv", frames)."""
    for name, want in files.items():
        path = tmp_path / name
        if want == "absent":
            assert not path.exists(), f"{name} was created"
        elif want == "old":
            assert path.read_bytes() == OLD, f"{name} was touched"
        elif want == "csv":
            csv_rows(path)
        elif want[0] == "mkv":
            assert mkv_frames(path) == want[1]
        elif want[0] == "pngs":
            assert len(list(path.glob("*.png"))) == want[1]


@pytest.fixture
def readonly_dir(tmp_path):
    """A folder no file can be made in: a read-only tmpfs for root (permissions do not stop root),
    else a folder without write permission."""
    folder = tmp_path / "ro"
    folder.mkdir()
    if os.geteuid() != 0:
        folder.chmod(0o500)
        yield folder
        folder.chmod(0o700)
        return
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k,ro", "tmpfs", str(folder)],
                             capture_output=True, text=True)
    if mounted.returncode:
        pytest.skip(f"root, and mounting a read-only tmpfs is not permitted here: {mounted.stderr.strip()}")
    yield folder
    subprocess.run(["umount", str(folder)], capture_output=True)


def _record_existing(tmp_path):
    (tmp_path / "old.mkv").write_bytes(OLD)


CASES = [
    # (id, arguments, exit code, message fragment, files left)
    ("run metrics in /proc", ["run", "--frames", "2", "--size", "160x120", "--output", "none",
                              "--metrics", "/proc/antiscatter-x.csv"], 2, "cannot write in the folder /proc", {}),
    ("run detections under a file", ["run", "--frames", "2", "--size", "160x120", "--output", "none",
                                     "--detections", "{tmp}/afile/d.csv", "--metrics", "{tmp}/m.csv"],
     2, "the folder {tmp}/afile is a file, not a folder", {"m.csv": "old"}),
    ("run metrics /dev/full", ["run", "--frames", "2", "--size", "160x120", "--output", "none",
                               "--metrics", "/dev/full"], 2, "/dev/full: not a regular file", {}),
    ("run detections read-only", ["run", "--frames", "2", "--size", "160x120", "--output", "none",
                                  "--detections", "{ro}/d.csv", "--metrics", "{tmp}/m.csv"],
     2, "cannot write in the folder {ro}", {"m.csv": "old"}),
    ("run png folder in /proc", ["run", "--frames", "2", "--size", "160x120", "--output", "files:/proc/antiscatter-x"],
     2, "cannot write in the folder /proc", {}),
    ("run video in /proc", ["run", "--frames", "2", "--size", "160x120", "--output", "files:/proc/x.mkv"],
     2, "cannot write in the folder /proc", {}),
    ("run video read-only", ["run", "--frames", "2", "--size", "160x120", "--output", "files:{ro}/p.mkv"],
     2, "cannot write in the folder {ro}", {}),
    ("run png tree not made", ["run", "--frames", "2", "--size", "160x120", "--output", "files:{tmp}/no/such/p",
                               "--metrics", "{tmp}/m.csv"],
     2, "the folder {tmp}/no/such does not exist", {"no": "absent", "m.csv": "old"}),
    ("run png folder one level made", ["run", "--frames", "2", "--size", "160x120", "--output", "files:{tmp}/pat",
                                       "--metrics", "{tmp}/m.csv"], 0, "", {"pat": ("pngs", 2), "m.csv": "csv"}),
    ("simulate in /proc", ["simulate", "/proc/antiscatter-x", "--frames", "1", "--size", "160x120"],
     2, "OUT /proc/antiscatter-x: cannot write in the folder /proc", {}),
    ("simulate read-only", ["simulate", "{ro}/out", "--frames", "1", "--size", "160x120"],
     2, "cannot write in the folder {ro}", {}),
    ("simulate tree not made", ["simulate", "{tmp}/no/such/out", "--frames", "1", "--size", "160x120"],
     2, "the folder {tmp}/no/such does not exist", {"no": "absent"}),
    ("evaluate csv in /proc", ["evaluate", "--truth", "{tmp}/t.csv", "--detections", "{tmp}/t.csv",
                               "--csv", "/proc/x.csv"], 2, "--csv /proc/x.csv: cannot write in the folder /proc", {}),
    ("evaluate plot in /proc", ["evaluate", "--truth", "{tmp}/t.csv", "--detections", "{tmp}/t.csv",
                                "--plot", "/proc/x.png"], 2, "--plot /proc/x.png: cannot write", {}),
    ("evaluate plot unknown format", ["evaluate", "--truth", "{tmp}/t.csv", "--detections", "{tmp}/t.csv",
                                      "--plot", "{tmp}/p.xyz"], 2, "p.xyz: allowed a file ending in", {"p.xyz": "absent"}),
    ("bench plot in /proc", ["bench", "--frames", "1", "--sizes", "64x48", "--plot", "/proc/x.png"],
     2, "--plot /proc/x.png: cannot write", {}),
    ("record in /proc", ["record", "/proc/x.mkv", "--frames", "2", "--size", "160x120"],
     2, "output /proc/x.mkv: cannot write in the folder /proc", {}),
    ("record read-only", ["record", "{ro}/r.mkv", "--frames", "2", "--size", "160x120"],
     2, "cannot write in the folder {ro}", {}),
    ("record over a recording", ["record", "{tmp}/old.mkv", "--frames", "2", "--size", "160x120"],
     2, "old.mkv: already exists; use --overwrite to replace it", {"old.mkv": "old"}),
    ("record over a recording, overflow stop", ["record", "{tmp}/old.mkv", "--frames", "2", "--size", "160x120",
                                               "--overflow", "stop"], 2, "already exists", {"old.mkv": "old"}),
    ("record --overwrite", ["record", "{tmp}/old.mkv", "--frames", "2", "--size", "160x120", "--overwrite"],
     0, "", {"old.mkv": ("mkv", 2)}),
    ("record buffer smaller than a frame", ["record", "{tmp}/r.mkv", "--frames", "3", "--size", "160x120",
                                            "--overflow", "stop", "--buffer-mb", "0.01"],
     2, "--buffer-mb 0.01: smaller than one frame", {"r.mkv": "absent"}),
]


@pytest.mark.parametrize("name, args, code, message, files", CASES, ids=[c[0] for c in CASES])
def test_outputs_checked_before_any_work(tmp_path, cli, readonly_dir, name, args, code, message, files):
    (tmp_path / "afile").write_text("x")
    (tmp_path / "m.csv").write_bytes(OLD)
    (tmp_path / "t.csv").write_text("frame,x,y,radius\n0,10,10,3\n")
    _record_existing(tmp_path)
    fill = {"tmp": tmp_path, "ro": readonly_dir}
    result = cli(*[a.format(**fill) for a in args])
    assert result.code == code, result.err
    if code:
        lines = result.err.strip().splitlines()
        assert len(lines) == 1 and "Traceback" not in result.err, result.err
        assert message.format(**fill) in lines[0]
    check_files(tmp_path, files)


@pytest.mark.parametrize("command, work", [
    (["calibrate", "/proc/x.json", "--twin"], "antiscatter.calibration.calibrate_planes"),
    (["twin", "--frames", "2", "--size", "200x150", "--plot", "/proc/x.png"], "antiscatter.twin.simulate_loop"),
    (["twin", "--frames", "2", "--size", "200x150", "--plot", "{tmp}/t.xyz"], "antiscatter.twin.simulate_loop"),
])
def test_long_commands_refuse_an_unwritable_output_before_their_work(tmp_path, cli, monkeypatch, command, work):
    def never(*args, **kwargs):
        raise AssertionError("the work ran before the output was checked")

    monkeypatch.setattr(work, never)
    result = cli(*[a.format(tmp=tmp_path) for a in command])
    assert result.code == 2 and len(result.err.strip().splitlines()) == 1, result.err


def test_check_output_path_refuses_each_kind_of_bad_path(tmp_path):
    (tmp_path / "f").write_text("x")
    with pytest.raises(UsageError, match=r"^--x .*/f/a\.csv: the folder .*/f is a file, not a folder$"):
        check_output_path(tmp_path / "f" / "a.csv", "--x")
    with pytest.raises(UsageError, match=r"already exists; use --overwrite to replace it$"):
        check_output_path(tmp_path / "f", "--x", overwrite=False)
    with pytest.raises(UsageError, match=r"^--x .*: is a folder, expected a file path$"):
        check_output_path(tmp_path, "--x")
    with pytest.raises(UsageError, match=r"allowed a file ending in \.png, \.pdf$"):
        check_output_path(tmp_path / "p.gif", "--x", suffixes=(".png", ".pdf"))
    assert check_output_path(tmp_path / "f", "--x") == tmp_path / "f"  # overwrite allowed by default
    assert not list(tmp_path.glob(".antiscatter-probe-*"))  # the probe leaves nothing
    with pytest.raises(UsageError, match="exists and is not a folder"):
        check_output_folder(tmp_path / "f", "OUT")
    assert check_output_folder(tmp_path / "new", "OUT") == tmp_path / "new"
    assert not (tmp_path / "new").exists()  # checked, not made


def _python(*args, cwd):
    return subprocess.Popen([sys.executable, "-m", "antiscatter", *args], cwd=cwd, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def test_run_on_sigterm_at_any_moment_leaves_whole_files_or_none_touched(tmp_path):
    """SIGTERM from start-up on: exit 143 with whole files, or (before Python can have a handler)
    killed with nothing touched; never a truncated file."""
    runs = []
    for delay in (0.2, 0.35, 0.5, 0.7, None):  # None: once the run has begun its files
        folder = tmp_path / f"at{delay}"
        folder.mkdir()
        (folder / "m.csv").write_bytes(OLD)
        runs.append((delay, folder, _python("run", "--size", "160x120", "--output", "none", "--metrics", "m.csv",
                                            "--detections", "d.csv", "--output", "files:p.mkv", cwd=folder)))
    started = time.monotonic()
    for delay, folder, proc in runs:
        if delay is None:
            assert _wait_for(lambda: (folder / "m.csv").read_bytes() != OLD)
        else:
            time.sleep(max(0.0, started + delay - time.monotonic()))
        proc.send_signal(signal.SIGTERM)
    for delay, folder, proc in runs:
        out, err = proc.communicate(timeout=30)
        assert "Traceback" not in err, err
        metrics = (folder / "m.csv").read_bytes()
        if proc.returncode == -signal.SIGTERM:  # before the interpreter ran our code: nothing touched
            assert metrics == OLD and not (folder / "d.csv").exists() and not (folder / "p.mkv").exists()
            continue
        assert proc.returncode == 143, (delay, err)
        if metrics != OLD:  # the run began: whole files
            assert csv_rows(folder / "m.csv")[0][0] == "Capture Duration (s)"
            assert csv_rows(folder / "d.csv")[0][:3] == ["frame", "time", "x"]
            if (folder / "p.mkv").exists():
                mkv_frames(folder / "p.mkv")
    assert (runs[-1][1] / "m.csv").read_bytes() != OLD  # the last one ran


def test_run_stops_on_a_signal_while_its_source_opens(tmp_path):
    """The stop handler is the run's first step: a signal while the source opens stops the run
    (exit code 130) with whole files."""
    import numpy as np

    from antiscatter.config import load_config
    from antiscatter.runtime import run
    from antiscatter.sources.base import Frame, FrameSource

    class Slow(FrameSource):
        size = (64, 48)

        def __enter__(self):
            os.kill(os.getpid(), signal.SIGINT)  # as Ctrl-C while a camera starts
            return self

        def read(self):
            return Frame(np.zeros((48, 64, 3), np.uint8), 0, time.monotonic_ns())

    config = load_config(overrides={"output": {"outputs": ("none",)},
                                    "run": {"metrics": str(tmp_path / "m.csv"), "frames": 5}})
    summary = run(config, source=Slow(), out=open(os.devnull, "w"), log=open(os.devnull, "w"))
    assert summary.stop_reason == "stopped by SIGINT" and summary.frames == 0
    assert len(csv_rows(tmp_path / "m.csv")) == 1  # the header, whole


def _wait_for(predicate, timeout=20.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.02)
    return False


def test_simulate_on_sigterm_exits_cleanly_and_removes_its_staging(tmp_path):
    out = tmp_path / "out"
    proc = _python("simulate", str(out), "--frames", "5000", "--size", "160x120", cwd=tmp_path)
    assert _wait_for(lambda: any(out.glob(".partial-*/0.png")))
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 143 and err.strip() == "antiscatter simulate: stopped by SIGTERM"
    assert list(out.iterdir()) == []  # no staging, nothing that looks complete


def test_simulate_removes_stale_staging_but_not_a_running_ones(tmp_path):
    from antiscatter.simulate.export import SimulationRequest, simulate

    out = tmp_path / "out"
    out.mkdir()
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    folders = {name: out / f".partial-{name}" for name in ("killed", "running", "old", "fresh")}
    for folder in folders.values():
        folder.mkdir()
        (folder / "0.png").write_bytes(b"x")
    (folders["killed"] / "pid").write_text(str(dead.pid))
    (folders["running"] / "pid").write_text(str(os.getpid()))
    hours_ago = time.time() - 2 * 3600
    os.utime(folders["old"], (hours_ago, hours_ago))
    simulate(SimulationRequest(out=out, frames=1, size=(64, 48)))
    assert {p.name for p in out.glob(".partial-*")} == {".partial-running", ".partial-fresh"}
    assert (out / "0.png").exists() and not (out / "pid").exists()


@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")
def test_a_sigterm_whose_exception_python_swallowed_still_stops_the_run(monkeypatch):
    """SIGTERM handled inside a finaliser the garbage collector ran: Python prints the Terminated
    as ignored and goes on; the run's stop flag, installed later, must still find it."""
    import threading

    from antiscatter import cli, runtime

    seen = threading.Event()
    monkeypatch.setattr(cli, "SIGTERM_RECEIVED", seen)
    monkeypatch.setattr(runtime, "SIGTERM_RECEIVED", seen)

    class Finalised:
        def __del__(self):
            cli._terminate(signal.SIGTERM, None)

    Finalised()  # the exception is lost ("Exception ignored in ..."): the test goes on
    assert seen.is_set()
    with runtime.StopFlag() as stop:
        assert stop and stop.reason == "SIGTERM"
    monkeypatch.setattr(runtime, "SIGTERM_RECEIVED", threading.Event())
    with runtime.StopFlag() as stop:  # a process never asked to stop
        assert not stop
