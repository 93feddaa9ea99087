"""Each dim hole's own light: just enough for its particle to stay visible."""

import numpy as np
import pytest

from antiscatter.detections import Detections
from antiscatter.levels import HoleLevels
from antiscatter.pattern import render_pattern


def seen(scores, ids):
    n = len(scores)
    return Detections(np.zeros((n, 2)), np.ones(n), np.asarray(scores, float)), np.asarray(ids, np.int64)


def test_a_dimmed_particle_is_brought_to_the_target_flux_at_most_halving_a_frame():
    levels = HoleLevels(0.1, floor=0.005, target=40.0)
    found, ids = seen([400.0], [7])
    levels.update(found, ids, dimmed=np.array([7]), alive=np.array([7]), confirmed=np.array([7]))
    # at 0.1 it sent back 400: 40 needs 0.01, but a level falls at most by half a frame
    assert levels.of(np.array([7]))[0] == pytest.approx(0.05)
    found, ids = seen([200.0], [7])  # at 0.05, 200: on target at 0.01
    levels.update(found, ids, dimmed=np.array([7]), alive=np.array([7]), confirmed=np.array([7]))
    assert levels.of(np.array([7]))[0] == pytest.approx(0.025)
    found, ids = seen([100.0], [7])
    levels.update(found, ids, dimmed=np.array([7]), alive=np.array([7]), confirmed=np.array([7]))
    assert levels.of(np.array([7]))[0] == pytest.approx(0.0125)
    found, ids = seen([50.0], [7])
    levels.update(found, ids, dimmed=np.array([7]), alive=np.array([7]), confirmed=np.array([7]))
    assert levels.of(np.array([7]))[0] == pytest.approx(0.01)  # on target: it stays
    # a faint one asks for more than the ceiling: it gets the ceiling
    found, ids = seen([10.0], [7])
    levels.update(found, ids, dimmed=np.array([7]), alive=np.array([7]), confirmed=np.array([7]))
    assert levels.of(np.array([7]))[0] == pytest.approx(0.04)
    found, ids = seen([1.0], [7])
    levels.update(found, ids, dimmed=np.array([7]), alive=np.array([7]), confirmed=np.array([7]))
    assert levels.of(np.array([7]))[0] == pytest.approx(0.1)


def test_a_particle_lost_under_its_hole_gets_twice_the_light_and_never_less_again():
    levels = HoleLevels(0.1, floor=0.02, target=40.0)
    found, ids = seen([4000.0], [3])  # new, seen in full light: straight to what it needs (the floor here)
    levels.update(found, ids, dimmed=None, alive=np.array([3]), confirmed=np.array([3]))
    assert levels.of(np.array([3]))[0] == pytest.approx(0.02)
    nothing = Detections.empty(), np.empty(0, np.int64)
    levels.update(*nothing, dimmed=np.array([3]), alive=np.array([3]), confirmed=np.array([3]))
    assert levels.of(np.array([3]))[0] == pytest.approx(0.04)  # missed in the dark of its own hole
    found, ids = seen([4000.0], [3])
    levels.update(found, ids, dimmed=np.array([3]), alive=np.array([3]), confirmed=np.array([3]))
    assert levels.of(np.array([3]))[0] == pytest.approx(0.04)  # as bright as ever: not below 0.04
    # a track missed while it had no hole on it (a miss of the detector's): its level stays
    levels.update(*nothing, dimmed=None, alive=np.array([3]), confirmed=np.array([3]))
    assert levels.of(np.array([3]))[0] == pytest.approx(0.04)


def test_only_confirmed_tracks_are_turned_down():
    # a tentative track's hole goes out when it misses its particle: it keeps the ceiling until confirmed
    levels = HoleLevels(0.1, floor=0.02, target=40.0)
    found, ids = seen([4000.0, 4000.0], [1, 2])
    levels.update(found, ids, dimmed=np.array([1, 2]), alive=np.array([1, 2]), confirmed=np.array([2]))
    assert levels.of(np.array([1, 2])) == pytest.approx([0.1, 0.05])
    levels.update(found, ids, dimmed=np.array([1, 2]), alive=np.array([1, 2]), confirmed=np.array([1, 2]))
    assert levels.of(np.array([1, 2])) == pytest.approx([0.05, 0.025])  # from the ceiling, by half


def test_unknown_tracks_untracked_holes_and_scores_that_are_no_flux_get_the_ceiling():
    levels = HoleLevels(0.2, floor=0.02, target=40.0)
    found, ids = seen([np.nan, 500.0, 500.0], [1, 2, -1])  # the seed detector's scores are NaN
    levels.update(found, ids, dimmed=np.array([1, 2]), alive=np.array([1, 2]), confirmed=np.array([1, 2]))
    assert levels.of(np.array([1, 2, -1, 99])) == pytest.approx([0.2, 0.1, 0.2, 0.2])
    assert levels.grey(np.array([1, 2])).tolist() == [51, 26]
    # tracks the tracker no longer holds are forgotten
    levels.update(Detections.empty(), np.empty(0, np.int64), dimmed=None, alive=np.array([1]),
                  confirmed=np.array([1]))
    assert levels.ids.tolist() == [1] and levels.of(np.array([2]))[0] == pytest.approx(0.2)
    with pytest.raises(ValueError, match="floor, ceiling"):
        HoleLevels(0.1, floor=0.2)
    with pytest.raises(ValueError, match="target, fall, rise"):
        HoleLevels(0.1, target=0.0)


def test_holes_drawn_at_their_own_levels_the_brighter_where_they_overlap():
    holes = Detections(np.array([[100.0, 100.0], [110.0, 100.0], [300.0, 200.0]]), np.array([8.0, 8.0, 5.0]))
    pattern = render_pattern(holes, size=(400, 300), hole=np.array([5, 40, 20], np.uint8))
    assert pattern[100, 94] == 5 and pattern[100, 116] == 40 and pattern[200, 300] == 20
    assert pattern[100, 105] == 40  # both holes: each particle there must stay visible
    assert pattern[0, 0] == 255
    with pytest.raises(ValueError, match="3 levels for 2 detections"):
        render_pattern(holes[np.array([0, 1])], size=(400, 300), hole=np.array([1, 2, 3]))


def test_ids_the_tracker_no_longer_holds_touch_no_other_track():
    # the holes of the last exposure may belong to tracks deleted since: they are nobody's miss
    levels = HoleLevels(0.1, floor=0.02, target=40.0)
    found, ids = seen([4000.0], [1])
    levels.update(found, ids, dimmed=np.array([1, 999]), alive=np.array([1, 2]), confirmed=np.array([1, 2, 998]))
    assert levels.of(np.array([1, 2])) == pytest.approx([0.05, 0.1])  # 2: not under a hole, not missed
    assert levels.least.tolist() == [0.0, 0.0]


def test_a_confirmed_track_just_found_rests_in_the_dark_through_the_next_exposure():
    levels = HoleLevels(0.1, floor=0.02, target=40.0, rest=1)
    alive = dict(alive=np.array([4, 9]), confirmed=np.array([4]))  # 9 is tentative: it never rests
    found, ids = seen([2000.0, 2000.0], [4, 9])  # both seen lit in full
    levels.update(found, ids, dimmed=None, **alive)
    assert list(levels.resting) == [4]
    assert levels.of(np.array([4, 9, -1])) == pytest.approx([0.0, 0.1, 0.1])  # 4's hole dark
    # not found in the dark of its hole: expected -- no more light for it, no less either
    nothing = Detections.empty(), np.empty(0, np.int64)
    levels.update(*nothing, dimmed=np.array([4, 9]), rested=np.array([4]), **alive)
    assert len(levels.resting) == 0
    assert levels.of(np.array([4])) == pytest.approx([0.02])  # target / flux = 0.02, as before
    assert levels.least[0] == 0.0  # a miss in the dark of a resting hole is no ratchet
    # dimmed and found again: it rests again
    found, ids = seen([40.0], [4])
    levels.update(found, ids, dimmed=np.array([4, 9]), **alive)
    assert list(levels.resting) == [4] and levels.of(np.array([4])) == pytest.approx([0.0])
    # found although its hole was dark: the hole missed it -- seen lit in full, it is looked at next
    found, ids = seen([800.0], [4])
    levels.update(found, ids, dimmed=np.array([4, 9]), rested=np.array([4]), **alive)
    assert len(levels.resting) == 0 and levels.of(np.array([4])) == pytest.approx([0.05])  # 40 / 800
    # dimmed and missed: twice the light, and no rest until it is found
    levels.update(*nothing, dimmed=np.array([4, 9]), **alive)
    assert len(levels.resting) == 0 and levels.of(np.array([4])) == pytest.approx([0.1])


def test_rest_counts_frames_and_zero_never_rests():
    found, ids = seen([40.0], [1])
    nothing = Detections.empty(), np.empty(0, np.int64)
    kept = HoleLevels(0.1, rest=0)
    kept.update(found, ids, dimmed=np.array([1]), alive=np.array([1]), confirmed=np.array([1]))
    assert len(kept.resting) == 0 and kept.of(np.array([1]))[0] > 0
    two = HoleLevels(0.1, rest=2)
    two.update(found, ids, dimmed=np.array([1]), alive=np.array([1]), confirmed=np.array([1]))
    assert list(two.resting) == [1]
    two.update(*nothing, dimmed=np.array([1]), rested=np.array([1]), alive=np.array([1]), confirmed=np.array([1]))
    assert list(two.resting) == [1]  # the second frame of its rest
    two.update(*nothing, dimmed=np.array([1]), rested=np.array([1]), alive=np.array([1]), confirmed=np.array([1]))
    assert len(two.resting) == 0  # looked at next
    two.update(*nothing, dimmed=None, alive=np.empty(0, np.int64), confirmed=np.empty(0, np.int64))
    assert len(two.resting) == 0 and len(two.ids) == 0
    for bad in (-1, 1.5, "1"):
        with pytest.raises(ValueError, match="rest: got"):
            HoleLevels(0.1, rest=bad)
