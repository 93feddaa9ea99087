"""The software camera-projector lock against a simulated free-running sensor."""

import collections

import numpy as np
import pytest

from antiscatter.lock import LOCKED_WITHIN, PhaseLock

REFRESH = 1_000_000_000 // 120
PERIOD = 2 * REFRESH
TARGET = (REFRESH - 4_000_000) // 2  # a 4 ms exposure in the middle of a refresh


def locked_from(start_ns, *, delay, shortest=16_560_000, ppm=50.0, frames=120):
    """Frames until a sensor whose clock runs ``ppm`` fast, applying each new duration ``delay``
    frames late, begins every exposure within LOCKED_WITHIN of the target; and its last errors."""
    lock = PhaseLock(REFRESH, PERIOD, TARGET, shortest_ns=shortest)
    applied = collections.deque([PERIOD] * delay)
    start, errors = start_ns, []
    for _ in range(frames):
        applied.append(lock.update(start, 0))  # (a vertical blank at 0: they repeat every refresh)
        errors.append(lock.error_ns)
        duration = applied.popleft()
        assert duration >= shortest
        start += round(max(duration, shortest) * (1 + ppm * 1e-6))
    inside = np.abs(errors) <= LOCKED_WITHIN * REFRESH
    first = next((k for k in range(frames) if inside[k:].all()), None)
    return first, errors[-10:]


@pytest.mark.parametrize("delay", [1, 2, 4, 6])
def test_the_lock_holds_the_exposures_at_the_target_from_any_phase(delay):
    for start in range(0, REFRESH, REFRESH // 9):
        first, last = locked_from(start, delay=delay)
        assert first is not None and first <= 30, (start, first)
        assert max(abs(e) for e in last) < 10_000  # a clock 50 ppm off: a few us from the target


def test_a_late_exposure_is_caught_up_the_long_way_round_when_the_sensor_cannot_shorten_its_frames():
    lock = PhaseLock(REFRESH, PERIOD, TARGET, shortest_ns=16_560_000, delay=0)
    # 3 ms late: shortening by at most 0.1 ms a frame would take 30 frames; lengthening closes it
    assert lock.update(TARGET + 3_000_000, 0) > PERIOD and lock.error_ns == 3_000_000 - REFRESH
    # 1 ms late (within a quarter refresh): shortened, as much as the sensor can
    assert lock.update(TARGET + 1_000_000, 0) == 16_560_000 and lock.error_ns == 1_000_000
    free = PhaseLock(REFRESH, PERIOD, TARGET, delay=0)  # a sensor that can shorten its frames
    assert free.update(TARGET + 3_000_000, 0) == PERIOD - round(free.gain * 3_000_000)
    assert not free.locked and free.update(TARGET + 1000, 7 * REFRESH) and free.locked  # any blank will do


def test_bad_lock_settings_are_refused():
    with pytest.raises(ValueError, match="period_ns: got 20000000, allowed a whole number of refreshes"):
        PhaseLock(REFRESH, 20_000_000, TARGET)
    with pytest.raises(ValueError, match="target_ns: got .*, allowed 0 <= target < one refresh"):
        PhaseLock(REFRESH, PERIOD, REFRESH)
    with pytest.raises(ValueError, match="gain: got 0, allowed 0 < gain <= 1"):
        PhaseLock(REFRESH, PERIOD, TARGET, gain=0)


@pytest.mark.parametrize("lag, ready, ahead", [
    (0, 11_170_000, False),  # no lag: the frame's own light reaches the next exposure after processing
    (REFRESH, 11_170_000, True),  # a refresh's lag: only the flip right after the read covers it
    (REFRESH, 7_000_000, False),  # ... unless the frame is ready before that flip
    (12_000_000, 11_170_000, False),  # 12 ms: not even that flip does (the next exposure is out of reach)
])
def test_the_light_goes_out_ahead_only_when_the_next_exposure_needs_it_before_the_frame_is_ready(lag, ready,
                                                                                               ahead):
    from antiscatter.runtime import light_ahead

    # a 4 ms exposure in the middle of a refresh's light (2.17 ms after the flip at 0 with no lag
    # or one refresh's, 5.83 ms with 12 ms), read as it ends; flips every refresh; the next
    # exposure a frame period on
    start = (TARGET + lag) % REFRESH
    next_flip = ((start + 4_000_000) // REFRESH + 1) * REFRESH
    assert light_ahead(next_flip, ready, start + PERIOD - lag, REFRESH) is ahead


@pytest.mark.parametrize("lag, ready, flip", [
    (12_000_000, 10_500_000, 2),  # 12 ms: the pattern at the flip after ready, the light at the next, for
    (13_500_000, 9_000_000, 2),   # the exposure after the next, before the next frame is read
    (12_000_000, 11_000_000, None),  # the pattern a flip later: both no longer fit before that exposure
    (14_000_000, 10_500_000, None),  # 14 ms: they do not with this processing
    (REFRESH, 10_500_000, None),  # a refresh's lag: that flip comes after the next read (the light ahead does)
    (0, 10_500_000, None),  # no lag: the frame's own light reaches the next exposure
])
def test_the_light_goes_out_after_the_pattern_only_when_it_is_due_before_the_next_read(lag, ready, flip):
    from antiscatter.runtime import light_after

    # the exposure starts in the middle of a refresh's light (flips every refresh, from 0), is read
    # 0.5 ms after its 4 ms end and is ready ``ready`` after its start; the pattern goes out at the
    # first flip after that
    start = TARGET + lag
    pattern_flip = -(-(start + ready) // REFRESH) * REFRESH
    next_read = start + PERIOD + 4_000_000 + 1_000_000
    got = light_after(pattern_flip, start + 2 * PERIOD, lag, next_read, REFRESH)
    if flip is None:
        assert got is None
    else:
        assert got == pytest.approx(pattern_flip + (flip - 1) * REFRESH)
        # its light is on before the exposure after the next begins, and still on through it
        assert got + lag <= start + 2 * PERIOD < got + lag + REFRESH - 4_000_000 + 1
        assert got < next_read
