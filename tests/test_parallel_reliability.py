"""The worker process dies with its parent, its own death ends a run in one line, and a failing
source keeps the frames already read -- in ``processes`` and ``processes-pickle`` alike."""

import csv
import io
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from antiscatter.config import load_config
from antiscatter.errors import RunError, UsageError
from antiscatter.parallel import RING_PREFIX, DetectorProcess, sweep_stale_rings
from antiscatter.runtime import StopFlag, run
from antiscatter.sources.simulated import SimulatorSource

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc and /dev/shm")

MODES = ["processes", "processes-pickle"]
#: seconds within which a dead parent's worker, tracker and shared memory must be gone
GONE_WITHIN_S = 2.0


def _children(pid: int) -> list[int]:
    """Pids of the live (not zombie) processes whose parent is ``pid``, from /proc."""
    found = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            state_ppid = _state_ppid(int(entry))
            if state_ppid and state_ppid[0] != "Z" and state_ppid[1] == pid:
                found.append(int(entry))
    return found


def _state_ppid(pid: int) -> tuple[str, int] | None:
    """(state letter, parent pid) of ``pid``, None once it is gone."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = stat[stat.rindex(")") + 2:].split()
    return fields[0], int(fields[1])


def _alive(pid: int) -> bool:
    state = _state_ppid(pid)
    return state is not None and state[0] not in "ZX"


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def _segments(pid: int) -> set[str]:
    """The shared-memory segments (``psm_*``, not the queues' semaphores) process ``pid`` has mapped."""
    try:
        maps = Path(f"/proc/{pid}/maps").read_text()
    except OSError:
        return set()
    return {line.split("/dev/shm/", 1)[1].split()[0] for line in maps.splitlines() if "/dev/shm/psm_" in line}


def _start_run(tmp_path: Path, mode: str, *, group: bool = False) -> tuple[subprocess.Popen, int]:
    """An endless ``run sim`` in ``mode`` writing m.csv and d.csv (its stdout and stderr to out.txt
    and err.txt: a surviving worker would hold pipes open); returns it and its worker's pid once
    frames have come back from the worker.  ``group``: in a process group of its own."""
    with (tmp_path / "out.txt").open("w") as out, (tmp_path / "err.txt").open("w") as err:
        proc = subprocess.Popen(
            [sys.executable, "-m", "antiscatter", "run", "sim", "--size", "320x240", "-o", "none", "--fps", "50",
             "--mode", mode, "--metrics", str(tmp_path / "m.csv"), "--detections", str(tmp_path / "d.csv")],
            stdout=out, stderr=err, start_new_session=group)
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline and proc.poll() is None:
        metrics = tmp_path / "m.csv"
        workers = [p for p in _children(proc.pid) if "antiscatter" in _cmdline(p)]
        if workers and metrics.exists() and metrics.read_text().count("\n") >= 4:
            return proc, workers[0]
        time.sleep(0.05)
    _kill_all(proc.pid, *_children(proc.pid))
    pytest.fail(f"the run did not start: exit {proc.poll()}\n{(tmp_path / 'err.txt').read_text()}")


def _kill_all(*pids: int, segments: set[str] = frozenset()) -> None:
    """Clean up after a failed test: SIGKILL what lives of ``pids``, unlink what is left of ``segments``."""
    for pid in pids:
        if _alive(pid):
            os.kill(pid, signal.SIGKILL)
    for name in segments:
        if os.path.exists(f"/dev/shm/{name}"):
            os.unlink(f"/dev/shm/{name}")


def _wait_gone(pids: list[int], segments: set[str]) -> tuple[list[int], set[str]]:
    """What is still there of ``pids`` and ``segments`` after up to GONE_WITHIN_S seconds."""
    deadline = time.monotonic() + GONE_WITHIN_S
    while True:
        left = [p for p in pids if _alive(p)]
        shm = {s for s in segments if os.path.exists(f"/dev/shm/{s}")}
        if not left and not shm or time.monotonic() > deadline:
            return left, shm
        time.sleep(0.02)


def _complete_csv(path: Path) -> list[list[str]]:
    """The rows of a CSV, asserted whole: it ends in a newline and every row has the header's fields."""
    text = path.read_text()
    assert text.endswith("\n")
    rows = list(csv.reader(io.StringIO(text)))
    assert all(len(row) == len(rows[0]) for row in rows)
    return rows


@pytest.mark.parametrize("mode", MODES)
def test_sigkill_of_the_parent_leaves_no_process_and_no_shared_memory(tmp_path, mode):
    proc, worker = _start_run(tmp_path, mode)
    children = _children(proc.pid)  # the worker and, with shared memory, the resource tracker
    segments = _segments(proc.pid)
    try:
        assert worker in children
        assert bool(segments) == (mode == "processes")
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
        left, shm = _wait_gone(children, segments)
        assert [f"{p}: {_cmdline(p)}" for p in left] == []
        assert shm == set()
    finally:
        _kill_all(proc.pid, *children, segments=segments)


@pytest.mark.parametrize("mode", MODES)
def test_a_killed_worker_ends_the_run_in_one_line_with_complete_files(tmp_path, mode):
    proc, worker = _start_run(tmp_path, mode)
    segments = _segments(proc.pid)
    os.kill(worker, signal.SIGKILL)
    try:
        proc.wait(timeout=10)
    finally:
        _kill_all(proc.pid, *_children(proc.pid))
    err = (tmp_path / "err.txt").read_text()
    assert proc.returncode == 1
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert [line for line in lines if "error" in line] == [lines[-1]]
    match = re.fullmatch(r"antiscatter run: error: the detector process died \(signal 9, SIGKILL\); "
                         r"(\d+) frames processed; files are complete", lines[-1])
    assert match, lines[-1]
    metrics = _complete_csv(tmp_path / "m.csv")
    assert len(metrics) - 1 == int(match.group(1)) >= 3
    assert [int(row[metrics[0].index("Frame")]) for row in metrics[1:]] == list(range(len(metrics) - 1))
    detections = _complete_csv(tmp_path / "d.csv")
    assert all(int(row[0]) < len(metrics) - 1 for row in detections[1:])
    assert not any(os.path.exists(f"/dev/shm/{name}") for name in segments)


@pytest.mark.parametrize("mode", MODES)
def test_sigterm_to_the_whole_group_is_a_clean_stop_not_a_dead_worker(tmp_path, mode):
    # as a service manager stops a run: the worker takes SIGTERM too and ends at once
    proc, worker = _start_run(tmp_path, mode, group=True)
    try:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=10)
    finally:
        _kill_all(proc.pid, worker)
    err = (tmp_path / "err.txt").read_text()
    assert proc.returncode == 143 and "error" not in err and "Traceback" not in err
    assert "stopped by SIGTERM" in (tmp_path / "out.txt").read_text()
    _complete_csv(tmp_path / "m.csv")


def _folder_with_a_corrupt_frame(folder: Path, frames: int = 6, corrupt: int = 3) -> Path:
    """``frames`` PNGs of bright discs on grey, frame ``corrupt`` not an image."""
    folder.mkdir()
    rng = np.random.default_rng(7)
    for i in range(frames):
        image = np.full((240, 320, 3), 40, np.uint8)
        for x, y in rng.integers(20, 220, (10, 2)):
            cv2.circle(image, (int(x) + 40, int(y)), 4, (250, 250, 250), -1)
        cv2.imwrite(str(folder / f"{i}.png"), image)
    (folder / f"{corrupt}.png").write_bytes(b"not a png")
    return folder


def _failing_run(tmp_path: Path, mode: str, source: object = None, spec: str = "sim") -> tuple[str, int, str]:
    """(detections CSV text, metrics rows, the error raised) of a run whose source fails."""
    detections, metrics = tmp_path / f"d-{mode}.csv", tmp_path / f"m-{mode}.csv"
    config = load_config(overrides={"source": {"spec": spec}, "output": {"outputs": ("none",)},
                                    "run": {"mode": mode, "detections": str(detections), "metrics": str(metrics)}})
    with pytest.raises((UsageError, RuntimeError)) as raised:
        run(config, log=io.StringIO(), out=io.StringIO(), source=source)
    rows = _complete_csv(metrics)
    assert [int(row[rows[0].index("Frame")]) for row in rows[1:]] == list(range(len(rows) - 1))
    return detections.read_text(), len(rows) - 1, str(raised.value)


@pytest.mark.parametrize("mode", MODES)
def test_a_folder_failing_mid_run_keeps_the_rows_single_mode_keeps(tmp_path, mode):
    folder = str(_folder_with_a_corrupt_frame(tmp_path / "frames"))
    single = _failing_run(tmp_path, "single", spec=folder)
    got = _failing_run(tmp_path, mode, spec=folder)
    assert single[1] == 3 and single[2].endswith("3.png: not a readable image")
    assert got == single
    assert single[0].count("\n") > 1  # particles found in the frames kept


class FailingSource(SimulatorSource):
    """The simulator at 320x240 whose ``read`` raises RuntimeError (a device failure) at frame ``fail_at``."""

    name = "failing"

    def __init__(self, fail_at: int) -> None:
        super().__init__(size=(320, 240))
        self.fail_at = fail_at

    def read(self):
        if self._count == self.fail_at:
            raise RuntimeError(f"camera: frame {self._count} timed out")
        return super().read()


@pytest.mark.parametrize("mode", MODES)
def test_a_device_failing_mid_run_keeps_the_rows_single_mode_keeps(tmp_path, mode):
    single = _failing_run(tmp_path, "single", source=FailingSource(5))
    got = _failing_run(tmp_path, mode, source=FailingSource(5))
    assert single[1] == 5 and single[2] == "camera: frame 5 timed out"
    assert got == single


def _sig_bits(pid: int, field: str) -> int:
    line = next(x for x in Path(f"/proc/{pid}/status").read_text().splitlines() if x.startswith(field + ":"))
    return int(line.split()[1], 16)


def test_the_worker_takes_sigterm_by_default_and_leaves_ctrl_c_to_the_main_process():
    image = np.zeros((64, 64), np.uint8)
    with StopFlag():  # the run's SIGTERM handler, which a forked worker inherits
        worker = DetectorProcess("contrast", None, image)
    try:
        worker.submit(0, image)
        assert worker.receive(timeout=10) is not None  # past its set-up
        pid = worker.process.pid
        assert not _sig_bits(pid, "SigCgt") & 1 << (signal.SIGTERM - 1)
        assert _sig_bits(pid, "SigIgn") & 1 << (signal.SIGINT - 1)
        os.kill(pid, signal.SIGTERM)
        deadline = time.monotonic() + 5
        with pytest.raises(RunError, match=re.escape("the detector process died (signal 15, SIGTERM)")):
            while time.monotonic() < deadline:
                worker.receive(timeout=0.05)
    finally:
        worker.close()


def test_a_worker_started_from_another_thread_outlives_it_and_still_dies_with_its_process():
    # the parent-death signal follows the forking thread, so here the worker's poll must notice
    script = (
        "import signal, threading, numpy as np\n"
        "from antiscatter.parallel import DetectorProcess\n"
        "image, made = np.zeros((64, 64), np.uint8), []\n"
        "t = threading.Thread(target=lambda: made.append(DetectorProcess('contrast', None, image)))\n"
        "t.start(); t.join()\n"
        "w = made[0]; w.submit(0, image)\n"
        "assert w.receive(timeout=10) is not None\n"
        "print(w.process.pid, w.ring.name, flush=True)\n"
        "signal.pause()\n")
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    pid = ring = None
    try:
        pid, ring = proc.stdout.readline().split()
        pid = int(pid)
        assert _alive(pid)
        proc.kill()
        proc.wait(timeout=10)
        left, shm = _wait_gone([pid], {ring})
        assert left == [] and shm == set()
    finally:
        proc.kill()
        if pid and _alive(pid):
            os.kill(pid, signal.SIGKILL)
        if ring and os.path.exists(f"/dev/shm/{ring}"):
            os.unlink(f"/dev/shm/{ring}")


def test_a_new_ring_removes_segments_of_dead_runs_only(tmp_path):
    dead = subprocess.Popen(["true"])
    dead.wait()
    stale = Path(f"/dev/shm/{RING_PREFIX}{dead.pid}_0badc0de")
    live = Path(f"/dev/shm/{RING_PREFIX}{os.getpid()}_0badc0de")
    other = Path(f"/dev/shm/psm_{os.getpid()}x_test")  # not a ring's name: left alone
    try:
        for path in (stale, live, other):
            path.write_bytes(b"\0" * 64)
        removed = sweep_stale_rings()
        assert stale.name in removed and not stale.exists()
        assert live.exists() and other.exists()
    finally:
        for path in (stale, live, other):
            path.unlink(missing_ok=True)
