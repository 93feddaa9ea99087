"""The report's bubble model (preset ``seed``) checked against SPEC section 1, re-derived here."""

import numpy as np

from antiscatter.simulate import make_scene
from antiscatter.simulate.report import ReportBubbles, disc_visibility


def reference(seed, frames, width=800, height=600, count=300, dt=1 / 60):
    """An independent, per-particle implementation of the SPEC's formulas and documented draw order."""
    rng = np.random.default_rng(seed)
    particles = []
    next_id = [1]

    def spawn(k):
        xs = rng.uniform(0, width, k)
        rs = rng.integers(2, 7, k)
        tvx = rng.uniform(-50, 50, k)
        tvy = rng.uniform(50, 200, k)
        for i in range(k):
            particles.append(dict(id=next_id[0], x=xs[i], y=float(height), r=float(rs[i]),
                                  tvx=tvx[i], tvy=tvy[i], vx=tvx[i], vy=tvy[i]))
            next_id[0] += 1

    spawn(count)
    states = [[(p["id"], p["x"], p["y"], p["r"]) for p in particles]]
    for _ in range(frames - 1):
        if rng.random() < 0.01:
            tvx = rng.uniform(-50, 50, len(particles))
            tvy = rng.uniform(50, 200, len(particles))
            for p, a, b in zip(particles, tvx, tvy):
                p["tvx"], p["tvy"] = a, b
        for p in particles:
            p["x"] += p["vx"] * dt
            p["y"] -= p["vy"] * dt
            p["vx"] += 0.1 * (p["tvx"] - p["vx"])
            p["vy"] += 0.1 * (p["tvy"] - p["vy"])
            p["r"] += 0.05 * (height - p["y"]) / height
        particles[:] = [p for p in particles if p["y"] > -p["r"]]
        spawn(count - len(particles))
        states.append([(p["id"], p["x"], p["y"], p["r"]) for p in particles])
    return states


def test_reproduces_the_reports_model_exactly():
    frames = 420  # long enough for particles to leave the top and respawn, and for velocity redraws
    scene = ReportBubbles(rng=np.random.default_rng(5))
    expected = reference(5, frames)
    respawned = False
    for k in range(frames):
        if k:
            scene.step()
        truth = scene.truth()
        ids, x, y, r = (np.array(v) for v in zip(*expected[k]))
        np.testing.assert_array_equal(truth.ids, ids)
        np.testing.assert_allclose(truth.centres[:, 0], x, atol=1e-9)
        np.testing.assert_allclose(truth.centres[:, 1], y, atol=1e-9)
        np.testing.assert_allclose(truth.radii, r, atol=1e-9)
        assert len(truth) == 300
        respawned |= bool(ids.max() > 300)
    assert respawned


def test_initial_state_follows_the_spec_ranges():
    scene = make_scene("seed", rng=np.random.default_rng(1))
    assert scene.size == (800, 600) and scene.fps == 60
    assert (scene.y == 600).all()
    assert set(np.unique(scene.r)) <= {2, 3, 4, 5, 6}
    assert (np.abs(scene.vx) <= 50).all() and ((scene.vy >= 50) & (scene.vy <= 200)).all()


def test_rendered_pixels_match_truth():
    scene = make_scene("seed", rng=np.random.default_rng(2))
    for _ in range(200):
        scene.step()
    image = scene.render()
    assert image.shape == (600, 800, 3)
    assert set(np.unique(image)) <= {0, 255}
    truth = scene.truth()
    inside = truth.visibility > 0.99
    xs = np.rint(truth.centres[inside, 0]).astype(int)
    ys = np.rint(truth.centres[inside, 1]).astype(int)
    assert (image[ys, xs, 0] == 255).all()  # every visible centre is lit
    lit = (image[..., 0] == 255).sum()
    area = (np.pi * truth.radii ** 2 * truth.visibility).sum()
    assert lit <= area * 1.05  # overlaps only remove pixels


def test_visibility_of_a_disc_cut_by_an_edge():
    vis = disc_visibility(np.array([50.0, 0.0, 50.0, -20.0]), np.array([50.0, 50.0, 600.0, 50.0]),
                          np.array([5.0, 5.0, 5.0, 5.0]), (800, 600))
    np.testing.assert_allclose(vis, [1.0, 0.5, 0.5, 0.0])


def test_same_seed_same_frames():
    a = make_scene("seed", rng=np.random.default_rng(9))
    b = make_scene("seed", rng=np.random.default_rng(9))
    for _ in range(30):
        a.step()
        b.step()
    np.testing.assert_array_equal(a.render(), b.render())
