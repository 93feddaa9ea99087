"""Stage 2 across frames: :class:`BackgroundModel`, the per-pixel background and sensor noise
learnt from the frames seen (what the detector learns).  Following the view as it moves is its
mixin :class:`~antiscatter.detection.contrast.follow.ViewFollowing`.
"""

from __future__ import annotations

from typing import Callable

import cv2
import numpy as np

from .bands import BandPool
from .background import NOISE_WINDOW, frame_alone, limit_map, prominence_level, spatial_background, threshold_mask
from .follow import ViewFollowing


class BackgroundModel(ViewFollowing):
    """Per-pixel background and sensor noise, learnt over ``memory`` frames in horizontal bands.

    The first frame (and any frame of another size, or of a new scene: see
    :meth:`new_scene`) starts from the spatial background and measures the noise
    everywhere; when the view pans, the learnt background moves with it
    (:meth:`follow`, :class:`ViewFollowing`).  After that, each frame
    updates one of ``bands`` horizontal bands -- background, noise and the
    threshold map there -- at ``bands`` times the per-frame rate, so every frame
    costs the same and a fraction of a full update; ``memory=0`` keeps the
    detector single-frame (everything recomputed from each frame).  This is what the
    detector learns.

    Attributes read by the detector: ``base`` (uint8 background), ``limit``
    (uint8: a pixel is a candidate where frame - base > limit) and ``noise``
    (float32 per coarse cell, grey levels).  The history of each constant below:
    docs/decisions/001-contrast-tuning.md.
    """

    #: frames a pixel must stay under an unchanging "particle" before it counts as scene, counted
    #: in band updates (``bands`` frames apart, at least two of them); PERSIST / 2 frames during
    #: the warm-up (shorter took a slow particle for scene)
    PERSIST = 8
    #: share of the learning rate at which a pixel under a particle learns (what it sees is mostly
    #: the particle), so slow particles do not sink into the background while they are seen;
    #: ``UNDER_WARM`` during the warm-up, when the static scene is still being told from particles
    UNDER = 0.05
    UNDER_WARM = 0.25
    #: in the warm-up, a frame's pixel is learnt as at most this many detection limits above the
    #: background: particles only add light, so what lies far above the background is a particle,
    #: not the scene (not while the view moves, nor under the lamp's pattern)
    LEARN_REACH = 2.0
    #: a pixel under a particle is steady while it lies within the detection limit of what it was
    #: when its run of steady updates began (True), not of its last update: a slowly creeping flake
    #: must not sink into the background
    ANCHORED = True
    #: how far (working pixels) the learnt background may lie from the frame while the view moves:
    #: the pan follower's whole-pixel steps leave up to half a pixel, and the background learnt over
    #: the last frames lags
    MISREGISTRATION = 1.5
    #: frames after a move for which the view counts as moving
    MOVED_FRAMES = 8
    #: the learning's memory (frames) while the view moves, when the detector's own is longer: each
    #: move resamples the learnt background, which a long memory smooths into false detections
    MOVING_MEMORY = 10
    #: share of the frame that must differ from the background for a new scene
    NEW_SCENE = 0.3
    #: share of the coarse cells the learnt background may explain worse than the frame's own
    #: spatial background before it is dropped (a cut, an unrelated still, the lamp moved)
    MISFIT_SHARE = 0.25
    #: a cell is explained worse when its mean |frame - learnt| exceeds its mean |frame - spatial|
    #: by this share of the latter plus MISFIT_LEVELS grey levels (the learnt background's own
    #: noise adds a little on plain water)
    MISFIT_RATIO = 0.1
    MISFIT_LEVELS = 0.5
    #: a pixel's deficit counts towards its cell's noise up to this many times the frame's typical
    #: (median) noise, so a background that learnt some passing particles does not inflate the
    #: noise (a 4 sigma deficit comes once in 30,000 pixels); not under the lamp's pattern
    NOISE_CAP = 4.0
    #: weight of the spatial start (the first frame's background from that frame alone) against
    #: each frame learnt after it, for the pixels where no particle was found: 0, the first
    #: learnt frame takes its place (on textured ground the spatial start is off by the texture)
    START_WEIGHT = 0.0
    #: frames after a (re)start during which the frame alone vets the learnt background's candidates
    YOUNG = 4
    #: frames after a (re)start during which every band learns every frame, so the first
    #: frames' static scene is absorbed in PERSIST / 2 frames (at least 2)
    WARMUP = 16

    def __init__(self, *, cell: int, memory: int, k: float = 4.0, min_contrast: float = 4.0,
                 bands: int = 4, follow: bool = True, window: int = 0, defer_looks: bool = False,
                 pool: BandPool | None = None) -> None:
        self.cell = cell
        self.window = window
        self.rings: tuple[int, ...] = ()
        self.prominent: np.ndarray | None = None
        self.noise_window = NOISE_WINDOW
        self.follows = follow
        #: routine looks at a still view's flow are taken by :meth:`look_deferred` (after the
        #: detections) instead of in :meth:`register`
        self.defer_looks = defer_looks
        #: threads the single-frame filters run on in bands (None: the caller's alone; the same result)
        self.pool = pool
        self.k = k
        self.min_contrast = min_contrast
        self.alpha = 1.0 / memory if memory else 0.0
        self.bands = bands if memory else 1
        self.reset()

    def reset(self) -> None:
        """Forget everything learnt: the next frame starts the model again."""
        self.background: np.ndarray | None = None
        self.base: np.ndarray | None = None
        self.limit: np.ndarray | None = None
        self.noise: np.ndarray | None = None
        self._deficit: np.ndarray | None = None  # mean of max(base - frame, 0) per coarse cell
        self._cap: float | None = None  # largest deficit a pixel adds to it (NOISE_CAP)
        self._previous: np.ndarray | None = None
        self._persist: np.ndarray | None = None
        self._updates = np.zeros(max(self.bands, 1), np.int64)
        self._next = 0
        self._frames = 0
        self._typical_noise = 0.0  # the noise map's median
        self._reset_view()

    def _rows(self, band: int, height: int) -> tuple[int, int, int, int]:
        """Pixel rows [r0, r1) and coarse-cell rows [c0, c1) of ``band``: bands hold whole cell rows."""
        cells = max(height // self.cell, 3)
        c0, c1 = band * cells // self.bands, (band + 1) * cells // self.bands
        return c0 * height // cells, c1 * height // cells, c0, c1

    def estimate(self, half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(base, limit) for this frame, both uint8 (h, w).  The learnt background follows the view
        when it pans or turns; a new scene starts the model again.  For ``MOVED_FRAMES`` frames
        after the view moved, the limit also takes ``MISREGISTRATION`` times the background's own
        slope: a background off by a fraction of a pixel is wrong by that much at every edge of
        the ground's texture."""
        if self.background is not None and self.background.shape == half.shape:
            if self.alpha > 0.0:
                # the view panned, then turned (each on its own: a vehicle yaws as it goes)
                if self.follows and (self.follow(half) != (0, 0)) | self.register(half):
                    # the view moved: the last frame's pixels are elsewhere now, start again
                    self._gain_last, self._gain, self._gain_var = None, 1.0, 0.0
                    self._moved_ago = 0
                else:
                    self._moved_ago = 0 if self._turn_moving else self._moved_ago + 1
                self.match_gain(half)
            if self.new_scene(half) or (not self.moving() and self.misfit(half)):
                self.reset()
            elif self._moved_ago <= self.MOVED_FRAMES:
                return self.base, cv2.add(self.limit, self._slope_limit())
        if self.alpha == 0.0 or self.background is None or self.background.shape != half.shape:
            if self.background is not None and self.background.shape != half.shape:
                self.reset()  # frames of another size: another stream, nothing carries over
            h, w = half.shape
            self._deficit = np.zeros((max(h // self.cell, 3), max(w // self.cell, 3)), np.float32)
            self.background = spatial_background(half, cell=self.cell, window=self.window, pool=self.pool)
            self.base = cv2.convertScaleAbs(self.background)  # rounded, saturated uint8 (background >= 0)
            self._each_band(lambda band: self._measure_noise(half, band))
            self._update_limit(half.shape)
            self._previous = self._persist = None
            self._profiles = None
            self._updates[:] = 0
            self._next = 0
            if self.rings:  # a single frame: its particles must stand out (the learning starts as before)
                level, self.noise = prominence_level(half, self.rings, cell=self.cell, window=self.noise_window,
                                                     pool=self.pool)
                limit = self._limit_map(self.noise, half.shape)
                self.prominent = threshold_mask(half, level, limit)[0]
                return self.base, limit
        return self.base, self.limit

    def _slope_limit(self) -> np.ndarray:
        """uint8 (h, w): ``MISREGISTRATION`` times the learnt background's slope (grey levels a working
        pixel, |d/dx| + |d/dy| from Sobel's 3x3, which is 8 times the slope)."""
        gx = cv2.Sobel(self.base, cv2.CV_16S, 1, 0)
        gy = cv2.Sobel(self.base, cv2.CV_16S, 0, 1)
        scale = self.MISREGISTRATION / 8
        return cv2.add(cv2.convertScaleAbs(gx, alpha=scale), cv2.convertScaleAbs(gy, alpha=scale))

    def _measure_noise(self, half: np.ndarray, band: int, frozen: np.ndarray | None = None) -> None:
        """Particles only ever add light, so the noise is measured on the *dark* side:
        per coarse cell, the mean of max(background - frame, 0), which for symmetric noise
        of spread s is s / sqrt(2 pi), whatever bright particles the cell holds.
        ``frozen`` pixels (unlit) are left out; a cell that is mostly frozen keeps its value.

        Against the float background, not the rounded ``base``: after 2x2 pooling a quiet
        sensor's noise is under a grey level, and the rounding (up to half a grey level either
        way) moved the dark-side mean by a large part of it."""
        r0, r1, c0, c1 = self._rows(band, half.shape[0])
        if c1 <= c0 or r1 <= r0:
            return
        deficit = cv2.subtract(self.background[r0:r1], half[r0:r1], dtype=cv2.CV_32F)
        cv2.max(deficit, 0.0, dst=deficit)
        if self._cap is not None and frozen is None:  # a pixel whose background is wrong says nothing
            cv2.min(deficit, self._cap, dst=deficit)  # about the noise (under no pattern: see NOISE_CAP)
        size = (self._deficit.shape[1], c1 - c0)
        if frozen is None or not frozen[r0:r1].any():
            cv2.resize(deficit, size, dst=self._deficit[c0:c1], interpolation=cv2.INTER_AREA)
            return
        live = (frozen[r0:r1] == 0).astype(np.float32)
        total = cv2.resize(deficit * live, size, interpolation=cv2.INTER_AREA)
        share = cv2.resize(live, size, interpolation=cv2.INTER_AREA)
        measured = share > 0.25
        self._deficit[c0:c1][measured] = total[measured] / share[measured]

    def _update_limit(self, shape: tuple[int, int]) -> None:
        """noise (3x3-cell median of the dark-side spread, so a few cells of particles
        do not inflate it) and the per-pixel limit max(k * noise, min_contrast) as
        uint8, rounded down (``excess > limit`` on integers is ``excess > k * noise``)."""
        self.noise = cv2.medianBlur(self._deficit, 3) * np.float32(2.5066)  # s = sqrt(2 pi) E[max(-x, 0)]
        self._typical_noise = float(np.median(self.noise))
        self._cap = max(self.NOISE_CAP * self._typical_noise, 2.0)
        self.limit = self._limit_map(self.noise, shape)

    def _limit_map(self, noise: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        """uint8 (h, w): the model's :func:`limit_map` (its ``k`` and ``min_contrast``)."""
        return limit_map(noise, shape, self.k, self.min_contrast)

    def new_scene(self, half: np.ndarray) -> bool:
        """True when more than ``NEW_SCENE`` of the frame (every 4th row) differs from the background by
        more than the limit, either way: the camera turned to another scene, the light changed.
        Particles cover a few per cent (the dense preset 7 %); after a cut it is over 90 %."""
        rows = slice(None, None, 4)
        changed = cv2.compare(cv2.absdiff(half[rows], self.base[rows]), self.limit[rows], cv2.CMP_GT)
        return cv2.countNonZero(changed) > self.NEW_SCENE * changed.size

    def misfit(self, half: np.ndarray) -> bool:
        """True when the learnt background explains this frame worse than the frame alone does in
        more than ``MISFIT_SHARE`` of the coarse cells: memory that does not fit the frame in hand
        gives way to single-frame detection (the model starts again from this frame).  Not asked
        while the view moves: a followed view's background lags it by design, and the frame alone
        vets those candidates instead (the chain's ``MOVING_SCALE``)."""
        h, w = half.shape
        size = (max(w // 2, 8), max(h // 2, 8))  # at half the working resolution: a quarter of the work
        small = cv2.resize(half, size, interpolation=cv2.INTER_AREA)
        cell = max(self.cell // 2, 2)
        cells = (max(size[0] // cell, 3), max(size[1] // cell, 3))
        own = spatial_background(small, cell=cell, window=self.window // 2 if self.window else 0, pool=self.pool)
        base = cv2.resize(self.base, size, interpolation=cv2.INTER_AREA)
        learnt = cv2.resize(cv2.absdiff(small, base).astype(np.float32), cells, interpolation=cv2.INTER_AREA)
        alone = cv2.resize(cv2.absdiff(small.astype(np.float32), own), cells, interpolation=cv2.INTER_AREA)
        worse = cv2.compare(learnt, alone * np.float32(1 + self.MISFIT_RATIO) + np.float32(self.MISFIT_LEVELS),
                            cv2.CMP_GT)
        return cv2.countNonZero(worse) > self.MISFIT_SHARE * worse.size

    def moving(self) -> bool:
        """True while the view counts as moving (``MOVED_FRAMES`` after the last pan or turn)."""
        return self._moved_ago <= self.MOVED_FRAMES

    def single_mask(self, half: np.ndarray, scale: float = 1.0) -> np.ndarray:
        """uint8 (h, w): this frame's candidates by the frame alone (:func:`frame_alone`), at
        ``scale`` times the limit."""
        return frame_alone(half, cell=self.cell, window=self.window, rings=self.rings, noise_window=self.noise_window,
                           k=self.k * scale, min_contrast=self.min_contrast * scale, pool=self.pool).mask

    def young(self) -> bool:
        """True for the first ``YOUNG`` frames after a (re)start: the learnt background still holds
        much of the spatial start, and the frame alone vets its candidates."""
        return self._frames < self.YOUNG

    def learnt(self) -> bool:
        """True once the warm-up is over: static scene has been told apart from particles."""
        return self._frames >= self.WARMUP

    def learn(self, half: np.ndarray, mask: np.ndarray, frozen: np.ndarray | None = None) -> None:
        """Update one band from this frame (``mask``: uint8, 255 = particle candidate; ``frozen``:
        uint8, 255 = pixels this frame says nothing about -- left unlit by the lamp -- which keep
        their background).

        Pixels without a particle (the mask grown by one pixel) learn at the full
        rate.  Under a particle a pixel learns at ``UNDER`` of it, so moving and
        slow particles leave almost no trace -- unless it has stayed within the
        detection limit (``limit``) of its first value over ``PERSIST`` frames (``ANCHORED``):
        then it is scene the first frames mistook for a particle (a bright pebble,
        a padding highlight) and learns at four times the rate.  The band's noise
        is measured too; the threshold map follows once every band has been.
        During the first ``WARMUP`` frames every band learns every frame and
        PERSIST / 2 frames suffice (at least 2): everything static is still to be told apart;
        there (while the view holds still, with no pattern of the lamp's on it) a pixel counts as at most ``LEARN_REACH`` limits
        above the background, so the particles of a thick cloud do not leave their light in it.
        """
        if self.alpha == 0.0 or self.background is None:
            return
        if self._previous is None or self._previous.shape != half.shape:
            self._previous = half.copy()
            self._persist = np.zeros(half.shape, np.uint8)
            self._frames = 0
            first = True
        else:
            first = False
        warm = self._frames < self.WARMUP
        self._frames += 1
        moving = self._moved_ago <= self.MOVED_FRAMES  # then a shorter memory (MOVING_MEMORY), no cap
        if warm:
            # the cap (LEARN_REACH): not while the view moves (a moved background is off both ways)
            # nor under the lamp's pattern
            capped = not (first or moving) and frozen is None
            self._each_band(lambda band: self._learn_band(half, mask, band, first, per_update=1,
                                                          needed=max(2, self.PERSIST // 2), under=self.UNDER_WARM,
                                                          frozen=frozen, capped=capped))
            self._next = 0
            self._update_limit(half.shape)
            return
        band = self._next
        self._next = (band + 1) % self.bands
        self._learn_band(half, mask, band, first, per_update=self.bands,
                         needed=max(2, -(-self.PERSIST // self.bands)), under=self.UNDER, frozen=frozen,
                         alpha=max(self.alpha, 1.0 / self.MOVING_MEMORY) if moving else self.alpha)
        if self._next == 0:  # a whole cycle of bands: the noise map has been renewed
            self._update_limit(half.shape)

    def _each_band(self, work: Callable[[int], None]) -> None:
        """``work(band)`` for every band; on the pool's threads at once when there is one (the bands
        read and write rows and cells of their own)."""
        if self.pool is None or self.pool.threads == 1:
            for band in range(self.bands):
                work(band)
            return
        count = min(self.pool.threads, self.bands)
        edges = [self.bands * i // count for i in range(count + 1)]

        def some(a: int, b: int) -> None:
            for band in range(a, b):
                work(band)

        self.pool.run(some, list(zip(edges[:-1], edges[1:])))

    def _learn_band(self, half: np.ndarray, mask: np.ndarray, band: int, first: bool, *, per_update: int,
                    needed: int, under: float, frozen: np.ndarray | None = None,
                    alpha: float | None = None, capped: bool = False) -> None:
        """Learn the rows of ``band``; ``per_update`` frames pass between its updates, ``needed``
        steady updates make a "particle" scene, pixels under a particle learn at ``under`` of the rate
        (``alpha`` a frame once learnt; None: the model's)."""
        alpha = self.alpha if alpha is None else alpha
        h, w = half.shape
        r0, r1, c0, c1 = self._rows(band, h)
        if r1 <= r0:
            return
        self._measure_noise(half, band, frozen)  # against the base this frame was thresholded with
        frame = half[r0:r1]
        top, bottom = max(r0 - 1, 0), min(r1 + 1, h)
        particles = cv2.dilate(mask[top:bottom], None)[r0 - top:r0 - top + (r1 - r0)]
        updates = int(self._updates[band])
        rate = min(1.0, max(alpha * per_update, 1.0 / (updates + 2)))
        # scene pixels: a running mean of the frames seen (then the memory's rate); the spatial start
        # is a guess, not a frame's worth of evidence (see START_WEIGHT)
        fresh = min(1.0, max(alpha * per_update, 1.0 / (updates + 1 + self.START_WEIGHT)))
        background = self.background[r0:r1]
        live = None if frozen is None else cv2.bitwise_not(frozen[r0:r1])  # pixels that may learn
        if live is not None:
            particles = cv2.bitwise_or(particles, frozen[r0:r1])
        if not first:
            change = cv2.absdiff(frame, self._previous[r0:r1])
            steady = cv2.bitwise_and(cv2.compare(change, self.limit[r0:r1], cv2.CMP_LE), particles)
            persist = self._persist[r0:r1]
            cv2.add(persist, 1, dst=persist, mask=steady)
            cv2.bitwise_and(persist, steady, dst=persist)
            scene = cv2.compare(persist, needed, cv2.CMP_GE)
            cv2.accumulateWeighted(frame, background, min(1.0, 4 * rate), mask=scene)
            if self.ANCHORED:
                cv2.copyTo(frame, cv2.bitwise_not(steady), self._previous[r0:r1])
            else:
                self._previous[r0:r1] = frame
        sample = frame
        if capped:  # particles only add light: what lies far above the background is not it
            sample = np.minimum(frame, background + self.limit[r0:r1] * np.float32(self.LEARN_REACH))
        cv2.accumulateWeighted(sample, background, rate * under, mask=live)
        cv2.accumulateWeighted(sample, background, fresh * (1 - under), mask=cv2.bitwise_not(particles))
        cv2.convertScaleAbs(background, dst=self.base[r0:r1])
        self._updates[band] = updates + 1
