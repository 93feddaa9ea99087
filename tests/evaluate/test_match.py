"""Matching on hand-made cases with known answers."""

import numpy as np

from antiscatter.evaluate import gates, match
from antiscatter.evaluate.metrics import hole_mask, prf, score_frame, summarise


def test_one_to_one():
    truth = np.array([[10, 10], [50, 50], [90, 20]], float)
    dets = np.array([[51, 50], [10.5, 10], [90, 21]], float)
    m, ut, ud = match(truth, np.full(3, 3.0), dets)
    assert sorted(map(tuple, m.tolist())) == [(0, 1), (1, 0), (2, 2)]
    assert len(ut) == 0 and len(ud) == 0


def test_duplicates_count_once():
    truth = np.array([[10, 10]], float)
    dets = np.array([[10, 10.5], [10.5, 10], [11, 11]], float)
    m, ut, ud = match(truth, np.array([3.0]), dets)
    assert len(m) == 1 and len(ud) == 2


def test_detection_between_two_particles_matches_only_one():
    truth = np.array([[0, 0], [6, 0]], float)
    dets = np.array([[3, 0]], float)
    m, ut, ud = match(truth, np.full(2, 3.5), dets)
    assert len(m) == 1 and len(ut) == 1 and len(ud) == 0


def test_optimal_not_greedy():
    # greedy nearest-first would pair t0-d0 and leave t1 unmatched
    truth = np.array([[0, 0], [4, 0]], float)
    dets = np.array([[2.5, 0], [-2.0, 0]], float)
    m, _, _ = match(truth, np.full(2, 3.0), dets)
    assert sorted(map(tuple, m.tolist())) == [(0, 1), (1, 0)]


def test_gate_prevents_far_matches():
    m, ut, ud = match(np.array([[0, 0]], float), np.array([2.0]), np.array([[2.5, 0]], float))
    assert len(m) == 0 and ut.tolist() == [0] and ud.tolist() == [0]


def test_empty_frames_both_ways():
    m, ut, ud = match(np.empty((0, 2)), np.empty(0), np.array([[1, 1]], float))
    assert m.shape == (0, 2) and ud.tolist() == [0]
    m, ut, ud = match(np.array([[1, 1]], float), np.array([2.0]), np.empty((0, 2)))
    assert m.shape == (0, 2) and ut.tolist() == [0]


def test_gates_rule():
    np.testing.assert_allclose(gates(np.array([0.5, 3.0]), min_gate=2.0), [2.0, 3.0])
    np.testing.assert_allclose(gates(np.array([3.0]), min_gate=2.0, scale=1.5), [4.5])


def test_many_particles_match_exactly_against_a_dense_solution():
    from scipy.optimize import linear_sum_assignment
    rng = np.random.default_rng(0)
    truth = rng.uniform(0, 400, (300, 2))
    dets = truth + rng.normal(0, 1.0, truth.shape)
    dets = np.vstack([dets, rng.uniform(0, 400, (40, 2))])
    gate = np.full(300, 3.0)
    m, _, _ = match(truth, gate, dets)
    d = np.hypot(*(truth[:, None, :] - dets[None, :, :]).transpose(2, 0, 1))
    cost = np.where(d <= 3.0, d, 1e6)
    a, b = linear_sum_assignment(cost)
    ok = cost[a, b] < 1e6
    assert len(m) == ok.sum()
    assert np.isclose(d[m[:, 0], m[:, 1]].sum(), cost[a[ok], b[ok]].sum())


def test_metrics_by_hand():
    assert prf(8, 2, 2) == (0.8, 0.8, 0.8000000000000002) or np.allclose(prf(8, 2, 2), (0.8, 0.8, 0.8))
    assert prf(0, 0, 5) == (1.0, 0.0, 0.0)  # an empty detections file: recall 0
    assert prf(0, 0, 0) == (1.0, 1.0, 1.0)
    truth = np.array([[10, 10], [30, 30], [50, 50]], float)
    counted = np.array([True, True, False])  # the third is not counted
    dets = np.array([[10, 11], [50, 50], [70, 70]], float)
    s = score_frame(0, truth, np.array([3.0, 3.0, 3.0]), counted, dets, np.array([4.0, 3.0, 3.0]))
    assert (s.tp, s.fp, s.fn) == (1, 1, 1)  # match to the uncounted particle is neither
    np.testing.assert_allclose(s.centre_errors, [1.0])
    np.testing.assert_allclose(s.radius_errors, [1.0])
    total = summarise([s, s])
    assert (total["tp"], total["fp"], total["fn"]) == (2, 2, 2)
    assert total["precision"] == 0.5 and total["recall"] == 0.5 and total["f1"] == 0.5


def test_pixel_metrics_on_small_masks():
    particle = np.zeros((20, 20), bool)
    particle[5:8, 5:8] = True  # 9 pixels
    particle[15, 15] = True  # 1 pixel, not covered
    s = score_frame(0, np.array([[6, 6], [15, 15]], float), np.array([2.0, 1.0]), np.array([True, True]),
                    np.array([[6.0, 6.0]]), np.array([2.0]), particle_mask=particle)
    holes = hole_mask((20, 20), np.array([[6.0, 6.0]]), np.array([2.0]))
    assert holes[5:8, 5:8].all()
    assert s.particle_px == 10 and s.covered_px == 9
    assert s.background_px == 390 and s.lit_px == 390 - (holes.sum() - 9)
    row = s.row()
    assert row["cancellation"] == 0.9
    assert np.isclose(row["light_kept"], (390 - (holes.sum() - 9)) / 390)
