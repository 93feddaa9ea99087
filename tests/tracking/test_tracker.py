"""The tracker on synthetic tracks with known ids and motion."""

import numpy as np
import pytest

from antiscatter.detections import Detections
from antiscatter.tracking import Tracker

DT = 1 / 60


def run(tracker, positions, radii=3.0):
    """positions: (frames, N, 2) with NaN for missing; returns the track id of each particle per frame."""
    ids = []
    for f, frame in enumerate(positions):
        present = ~np.isnan(frame[:, 0])
        tracks = tracker.update(Detections(frame[present], np.full(present.sum(), radii)), f * DT)
        row = np.full(len(frame), -1)
        row[present] = tracks.detection_ids
        ids.append(row)
    return np.array(ids)


def test_straight_lines_keep_their_ids_and_velocities():
    rng = np.random.default_rng(0)
    start = rng.uniform(50, 750, (40, 2))
    velocity = rng.uniform(-150, 150, (40, 2))
    t = np.arange(60)[:, None, None] * DT
    positions = start + velocity * t + rng.normal(0, 0.3, (60, 40, 2))
    tracker = Tracker()
    ids = run(tracker, positions)
    assert (ids == ids[0]).all()  # every particle keeps its first id
    assert len(set(ids[0].tolist())) == 40
    order = np.argsort(tracker.ids)
    error = np.abs(tracker.x[order, 2:4] - velocity[np.argsort(ids[0])])
    assert error.mean() < 12  # px/s: 0.3 px noise at 60 fps differentiates to ~25 px/s raw


def test_curved_tracks():
    t = np.arange(90) * DT
    angle = 2 * np.pi * 0.5 * t  # half a turn per second, radius 60 px
    a = np.column_stack([400 + 60 * np.cos(angle), 300 + 60 * np.sin(angle)])
    b = np.column_stack([150 + 100 * t, 100 + 30 * np.sin(4 * t)])
    ids = run(Tracker(), np.stack([a, b], axis=1))
    assert (ids[:, 0] == ids[0, 0]).all() and (ids[:, 1] == ids[0, 1]).all()


def test_crossing_particles_keep_their_ids():
    t = np.arange(60) * DT
    a = np.column_stack([100 + 300 * t, 200 + 0 * t])
    b = np.column_stack([200 + 0 * t, 100 + 300 * t])  # crosses a's path near frame 20
    ids = run(Tracker(), np.stack([a, b], axis=1))
    assert len(set(ids[:, 0].tolist())) == 1 and len(set(ids[:, 1].tolist())) == 1


def test_short_disappearance_keeps_the_id_and_long_one_does_not():
    t = np.arange(40) * DT
    path = np.column_stack([100 + 200 * t, 300 - 100 * t])[:, None, :].copy()
    gap = path.copy()
    gap[15:19] = np.nan  # 4 missing frames < max_misses = 5
    ids = run(Tracker(max_misses=5), gap)
    seen = ids[ids >= 0]
    assert len(set(seen.tolist())) == 1
    long_gap = path.copy()
    long_gap[15:25] = np.nan
    ids = run(Tracker(max_misses=5, keep_misses=5), long_gap)
    assert len(set(ids[ids >= 0].tolist())) == 2
    ids = run(Tracker(max_misses=5, keep_misses=12), long_gap)  # 10 misses: the identity is kept
    assert len(set(ids[ids >= 0].tolist())) == 1
    with pytest.raises(ValueError, match="keep_misses"):
        Tracker(max_misses=5, keep_misses=4)


def test_a_lost_track_keeps_its_hole_for_max_misses_and_its_id_for_keep_misses():
    tracker = Tracker(max_misses=3, keep_misses=8)
    velocity = np.array([200.0, -100.0])
    holes = []
    for f in range(30):
        seen = not 10 <= f < 18  # lost for 8 frames
        centre = np.array([100.0, 300.0]) + velocity * f * DT
        tracks = tracker.update(Detections([centre], [3.0]) if seen else Detections.empty(), f * DT)
        holes.append(len(tracker.holes(f * DT)))
        if f == 9:
            first = int(tracks.ids[0])
    assert holes[10:13] == [1, 1, 1] and holes[13:18] == [0] * 5  # coasting for 3 frames, then no hole
    assert tracks.detection_ids.tolist() == [first] and holes[18] == 1  # back with its id


def test_a_track_found_after_its_hole_went_keeps_its_id_but_starts_its_motion_afresh():
    tracker = Tracker(max_misses=3)  # keep_misses by default 12
    velocity = np.array([300.0, 0.0])
    for f in range(10):
        tracks = tracker.update(Detections([np.array([100.0, 200.0]) + velocity * f * DT], [3.0]), f * DT)
    first = int(tracks.ids[0])
    for f in range(10, 16):  # lost for 6 frames: past max_misses, within keep_misses
        tracker.update(Detections.empty(), f * DT)
    # found again 6 px short of where its motion would have taken it (inside its gate, which its
    # steady motion has narrowed to 9 px): another particle, or the same one slowed -- its old
    # motion is stale
    tracks = tracker.update(Detections([[174.0, 200.0]], [3.0]), 16 * DT)
    assert tracks.detection_ids.tolist() == [first]
    assert not tracks.confirmed[0] and np.allclose(tracks.velocities[0], 0.0)
    assert tracker.qa[0] == tracker.accel_noise  # its motion not known again: a new track's noise
    hole = tracker.holes(16 * DT + 0.02)  # seen once since: its hole where it was seen, not moved on
    assert np.allclose(hole.centres[0], [174.0, 200.0], atol=0.5)
    # within max_misses the motion is kept: the hole moves on
    tracker = Tracker(max_misses=3)
    for f in range(10):
        tracker.update(Detections([np.array([100.0, 200.0]) + velocity * f * DT], [3.0]), f * DT)
    tracker.update(Detections.empty(), 10 * DT)
    tracks = tracker.update(Detections([np.array([100.0, 200.0]) + velocity * 11 * DT], [3.0]), 11 * DT)
    assert tracks.confirmed[0] and tracks.velocities[0][0] > 250.0


def test_a_track_found_again_where_its_motion_took_it_keeps_its_motion():
    # a faint particle invisible under its own hole: its track coasts, is lost past max_misses, and
    # the particle is found again right on its path -- the same particle, moving so
    tracker = Tracker(max_misses=3)
    velocity = np.array([300.0, 0.0])
    for f in range(10):
        tracks = tracker.update(Detections([np.array([100.0, 200.0]) + velocity * f * DT], [3.0]), f * DT)
    first = int(tracks.ids[0])
    for f in range(10, 16):
        tracker.update(Detections.empty(), f * DT)
    on_path = np.array([100.0, 200.0]) + velocity * 16 * DT + [1.0, 0.5]
    tracks = tracker.update(Detections([on_path], [3.0]), 16 * DT)
    assert tracks.detection_ids.tolist() == [first]
    assert tracks.confirmed[0] and tracks.velocities[0][0] == pytest.approx(300.0, rel=0.05)


def test_a_lost_track_only_takes_a_detection_no_track_with_a_hole_wants():
    tracker = Tracker(max_misses=3, position_noise=1.5)
    for f in range(8):  # two particles at rest, 4 px apart
        tracks = tracker.update(Detections([[100.0, 100.0], [104.0, 100.0]], [2.0, 2.0]), f * DT)
    a, b = tracks.detection_ids.tolist()
    for f in range(8, 12):  # the first is lost past max_misses
        tracks = tracker.update(Detections([[104.0, 100.0]], [2.0]), f * DT)
    assert tracks.detection_ids.tolist() == [b] and a in tracks.ids.tolist()  # kept for its identity
    # the second moves 3 px towards where the first was: nearer the lost track, but its own
    tracks = tracker.update(Detections([[101.0, 100.0]], [2.0]), 12 * DT)
    assert tracks.detection_ids.tolist() == [b]


@pytest.mark.parametrize("size", [(800, 600), None])
def test_a_track_that_left_the_view_hands_its_id_to_no_newcomer(size):
    # a particle drifts out at the right edge, 4 px a frame; 3 frames after its last sighting
    # another comes in just inside that edge: within the lost track's gate, but the first particle
    # is out of sight by then (its predicted centre at 804, over 3 px, its radius, past the edge)
    tracker = Tracker(frame_size=size)
    leaving = [tracker.update(Detections([[776.0 + 4 * f, 300.0]], [3.0]), f * DT).detection_ids[0] for f in range(5)]
    for f in range(5, 7):
        tracker.update(Detections.empty(), f * DT)
    newcomer = tracker.update(Detections([[797.0, 300.0]], [3.0]), 7 * DT).detection_ids[0]
    assert len(set(leaving)) == 1
    assert (newcomer != leaving[0]) == (size is not None)  # without the view's edges it took the id


def test_motion_settings_scale_with_the_frame_width():
    wide = Tracker(frame_size=(1600, 1200), flow_neighbours=0)
    assert (wide.initial_speed, wide.accel_noise, wide.max_gate) == (800.0, 3000.0, 160.0)
    narrow = Tracker(frame_size=(640, 480))
    assert (narrow.initial_speed, narrow.accel_noise, narrow.max_gate) == (400.0, 1500.0, 80.0)
    # a particle crossing 40 px a frame: twice the same motion on a frame twice as wide as 800
    for tracker, identities in ((Tracker(flow_neighbours=0), 6), (wide, 1)):  # out of the gate: born again
        ids = [int(tracker.update(Detections([[100.0 + 40 * f, 300.0]], [3.0]), f * DT).detection_ids[0])
               for f in range(6)]
        assert len(set(ids)) == identities


def test_prediction_for_constant_velocity_is_near_exact():
    tracker = Tracker(position_noise=0.5)
    velocity = np.array([120.0, -80.0])
    for f in range(30):
        tracker.update(Detections([[200, 200] + velocity * f * DT], [4.0]), f * DT)
    holes = tracker.holes(29 * DT + 0.02)  # 20 ms of latency ahead
    expected = [200, 200] + velocity * (29 * DT + 0.02)
    assert np.hypot(*(holes.centres[0] - expected)) < 0.3
    assert holes.radii[0] >= 4.0  # grown by the prediction's uncertainty, never shrunk


def test_unconfirmed_particles_get_holes_where_seen():
    tracker = Tracker(confirm_hits=3, flow_holes=False)
    tracker.update(Detections([[50, 50]], [3.0]), 0.0)
    holes = tracker.holes(0.05)
    np.testing.assert_allclose(holes.centres, [[50, 50]])
    assert holes.radii[0] == pytest.approx(3.0)
    # with flow_holes (default) and no neighbours to take a flow from: at rest, grown by its uncertainty
    tracker = Tracker(confirm_hits=3)
    tracker.update(Detections([[50, 50]], [3.0]), 0.0)
    holes = tracker.holes(0.05)
    np.testing.assert_allclose(holes.centres, [[50, 50]])
    assert holes.radii[0] == pytest.approx(3.0 + 1.25)


def test_a_particle_seen_once_has_its_hole_moved_along_its_neighbours_flow():
    crowd = np.array([[100.0 + 60 * i, 100.0 + 70 * j] for i in range(3) for j in range(3)])
    for flow_holes, expected_x in ((True, 130.0 + 600 * 2 * DT), (False, 130.0)):
        tracker = Tracker(flow_holes=flow_holes)
        for f in range(5):  # nine particles drifting right at 600 px/s, confirmed
            tracker.update(Detections(crowd + np.array([600.0, 0.0]) * f * DT, np.full(9, 2.0)), f * DT)
        found = np.vstack([crowd + np.array([600.0, 0.0]) * 5 * DT, [[130.0, 135.0]]])
        tracks = tracker.update(Detections(found, np.full(10, 2.0)), 5 * DT)  # a newcomer among them
        new = tracks.detection_ids[-1]
        holes = tracker.holes(7 * DT)
        at = int(np.flatnonzero(holes.track_ids == new)[0])
        assert holes.centres[at, 0] == pytest.approx(expected_x, abs=0.1)  # the neighbours' filtered velocity
        assert holes.centres[at, 1] == pytest.approx(135.0, abs=1e-6)


def test_a_particle_seen_twice_moves_its_hole_before_it_is_confirmed():
    tracker = Tracker(confirm_hits=3)
    tracker.update(Detections([[50, 50]], [3.0]), 0.0)
    tracks = tracker.update(Detections([[60, 50]], [3.0]), DT)  # 600 px/s to the right
    assert not tracks.confirmed[0]
    holes = tracker.holes(2 * DT)
    # two sightings give the velocity: the hole is where the particle will be, not where it was seen
    assert holes.centres[0, 0] == pytest.approx(70, abs=1.5) and holes.centres[0, 1] == pytest.approx(50)
    assert holes.radii[0] > 3.0  # grown by the uncertainty of a two-point velocity


def test_a_particle_back_after_a_gap_gets_its_id_back_with_revive_frames():
    def gap_run(revive):
        tracker = Tracker(confirm_hits=3, max_misses=1, keep_misses=1, tentative_misses=1, revive_frames=revive)
        ids = []
        for f in range(12):
            x = 50.0 + 6 * f  # 360 px/s to the right, unseen in frames 5-7
            found = Detections.empty() if 5 <= f <= 7 else Detections([[x, 40.0]], [3.0])
            tracks = tracker.update(found, f * DT)
            ids.extend(tracks.detection_ids.tolist())
        return ids, tracker
    ids, _ = gap_run(0)
    assert len(set(ids)) == 2  # deleted after one miss; a new track when it comes back
    ids, tracker = gap_run(5)
    assert len(set(ids)) == 1  # revived: where its motion carried it
    holes = tracker.holes(11 * DT)
    assert holes.centres[0, 0] == pytest.approx(50 + 6 * 11, abs=1.0)
    # a detection far from where the dead track would be is a new particle
    tracker = Tracker(confirm_hits=3, max_misses=1, keep_misses=1, tentative_misses=1, revive_frames=5)
    for f in range(5):
        tracker.update(Detections([[50.0 + 6 * f, 40.0]], [3.0]), f * DT)
    for f in range(5, 8):
        tracker.update(Detections.empty(), f * DT)
    tracks = tracker.update(Detections([[300.0, 200.0]], [3.0]), 8 * DT)
    assert tracks.detection_ids[0] != 1
    with pytest.raises(ValueError, match="revive_frames"):
        Tracker(revive_frames=-1)


def test_empty_frames():
    tracker = Tracker()
    tracks = tracker.update(Detections.empty(), 0.0)
    assert len(tracks) == 0 and tracks.detection_ids.shape == (0,)
    assert tracker.holes(0.1).centres.shape == (0, 2)
    tracker.update(Detections([[10, 10]], [2.0]), DT)
    for f in range(2, 5):
        tracks = tracker.update(Detections.empty(), f * DT)
        assert len(tracks) == 1 and len(tracker.holes(f * DT)) == 0  # a tentative track survives 3 misses, unlit
    tracks = tracker.update(Detections.empty(), 5 * DT)
    assert len(tracks) == 0  # ... and is dropped at the fourth
    strict = Tracker(tentative_misses=0)
    strict.update(Detections([[10, 10]], [2.0]), DT)
    assert len(strict.update(Detections.empty(), 2 * DT)) == 0


def test_a_faint_new_particle_missed_once_keeps_its_id():
    tracker = Tracker()
    first = tracker.update(Detections([[50.0, 50.0]], [2.0]), 0.0).detection_ids[0]
    tracker.update(Detections.empty(), DT)
    again = tracker.update(Detections([[50.0, 50.0]], [2.0]), 2 * DT).detection_ids[0]
    assert again == first


def test_gating_prevents_absurd_matches():
    tracker = Tracker(max_gate=40)
    for f in range(5):
        tracker.update(Detections([[100 + f, 100]], [3.0]), f * DT)
    tracks = tracker.update(Detections([[400, 400]], [3.0]), 5 * DT)
    first = tracks.ids.min()
    assert tracks.detection_ids[0] != first  # a new track, not a 400 px jump


@pytest.mark.parametrize("miss_cost", [0.0, 30.0])
def test_a_track_seen_once_does_not_take_a_contested_stray_from_afar(miss_cost):
    # a particle held still; another seen once 50 px away, three frames ago (its gate has grown
    # past 50 px); then a stray detection 3.5 px beside the held one, inside both gates.  Matching
    # the most first gives the stray to the old sighting, 50 px off; a miss costing 30 px does not
    # (it is left to a new track), and the held particle keeps its track either way
    tracker = Tracker(frame_size=(800, 600), miss_cost=miss_cost)
    for f in range(8):
        centres = [[100.0, 100.0]] + ([[150.0, 100.0]] if f == 4 else []) + ([[96.5, 100.0]] if f == 7 else [])
        tracks = tracker.update(Detections(centres, np.full(len(centres), 3.0)), f * DT)
    held, stray = tracks.detection_ids
    assert held == 1
    assert stray == (2 if miss_cost == 0 else 3)


@pytest.mark.parametrize("flux_cost", [0.0, 16.0])
def test_of_two_near_detections_a_track_takes_the_one_alike_in_brightness(flux_cost):
    # a particle held still with a flux of 100; then its own detection 1.5 px off and a newcomer
    # four times as bright 1 px off, both inside its gate and within flux_ratio.  By distance
    # alone the track takes the newcomer; a flux cost keeps it on its own particle, and the
    # newcomer gets a new track
    tracker = Tracker(frame_size=(800, 600), flux_cost=flux_cost)
    for f in range(5):
        tracks = tracker.update(Detections([[100.0, 100.0]], [3.0], scores=[100.0]), f * DT)
    held = int(tracks.ids[0])
    tracks = tracker.update(Detections([[101.5, 100.0], [99.0, 100.0]], [3.0, 3.0], scores=[100.0, 400.0]), 5 * DT)
    own, newcomer = tracks.detection_ids.tolist()
    assert (own, newcomer != held) == ((held, True) if flux_cost else (held + 1, False))


def test_a_flux_cost_is_not_charged_to_a_track_under_its_own_hole():
    # the particle dimmed to a fifth under its hole, its faint detection 1 px off; a stray as
    # bright as the particle was lit, 2 px off.  Charged by flux the track would take the stray;
    # under its hole its light says nothing, and the nearer, its own, is taken
    tracker = Tracker(frame_size=(800, 600), flux_cost=16.0)
    for f in range(5):
        tracks = tracker.update(Detections([[100.0, 100.0]], [3.0], scores=[100.0]), f * DT)
    held = int(tracks.ids[0])
    tracks = tracker.update(Detections([[101.0, 100.0], [98.0, 100.0]], [3.0, 3.0], scores=[20.0, 100.0]), 5 * DT,
                            unlit=np.array([held]))
    assert tracks.detection_ids[0] == held
    lit = Tracker(frame_size=(800, 600), flux_cost=16.0)  # lit, the same detections: the stray is taken
    for f in range(5):
        lit.update(Detections([[100.0, 100.0]], [3.0], scores=[100.0]), f * DT)
    tracks = lit.update(Detections([[101.0, 100.0], [98.0, 100.0]], [3.0, 3.0], scores=[20.0, 100.0]), 5 * DT)
    assert tracks.detection_ids[1] == held


def test_coasting_keeps_the_hole_on_the_predicted_path():
    tracker = Tracker(max_misses=4)
    for f in range(10):
        tracker.update(Detections([[100 + 3 * f, 100]], [3.0]), f * DT)
    for f in range(10, 13):  # the particle went dark under its own hole
        tracker.update(Detections.empty(), f * DT)
    holes = tracker.holes(12 * DT)
    assert len(holes) == 1
    assert abs(holes.centres[0, 0] - (100 + 3 * 12)) < 1.0


def test_bad_arguments_and_time_going_back():
    with pytest.raises(ValueError, match="confirm_hits: got 0, out of range"):
        Tracker(confirm_hits=0)
    tracker = Tracker()
    tracker.update(Detections.empty(), 1.0)
    with pytest.raises(ValueError, match="earlier than the last update"):
        tracker.update(Detections.empty(), 0.5)


@pytest.mark.parametrize("floor", [1.0, 0.25])
def test_block_filter_equals_the_full_5x5_kalman_filter(floor):
    """The tracker's closed-form per-axis filter against a textbook full-matrix Kalman filter --
    and with its noise matched to the motion, against the same filter with the noise corrected by
    the averaged normalised innovation squared, step by step."""
    from antiscatter.tracking.kalman import NIS_MEMORY, NIS_RATE, WHITE_GAIN, WHITE_MEMORY

    rng = np.random.default_rng(3)
    tracker = Tracker(accel_noise=900.0, radius_noise=3.0, position_noise=0.8, radius_measurement_noise=1.2,
                      initial_speed=250.0, accel_floor=floor)
    accel, rn, pm, rm, v0 = 900.0, 3.0 ** 2, 0.8 ** 2, 1.2 ** 2, 250.0 ** 2
    nis, lag, power, last = 2.0, 0.0, 0.0, np.zeros(2)
    accels = []
    H = np.array([[1, 0, 0, 0, 0], [0, 1, 0, 0, 0], [0, 0, 0, 0, 1]], float)
    R = np.diag([pm, pm, rm])
    times = np.cumsum(rng.uniform(0.01, 0.03, 25))
    truth = np.array([100.0, 50.0])
    x = P = None
    for i, t in enumerate(times):
        z = np.array([*(truth + [120 * t, -60 * t] + rng.normal(0, 0.8, 2)), 4 + rng.normal(0, 1)])
        tracker.update(Detections([z[:2]], [z[2]]), t)
        if x is None:
            x = np.array([z[0], z[1], 0, 0, z[2]])
            P = np.diag([pm, pm, v0, v0, rm])
        else:
            dt = t - times[i - 1]
            F = np.eye(5)
            F[0, 2] = F[1, 3] = dt
            q = accel ** 2
            Q = np.zeros((5, 5))
            for p, v in ((0, 2), (1, 3)):
                Q[p, p], Q[p, v], Q[v, p], Q[v, v] = q * dt ** 4 / 4, q * dt ** 3 / 2, q * dt ** 3 / 2, q * dt ** 2
            Q[4, 4] = rn * dt
            x, P = F @ x, F @ P @ F.T + Q
            S = H @ P @ H.T + R
            innovation = z - H @ x
            u = innovation[:2] / np.sqrt([S[0, 0], S[1, 1]])
            nis = NIS_MEMORY * nis + (1 - NIS_MEMORY) * (u @ u)
            lag = WHITE_MEMORY * lag + (1 - WHITE_MEMORY) * (u @ last)
            power = WHITE_MEMORY * power + (1 - WHITE_MEMORY) * (u @ u + last @ last) / 2
            last = u
            factor = (nis / 2) ** NIS_RATE * 2 ** (WHITE_GAIN * lag / power)
            accel = min(max(accel * factor, floor * 900.0), 900.0) if floor < 1 else accel
            K = P @ H.T @ np.linalg.inv(S)
            x, P = x + K @ innovation, (np.eye(5) - K @ H) @ P
        accels.append(accel)
        assert tracker.qa[0] == pytest.approx(accel, rel=1e-9)
    if floor < 1:  # straight, steady motion: the noise fell
        assert accels[-1] < 0.5 * 900.0
    np.testing.assert_allclose(tracker.x[0], x, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose([tracker.pp[0, 0], tracker.pv[0, 0], tracker.vv[0, 0], tracker.rr[0]],
                               [P[0, 0], P[0, 2], P[2, 2], P[4, 4]], rtol=1e-9)


def test_each_tracks_noise_follows_its_own_motion():
    """A steady particle's acceleration noise falls to the floor and its gate and hole narrow; a
    wobbling one beside it keeps its noise high and its id."""
    rng = np.random.default_rng(5)
    t = np.arange(90) * DT
    steady = np.column_stack([100 + 120 * t, 300 + 40 * t])
    wobble = np.column_stack([500 + 60 * t + 6 * np.sin(2 * np.pi * 3 * t), 300 + 6 * np.cos(2 * np.pi * 3 * t)])
    positions = np.stack([steady, wobble], axis=1) + rng.normal(0, 0.3, (90, 2, 2))
    tracker = Tracker()
    ids = run(tracker, positions)
    assert (ids == ids[0]).all()
    order = [int(np.flatnonzero(tracker.ids == i)[0]) for i in ids[0]]
    floor = tracker.accel_floor * tracker.accel_noise
    assert tracker.qa[order[0]] == pytest.approx(floor)
    assert tracker.qa[order[1]] > 2 * floor  # 6 px at 3 Hz: 2100 px/s^2
    gates = tracker._gates(tracker.pp[order])
    assert gates[0] < gates[1]
    # the same particles with one noise for both: the steady one's hole grows more
    fixed = Tracker(accel_floor=1.0)
    run(fixed, positions)
    at = 89 * DT + 0.02
    assert tracker.holes(at).radii[order[0]] < fixed.holes(at).radii[order[0]]


def test_a_filter_lagging_an_accelerating_particle_keeps_its_noise_up(monkeypatch):
    """A particle speeding up steadily (900 px/s^2) is lagged by a constant-velocity filter: its
    innovations stay small -- the NIS alone would lower its noise -- but keep one sign, and their
    correlation from one sighting to the next keeps the noise up, and the prediction closer."""
    import antiscatter.tracking.kalman as kalman

    rng = np.random.default_rng(2)
    t = np.arange(121) * DT
    truth = np.column_stack([100 + 60 * t + 450 * t ** 2, 300 + 0 * t])
    seen = truth + rng.normal(0, 0.3, truth.shape)

    def follow():
        tracker = Tracker()
        errors = []
        for f in range(120):
            tracker.update(Detections([seen[f]], [3.0]), f * DT)
            errors.append(np.hypot(*(tracker.x[0, :2] + tracker.x[0, 2:4] * DT - truth[f + 1])))
        return tracker.qa[0], np.mean(errors[60:])

    noise, error = follow()
    monkeypatch.setattr(kalman, "WHITE_GAIN", 0.0)
    nis_noise, nis_error = follow()
    assert noise == pytest.approx(1500.0) and nis_noise < 0.7 * noise
    assert error < 0.9 and nis_error > 1.4 * error


def test_a_track_in_the_dark_of_its_own_hole_lives_on_with_max_dark():
    def run(max_dark, **kw):
        tracker = Tracker(max_dark=max_dark, **kw)
        for f in range(4):  # confirmed, moving right at 2 px per frame
            tracker.update(Detections([[100.0 + 2 * f, 50.0]], [3.0]), f * DT)
        first = int(tracker.ids[0])
        for f in range(4, 12):  # under its hole: unseen, and expected so
            tracker.update(Detections.empty(), f * DT, unlit=np.array([first]))
        holed = len(tracker.holes(11 * DT)) == 1
        tracks = tracker.update(Detections([[100.0 + 2 * 12, 50.0]], [3.0]), 12 * DT)
        run.confirmed, run.vx = bool(tracks.confirmed[0]), float(tracks.velocities[0, 0]) * DT
        return holed, int(tracks.detection_ids[0]) == first

    assert run(10) == (True, True)  # 8 dark frames: its hole still on its path, and the particle is found again
    assert run.confirmed and abs(run.vx - 2.0) < 0.3  # not lost while its hole was on: motion and confirmation kept
    assert run(0, keep_misses=5) == (False, False)  # expected misses count like any: no hole, no track after 5
    assert run(0) == (False, True)  # by default no hole after 5, the id kept for 12
    tracker = Tracker(max_dark=3)
    tracker.update(Detections([[10.0, 10.0]], [2.0]), 0.0)
    tracker.update(Detections.empty(), DT, unlit=np.array([int(tracker.ids[0])]))
    assert len(tracker.ids) == 1 and len(tracker.holes(DT)) == 0  # tentative: no dark bonus, no hole


def test_a_new_fast_particle_starts_with_its_neighbours_motion():
    # sand in a thruster wash: everything moves 25 px a frame to the right; a grain that comes into
    # view at 30 px a frame is found again in its second frame only if its track starts moving like
    # its neighbours (a track at rest has a 27 px gate)
    crowd = np.array([[100.0 + 60 * i, 100.0 + 70 * j] for i in range(4) for j in range(4)])

    def run(**kw):
        tracker = Tracker(**kw)
        for f in range(6):
            found = crowd + np.array([1500.0, 100.0]) * f * DT
            if f >= 4:  # the new grain, between the others
                found = np.vstack([found, np.array([130.0, 135.0]) + np.array([1800.0, 0.0]) * (f - 4) * DT])
            tracks = tracker.update(Detections(found, np.full(len(found), 2.0)), f * DT)
            if f == 4:
                born = int(tracks.detection_ids[-1])
        return born, int(tracks.detection_ids[-1])
    born, later = run()
    assert later == born
    born, later = run(flow_neighbours=0)  # at rest, its first move is beyond its gate: born again
    assert later != born


def _overtaking(tracker, frames=50, r=3.0):
    """Particle a (1.5 px a frame) overtakes b (0.5 px a frame) 1 px beside it: for 15 frames the
    detector sees one disc between them covering both.  Returns (ids of a, ids of b) in the frames
    they are seen apart and how many frames merged."""
    t = np.arange(frames) * DT
    a = np.column_stack([100 + 90 * t, np.full(frames, 300.0)])
    b = np.column_stack([120 + 30 * t, np.full(frames, 301.0)])
    ida, idb, merged = [], [], 0
    for f in range(frames):
        gap = float(np.hypot(*(a[f] - b[f])))
        if gap < 2 * r + 2:  # discs and halos touch: one detection at the middle
            detections = Detections([(a[f] + b[f]) / 2], [gap / 2 + r + 1])
            merged += 1
        else:
            detections = Detections(np.stack([a[f], b[f]]), [r + 1, r + 1])
        tracks = tracker.update(detections, f * DT)
        if len(detections) == 2:
            ida.append(int(tracks.detection_ids[0]))
            idb.append(int(tracks.detection_ids[1]))
    return ida, idb, merged


def test_particles_merged_in_one_detection_keep_their_ids_and_motion():
    tracker = Tracker()
    ida, idb, merged = _overtaking(tracker)
    assert merged == 15
    assert set(ida) == {ida[0]} and set(idb) == {idb[0]} and ida[0] != idb[0]
    speed = dict(zip(tracker.ids.tolist(), tracker.x[:, 2].tolist()))
    assert speed[ida[0]] == pytest.approx(90, abs=5) and speed[idb[0]] == pytest.approx(30, abs=5)


def test_without_merge_handling_the_overtaken_particle_loses_its_id():
    # with one noise for every track (the matched noise, steady here, carries both tracks through
    # this clean overtaking on their predictions alone: both ways 2 ids)
    ida, idb, _ = _overtaking(Tracker(merge_reach=0, accel_floor=1.0))
    assert len(set(ida) | set(idb)) == 3  # one of them is born again after the merge
    ida, idb, _ = _overtaking(Tracker(merge_reach=0.7, accel_floor=1.0))
    assert len(set(ida) | set(idb)) == 2


def test_two_tracks_on_one_particle_are_no_merge():
    # a duplicate track a fraction of a pixel from the first: the detection still moves the track it is
    # given to (two tracks that close are one particle seen twice, not two particles merged)
    tracker = Tracker(confirm_hits=1)
    tracker.update(Detections([[100.0, 100.0], [100.3, 100.0]], [4.0, 4.0]), 0.0)
    tracks = tracker.update(Detections([[102.0, 100.0]], [4.0]), DT)
    row = np.flatnonzero(tracks.ids == tracks.detection_ids[0])[0]
    assert tracks.centres[row, 0] == pytest.approx(102.0, abs=0.3)
    tracker = Tracker(confirm_hits=1)  # 3 px apart, both inside the disc: merged, neither moved
    tracker.update(Detections([[100.0, 100.0], [103.0, 100.0]], [4.0, 4.0]), 0.0)
    tracks = tracker.update(Detections([[101.5, 100.0]], [4.0]), DT)
    assert sorted(tracks.centres[:, 0].tolist()) == pytest.approx([100.0, 103.0])
    assert (tracks.misses == 0).all()


def test_merge_reach_must_not_be_negative():
    with pytest.raises(ValueError, match="merge_reach: got -0.1, out of range"):
        Tracker(merge_reach=-0.1)


def _faint_then_bright(tracker):
    """A faint particle (flux 50) seen once; the next frame it is under its own hole and not seen, and a
    bright one (flux 5000) comes into the lamp 12 px away, inside the new track's gate.  Returns (the
    faint one's id, the id the bright one is given)."""
    first = tracker.update(Detections([[100.0, 100.0]], [3.0], [50.0]), 0.0)
    faint = int(first.detection_ids[0])
    second = tracker.update(Detections([[112.0, 100.0]], [6.0], [5000.0]), DT, unlit=np.array([faint]))
    return faint, int(second.detection_ids[0])


def test_a_far_brighter_detection_is_not_a_faint_tracks_particle():
    # the twin's start-up: the faint track took the bright newcomer and flew off with its motion,
    # and the newcomer, the brightest source of backscatter in view, went unconfirmed for frames
    faint, bright = _faint_then_bright(Tracker())
    assert bright != faint
    faint, bright = _faint_then_bright(Tracker(flux_ratio=0))  # without the check: taken
    assert bright == faint


def _lit_lit_dimmed(last_flux):
    """Ids a particle moving 1 px a frame is given: lit, lit, under its own hole (dimmed 50 times),
    then lit again with ``last_flux`` (the first three frames' ids, the last frame's id)."""
    tracker = Tracker(confirm_hits=2)
    ids = set()
    for f, (flux, under) in enumerate([(1000.0, False), (1000.0, False), (20.0, True)]):
        tracks = tracker.update(Detections([[100.0 + f, 100.0]], [4.0], [flux]), f * DT,
                                unlit=tracker.ids.copy() if under else None)
        ids.add(int(tracks.detection_ids[0]))
    tracks = tracker.update(Detections([[103.0, 100.0]], [4.0], [last_flux]), 3 * DT)
    return ids, int(tracks.detection_ids[0]), tracker


def test_a_particle_may_fade_under_its_own_hole_and_come_back_bright():
    ids, last, tracker = _lit_lit_dimmed(1000.0)
    assert ids == {last}
    # with no hole to explain it, a detection 50 times fainter where the particle should be is another
    tracks = tracker.update(Detections([[104.0, 100.0]], [4.0], [20.0]), 4 * DT)
    assert int(tracks.detection_ids[0]) != last
    # back lit far brighter than the least light a hole leaves (MIN_LEVEL) explains: another
    ids, last, _ = _lit_lit_dimmed(20000.0)
    assert last not in ids


def test_detections_without_a_flux_are_matched_by_position_alone():
    tracker = Tracker()
    tracker.update(Detections([[100.0, 100.0]], [3.0], [50.0]), 0.0)
    tracks = tracker.update(Detections([[101.0, 100.0]], [3.0]), DT)  # scores NaN (the seed detector)
    assert tracks.detection_ids[0] == tracker.ids[0] and len(tracker.ids) == 1


def test_flux_ratio_below_one_is_rejected():
    with pytest.raises(ValueError, match="flux_ratio: got 0.5, out of range"):
        Tracker(flux_ratio=0.5)


def _fast_near_particle(tracker, frames=6, bright=(4000.0,) * 6, step=30.0):
    """Twenty faint particles (flux 50) drifting 0.5 px a frame, and from frame 2 on a bright one
    (flux ``bright[f]``) crossing ``step`` px a frame -- beyond a new track's gate, as a near
    particle does.  Returns the ids the bright one is given, frame by frame, and the last tracks."""
    rng = np.random.default_rng(3)
    faint = rng.uniform(50, 750, (20, 2))
    ids, tracks = [], None
    for f in range(frames + 2):
        centres, radii, flux = faint + [0.5 * f, 0.0], [3.0] * 20, [50.0] * 20
        if f >= 2:
            centres = np.vstack([centres, [[100.0 + step * (f - 2), 300.0]]])
            radii, flux = radii + [6.0], flux + [bright[f - 2]]
        tracks = tracker.update(Detections(centres, radii, flux), f * DT)
        if f >= 2:
            ids.append(int(tracks.detection_ids[-1]))
    return ids, tracks


def test_a_bright_fast_particle_is_found_again_beyond_a_new_tracks_gate():
    # the twin's near bubble crossing 28 px a frame among far, slow particles: born again in every
    # frame, it never had its hole where it was
    ids, tracks = _fast_near_particle(Tracker())
    assert set(ids) == {ids[0]}
    row = np.flatnonzero(tracks.ids == ids[0])[0]
    assert tracks.confirmed[row] and tracks.velocities[row, 0] == pytest.approx(30.0 / DT, rel=0.05)
    ids, _ = _fast_near_particle(Tracker(far_bright=0))
    assert len(set(ids)) == len(ids)


def test_only_alike_flux_is_found_again_far_away():
    # twice as bright in its second frame (FAR_RATIO 1.5): another particle, not this one far away
    ids, _ = _fast_near_particle(Tracker(), frames=2, bright=(4000.0, 8000.0))
    assert ids[0] != ids[1]
    # as faint as the rest: no brighter than the median, so no far search
    ids, _ = _fast_near_particle(Tracker(), frames=2, bright=(50.0, 50.0))
    assert ids[0] != ids[1]


def test_no_far_match_where_two_bright_particles_could_be_either():
    tracker = Tracker()
    faint = [[600.0 + 10 * i, 500.0] for i in range(10)]
    # two new bright tracks 40 px apart, and two bright detections 50 px on, each 51 px from one
    # track and 58 px from the other: beyond both gates, within reach of both
    first = tracker.update(Detections(faint + [[100.0, 100.0], [100.0, 140.0]], [3.0] * 10 + [6.0, 6.0],
                                      [50.0] * 10 + [4000.0, 4200.0]), 0.0)
    second = tracker.update(Detections(faint + [[150.0, 110.0], [150.0, 130.0]], [3.0] * 10 + [6.0, 6.0],
                                       [50.0] * 10 + [4100.0, 4100.0]), DT)
    born = set(first.detection_ids[-2:].tolist())
    assert not born & set(second.detection_ids[-2:].tolist())  # each could be either: both born again


def test_far_bright_below_one_is_rejected():
    with pytest.raises(ValueError, match="far_bright: got 0.5, out of range"):
        Tracker(far_bright=0.5)
