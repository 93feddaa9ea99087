"""Following the view: the learnt background moved with the camera's pans (:meth:`ViewFollowing.follow`),
turns and zooms (:meth:`ViewFollowing.register`), and scaled with the whole scene's brightness
(:meth:`ViewFollowing.match_gain`).

Brightness profiles and their shift are plain functions (:func:`_profile_shift`); the following
itself is :class:`ViewFollowing`, the half of :class:`~antiscatter.detection.contrast.model.BackgroundModel`
that moves what the model learnt.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from .kernels import _K3


#: largest view shift between two frames that the background follows (working pixels)
MAX_FOLLOW = 16
#: a profile whose high-passed spread is below this (grey levels) is a plain view with nothing to
#: follow (0.2 took smooth seabed for plain; history: docs/decisions/001-contrast-tuning.md)
PLAIN = 0.1
#: the correlation a profile taken again over the shared ground needs (the first axis's shift
#: found, and the move still has to fit better; 0.8 left pans over ground with little structure
#: unfollowed, 0.6 took the seed tank's rising discs for a move)
OVERLAP_SCORE = 0.7

#: Lucas-Kanade iterations stop after 10 or a move under 0.03 px (OpenCV's default 30 / 0.01 cost a
#: flat view's points 30 iterations each: 0.55 ms a look in the mixed scene)
_LK_STOP = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 10, 0.03)


def _fits_better(frame: np.ndarray, base: np.ndarray, dx: int, dy: int) -> bool:
    """True when the background moved by (dx, dy) lies closer to the frame than where it is (mean
    absolute difference over every 4th row of the overlap).  The profiles of a still view
    jitter (a big bright bubble passing once shifts them by half a pixel): the move is checked
    against the whole image before it is made."""
    h, w = frame.shape
    ys, xs = slice(max(dy, 0), h + min(dy, 0)), slice(max(dx, 0), w + min(dx, 0))
    moved = base[max(-dy, 0):h - max(dy, 0), max(-dx, 0):w - max(dx, 0)]  # base[y - dy, x - dx]
    here = frame[ys, xs][::4]
    return cv2.norm(here, moved[::4], cv2.NORM_L1) < cv2.norm(here, base[ys, xs][::4], cv2.NORM_L1)


def _overlap_shift(reference: np.ndarray, frame: np.ndarray, axis: int, other: int) -> float | None:
    """:func:`_profile_shift` along ``axis`` (0: x from column profiles, 1: y from row profiles) of
    two images whose view moved by ``other`` samples along the other axis: the profiles are taken
    over the part both show."""
    n = reference.shape[axis]  # the other axis's length: rows for x (axis 0), columns for y
    if abs(other) >= n // 2:
        return None
    keep = slice(max(0, -other), n - max(0, other))  # in the reference; the frame's is shifted by other
    seen = slice(max(0, other), n - max(0, -other))
    ref, cur = (reference[keep], frame[seen]) if axis == 0 else (reference[:, keep], frame[:, seen])
    profiles = [cv2.reduce(v, axis, cv2.REDUCE_AVG, dtype=cv2.CV_32F).ravel() for v in (ref, cur)]
    return _profile_shift(_highpass(profiles[0]), profiles[1], MAX_FOLLOW // 2, OVERLAP_SCORE)


def _highpass(profile: np.ndarray) -> np.ndarray | None:
    """A brightness profile (1-D) minus its 15-sample running mean, float32, so the lamp's cone does
    not count; None for a plain view (open water: spread below ``PLAIN``), with nothing to follow."""
    row = profile.astype(np.float32).reshape(1, -1)
    row -= cv2.blur(row, (15, 1), borderType=cv2.BORDER_REPLICATE)
    return None if cv2.meanStdDev(row)[1][0, 0] < PLAIN else row.ravel()


def _profile_shift(reference: np.ndarray | None, profile: np.ndarray, max_shift: int,
                   min_score: float = 0.8) -> float | None:
    """Shift (samples, sub-sample) that best lays ``reference`` onto ``profile`` (1-D float32, same
    length), within +-max_shift; None when their high-passed correlation there is below 0.8 (no
    texture to go by, or the view changed more than it moved).  ``reference`` is already
    :func:`_highpass`'s (None: a plain view), as :meth:`BackgroundModel.follow` keeps it."""
    n = len(profile)
    if n < 4 * max_shift:
        return None
    p = None if reference is None else _highpass(profile)
    if p is None:
        return None
    # normalised correlation of the profile's middle with every window of the reference (OpenCV, one
    # call); the window starting at j stands for the shift max_shift - j: reversed, index i <-> i - max
    middle = p[max_shift:n - max_shift].reshape(1, -1)
    scores = cv2.matchTemplate(reference.reshape(1, -1), middle, cv2.TM_CCOEFF_NORMED).ravel()[::-1]
    best = int(np.argmax(scores))
    if scores[best] < min_score:
        return None
    offset = 0.0
    if 0 < best < len(scores) - 1:  # parabola through the peak and its neighbours
        a, b, c = scores[best - 1], scores[best], scores[best + 1]
        denominator = a - 2 * b + c
        if denominator < 0:
            offset = 0.5 * (a - c) / denominator
    return float(best - max_shift + offset)


def _middle(values: np.ndarray) -> float:
    """The median of a 1-D array (the upper middle when even), by one partition: a quarter of
    np.median's time on a few thousand values."""
    k = len(values) // 2
    return float(np.partition(values, k)[k])


class ViewFollowing:
    """Keeps :class:`~antiscatter.detection.contrast.model.BackgroundModel`'s learnt background on
    the view as the camera pans, turns, zooms or changes its exposure; a mixin of the model.

    It moves the model's ``background`` (float32 (h, w)), ``base`` (its uint8) and the learning's
    per-pixel ``_previous`` and ``_persist``, and reads its ``bands``, ``follows``,
    ``defer_looks``, ``_frames``, ``WARMUP``, ``learnt()`` and ``_typical_noise``.  Its own state
    lasts across frames and is started again by :meth:`_reset_view` (the model's ``reset``).
    """

    background: np.ndarray | None
    base: np.ndarray | None
    bands: int
    follows: bool
    defer_looks: bool
    WARMUP: int
    _frames: int
    _previous: np.ndarray | None
    _persist: np.ndarray | None
    _typical_noise: float

    #: points of the grid (across, down) that :meth:`register` follows, at half the working resolution
    TURN_GRID = (8, 6)
    #: points that must agree with a turn (RANSAC inliers within 1 working pixel)
    TURN_INLIERS = 12
    #: smallest move of a frame corner (working pixels, |dx| + |dy|) that turns the background
    TURN_MIN = 0.5
    #: share by which the background must lie closer to the frame for the first move (between
    #: what true first moves gain and a still view's false candidates)
    TURN_GAIN = 0.01
    #: frames learnt before the first look (later left a turning view unfollowed at the start)
    TURN_AFTER = 2
    #: frames between looks while the view holds still
    TURN_EVERY = 6
    #: in the warm-up, the view is looked at every frame, and a first look whose move is turned down
    #: after one that saw the view move is taken again the next frame, this many times in a row
    #: (a young background's flow is a poor guide; after the warm-up, retries let a still view's
    #: noisy looks agree)
    TURN_RETRIES = 3
    #: once the view turns it is followed every frame until this many looks in a row find it moving
    #: no corner by more than ``TURN_STILL`` working pixels
    TURN_STILL = 0.15
    TURN_STILL_LOOKS = 4
    #: ... or the moves of this many looks in a row add up to less than ``TURN_STILL`` a look (:meth:`_drifted`)
    TURN_DRIFT_LOOKS = 16
    #: while following, a move of no corner by this much (working pixels) waits for the next look
    TURN_STEP = 0.3
    #: opening of both frames before the flow while following (particles out, ground texture kept)
    FLOW_OPEN = np.ones((3, 3), np.uint8)
    #: a move that scales the view by s scales the background's brightness by s^2 (the median over
    #: this many moves; 0 = never): the lamp rides with the camera, and ground that grows by s came
    #: s times closer (:meth:`match_gain` cannot follow the brightness across moves)
    BRIGHTEN = 5

    #: pixels the brightness ratio is taken over (whole rows spread over the frame)
    GAIN_SAMPLES = 2000
    #: backgrounds darker than this (grey levels) say little about a ratio: their noise is most of them
    GAIN_MIN_LEVEL = 8.0
    #: smallest change of brightness followed at once (over textured ground at levels of 40-100
    #: with a noise of 2, one frame's ratio is good to about 0.1 %)
    GAIN_STEP = 0.003
    #: ... and it must exceed this many standard errors (over dark water, levels near 10 with a
    #: noise of 1.5, one frame's ratio is good to about 0.5 % only)
    GAIN_SIGMAS = 4.0
    #: frames whose difference, the brightness change taken out, spreads more than this many
    #: times the two frames' noise are not the same view: not compared
    GAIN_SPREAD = 2.0

    def _reset_view(self) -> None:
        """Forget the following's state (part of the model's ``reset``)."""
        self._profiles: tuple | None = None  # the background opened at half resolution, its profiles (follow)
        self._profiled = 0  # frames since they were taken
        # register: the grid of points it follows and the size it is for, frames until the next look,
        # the last look's move of the frame's corners
        self._turn_grid = np.empty((0, 1, 2), np.float32)
        self._turn_size: tuple[int, int] | None = None
        self._turn_wait = 0
        self._turn_last: np.ndarray | None = None
        self._turn_retries = 0  # looks in a row whose move was turned down after one that saw it
        self._moved_ago = 1 << 30  # frames since the view last moved (pan or turn)
        self._turn_moving = False  # a turn was made and the view has not been seen still since
        self._turn_still = 0  # looks in a row that found it still
        self._turn_moves: list[np.ndarray] = []  # while it moves: the corners' moves of the last looks
        self._look_due = False  # a routine look left for after the detections (defer_looks)
        # the frame (at half the working resolution) a look last moved the background to fit, and
        # the pans follow() made since
        self._look_ref: np.ndarray | None = None
        self._panned = np.zeros(2)
        self._growths: list[float] = []  # the last moves' growth of the view's area (BRIGHTEN)
        # match_gain: the rows it reads, for frames of this shape; the pixels of them it compares
        # (flat indices) and frames since they were chosen; the last frame's rows (None: nothing
        # to compare); the brightness change since the background was last scaled, its variance
        self._gain_shape: tuple[int, int] | None = None
        self._gain_rows = np.empty(0, np.intp)
        self._gain_pixels = np.empty(0, np.intp)
        self._gain_age = 0
        self._gain_last: np.ndarray | None = None
        self._gain = 1.0
        self._gain_var = 0.0

    def follow(self, half: np.ndarray) -> tuple[int, int]:
        """Move the learnt background with the view: the shift between it and this frame, from their
        column and row brightness profiles (high-passed, so the lamp's cone does not count) after
        an opening at half resolution that takes out particles (small bright blobs) and keeps the
        ground's texture.  When only one axis's profiles match, the other's are taken again over
        the ground both views share (:func:`_overlap_shift`).  A plain view (open water) has no
        texture to go by and is left alone; a move is made only when it brings the background
        closer to the frame (:func:`_fits_better`), and by the shift measured, to a fraction of a
        pixel (linear interpolation: whole pixels left the texture up to half a pixel off, which
        ``point`` pooling shows as false detections); the ground that came into view takes its
        background from the frame (:meth:`_fill_entered`).  The background's opened image and
        profiles are renewed every ``bands`` frames (one learning cycle) and after each move.
        Returns the move in whole working pixels (dx, dy)."""
        sub = (slice(None, None, 2), slice(None, None, 2))
        if self._profiles is None or self._profiled >= self.bands:
            base = cv2.morphologyEx(self.base[sub], cv2.MORPH_OPEN, _K3)
            self._profiles = (base, [_highpass(cv2.reduce(base, axis, cv2.REDUCE_AVG, dtype=cv2.CV_32F).ravel())
                                     for axis in (0, 1)])
            self._profiled = 0
        self._profiled += 1
        opened, profiles = self._profiles  # the background opened, its column and row profiles high-passed
        frame = cv2.morphologyEx(half[sub], cv2.MORPH_OPEN, _K3)
        # 0: column profile -> x shift; 1: row profile -> y shift
        shifts = [_profile_shift(profiles[axis], cv2.reduce(frame, axis, cv2.REDUCE_AVG, dtype=cv2.CV_32F).ravel(),
                                 MAX_FOLLOW // 2) for axis in (0, 1)]
        if (shifts[0] is None) != (shifts[1] is None):
            # a pan along one axis changes the other profile as ground enters and leaves the view:
            # that one is taken again over the ground both views share
            axis = 0 if shifts[0] is None else 1
            shifts[axis] = _overlap_shift(opened, frame, axis, int(round(shifts[1 - axis])))
        if shifts[0] is None or shifts[1] is None:
            return 0, 0
        shifts = [2 * v for v in shifts]
        dx, dy = (int(round(v)) for v in shifts)
        if (dx == 0 and dy == 0) or not _fits_better(half, self.base, dx, dy):
            return 0, 0
        h, w = half.shape
        m = np.float32([[1, 0, dx], [0, 1, dy]])

        def move(image: np.ndarray) -> np.ndarray:
            return cv2.warpAffine(image, m, (w, h), flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
        fine = np.float32([[1, 0, shifts[0]], [0, 1, shifts[1]]])
        self._panned += shifts
        self.background = cv2.warpAffine(self.background, fine, (w, h), flags=cv2.INTER_LINEAR,
                                         borderMode=cv2.BORDER_REPLICATE)
        self._fill_entered(half, (max(dx, 0), max(-dx, 0), max(dy, 0), max(-dy, 0)))
        self.base = cv2.convertScaleAbs(self.background)
        self._profiles = None
        if self._previous is not None:
            self._previous = move(self._previous)
        if self._persist is not None:
            self._persist = move(self._persist)
        return dx, dy

    def register(self, half: np.ndarray) -> bool:
        """Turn and scale the learnt background with the view: the vehicle yawing or rolling, closing
        on or leaving the ground, or drifting across it a fraction of a pixel a frame
        (:meth:`follow` takes whole-pixel translation only: a row or column profile says nothing
        about a turn).

        Lucas-Kanade optical flow (OpenCV) at half the working resolution from a grid of
        ``TURN_GRID`` points of the learnt background to this frame (the background's brightness
        matched to the frame's first: the flow takes brightness for constant, and an exposure ramp
        read as a turn), and the similarity transform (turn, scale, shift) that fits them (RANSAC:
        particles on a point are outliers).  The first move is made when the transform moves
        some corner of the frame by more than ``TURN_MIN`` working pixels, ``TURN_INLIERS`` points
        agree with it, the background so moved lies closer to the frame by ``TURN_GAIN`` (:meth:`_misfit`)
        than where it is and than moved the other way -- resampled by a fraction of a pixel any
        background comes out smoother and fits a noisy frame a little better, whichever way -- and
        the look before found the view moving the same way (a still view's looks point anywhere).
        From then on the view is followed every frame, each move made however small while it fits
        better than none and than its reverse, until ``TURN_STILL_LOOKS`` looks in a row find the
        view still (no corner moving ``TURN_STILL``) or the moves of the last ``TURN_DRIFT_LOOKS``
        cancel out (:meth:`_drifted`); a look whose move is turned down does not count as still
        (a slow approach's estimates are noisy with particles on the points).
        Looks every ``TURN_EVERY`` frames while the view holds still, none in the first
        ``TURN_AFTER``.

        While it follows, the flow is taken from the frame the background was last moved to fit
        (both opened with ``FLOW_OPEN``, which takes the particles out) instead of from the learnt
        background: a background learnt while the view grows or turns every frame is a blur of
        where the ground was, and particles flowing faster than the ground (nearer) pulled the
        fit.  A move smaller than ``TURN_STEP`` waits for the next look, measured over more frames
        then.  And as the vehicle closes on the ground its lamp lights it more (``BRIGHTEN``).
        Figures and cost: docs/decisions/001-contrast-tuning.md.
        Returns True when it moved the background."""
        if self._frames < self.TURN_AFTER:  # the first frames' background is mostly a guess
            return False
        if self._turn_wait > 0 and not self._turn_moving:
            self._turn_wait -= 1
            return False
        self._turn_wait = self.TURN_EVERY - 1 if self._frames >= self.WARMUP else 0
        if self.defer_looks and not self._turn_moving and self._turn_last is None:
            # a routine look at a still view cannot move it (that takes two looks that agree): it is
            # taken after the detections are out (:meth:`look_deferred`)
            self._look_due = True
            return False
        return self._look(half)

    def look_deferred(self, half: np.ndarray) -> None:
        """The routine look :meth:`register` left for after this frame's detections (call before
        :meth:`learn`, with the frame :meth:`estimate` had): the same look, on the same
        background; if it sees the view move, the next frame looks again, before its detection."""
        if self._look_due:
            self._look_due = False
            self._look(half)

    def _look(self, half: np.ndarray) -> bool:
        """One look at the view's flow (see :meth:`register`); True when it moved the background."""
        h, w = half.shape
        size = (w // 2, h // 2)
        if min(size) < 32:
            return False
        if self._turn_size != size:  # the grid, at half the working resolution
            (nx, ny), self._turn_size = self.TURN_GRID, size
            ys, xs = np.mgrid[0:ny, 0:nx]
            self._turn_grid = np.column_stack([(xs.ravel() + 0.5) * size[0] / nx, (ys.ravel() + 0.5) * size[1] / ny]
                                              ).astype(np.float32).reshape(-1, 1, 2)
        small = cv2.resize(half, size, interpolation=cv2.INTER_AREA)
        total = cv2.sumElems(small)[0]
        ref = self._look_ref
        chained = self._turn_moving and ref is not None and ref.shape == small.shape
        if chained:  # following: from the frame the background was last moved to fit, particles out
            source = cv2.convertScaleAbs(ref, alpha=total / max(cv2.sumElems(ref)[0], 1.0))
            source, target = (cv2.morphologyEx(image, cv2.MORPH_OPEN, self.FLOW_OPEN) for image in (source, small))
        else:
            small_base = cv2.resize(self.base, size, interpolation=cv2.INTER_AREA)
            gain = total / max(cv2.sumElems(small_base)[0], 1.0)  # an exposure change not yet followed
            source, target = cv2.convertScaleAbs(small_base, alpha=gain), small
        points = self._turn_grid
        moved, status, _ = cv2.calcOpticalFlowPyrLK(source, target, points, None, winSize=(11, 11), maxLevel=2,
                                                    criteria=_LK_STOP, minEigThreshold=1e-5)
        ok = status.ravel() == 1
        if ok.sum() < self.TURN_INLIERS:
            return False
        # in working pixels: the half-resolution pixel centres map as u = 2 x + 0.5
        m, inliers = cv2.estimateAffinePartial2D(2 * points[ok] + 0.5, 2 * moved[ok] + 0.5, method=cv2.RANSAC,
                                                 ransacReprojThreshold=1.0, maxIters=100)
        if m is None or int(inliers.sum()) < self.TURN_INLIERS:
            return False
        if chained:  # the pans made since are in the background already
            m[:, 2] -= m[:, :2] @ self._panned
        corners = np.array([[0.0, 0.0], [w - 1.0, 0.0], [0.0, h - 1.0], [w - 1.0, h - 1.0]])
        shift = corners @ m[:, :2].T + m[:, 2] - corners  # where the move takes each corner
        far = float(np.abs(shift).sum(axis=1).max())
        if self._turn_moving:  # every move, however small, that fits better than none and than its reverse
            if far < self.TURN_STILL:
                self._turn_still += 1
                self._turn_moving = self._turn_still < self.TURN_STILL_LOOKS
                self._drifted(None)
                return False
            self._turn_still = 0
            if chained and far < self.TURN_STEP:  # measured again over more frames at the next look
                self._drifted(None)
                return False
            if not chained and not self._fits_better(half, m, gain, 0.0):
                self._drifted(None)
                return False  # a poor estimate this frame: the view still counts as moving
            self._move_to(m, half, small)
            self._drifted(shift)
            return True
        last, self._turn_last = self._turn_last, None
        if far <= self.TURN_MIN:
            return False
        if not self._fits_better(half, m, gain, self.TURN_GAIN):
            if last is not None and self._turn_retries < self.TURN_RETRIES and self._frames < self.WARMUP:
                # the look before saw the view move and this one's estimate was poor: look again next frame
                self._turn_last, self._turn_wait = last, 0
                self._turn_retries += 1
            return False
        self._turn_retries = 0
        self._turn_last = shift
        self._turn_wait = 0  # look again next frame
        if last is None or float((last * shift).sum()) < 0.25 * float((last * last).sum()):
            return False  # the first look that saw it, or one that saw the view move another way
        self._move_to(m, half, small)
        self._turn_moving, self._turn_still, self._turn_moves = True, 0, []
        return True

    def _move_to(self, m: np.ndarray, half: np.ndarray, small: np.ndarray) -> None:
        """A look's move: the background moved by ``m`` now fits this frame (``small``: at half
        the working resolution), which the next look's flow starts from."""
        self._move_background(m, half)
        self._look_ref = small
        self._panned = np.zeros(2)

    def _drifted(self, shift: np.ndarray | None) -> None:
        """While following a turning view: this look's move of the frame's corners (None: none made).
        Over the last ``TURN_DRIFT_LOOKS`` looks the moves of a view that holds still cancel -- each
        look's estimate, noisy with particles on the points, moves the background a little, and
        the next takes it back -- where a turning or zooming view's add up; when they sum to less
        than ``TURN_STILL`` a look on average the view is still (counted one look at a time, a
        still view's estimates stay over ``TURN_STILL`` most of the time)."""
        if not self._turn_moving:
            return
        self._turn_moves = (self._turn_moves + [np.zeros((4, 2)) if shift is None else shift])[-self.TURN_DRIFT_LOOKS:]
        if len(self._turn_moves) < self.TURN_DRIFT_LOOKS:
            return
        net = float(np.abs(np.sum(self._turn_moves, axis=0)).sum(axis=1).max())
        if net < self.TURN_STILL * self.TURN_DRIFT_LOOKS:
            self._turn_moving, self._turn_still, self._turn_moves = False, 0, []

    def _fits_better(self, half: np.ndarray, m: np.ndarray, gain: float, margin: float) -> bool:
        """True when the background moved by ``m`` lies closer to the frame, by ``margin`` (a share),
        than both where it is and moved the reverse way (resampled by a fraction of a pixel any
        background comes out smoother and fits a noisy frame a little better, whichever way)."""
        rivals = min(self._misfit(half, None, gain), self._misfit(half, cv2.invertAffineTransform(m), gain))
        return self._misfit(half, m, gain) < (1.0 - margin) * rivals

    def _misfit(self, half: np.ndarray, move: np.ndarray | None, gain: float) -> float:
        """How far the background moved by ``move`` (None: where it is) lies from the frame: the
        summed difference over every 4th row (the background warped for those rows alone), each
        pixel's capped at 3 noise units so particles count as little as they can."""
        rows = slice(None, None, 4)
        seen = self.background[rows]
        if move is not None:
            inverse = cv2.invertAffineTransform(move)
            inverse[:, 1] *= 4  # the check's row y' is the frame's row 4 y'
            seen = cv2.warpAffine(self.background, inverse, (half.shape[1], seen.shape[0]),
                                  flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE)
        cap = max(3.0 * self._typical_noise, 2.0)
        return cv2.sumElems(cv2.min(cv2.absdiff(half[rows], cv2.convertScaleAbs(seen, alpha=gain)), cap))[0]

    def _move_background(self, m: np.ndarray, half: np.ndarray) -> None:
        """Move the learnt background (and the learning's per-pixel state) by the affine map ``m``;
        what came into view is this frame's, as for a pan (:meth:`_fill_entered`), wherever it lies.
        Bicubic: the view moving a fraction of a pixel every frame, bilinear resampling blurred the
        background frame after frame."""
        h, w = self.background.shape
        self.background = cv2.warpAffine(self.background, m, (w, h), flags=cv2.INTER_CUBIC,
                                         borderMode=cv2.BORDER_REPLICATE)
        if self.BRIGHTEN:  # the lamp rides with the camera: ground that grows by s came closer by s
            # and is lit s^2 brighter; the median of the last moves' s^2, as one look's s is noisy
            # (+-0.5 % for a turn over fractal ground) where a vehicle's approach is steady
            self._growths = (self._growths + [abs(float(np.linalg.det(m[:, :2])))])[-self.BRIGHTEN:]
            self.background *= np.float32(np.median(self._growths))
            np.minimum(self.background, 255.0, out=self.background)
        entered = cv2.warpAffine(np.ones((h, w), np.uint8), m, (w, h), flags=cv2.INTER_NEAREST,
                                 borderMode=cv2.BORDER_CONSTANT, borderValue=0) == 0
        np.copyto(self.background, half, where=entered, casting="unsafe")  # the ground that came into view
        self.base = cv2.convertScaleAbs(self.background)
        for name in ("_previous", "_persist"):
            image = getattr(self, name)
            if image is not None:
                setattr(self, name, cv2.warpAffine(image, m, (w, h), flags=cv2.INTER_NEAREST,
                                                   borderMode=cv2.BORDER_REPLICATE))
        self._profiles = None

    def match_gain(self, half: np.ndarray) -> float:
        """Follow a change of the whole scene's brightness at once: the camera's exposure or gain
        stepping or drifting (auto-exposure), the lamp dimmed, the vehicle closing on the ground.
        Learning alone lags such a change by many frames, and every pixel of textured ground
        then shows as a particle.

        The change from the last frame is the ratio of the two frames' sums over about
        ``GAIN_SAMPLES`` pixels of rows spread over the frame whose learnt background is at
        least ``GAIN_MIN_LEVEL``, leaving out those whose difference is far from the typical
        one (particles, moving, are a few per cent of them).  The two frames being alike, it is unbiased whatever the
        noise's shape; a median of ratios stuck at exactly 1 on whole grey levels, and pixels
        chosen by either frame's brightness biased it by their noise.  Its standard error
        comes from what the ratio leaves unexplained.  The changes are multiplied up, with
        their variances, until their product differs from 1 by more than ``GAIN_STEP`` and
        ``GAIN_SIGMAS`` standard errors; the learnt background is then scaled by it.  Nothing is
        read across a pan (:meth:`follow` moved the background: the sampled pixels saw other
        ground) or when the frames differ by more than a
        brightness change and ``GAIN_SPREAD`` times the noise (the view moved by less than
        ``follow`` takes up, or the scene changed).  During the warm-up the background learns
        fast enough to follow by itself.  Figures and cost: docs/decisions/001-contrast-tuning.md.
        Returns the factor applied (1.0: none)."""
        if self._gain_shape != half.shape:
            h, w = self._gain_shape = half.shape
            # whole rows spread over the frame, read as contiguous memory (every pixel sees the
            # same exposure): enough of them for GAIN_SAMPLES pixels
            count = max(2, min(h, -(-self.GAIN_SAMPLES // w)))
            self._gain_rows = (np.arange(count) * (h - 1) // (count - 1)).astype(np.intp)
            self._gain_age = self.bands
            self._gain_last = None
        # those rows of this frame and of the last (a copy: the frame itself is not kept alive)
        rows, previous = half[self._gain_rows], self._gain_last
        self._gain_last = rows
        if not self.learnt() or previous is None:
            return 1.0
        if self._gain_age >= self.bands:  # the pixels used, chosen again as the background is learnt:
            # by the learnt background -- chosen by either frame, their noise would bias the ratio
            self._gain_pixels = np.flatnonzero(self.background[self._gain_rows] >= self.GAIN_MIN_LEVEL)
            self._gain_age = 0
        self._gain_age += 1
        if len(self._gain_pixels) < self.GAIN_SAMPLES // 10:
            return 1.0
        now = rows.reshape(-1).take(self._gain_pixels).astype(np.float32)
        before = previous.reshape(-1).take(self._gain_pixels).astype(np.float32)
        diff = now - before
        middle = _middle(diff)
        deviation = np.abs(diff - middle)
        # particles (and the odd noise spike) out: differences far from the typical one.  Centred
        # on the median difference: a sum ratio over all pixels would be pulled by particles --
        # in the dense cloud those pixels whose background is lit at all are mostly where
        # particles were, and are leaving -- and 0.5 % a frame added up to false steps of 25 %
        keep = deviation <= 2.5 * 1.4826 * _middle(deviation) + 1.0
        if np.count_nonzero(keep) < self.GAIN_SAMPLES // 10:
            return 1.0
        now, before = now[keep], before[keep]
        total = float(before.sum())
        if total <= 0.0:  # the last frame black there (particles the background learnt have gone)
            return 1.0
        ratio = float(now.sum()) / total
        left = now - np.float32(ratio) * before
        residual = math.sqrt(max(float(np.dot(left, left)) / len(left) - (float(left.sum()) / len(left)) ** 2, 0.0))
        if residual > self.GAIN_SPREAD * math.sqrt(2.0) * self._typical_noise:
            self._gain, self._gain_var = 1.0, 0.0  # not the same view: nothing to read
            return 1.0
        # (the kept pixels' spread is cut at the window: never below the two frames' noise)
        error = max(residual, math.sqrt(2.0) * self._typical_noise) * math.sqrt(len(now)) / total
        self._gain *= ratio
        self._gain_var += error * error
        change = self._gain
        if abs(change - 1.0) <= max(self.GAIN_STEP, self.GAIN_SIGMAS * math.sqrt(self._gain_var)):
            return 1.0
        self._gain, self._gain_var = 1.0, 0.0
        self.background *= np.float32(change)
        np.minimum(self.background, 255.0, out=self.background)
        self.base = cv2.convertScaleAbs(self.background)
        self._profiles = None
        return change

    def _fill_entered(self, half: np.ndarray, depths: tuple[int, int, int, int]) -> None:
        """The ground that came into view with a pan has nothing learnt: its background is this
        frame itself, over a band along each edge ``depths`` (left, right, top, bottom) pixels
        deep (a turn's new ground, thin wedges along every edge, is filled the same way by
        :meth:`_move_background`); a particle in it is taken for ground for a frame (it
        moves on, off what was learnt of it).  Repeating the edge, or the frame's spatial
        background, there showed the ground's texture as particles at the leading edge."""
        h, w = half.shape
        for edge, d in enumerate(depths):
            if d <= 0:
                continue
            size = w if edge < 2 else h
            a, b = (0, d) if edge % 2 == 0 else (size - d, size)  # the band [a, b) along this edge
            strip = (slice(None), slice(a, b)) if edge < 2 else (slice(a, b), slice(None))
            self.background[strip] = half[strip]
