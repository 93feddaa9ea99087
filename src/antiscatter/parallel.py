"""The report's multi-process design rebuilt: frames through shared memory, small messages pickled.

``run --mode processes`` captures, renders and shows in the main process and
detects in a worker process.  Frames travel through a ring of shared-memory
slots (``multiprocessing.shared_memory``): the main process copies each frame
once into a free slot and sends the worker only the slot number; the worker
reads the frame in place and sends back the particles (a few kilobytes).
``transport="pickle"`` instead sends every frame through the queue, as the
report did, to measure what that costs.  Up to ``slots - 1`` frames are in
flight, so capture overlaps detection.  The worker ignores Ctrl-C (the main
process stops it) but not SIGTERM; a crash in it stops the run with its error,
its death with a one-line :class:`~antiscatter.errors.RunError`.  It dies with
the main process: a parent-death signal (Linux), else it sees its parent gone
within ``PARENT_POLL_S``.  The shared memory is unlinked however the run ends:
by the main process, else by the resource tracker once both processes are gone,
else by the next run (segments are named after the pid that made them).
"""

from __future__ import annotations

import ctypes
import multiprocessing as mp
import os
import queue
import re
import secrets
import signal
import sys
import threading
from multiprocessing import shared_memory
from typing import Any

import numpy as np

from .detections import Detections
from .errors import RunError

__all__ = ["FrameRing", "DetectorProcess", "sweep_stale_rings", "RING_PREFIX", "PARENT_POLL_S"]

#: name prefix of a ring's shared-memory segment, followed by the creating pid: ``psm_as<pid>_<hex>``
RING_PREFIX = "psm_as"
#: seconds between the worker's checks that its parent still lives (where no parent-death signal is set)
PARENT_POLL_S = 0.2
_RING_NAME = re.compile(rf"^{RING_PREFIX}(\d+)_[0-9a-f]+$")
_PR_SET_PDEATHSIG = 1  # prctl option (linux/prctl.h)


def _pid_alive(pid: int) -> bool:
    """Whether a process ``pid`` exists (one of another user's counts)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def sweep_stale_rings(folder: str = "/dev/shm") -> list[str]:
    """Unlink ring segments whose creating process is gone (a run killed with its resource tracker).

    Returns the names removed; nothing where ``folder`` (POSIX shared memory's) does not exist.
    """
    removed = []
    try:
        names = os.listdir(folder)
    except OSError:
        return removed
    for name in names:
        match = _RING_NAME.match(name)
        if match and not _pid_alive(int(match.group(1))):
            try:
                os.unlink(os.path.join(folder, name))
            except OSError:
                continue
            removed.append(name)
    return removed


class FrameRing:
    """``slots`` frames of one shape and dtype in one shared-memory block."""

    def __init__(self, shape: tuple[int, ...], dtype: Any = np.uint8, slots: int = 4, *,
                 name: str | None = None) -> None:
        self.shape, self.dtype, self.slots = tuple(shape), np.dtype(dtype), slots
        self.frame_bytes = int(np.prod(shape)) * self.dtype.itemsize
        if name is None:
            sweep_stale_rings()
            self.shm = shared_memory.SharedMemory(name=f"{RING_PREFIX}{os.getpid()}_{secrets.token_hex(4)}",
                                                  create=True, size=self.frame_bytes * slots)
            self.owner = True
        else:
            self.shm = shared_memory.SharedMemory(name=name)
            self.owner = False
        self.array = np.ndarray((slots, *self.shape), self.dtype, buffer=self.shm.buf)

    @property
    def name(self) -> str:
        return self.shm.name

    def write(self, slot: int, image: np.ndarray) -> None:
        np.copyto(self.array[slot], image)

    def view(self, slot: int) -> np.ndarray:
        return self.array[slot]

    def close(self, *, unlink: bool | None = None) -> None:
        """Unmap the ring; ``unlink`` (default: when this process made it) removes the segment too."""
        del self.array
        self.shm.close()
        if self.owner if unlink is None else unlink:
            try:
                self.shm.unlink()
            except FileNotFoundError:
                pass


def _die_with_parent(parent: int, *, signal_it: bool) -> bool:
    """Ask Linux to SIGKILL this process when its parent's thread ends (``signal_it``); False when the
    parent ``parent`` (pid) is already gone -- it may have died before the request took effect."""
    if signal_it and sys.platform.startswith("linux"):
        try:
            ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
        except (OSError, AttributeError):
            pass  # the poll in the request loop still notices
    return os.getppid() == parent


def _worker(detector_name: str, params: Any, ring_spec: tuple | None, requests: Any, replies: Any,
            parent: int = 0, signal_it: bool = False, threads: int = 1) -> None:
    """The detector process: read a frame (from the ring or the message), detect, reply.

    ``parent``: the main process's pid (0: not watched); ``signal_it``: set the parent-death
    signal (only when forked from the main thread: the signal follows the forking thread);
    ``threads``: threads it detects on (the detector's and OpenCV's, as ``run --threads``).
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the group: the main process decides
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # not the main process's stop handler, inherited by fork
    if parent and not _die_with_parent(parent, signal_it=signal_it):
        return
    from .detection import make_detector
    from .system import time_stages

    ring = FrameRing(ring_spec[0], ring_spec[1], ring_spec[2], name=ring_spec[3]) if ring_spec else None
    orphaned = False
    try:
        import cv2

        cv2.setNumThreads(threads)
        detector = make_detector(detector_name, params, threads=threads)
        while True:
            try:
                message = requests.get(timeout=PARENT_POLL_S) if parent else requests.get()
            except queue.Empty:
                if os.getppid() != parent:
                    orphaned = True
                    return
                continue
            if message is None:
                return
            index, payload = message
            try:
                image = ring.view(payload) if ring is not None else payload
                found, stage_ns = time_stages(detector, image)
                replies.put((index, found.centres, found.radii, found.scores, found.cut, stage_ns))
            except BaseException as exc:  # noqa: BLE001 - reported to the main process
                replies.put((index, "error", f"{type(exc).__name__}: {exc}", None, 0, None))
                return
    finally:
        if ring is not None:
            ring.close(unlink=orphaned or None)  # no one else is left to remove it


def _ended_by(exitcode: int | None) -> str:
    """How a process ended, from its ``exitcode`` (negative: the signal's number)."""
    if exitcode is None or exitcode >= 0:
        return f"exit code {exitcode}"
    try:
        return f"signal {-exitcode}, {signal.Signals(-exitcode).name}"
    except ValueError:
        return f"signal {-exitcode}"


class DetectorProcess:
    """A detector running in its own process, fed through a shared-memory frame ring.

    submit(index, image) hands a frame over (copied once into the ring, or
    pickled with ``transport="pickle"``); results() yields what came back, in order.
    """

    def __init__(self, detector_name: str, params: Any, first_frame: np.ndarray, *, slots: int = 4,
                 transport: str = "shm", threads: int = 1) -> None:
        if transport not in ("shm", "pickle"):
            raise ValueError(f"transport: got {transport!r}, allowed shm, pickle")
        method = "fork" if sys.platform.startswith("linux") else "spawn"
        ctx = mp.get_context(method)
        self.transport = transport
        self.ring = FrameRing(first_frame.shape, first_frame.dtype, slots) if transport == "shm" else None
        self.slots = slots
        self.requests, self.replies = ctx.Queue(), ctx.Queue()
        spec = (self.ring.shape, self.ring.dtype.str, slots, self.ring.name) if self.ring else None
        signal_it = method == "fork" and threading.current_thread() is threading.main_thread()
        self.process = ctx.Process(target=_worker, args=(detector_name, params, spec, self.requests, self.replies,
                                                         os.getpid(), signal_it, threads),
                                   name="antiscatter-detector", daemon=True)
        self.process.start()
        self.in_flight = 0

    def submit(self, index: int, image: np.ndarray) -> None:
        if self.ring is not None:
            slot = index % self.slots
            self.ring.write(slot, image)
            self.requests.put((index, slot))
        else:
            self.requests.put((index, np.ascontiguousarray(image)))
        self.in_flight += 1

    def receive(self, timeout: float = 0.05) -> tuple[int, Detections, list[int]] | None:
        """One result, or None when none arrived within ``timeout`` (seconds).

        Raises RunError (one line) when the worker died, RuntimeError with its error when it failed.
        """
        try:
            index, centres, radii, scores, cut, stage_ns = self.replies.get(timeout=timeout)
        except queue.Empty:
            if not self.process.is_alive():
                raise RunError(f"the detector process died ({_ended_by(self.process.exitcode)})") from None
            return None
        self.in_flight -= 1
        if isinstance(centres, str):
            raise RuntimeError(f"detector process: {radii}")
        return index, Detections(centres, radii, scores, cut=cut), stage_ns

    @property
    def full(self) -> bool:
        return self.in_flight >= self.slots - 1

    def close(self) -> None:
        try:
            if self.process.is_alive():
                self.requests.put(None)
                self.process.join(timeout=2)
            if self.process.is_alive():
                self.process.terminate()
                self.process.join(timeout=2)
        finally:
            for q in (self.requests, self.replies):
                q.close()
                q.cancel_join_thread()
            if self.ring is not None:
                self.ring.close()
