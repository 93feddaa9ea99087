"""Depth by bisection along the epipolar line, judged by what the camera sees next."""

import cv2
import numpy as np
import pytest

from antiscatter.detections import Detections
from antiscatter.probe import DepthProbe
from antiscatter.twin import TwinGeometry, TwinRun

GEOMETRY = TwinGeometry(baseline_m=0.12)


def probe():
    return DepthProbe(GEOMETRY.plane_mapping, near_m=0.3, far_m=3.0, dim_level=0.2, settle_px=12.0)


def test_bisection_finds_a_particles_depth_from_lit_and_dimmed_exposures():
    p = probe()
    centre = np.array([[400.0, 300.0]])
    true_w = 1 / 0.8  # the particle is 0.8 m away
    lit = 100.0
    hole = Detections(centre, [4.0], scores=[lit], track_ids=[7])
    p.observe(hole, {}, np.empty(0))  # first sight, fully lit: its brightness is learnt
    for _ in range(12):
        a, b = p.probes(hole)[7]
        brightness = lit * (0.2 if a <= true_w <= b else 1.0)  # dimmed only when the probe held it
        p.observe(Detections(centre, [4.0], scores=[brightness], track_ids=[7]), {7: (a, b)}, np.empty(0))
    lo, hi = p.intervals()[7]
    assert lo <= true_w <= hi
    assert p.span_px(centre, np.array([lo]), np.array([hi]))[0] <= 12.0
    # settled: the probe is the whole (small) interval; a particle that vanished counts as dimmed
    a, b = p.probes(hole)[7]
    assert (a, b) == (lo, hi)
    p.observe(Detections.empty(), {7: (a, b)}, np.array([7]))
    assert p.intervals()[7] == (a, b)
    # the settled hole missed (the particle came back fully lit) twice in a row: the search starts again
    p.observe(Detections(centre, [4.0], scores=[lit], track_ids=[7]), {7: (a, b)}, np.empty(0))
    assert p.intervals()[7] == (a, b)
    p.observe(Detections(centre, [4.0], scores=[lit], track_ids=[7]), {7: (a, b)}, np.empty(0))
    assert p.intervals()[7] == (p.w_far, p.w_near)


@pytest.mark.parametrize("covered, under", [(0.7, True), (0.3, False)])
def test_a_particle_is_under_the_probe_when_most_of_it_is(covered, under):
    # a big particle straddling the probe's end: the share of it under the probe gets 0.1 of the light
    p = DepthProbe(GEOMETRY.plane_mapping, near_m=0.3, far_m=3.0, dim_level=0.1)
    centre = np.array([[400.0, 300.0]])
    lit = 100.0
    p.observe(Detections(centre, [8.0], scores=[lit], track_ids=[2]), {}, np.empty(0))
    a, b = p.probes(Detections(centre, [8.0], track_ids=[2]))[2]
    seen = lit * (covered * 0.1 + (1 - covered))
    p.observe(Detections(centre, [8.0], scores=[seen], track_ids=[2]), {2: (a, b)}, np.empty(0))
    assert (p.intervals()[2] == (a, b)) is under  # under: the probe's half; not: the other half
    if not under:
        assert p.intervals()[2] == (b, p.w_near)


def _crossed(p, centre, probes, near=None):
    """The exposure's light (uint8): the probes drawn at the dim level, and -- when ``near`` is given
    -- a neighbour's probe (dark at the dim level too) along this track's epipolar line from 0.35 m
    to ``near`` m: a particle just beside this one, searching its own near part."""
    holes = Detections(centre, [3.0], track_ids=list(probes))
    light = p.render(holes, probes, size=GEOMETRY.projector_size, hole=int(round(p.dim_level * 255)))
    if near is not None:
        ends = [p.mapping_at(d) @ [*centre[0], 1.0] for d in (0.35, near)]
        a, b = ((int(round(u / w)), int(round(v / w))) for u, v, w in ends)
        cv2.line(light, a, b, int(round(p.dim_level * 255)), 8)
    return light


@pytest.mark.parametrize("vanished", [False, True])
def test_a_particle_dimmed_by_a_neighbours_hole_keeps_that_depth_in_its_interval(vanished):
    # the particle is near (0.4 m), out of its first probe (the far half: 3 m .. 0.55 m), but a
    # neighbour's probe lies along its line from 0.35 to 0.5 m: dimmed, it could be in either place
    centre = np.array([[400.0, 300.0]])
    lit, true_w = 100.0, 1 / 0.4
    for crossed in (False, True):
        p = probe()
        p.observe(Detections(centre, [3.0], scores=[lit], track_ids=[5]), {}, np.empty(0))
        probes = p.probes(Detections(centre, [3.0], track_ids=[5]))
        a, b = probes[5]
        assert not a <= true_w <= b
        light = _crossed(p, centre, probes, 0.5 if crossed else None)
        if vanished:  # not found at all: a confirmed track coasting at its predicted centre
            p.observe(Detections.empty(), probes, np.array([5]), exposure=light, coasting_centres=centre)
        else:
            p.observe(Detections(centre, [3.0], scores=[lit * p.dim_level], track_ids=[5]), probes, np.empty(0),
                      exposure=light)
        lo, hi = p.intervals()[5]
        if crossed:  # both places kept, no more: the search goes on over both
            assert lo == a and 1 / 0.4 <= hi < p.w_near
        else:  # nothing else was dark along its line: its own probe held it
            assert (lo, hi) == (a, b)
    # the light as a float (the twin's), and the verdict without it: its own probe alone
    p = probe()
    p.observe(Detections(centre, [3.0], scores=[lit], track_ids=[5]), {}, np.empty(0))
    probes = p.probes(Detections(centre, [3.0], track_ids=[5]))
    light = _crossed(p, centre, probes, 0.5).astype(np.float32) / 255
    dimmed = Detections(centre, [3.0], scores=[lit * p.dim_level], track_ids=[5])
    p.observe(dimmed, probes, np.empty(0), exposure=light)
    assert p.intervals()[5][1] >= true_w
    p = probe()
    p.observe(Detections(centre, [3.0], scores=[lit], track_ids=[5]), {}, np.empty(0))
    p.observe(dimmed, probes, np.empty(0))
    assert p.intervals()[5] == probes[5]


def test_a_neighbours_hole_over_a_small_part_of_the_line_leaves_the_own_probes_verdict():
    # the own probe darkened half the interval; a neighbour's hole a few samples of the rest: the
    # particle is far likelier in its probe (SURE), which stays its interval
    p = probe()
    centre = np.array([[400.0, 300.0]])
    p.observe(Detections(centre, [3.0], scores=[100.0], track_ids=[5]), {}, np.empty(0))
    probes = p.probes(Detections(centre, [3.0], track_ids=[5]))
    light = _crossed(p, centre, probes)
    lo, hi = p.intervals()[5]
    ends = [p.mapping_at(1 / w) @ [400.0, 300.0, 1.0] for w in (hi - 0.35, hi - 0.15)]  # 3 of 48 samples
    a, b = ((int(round(u / s)), int(round(v / s))) for u, v, s in ends)
    cv2.line(light, a, b, 0, 8)
    p.observe(Detections(centre, [3.0], scores=[100.0 * p.dim_level], track_ids=[5]), probes, np.empty(0),
              exposure=light)
    assert p.intervals()[5] == probes[5]


def test_the_segment_spans_the_disparity_between_near_and_far():
    p = probe()
    centre = np.array([[400.0, 300.0]])
    full = p.span_px(centre, np.array([p.w_far]), np.array([p.w_near]))[0]
    expected = GEOMETRY.projector_focal * 0.12 * (1 / 0.3 - 1 / 3.0)
    assert full == pytest.approx(expected, rel=1e-9)
    hole = Detections(centre, [2.0], track_ids=[3])
    pattern = p.render(hole, {}, size=GEOMETRY.projector_size)  # unknown depth: the whole segment
    near = GEOMETRY.plane_mapping(0.3) @ [400.0, 300.0, 1.0]
    far = GEOMETRY.plane_mapping(3.0) @ [400.0, 300.0, 1.0]
    for t in (0.0, 0.5, 1.0):
        u, v = far[:2] + t * (near[:2] - far[:2])
        assert pattern[int(round(v)), int(round(u))] == 0
    assert pattern[int(round(far[1])) + 20, int(round(far[0]))] == 255
    none = np.empty((0, 2))
    assert p.span_px(none, np.empty(0), np.empty(0)).shape == (0,)
    assert p.project(none, np.empty(0)).shape == (0, 2)
    forgotten = probe()
    forgotten.observe(Detections(centre, [2.0], scores=[50.0], track_ids=[3]), {}, np.empty(0))
    forgotten.forget(np.array([4]))
    assert len(forgotten.intervals()) == 0


def test_a_probed_hole_withholds_light_over_its_interval_and_no_further():
    p = probe()
    centre = np.array([[400.0, 300.0]])
    hole = Detections(centre, [3.0], scores=[80.0], track_ids=[5])
    p.observe(hole, {}, np.empty(0))  # a track seen lit: its probe is the far half of its interval
    lo, hi = p.probes(hole)[5]
    assert (lo, hi) == (p.w_far, (p.w_far + p.w_near) / 2)
    pattern = p.render(hole, {5: (lo, hi)}, size=GEOMETRY.projector_size, margin=2.0)
    a = GEOMETRY.plane_mapping(1 / lo) @ [400.0, 300.0, 1.0]
    b = GEOMETRY.plane_mapping(1 / hi) @ [400.0, 300.0, 1.0]
    a, b = a[:2] / a[2], b[:2] / b[2]
    direction = (b - a) / np.linalg.norm(b - a)
    ys, xs = np.nonzero(pattern == 0)
    along = (np.column_stack([xs, ys]) - a) @ direction  # 0 at the interval's far end, |b - a| at the other
    length = np.linalg.norm(b - a)
    # caps included, the dark pixels span the interval: none more than a pixel past either end
    assert along.min() >= -1.5 and along.max() <= length + 1.5
    assert along.min() <= 1.5 and along.max() >= length - 1.5
    # a whole interval -- depth unknown, or the one kept dark between pulses -- only has to cover
    # the particle: drawn in full, caps and all
    far = GEOMETRY.plane_mapping(3.0) @ [400.0, 300.0, 1.0]
    for whole in (p.render(hole, {}, size=GEOMETRY.projector_size, margin=2.0),
                  p.render(hole, p.intervals(), size=GEOMETRY.projector_size, margin=2.0)):
        ys, xs = np.nonzero(whole == 0)
        assert ((np.column_stack([xs, ys]) - far[:2] / far[2]) @ direction).min() < -3


def test_a_hole_is_drawn_only_where_its_backscatter_is_worth_the_scene_light_it_takes():
    # a bright bubble and a faint grain, both of unknown depth: each one's hole is a segment some
    # 550 projector px long.  The grain sends back 1/20000 of the frame's backscatter and its line
    # would darken about 0.1 % of the field: not worth it at min_worth 0.2 (it would need 0.02 %)
    size = GEOMETRY.projector_size
    centres = np.array([[300.0, 300.0], [500.0, 200.0]])
    lit = [20000.0, 1.0]

    def searching(**kw):
        p = DepthProbe(GEOMETRY.plane_mapping, near_m=0.3, far_m=3.0, dim_level=0.2, **{"projector_size": size, **kw})
        p.observe(Detections(centres, [4.0, 1.0], scores=lit, track_ids=[1, 2]), {}, np.empty(0))
        return p, Detections(centres, [4.0, 1.0], track_ids=[1, 2])

    p, holes = searching()
    share = p.span_px(centres[1:], np.array([p.w_far]), np.array([p.w_near]))[0] * 2 / (size[0] * size[1])
    assert 0.2 * share > 3 / 20001  # the grain fails by a factor of several
    assert set(p.probes(holes)) == {1} and set(p.covers(holes)) == {1}
    assert p.covers(holes)[1] == (p.w_far, p.w_near)
    light = p.render(holes, p.covers(holes), size=size, given_only=True)
    mid = [p.project(centres, np.full(2, (p.w_far + p.w_near) / 2))[i] for i in range(2)]
    assert light[int(mid[0][1]), int(mid[0][0])] == 0 and light[int(mid[1][1]), int(mid[1][0])] == 255
    # not drawn: no verdict -- the grain comes back as bright and keeps its whole interval
    p.observe(Detections(centres, [4.0, 1.0], scores=[20000.0 * 0.2, 1.0], track_ids=[1, 2]), p.probes(holes),
              np.empty(0))
    assert p.intervals()[2] == (p.w_far, p.w_near) and p.intervals()[1] != (p.w_far, p.w_near)
    # without the rule (0), or without the projector's size, every hole is drawn; a brighter grain passes
    for kw in ({"min_worth": 0.0}, {"projector_size": None}):
        p, holes = searching(**kw)
        assert set(p.probes(holes)) == {1, 2} and set(p.covers(holes)) == {1, 2}
    lit[1] = 200.0  # 1/100 of the backscatter
    p, holes = searching()
    assert set(p.probes(holes)) == {1, 2}
    with pytest.raises(ValueError, match="min_worth: got -1"):
        DepthProbe(GEOMETRY.plane_mapping, min_worth=-1.0)


def test_probe_runs_need_dim_holes():
    with pytest.raises(ValueError, match="probe needs strategy dim or pulse"):
        TwinRun("contrast", "probe", "flash", predict=True)
    TwinRun("contrast", "probe", "dim", predict=False)  # holes where the particles were seen


def _settle(p, tid, centre, true_w, lit, frames=14):
    """Run a track through the bisection with exact verdicts until its settled hole has held it."""
    p.observe(Detections(centre, [3.0], scores=[lit], track_ids=[tid]), {}, np.empty(0))
    for _ in range(frames):
        a, b = p.probes(Detections(centre, [3.0], track_ids=[tid]))[tid]
        seen = lit * (0.2 if a <= true_w <= b else 1.0)
        p.observe(Detections(centre, [3.0], scores=[seen], track_ids=[tid]), {tid: (a, b)}, np.empty(0))


def test_brightness_learnt_from_settled_depths_narrows_a_new_particles_search():
    # particles lit by the lamp: their flux (the detector's score) falls with the fourth power of
    # the distance (albedo 0.6-1)
    rng = np.random.default_rng(3)
    p = probe()
    centre = np.array([[400.0, 300.0]])
    full = (p.w_far, p.w_near)
    for tid in range(1, 41):
        z = rng.uniform(0.35, 2.5)
        lit = 40.0 * rng.uniform(0.6, 1.0) / z ** 4
        if tid == 1:  # before enough settled tracks: the whole range
            p.observe(Detections(centre, [3.0], scores=[lit], track_ids=[tid]), {}, np.empty(0))
            assert p.intervals()[tid] == full
        _settle(p, tid, centre, 1 / z, lit)
        p.forget(np.array([]))
    for z in (0.5, 1.0, 2.0):
        lit = 40.0 * 0.8 / z ** 4
        lo, hi = p.prior(lit)
        assert lo < 1 / z < hi
        assert (hi - lo) < 0.5 * (p.w_near - p.w_far)  # at most half the range to search
        p.observe(Detections(centre, [3.0], scores=[lit], track_ids=[99]), {}, np.empty(0))
        assert p.intervals()[99] == (lo, hi)  # where a new track starts
        p.forget(np.array([]))
    # a settled hole that misses twice in a row starts again from the prior once, then from the
    # whole range
    z = 1.0
    lit = 40.0 * 0.8 / z ** 4
    _settle(p, 50, centre, 1 / z, lit)
    for expected in (p.prior(lit), full):
        a, b = p.probes(Detections(centre, [3.0], track_ids=[50]))[50]
        assert (a, b) == p.intervals()[50]  # settled
        for _ in range(DepthProbe.RESTART - 1):  # a single miss may be noise: the hole stays
            p.observe(Detections(centre, [3.0], scores=[lit], track_ids=[50]), {50: (a, b)}, np.empty(0))
            assert p.intervals()[50] == (a, b)
        p.observe(Detections(centre, [3.0], scores=[lit], track_ids=[50]), {50: (a, b)}, np.empty(0))
        assert p.intervals()[50] == expected
        _settle(p, 50, centre, 1 / z, lit)


def test_a_few_settled_depths_fix_the_brightness_laws_level():
    # before FIT_SLOPE tracks the slope is the flux's fourth-power law and only its level is learnt:
    # from MIN_PRIOR settled tracks on, a new particle's search is narrowed around it
    rng = np.random.default_rng(5)
    p = probe()
    centre = np.array([[400.0, 300.0]])
    for tid in range(1, DepthProbe.MIN_PRIOR + 1):
        assert p.prior(30.0) == (p.w_far, p.w_near)  # too few yet
        z = rng.uniform(0.4, 2.5)
        _settle(p, tid, centre, 1 / z, 40.0 * rng.uniform(0.6, 1.0) / z ** 4)
        p.forget(np.array([]))
    assert p.prior_size() == DepthProbe.MIN_PRIOR < DepthProbe.FIT_SLOPE
    for z in (0.4, 1.0, 2.5):  # across the range, also beyond the depths it learnt from
        lo, hi = p.prior(40.0 * 0.8 / z ** 4)
        assert lo < 1 / z < hi and (hi - lo) < 0.5 * (p.w_near - p.w_far)
        if p.w_far < lo and hi < p.w_near:  # not cut by the working range: FEW_BAND either side at least
            assert hi / lo >= np.exp(2 * DepthProbe.FEW_BAND) - 1e-9


def test_a_settled_hole_that_misses_once_between_hits_stays():
    p = probe()
    centre = np.array([[400.0, 300.0]])
    _settle(p, 1, centre, 1 / 0.8, 100.0)
    settled = p.intervals()[1]
    for seen in (100.0, 20.0, 100.0, 20.0):  # miss, hit, miss, hit: never two misses in a row
        p.observe(Detections(centre, [3.0], scores=[seen], track_ids=[1]), {1: settled}, np.empty(0))
        assert p.intervals()[1] == settled
    p.observe(Detections(centre, [3.0], scores=[100.0], track_ids=[1]), {1: settled}, np.empty(0))
    p.observe(Detections(centre, [3.0], scores=[100.0], track_ids=[1]), {1: settled}, np.empty(0))
    assert p.intervals()[1] != settled  # two in a row: searched again


def test_a_depth_is_learnt_only_once_its_settled_hole_has_held_the_particle_twice():
    p = probe()
    centre = np.array([[400.0, 300.0]])
    _settle(p, 1, centre, 1 / 0.8, 100.0, frames=5)  # still searching: nothing learnt
    assert p.prior_size() == 0
    _settle(p, 2, centre, 1 / 0.8, 100.0)
    assert p.prior_size() == 1
    with pytest.raises(ValueError, match="prior_samples"):
        DepthProbe(GEOMETRY.plane_mapping, prior_samples=-1)
    off = DepthProbe(GEOMETRY.plane_mapping, prior_samples=0)
    _settle(off, 2, centre, 1 / 0.8, 100.0)
    assert off.prior_size() == 0 and off.prior(100.0) == (off.w_far, off.w_near)


def test_the_priors_line_is_the_least_squares_fit():
    # the normal equations (cheaper than np.polyfit, run whenever a track settles) give polyfit's line
    from antiscatter.probe import _line

    rng = np.random.default_rng(4)
    x = rng.normal(3.0, 1.0, 200)
    y = 0.45 * x - 1.2 + rng.normal(0, 0.1, 200)
    assert np.allclose(_line(x, y), np.polyfit(x, y, 1), rtol=1e-9, atol=1e-12)
    assert _line(np.full(5, 2.0), np.arange(5.0)) == (0.0, 2.0)  # x all alike: flat, at y's mean


def test_the_priors_quantiles_are_numpys():
    from antiscatter.probe import _quantiles

    rng = np.random.default_rng(6)
    for n in (1, 2, 3, 7, 40, 399, 400):
        values = rng.normal(size=n) * 3.0
        np.testing.assert_array_equal(_quantiles(values, (0.1, 0.9)), np.quantile(values, [0.1, 0.9]))


def test_the_priors_median_is_numpys():
    from antiscatter.probe import _median

    rng = np.random.default_rng(8)
    for n in (1, 2, 3, 8, 39):
        values = rng.normal(size=n)
        assert _median(values) == np.median(values)


class _OneByOne:
    """The probe's rules written track by track, in the detections' order -- what the vectorised
    ``observe`` must equal, prior included (new and restarted tracks read it between the depths
    learnt before them in the same exposure)."""

    def __init__(self, p: DepthProbe):
        self.p = p  # only for its prior (samples learnt here, fits asked here)
        self.state: dict[int, list] = {}  # id -> [lo, hi, lit, held, missed, restarted]

    def observe(self, detections, shown, coasting):
        p, state = self.p, self.state
        for tid, score in zip(detections.track_ids.tolist(), detections.scores.tolist()):
            if tid < 0 or not np.isfinite(score):
                continue
            if tid not in state:
                state[tid] = [*p.prior(score), 0.0, 0, 0, False]
            t = state[tid]
            probe = shown.get(tid)
            if probe is None or t[2] <= 0:
                t[2] = score if t[2] <= 0 else 0.7 * t[2] + 0.3 * score
                continue
            if score < (1 + p.dim_level) / 2 * t[2]:
                t[3] = t[3] + 1 if probe == (t[0], t[1]) else 0
                if t[3] == p.HELD:
                    p._learn(t[2], t[0], t[1])
                self._hit(t, probe)
            else:
                t[3] = 0
                a, b = probe
                if a <= t[0] + 1e-12 and b >= t[1] - 1e-12:
                    t[4] += 1
                    if t[4] >= p.RESTART:
                        t[4] = 0
                        t[0], t[1] = p.prior(t[2]) if not t[5] else (p.w_far, p.w_near)
                        t[5] = True
                elif a <= t[0] + 1e-12:
                    t[0] = max(t[0], b)
                elif b >= t[1] - 1e-12:
                    t[1] = min(t[1], a)
                t[2] = 0.7 * t[2] + 0.3 * score
        for tid in coasting.tolist():
            if tid in state and tid in shown:
                self._hit(state[tid], shown[tid])

    @staticmethod
    def _hit(t, probe):
        t[4] = 0
        lo, hi = max(t[0], probe[0]), min(t[1], probe[1])
        t[0], t[1] = (lo, hi) if lo < hi else probe


def test_every_tracks_verdict_at_once_equals_the_rules_applied_one_track_at_a_time():
    # 60 particles coming and going over 80 exposures, at random depths and brightnesses, some
    # dimmed by their probes, some lit, some vanished under them, some missed by the detector
    rng = np.random.default_rng(11)
    fast, slow = probe(), _OneByOne(probe())
    fast.MIN_PRIOR = slow.p.MIN_PRIOR = 2  # the prior soon in play, so its order matters
    depth = 1 / rng.uniform(0.35, 2.8, 60)
    lit = rng.uniform(20, 200, 60)
    centres = rng.uniform([50, 50], [750, 550], (60, 2))
    alive = np.zeros(60, bool)
    shown = {}
    for frame in range(80):
        alive = np.where(rng.random(60) < 0.06, ~alive, alive)
        ids = np.flatnonzero(alive)
        seen = rng.random(len(ids)) > 0.1  # the detector misses one in ten
        scores = []
        for tid in ids[seen]:
            a, b = shown.get(tid, (0.0, 0.0))
            dimmed = a <= depth[tid] <= b and rng.random() > 0.05  # and a verdict is sometimes wrong
            scores.append(lit[tid] * (fast.dim_level if dimmed else 1.0) * rng.uniform(0.9, 1.1))
        order = rng.permutation(int(seen.sum()))
        found = Detections(centres[ids[seen]][order], np.full(int(seen.sum()), 3.0),
                           scores=np.array(scores)[order], track_ids=ids[seen][order])
        coasting = ids[~seen]
        fast.observe(found, shown, coasting)
        slow.observe(found, shown, coasting)
        fast.forget(ids)
        slow.state = {t: s for t, s in slow.state.items() if t in set(ids.tolist())}
        expected = {t: (s[0], s[1]) for t, s in slow.state.items()}
        assert dict(fast.intervals()) == expected, frame
        assert fast.prior_size() == slow.p.prior_size()
        holes = Detections(centres[ids], np.full(len(ids), 3.0), track_ids=ids)
        shown = dict(fast.probes(holes))
    assert fast.prior_size() >= 5  # depths were learnt and new particles' priors came from them


def test_the_probe_benchmark_script_runs_and_reports_every_call():
    import subprocess
    import sys
    from pathlib import Path

    script = Path(__file__).resolve().parents[1] / "scripts" / "bench_probe.py"
    out = subprocess.run([sys.executable, str(script), "--particles", "20", "--frames", "15"], capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    for call in ("observe", "plan", "render (each of 2)", "frame"):
        assert f"{call}: median" in out.stdout
    assert "settled depths learnt for the prior: " in out.stdout
