"""The report's multi-process design rebuilt: frames through shared memory, small messages pickled.

``run --mode processes`` captures, renders and shows in the main process and
detects in a worker process.  Frames travel through a ring of shared-memory
slots (``multiprocessing.shared_memory``): the main process copies each frame
once into a free slot and sends the worker only the slot number; the worker
reads the frame in place and sends back the particles (a few kilobytes).
``transport="pickle"`` instead sends every frame through the queue, as the
report did, to measure what that costs.  Up to ``slots - 1`` frames are in
flight, so capture overlaps detection.  The worker ignores Ctrl-C (the main
process stops it); a crash in it stops the run with its error; the shared
memory is unlinked however the run ends.
"""

from __future__ import annotations

import multiprocessing as mp
import queue
import signal
import sys
from multiprocessing import shared_memory
from typing import Any

import numpy as np

from .detections import Detections

__all__ = ["FrameRing", "DetectorProcess"]


class FrameRing:
    """``slots`` frames of one shape and dtype in one shared-memory block."""

    def __init__(self, shape: tuple[int, ...], dtype: Any = np.uint8, slots: int = 4, *,
                 name: str | None = None) -> None:
        self.shape, self.dtype, self.slots = tuple(shape), np.dtype(dtype), slots
        self.frame_bytes = int(np.prod(shape)) * self.dtype.itemsize
        if name is None:
            self.shm = shared_memory.SharedMemory(create=True, size=self.frame_bytes * slots)
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

    def close(self) -> None:
        del self.array
        self.shm.close()
        if self.owner:
            try:
                self.shm.unlink()
            except FileNotFoundError:
                pass


def _worker(detector_name: str, params: Any, ring_spec: tuple | None, requests: Any, replies: Any) -> None:
    """The detector process: read a frame (from the ring or the message), detect, reply."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the main process decides when to stop
    from .detection import make_detector
    from .runtime import time_stages

    ring = FrameRing(ring_spec[0], ring_spec[1], ring_spec[2], name=ring_spec[3]) if ring_spec else None
    try:
        detector = make_detector(detector_name, params)
        while True:
            message = requests.get()
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
            ring.close()


class DetectorProcess:
    """A detector running in its own process, fed through a shared-memory frame ring.

    submit(index, image) hands a frame over (copied once into the ring, or
    pickled with ``transport="pickle"``); results() yields what came back, in order.
    """

    def __init__(self, detector_name: str, params: Any, first_frame: np.ndarray, *, slots: int = 4,
                 transport: str = "shm") -> None:
        if transport not in ("shm", "pickle"):
            raise ValueError(f"transport: got {transport!r}, allowed shm, pickle")
        method = "fork" if sys.platform.startswith("linux") else "spawn"
        ctx = mp.get_context(method)
        self.transport = transport
        self.ring = FrameRing(first_frame.shape, first_frame.dtype, slots) if transport == "shm" else None
        self.slots = slots
        self.requests, self.replies = ctx.Queue(), ctx.Queue()
        spec = (self.ring.shape, self.ring.dtype.str, slots, self.ring.name) if self.ring else None
        self.process = ctx.Process(target=_worker, args=(detector_name, params, spec, self.requests, self.replies),
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
        """One result, or None when none arrived within ``timeout``; raises if the worker failed."""
        try:
            index, centres, radii, scores, cut, stage_ns = self.replies.get(timeout=timeout)
        except queue.Empty:
            if not self.process.is_alive():
                raise RuntimeError(f"detector process died (exit code {self.process.exitcode})") from None
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
