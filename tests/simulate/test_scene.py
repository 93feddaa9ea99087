"""The realistic scene: geometry, truth against pixels, and every part switchable."""

from dataclasses import replace

import cv2
import numpy as np
import pytest

from antiscatter.simulate import PRESETS, make_scene
from antiscatter.simulate.presets import BUBBLES, SAND, SNOW
from antiscatter.simulate.scene import KindConfig, RealisticScene, SceneConfig

SIZE = (320, 240)
#: share of its bounding disc that a sand template fills (1 - rho^4 inside, stretched up to 1.6:1)
SAND_TEMPLATE_FILL = 0.55
PLAIN = SceneConfig(background="black", defocus=0.0, exposure_s=0.0, read_noise=0.0, shot_noise=0.0,
                    lamp_cone=False)


def render(config, *, seed=0, size=SIZE, steps=0):
    scene = RealisticScene(config, size=size, rng=np.random.default_rng(seed))
    for _ in range(steps):
        scene.step()
    labels = np.zeros((size[1], size[0]), np.uint16)
    image = scene.render(labels=labels)
    return scene, image, labels, scene.truth()


@pytest.mark.parametrize("kind", ["bubbles", "sand"])
@pytest.mark.parametrize("radius_mm, depth", [(2.0, 0.5), (4.0, 0.4), (3.0, 1.0)])
def test_single_round_particle_size_follows_the_pinhole(kind, radius_mm, depth):
    one = KindConfig(count=1, size_mm=(radius_mm, radius_mm), depth_m=(depth, depth), speed=(0, 0))
    scene, image, labels, truth = render(replace(PLAIN, **{kind: one}))
    expected = scene.focal * radius_mm / 1000 / depth
    assert len(truth) == 1
    assert abs(truth.radii[0] - expected) < 1.0
    ys, xs = np.nonzero(labels == truth.labels[0])
    assert abs(xs.mean() - truth.centres[0, 0]) < 1.0 and abs(ys.mean() - truth.centres[0, 1]) < 1.0
    assert truth.depths[0] == pytest.approx(depth)


def test_truth_consistent_with_pixels_for_isolated_bubbles():
    config = replace(SceneConfig(), bubbles=replace(BUBBLES, count=40), background="water")
    scene, image, labels, truth = render(config, size=(640, 480), steps=3)
    grey = image.astype(np.float32).mean(axis=2)
    background = cv2.medianBlur(image, 21).astype(np.float32).mean(axis=2)
    checked = 0
    for i in range(len(truth)):
        if truth.visibility[i] < 1 or truth.snr[i] < 15 or truth.radii[i] < 2:
            continue
        x, y, r = truth.centres[i, 0], truth.centres[i, 1], truth.radii[i]
        # isolated: no other particle within 3 radii
        others = np.hypot(truth.centres[:, 0] - x, truth.centres[:, 1] - y)
        others[i] = np.inf
        if others.min() < 3 * (r + truth.radii.max()):
            continue
        ys, xs = np.nonzero(labels == truth.labels[i])
        assert abs(np.sqrt(len(xs) / np.pi) - r) < 1.0
        light = np.clip(grey[ys, xs] - background[ys, xs], 0, None)
        cx, cy = (light * xs).sum() / light.sum(), (light * ys).sum() / light.sum()
        assert np.hypot(cx - x, cy - y) < 1.0, (i, cx, cy, x, y)
        assert light.mean() > 5
        checked += 1
    assert checked >= 5


def test_visibility_and_labels():
    scene, image, labels, truth = render(replace(SceneConfig(), snow=replace(SNOW, count=300)), steps=2)
    assert ((truth.visibility >= 0) & (truth.visibility <= 1)).all()
    assert set(np.unique(labels)) - {0} <= set(truth.labels[truth.labels > 0].tolist())
    hidden = truth.labels == 0
    assert (truth.visibility[hidden] == 0).all()
    edge = (truth.centres[:, 0] < 0) | (truth.centres[:, 0] >= SIZE[0])
    assert (truth.visibility[edge] < 0.75).all()  # partly outside the frame


def _stats(config, seed=0):
    return render(config, seed=seed)


def test_background_part_changes_the_frame():
    _, black, _, _ = render(replace(PLAIN, background="black"))
    _, bed, _, _ = render(replace(PLAIN, background="seabed", background_level=80))
    _, pad, _, _ = render(replace(PLAIN, background="padding", background_level=150))
    assert black.max() == 0
    for image in (bed, pad):
        grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        assert grey.mean() > 20
        assert cv2.Laplacian(grey, cv2.CV_32F).var() > 1.0  # textured, not flat


def test_lamp_cone_lights_the_frame_unevenly():
    flat = replace(PLAIN, background="water", background_level=100)
    _, uniform, _, _ = render(flat)
    _, cone, _, _ = render(replace(flat, lamp_cone=True))
    def centre_over_corner(image):
        g = image.astype(float).mean(axis=2)
        return g[100:140, 140:180].mean() / g[:30, :30].mean()
    assert centre_over_corner(cone) > 1.5 * centre_over_corner(uniform)


def test_noise_part():
    flat = replace(PLAIN, background="water", background_level=100)
    _, clean, _, _ = render(flat)
    _, noisy, _, _ = render(replace(flat, read_noise=3.0, shot_noise=0.5))
    residual = noisy.astype(float) - clean.astype(float)
    assert np.abs(residual).max() > 5
    assert 3.0 < residual.std() < 8.0  # sqrt(9 + 0.5 * ~40) ~ 5


def test_brightness_falls_with_depth():
    many = KindConfig(count=200, size_mm=(2, 2), depth_m=(0.3, 2.5), speed=(0, 0), albedo=(1, 1))
    _, _, _, truth = render(replace(PLAIN, sand=many, defocus=0.0), size=(640, 480))
    inside = truth.visibility > 0.99
    order = np.argsort(truth.depths[inside])
    peaks = truth.peaks[inside][order]
    near, far = peaks[: len(peaks) // 4].mean(), peaks[-len(peaks) // 4:].mean()
    assert near > 5 * far  # inverse square and attenuation


@pytest.mark.parametrize("radius_px", [0.05, 0.2, 0.5, 1.0])
def test_a_grain_smaller_than_a_pixel_keeps_its_light_wherever_it_falls(radius_px):
    # sampled once per pixel, a grain a fraction of a pixel across vanished between pixel centres
    # and showed its full peak at them: 0 to 16 times its light by where it fell
    focal = RealisticScene(PLAIN, size=SIZE, rng=np.random.default_rng(0)).focal
    grain = KindConfig(count=1, size_mm=(1000 * radius_px / focal,) * 2, depth_m=(1.0, 1.0), speed=(0.37, 0.37),
                       direction_deg=20.0, spread_deg=0.0, albedo=(1, 1))
    # bright enough that its light (about 150 grey levels in all) is not lost to 8-bit rounding
    config = replace(PLAIN, sand=grain, brightness=150.0 / (np.pi * radius_px ** 2 * SAND_TEMPLATE_FILL))
    scene = RealisticScene(config, size=SIZE, rng=np.random.default_rng(3))
    expected = float(scene.full_light_brightness()[0]) * np.pi * radius_px ** 2 * SAND_TEMPLATE_FILL
    totals = []
    for _ in range(12):  # 0.37 m/s at 1 m: about 4 px a frame, every sub-pixel phase
        totals.append(scene.render().astype(np.float64).mean(axis=2).sum())
        scene.step()
    totals = np.array(totals)
    assert totals.min() > 0.75 * totals.max()
    assert np.median(totals) == pytest.approx(expected, rel=0.3)


def test_defocus_spreads_near_particles():
    near = KindConfig(count=1, size_mm=(2, 2), depth_m=(0.3, 0.3), speed=(0, 0))
    _, sharp, _, t_sharp = render(replace(PLAIN, sand=near, defocus=0.0))
    _, blurred, _, t_blur = render(replace(PLAIN, sand=near, defocus=1.5))
    assert t_blur.radii[0] > t_sharp.radii[0] + 1.0
    assert t_blur.peaks[0] < 0.7 * t_sharp.peaks[0]


def test_motion_blur_streaks_along_the_velocity():
    fast = KindConfig(count=1, size_mm=(0.5, 0.5), depth_m=(0.5, 0.5), speed=(2.0, 2.0), direction_deg=0.0,
                      spread_deg=0.0)
    def elongation(exposure):
        _, _, labels, truth = render(replace(PLAIN, sand=fast, exposure_s=exposure))
        ys, xs = np.nonzero(labels == truth.labels[0])
        return np.ptp(xs) + 1, np.ptp(ys) + 1
    w0, h0 = elongation(0.0)
    w1, h1 = elongation(1 / 100)
    assert w1 >= w0 + 8 and abs(h1 - h0) <= 1  # 2 m/s at 0.5 m over 10 ms: ~10 px


def test_saturation_switch():
    bright = KindConfig(count=30, size_mm=(3, 3), depth_m=(0.3, 0.4), speed=(0, 0), albedo=(1, 1))
    _, clipped, _, _ = render(replace(PLAIN, bubbles=bright, brightness=800))
    _, rolled, _, _ = render(replace(PLAIN, bubbles=bright, brightness=800, saturate=False))
    assert (clipped == 255).sum() > 50
    assert (rolled == 255).sum() == 0 and rolled.max() > 200


def test_jpeg_artefacts_switch():
    base = replace(PLAIN, snow=replace(SNOW, count=150), background="seabed", background_level=80)
    _, clean, _, _ = render(base)
    _, jpeg, _, _ = render(replace(base, jpeg_quality=30))
    diff = np.abs(jpeg.astype(float) - clean.astype(float)).mean(axis=2)
    # 8x8 block structure: errors jump across block boundaries
    cols = np.abs(np.diff(jpeg.astype(float).mean(axis=2), axis=1))
    at_edges, elsewhere = cols[:, 7::8].mean(), np.delete(cols, np.s_[7::8], axis=1).mean()
    assert diff.mean() > 0.5
    assert at_edges > 1.1 * elsewhere


def test_kinds_move_their_own_way():
    config = replace(PLAIN, bubbles=replace(BUBBLES, count=30), snow=replace(SNOW, count=30),
                     sand=replace(SAND, count=30))
    scene = RealisticScene(config, size=(640, 480), rng=np.random.default_rng(4))
    scene.render()
    before = scene.truth()
    radius_before = dict(zip(scene._state["ids"].tolist(), scene._state["R"].tolist()))
    scene.step()
    scene.render()
    after = scene.truth()
    common, a, b = np.intersect1d(before.ids, after.ids, return_indices=True)
    motion = after.centres[b] - before.centres[a]
    kinds = before.kinds[a]
    assert motion[kinds == 0, 1].mean() < -1.0  # bubbles rise
    assert motion[kinds == 1, 1].mean() > 0.0  # snow sinks
    assert motion[kinds == 2, 0].mean() > 5.0  # sand flies right, fast
    grew = [r > radius_before[i] for i, r, k in zip(scene._state["ids"].tolist(), scene._state["R"].tolist(),
                                                   scene._state["kind"].tolist()) if k == 0 and i in radius_before]
    assert grew and all(grew)  # bubbles grow as they rise


def test_particles_keep_the_count_and_get_new_ids_when_replaced():
    config = replace(PLAIN, sand=replace(SAND, count=50))
    scene = RealisticScene(config, size=(160, 120), rng=np.random.default_rng(0))
    first_ids = set(scene._state["ids"].tolist())
    for _ in range(60):
        scene.step()
    assert len(scene._state["ids"]) == 50
    assert set(scene._state["ids"].tolist()) - first_ids  # replaced from upstream


@pytest.mark.parametrize("preset", [p for p in PRESETS if p not in ("seed", "fullres", "dense")])
def test_presets_render_with_truth(preset):
    scene = make_scene(preset, rng=np.random.default_rng(0), size=(320, 240))
    image = scene.render()
    truth = scene.truth()
    assert image.shape == (240, 320, 3) and image.dtype == np.uint8
    assert len(truth) > 10 and (truth.snr > 3).sum() > 5


def test_same_seed_same_frames_and_truth():
    a = make_scene("mixed", rng=np.random.default_rng(3), size=(200, 150))
    b = make_scene("mixed", rng=np.random.default_rng(3), size=(200, 150))
    for _ in range(3):
        a.step()
        b.step()
    np.testing.assert_array_equal(a.render(), b.render())
    np.testing.assert_array_equal(a.truth().centres, b.truth().centres)


def _moved(before, after):
    """(turn in degrees, scale, shift at the centre) of the similarity taking ``before`` to ``after``
    (grey views of the same surface), from optical flow on a grid of points."""
    ys, xs = np.mgrid[20:before.shape[0] - 20:16, 20:before.shape[1] - 20:16]
    points = np.column_stack([xs.ravel(), ys.ravel()]).astype(np.float32).reshape(-1, 1, 2)
    moved, status, _ = cv2.calcOpticalFlowPyrLK(before, after, points, None, winSize=(21, 21), maxLevel=3)
    ok = status.ravel() == 1
    m, _ = cv2.estimateAffinePartial2D(points[ok], moved[ok], method=cv2.RANSAC, ransacReprojThreshold=0.5)
    centre = np.array([(before.shape[1] - 1) / 2, (before.shape[0] - 1) / 2])
    return np.degrees(np.arctan2(m[1, 0], m[0, 0])), np.hypot(m[0, 0], m[1, 0]), m[:, :2] @ centre + m[:, 2] - centre


def test_a_moving_vehicle_moves_the_surface_and_the_water_the_other_way():
    # sideways 0.3 m/s, closing on a seabed 2 m away at 0.2 m/s, turning 6 degrees a second; 12 frames
    config = replace(PLAIN, background="seabed", background_level=120.0, vehicle_m_s=(0.3, 0.0, 0.2),
                     yaw_deg_s=6.0, ground_m=2.0, sand=replace(SAND, count=40, speed=(0.0, 0.0)))
    scene = RealisticScene(config, size=(640, 480), rng=np.random.default_rng(2))
    first = cv2.cvtColor(scene.render(), cv2.COLOR_BGR2GRAY)
    particles = scene.particles()
    for _ in range(12):
        scene.step()
    seconds, distance = 12 / scene.fps, 2.0 - 0.2 * 12 / scene.fps
    turn, scale, shift = _moved(first, cv2.cvtColor(scene.render(), cv2.COLOR_BGR2GRAY))
    assert turn == pytest.approx(-6.0 * seconds, abs=0.05)  # the view turns the other way
    assert scale == pytest.approx(2.0 / distance, abs=0.002)  # the surface grows as it comes closer
    # the surface's point on the axis moves the other way, f v t / its distance then
    assert shift[0] == pytest.approx(-scene.focal * 0.3 * seconds / distance, abs=1.0)
    assert abs(shift[1]) < 1.0
    # and brightens with the inverse square of its distance (the lamp at the camera)
    start = RealisticScene(config, size=(640, 480), rng=np.random.default_rng(2))
    assert scene._background.mean() / start._background.mean() == pytest.approx((2.0 / distance) ** 2, rel=0.05)
    # particles at rest in the water: they turn the other way, come closer and pass sideways
    after = scene.particles()
    common, a, b = np.intersect1d(particles["ids"], after["ids"], return_indices=True)
    assert len(common) > 10
    assert np.allclose(after["Z"][b], particles["Z"][a] - 0.2 * seconds)
    angle = -np.radians(6.0 / scene.fps)
    x, y = particles["X"][a], particles["Y"][a]
    for _ in range(12):  # the step's order: carried by the water, then turned
        x = x - 0.3 / scene.fps
        x, y = np.cos(angle) * x - np.sin(angle) * y, np.sin(angle) * x + np.cos(angle) * y
    assert np.allclose(after["X"][b], x) and np.allclose(after["Y"][b], y)


def test_a_moving_view_needs_a_still_background(tmp_path):
    video = tmp_path / "bg.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10, (64, 48))
    for i in range(3):
        writer.write(np.full((48, 64, 3), 40 * i, np.uint8))
    writer.release()
    with pytest.raises(ValueError, match="a moving view needs a still background"):
        RealisticScene(replace(PLAIN, background=str(video), yaw_deg_s=2.0), size=(64, 48),
                       rng=np.random.default_rng(0))
    with pytest.raises(ValueError, match="ground_m"):
        SceneConfig(ground_m=0.0)
