"""Gated optimal assignment on hand-made cases with known answers."""

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from antiscatter.assignment import gates, match


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


@pytest.mark.parametrize("count, field, gate", [(300, 400, 3.0), (700, 300, 6.0)])
def test_many_particles_match_exactly_against_a_dense_solution(count, field, gate):
    # the second case's candidate groups are too many for one dense problem: solved as one sparse problem
    rng = np.random.default_rng(0)
    truth = rng.uniform(0, field, (count, 2))
    dets = truth + rng.normal(0, 1.0, truth.shape)
    dets = np.vstack([dets, rng.uniform(0, field, (40, 2))])
    m, _, _ = match(truth, np.full(count, gate), dets)
    d = np.hypot(*(truth[:, None, :] - dets[None, :, :]).transpose(2, 0, 1))
    cost = np.where(d <= gate, d, 1e6)
    a, b = linear_sum_assignment(cost)
    ok = cost[a, b] < 1e6
    assert len(m) == ok.sum()
    assert np.isclose(d[m[:, 0], m[:, 1]].sum(), cost[a[ok], b[ok]].sum())


def test_candidates_are_the_nearest_detections_inside_each_gate():
    # the sweep along x against every distance at once: each truth point's candidates are the
    # `neighbours` nearest detections within its gate, whatever the gates' sizes (crowded ones too)
    from antiscatter.assignment import _candidates

    rng = np.random.default_rng(11)
    for _ in range(300):
        nt, nd = rng.integers(1, 60), rng.integers(1, 60)
        truth, dets = rng.uniform(0, 100, (nt, 2)), rng.uniform(0, 100, (nd, 2))
        gate = rng.uniform(0.5, rng.choice([5.0, 15.0, 40.0]), nt)
        k = int(rng.integers(1, 10))
        rows, cols, dist = _candidates(truth, gate, dets, k)
        d = np.hypot(*(truth[:, None, :] - dets[None, :, :]).transpose(2, 0, 1))
        for t in range(nt):
            inside = np.flatnonzero(d[t] <= gate[t])
            nearest = inside[np.argsort(d[t, inside], kind="stable")][:k]
            assert sorted(cols[rows == t].tolist()) == sorted(nearest.tolist())
        np.testing.assert_allclose(dist, d[rows, cols])


def test_crowded_gates_still_give_an_optimal_assignment():
    # wide gates over a crowded field: far more than `neighbours` detections in most gates; the
    # matches are as many, at the same summed distance, as a dense solution over every pair
    rng = np.random.default_rng(3)
    truth = rng.uniform(0, 60, (40, 2))
    dets = truth + rng.normal(0, 1.0, truth.shape)
    gate = np.full(40, 25.0)
    m, _, _ = match(truth, gate, dets)
    d = np.hypot(*(truth[:, None, :] - dets[None, :, :]).transpose(2, 0, 1))
    a, b = linear_sum_assignment(np.where(d <= 25.0, d, 1e6))
    assert len(m) == 40
    assert np.isclose(d[m[:, 0], m[:, 1]].sum(), d[a, b].sum())


def test_bounds_keep_a_pair_out_unless_the_value_fits():
    truth = np.array([[0.0, 0.0], [10.0, 0.0]])
    dets = np.array([[1.0, 0.0], [10.5, 0.0]])
    low, high = np.array([0.0, 0.0]), np.array([5.0, np.nan])
    matches, free_truth, free_dets = match(truth, np.array([3.0, 3.0]), dets,
                                           bounds=(low, high, np.array([9.0, 100.0])))
    # the first detection's value is out of the first particle's bounds; a NaN bound checks nothing
    assert matches.tolist() == [[1, 1]] and free_truth.tolist() == [0] and free_dets.tolist() == [0]
    matches, _, _ = match(truth, np.array([3.0, 3.0]), dets, bounds=(low, high, np.array([np.nan, 100.0])))
    assert matches.tolist() == [[0, 0], [1, 1]]  # a NaN value checks nothing either


def _chain(offset: float = 0.0):
    # t0 has b at 1 px; t1 (a wide gate) has b at 25 and c, 27 px from b, too far for t0's gate
    truth = np.array([[0.0, 0.0], [25.0, 0.0]]) + offset
    dets = np.array([[1.0, 0.0], [-26.0, 0.0]]) + offset  # b, c
    return truth, np.array([28.0, 30.0]), dets


def test_a_miss_cost_keeps_a_long_chain_of_pairs_from_buying_one_more_match():
    truth, gate, dets = _chain()
    m, ut, ud = match(truth, gate, dets)  # the most matches first: t1-b, t0-c
    assert sorted(map(tuple, m.tolist())) == [(0, 1), (1, 0)]
    m, ut, ud = match(truth, gate, dets, miss_cost=30.0)  # 27 + 24 px for one more match: no
    assert m.tolist() == [[0, 0]] and ut.tolist() == [1] and ud.tolist() == [1]
    m, _, _ = match(truth, gate, dets, miss_cost=60.0)  # worth it at 60 px a miss
    assert sorted(map(tuple, m.tolist())) == [(0, 1), (1, 0)]


def test_a_penalty_reorders_competing_pairs_but_not_the_gate():
    truth = np.array([[0.0, 0.0], [4.0, 0.0]])
    dets = np.array([[1.0, 0.0], [3.5, 0.0]])
    gate = np.array([6.0, 6.0])
    m, _, _ = match(truth, gate, dets)  # by distance: t0-d0 (1), t1-d1 (0.5)
    assert m.tolist() == [[0, 0], [1, 1]]
    # the straight pairs cost |0 - 10| = 10 px more each, the crossed ones nothing: those (3.5 + 3)
    # are cheaper
    swap = (np.array([0.0, 10.0]), np.array([10.0, 0.0]))
    m, _, _ = match(truth, gate, dets, penalty=swap)
    assert m.tolist() == [[0, 1], [1, 0]]
    # a penalty does not widen a gate: a detection beyond it is not matched however cheap
    m, ut, ud = match(truth[:1], np.array([2.0]), dets[1:], penalty=(np.array([5.0]), np.array([5.0])))
    assert len(m) == 0 and ut.tolist() == [0] and ud.tolist() == [0]


def test_a_miss_cost_leaves_an_uncontested_pair_matched_within_its_gate():
    m, _, _ = match(np.array([[0.0, 0.0]]), np.array([50.0]), np.array([[45.0, 0.0]]), miss_cost=30.0)
    assert m.tolist() == [[0, 0]]


def test_a_miss_cost_gives_the_same_answer_in_crowds_as_in_small_problems():
    # 300 chains far apart: too many for one dense problem, solved as one sparse problem
    truth = np.vstack([_chain(200.0 * i)[0] for i in range(300)])
    dets = np.vstack([_chain(200.0 * i)[2] for i in range(300)])
    gate = np.tile([28.0, 30.0], 300)
    m, ut, ud = match(truth, gate, dets, miss_cost=30.0)
    assert m.tolist() == [[2 * i, 2 * i] for i in range(300)]
    m, _, _ = match(truth, gate, dets)
    assert len(m) == 600


def test_a_miss_cost_gives_the_optimum_of_a_way_out_for_every_point():
    # against the textbook form: each truth point with a column of its own at the miss cost (the
    # pairs that are the only candidate of both their ends matched as they are, as match does)
    rng = np.random.default_rng(5)
    for _ in range(200):
        nt, nd = rng.integers(1, 40, 2)
        truth, dets = rng.uniform(0, 60, (nt, 2)), rng.uniform(0, 60, (nd, 2))
        gate, miss = rng.uniform(2, 25, nt), float(rng.uniform(1, 40))
        m, _, _ = match(truth, gate, dets, miss_cost=miss, neighbours=nd)
        d = np.hypot(*(truth[:, None, :] - dets[None, :, :]).transpose(2, 0, 1))
        inside = d <= gate[:, None]
        alone = inside & (inside.sum(1) == 1)[:, None] & (inside.sum(0) == 1)[None, :]
        rows, cols = np.flatnonzero(~alone.any(1)), np.flatnonzero(~alone.any(0))
        big = 1e9
        cost = np.full((len(rows), len(cols) + len(rows)), big)
        cost[:, :len(cols)] = np.where(inside[np.ix_(rows, cols)], d[np.ix_(rows, cols)], big)
        cost[np.arange(len(rows)), len(cols) + np.arange(len(rows))] = miss
        a, b = linear_sum_assignment(cost)
        best = cost[a, b].sum() + d[alone].sum()
        got = d[m[:, 0], m[:, 1]].sum() + miss * (nt - len(m))
        assert np.all(inside[m[:, 0], m[:, 1]])
        assert got == pytest.approx(best, abs=1e-6)
