"""Horizontal bands of the frame on a pool of threads: :class:`BandPool`.

The chain's costly frame-wide filters (the pooling to the working image, the rings a single
frame's particles must outshine, its texture median and its cut to prominent spots, the split's
smoothing) are local: an output row depends on the input rows within the filter's reach.  Cut
into bands that each read ``halo`` rows beyond their own, they give exactly the whole frame's
result, and OpenCV releases the GIL while it filters, so the bands run at once on several cores.
The candidates are labelled once, whole; their components are measured in bands of labels
(:func:`~.components.measure_in_bands`), each whole component in one band, so a particle on a
seam is found once; everything the detector learns across frames stays in the calling thread.
Measured history: docs/decisions/008-threads.md.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from typing import Any, Callable, TypeVar

import numpy as np

from .. import check_threads

T = TypeVar("T")
U = TypeVar("U")

#: fewest rows (output rows) a band holds: thinner bands spend more on their halo than they save
MIN_ROWS = 32


class BandPool:
    """``threads`` threads (the caller's and ``threads - 1`` workers) that filter horizontal bands of
    an image at once (:meth:`filter`).  With one thread it filters the whole image in the caller.

    The workers live as long as the pool (one pool a detector); they hold no state of their own.
    Work handed to the pool must not hand work to it in turn (its workers would wait on themselves).
    """

    def __init__(self, threads: int = 1) -> None:
        self.threads = check_threads(threads)
        self._workers = (ThreadPoolExecutor(threads - 1, thread_name_prefix="antiscatter-band")
                         if threads > 1 else None)

    def spans(self, rows: int) -> list[tuple[int, int]]:
        """[r0, r1) row ranges of at most ``threads`` bands of ``rows`` rows, about equal, each at
        least ``MIN_ROWS`` rows unless there is one band."""
        count = max(1, min(self.threads, rows // MIN_ROWS))
        edges = [rows * i // count for i in range(count + 1)]
        return [(edges[i], edges[i + 1]) for i in range(count)]

    def run(self, work: Callable[[int, int], None], spans: list[tuple[int, int]]) -> None:
        """``work(a, b)`` for every span (rows, or the labels of :func:`~.components.measure_in_bands`),
        the first in the caller's thread and the others on the workers at the same time; returns
        when all are done (the first error raised again)."""
        if self._workers is None or len(spans) == 1:
            for r0, r1 in spans:
                work(r0, r1)
            return
        futures = [self._workers.submit(work, r0, r1) for r0, r1 in spans[1:]]
        try:
            work(*spans[0])
        finally:
            for future in futures:
                future.exception()  # every band finished before its buffers are read or reused
        for future in futures:
            future.result()

    def call(self, first: Callable[[], T], second: Callable[[], U]) -> tuple[T, U]:
        """(first(), second()): ``second`` on a worker while ``first`` runs in the caller (one after
        the other with one thread); the first error raised again once both are done."""
        if self._workers is None:
            return first(), second()
        future = self._workers.submit(second)
        try:
            done = first()
        finally:
            future.exception()
        return done, future.result()

    def filter(self, fn: Callable[[np.ndarray], Any], image: np.ndarray, halo: int, out: Any) -> Any:
        """``fn(image)`` computed in bands into ``out``: each band hands ``fn`` its rows and ``halo``
        more rows of ``image`` on either side, and keeps the output rows of its own.  ``fn`` may
        give a tuple of images, ``out`` then a tuple of as many buffers (None: that image not kept).

        fn: a local filter, rows of ``image`` -> as many rows of output, whose output row depends
            only on the input rows within ``halo`` of it: then the result equals ``fn(image)``
            exactly, band seams included.  At the image's top and bottom a band stops where the
            image does, so ``fn``'s own border rule applies there as on the whole image.
        halo: rows.
        out: the output buffer(s), as many rows as ``image``.
        Returns ``out``.
        """
        outs = out if isinstance(out, tuple) else (out,)
        rows = image.shape[0]

        def work(r0: int, r1: int) -> None:
            a, b = max(r0 - halo, 0), min(r1 + halo, rows)
            got = fn(image[a:b])
            for buffer, part in zip(outs, got if isinstance(out, tuple) else (got,)):
                if buffer is not None:
                    buffer[r0:r1] = part[r0 - a: r1 - a]

        self.run(work, self.spans(rows))
        return out


def downsample_in_bands(image: np.ndarray, pool: BandPool, *, factor: int, channel: str,
                        point: float) -> tuple[np.ndarray, np.ndarray]:
    """(the frame's channel (H, W) uint8, the working image (H/f, W/f) uint8): what
    :func:`~.working.to_channel` and :func:`~.working.downsample` give, made in bands of whole
    f x f blocks on ``pool`` (frames of whole blocks, f >= 2: no band reads another's rows).
    A grey or Y frame is its own channel (not copied)."""
    from .working import downsample, to_channel

    h, w = image.shape[0] // factor, image.shape[1] // factor
    if factor < 2 or image.shape[0] != h * factor or image.shape[1] != w * factor:
        raise ValueError(f"frame of {image.shape[1]}x{image.shape[0]} px: allowed whole {factor}x{factor} blocks")
    grey = image if image.ndim == 2 else np.empty(image.shape[:2], np.uint8)
    half = np.empty((h, w), np.uint8)

    def work(r0: int, r1: int) -> None:
        rows = slice(r0 * factor, r1 * factor)
        if image.ndim == 3:
            to_channel(image[rows], channel, out=grey[rows])
        half[r0:r1] = downsample(grey[rows], factor=factor, channel=channel, point=point)

    pool.run(work, pool.spans(h))
    return grey, half
