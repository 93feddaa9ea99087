"""The default detector on several threads: the bands of the frame give exactly the one-thread detections."""

import cv2
import numpy as np
import pytest

from antiscatter.detection import MAX_THREADS, make_detector
from antiscatter.detection.contrast import ContrastParams, label, measure
from antiscatter.detection.contrast.background import prominent_only, ring_level
from antiscatter.detection.contrast.bands import MIN_ROWS, BandPool, downsample_in_bands
from antiscatter.detection.contrast.components import measure_in_bands
from antiscatter.detection.contrast.split import split_images
from antiscatter.detection.contrast.working import downsample
from antiscatter.simulate import make_scene

from test_contrast import scene


def _same(a, b):
    """Two Detections equal to the last bit, in the same order."""
    return (np.array_equal(a.centres, b.centres) and np.array_equal(a.radii, b.radii)
            and np.array_equal(a.scores, b.scores) and a.cut == b.cut)


def _run(frames, threads, params=None, light=None):
    detector = make_detector("contrast", params, threads=threads)
    found = []
    for frame in frames:
        if light is not None:
            detector.set_light(light)
        found.append(detector.detect(frame))
    return found


def _check_equal(frames, params=None, light=None):
    reference = _run(frames, 1, params, light)
    assert sum(len(f) for f in reference) > 0
    for threads in (2, 3, 4):
        for k, (one, many) in enumerate(zip(reference, _run(frames, threads, params, light))):
            assert _same(one, many), f"{threads} threads, frame {k}: {len(many)} detections, 1 thread {len(one)}"


def _seams(rows, threads):
    """The working-image rows where bands meet for ``rows`` rows on ``threads`` threads."""
    return [r0 for r0, _ in BandPool(threads).spans(rows)[1:]]


@pytest.mark.parametrize("rows,threads", [(544, 2), (544, 4), (300, 3), (33, 4), (64, 4), (5, 2)])
def test_the_bands_cover_every_row_once_in_order(rows, threads):
    spans = BandPool(threads).spans(rows)
    assert spans[0][0] == 0 and spans[-1][1] == rows
    assert all(a[1] == b[0] for a, b in zip(spans, spans[1:]))
    assert len(spans) <= threads and (len(spans) == 1 or min(r1 - r0 for r0, r1 in spans) >= MIN_ROWS)


@pytest.mark.parametrize("threads", [2, 3, 4])
def test_a_local_filter_in_bands_equals_it_on_the_whole_image(threads):
    image = np.random.default_rng(1).integers(0, 256, (301, 203), np.uint8)
    pool = BandPool(threads)
    for rings in ((3,), (2, 5, 11)):
        whole = ring_level(image, rings)
        banded = pool.filter(lambda rows: ring_level(rows, rings), image, max(rings) + 2, np.empty_like(image))
        assert np.array_equal(banded, whole)
    whole = cv2.medianBlur(image, 13)
    assert np.array_equal(pool.filter(lambda rows: cv2.medianBlur(rows, 13), image, 6, np.empty_like(image)), whole)
    mask = cv2.compare(image, 200, cv2.CMP_GT)
    prominent = cv2.compare(image, 250, cv2.CMP_GT)
    assert np.array_equal(prominent_only(mask, prominent, 7, pool), prominent_only(mask, prominent, 7))


@pytest.mark.parametrize("fine", [True, False])
def test_the_splits_images_in_bands_equal_the_whole_frames(fine):
    excess = np.random.default_rng(3).integers(0, 256, (277, 190), np.uint8)
    whole = split_images(excess, fine)
    for got, want in zip(split_images(excess, fine, BandPool(4)), whole):
        assert (got is None and want is None) or (got.dtype == want.dtype and np.array_equal(got, want))


def _clusters(seed):
    """(components, excess, noise) of a frame of touching and lone discs, many split, working pixels."""
    rng = np.random.default_rng(seed)
    excess = np.zeros((300, 400), np.float32)
    for _ in range(140):
        x, y = rng.uniform(5, [395, 295])
        for dx in (0.0, rng.uniform(2.5, 6.0)) if rng.random() < 0.5 else (0.0,):
            cv2.circle(excess, (int((x + dx) * 16), int(y * 16)), int(rng.uniform(1, 4) * 16),
                       float(rng.uniform(30, 250)), -1, cv2.LINE_AA, 4)
    excess = cv2.GaussianBlur(excess, (0, 0), 0.8).astype(np.uint8)
    mask = cv2.compare(excess, 12, cv2.CMP_GT)
    return label(mask), excess, np.full((19, 25), 2.0, np.float32)


@pytest.mark.parametrize("budget", [0, 3000])
def test_components_measured_in_bands_give_measures_detections_in_its_order(budget):
    components, excess, noise = _clusters(4)
    settings = dict(halo=1.0, core=0.5, max_radius=48.0, split=True, frame_width=800, factor=2, lone_k=5.0,
                    split_budget=budget)
    want = measure(components, excess, noise, **settings)
    assert len(want) > components["count"] > 100  # the split made more particles than components
    assert (want.cut > 0) == (budget > 0)  # a small budget leaves some whole: the frame measured whole again
    for threads in (2, 3, 4):
        assert _same(measure_in_bands(components, excess, noise, BandPool(threads), **settings), want)


@pytest.mark.parametrize("channel,point", [("luma", 0.15), ("min", 0.0), ("green", 1.0)])
def test_the_pooling_in_bands_equals_the_whole_frames(channel, point):
    frame = np.random.default_rng(2).integers(0, 256, (218, 302, 3), np.uint8)
    grey, half = downsample_in_bands(frame, BandPool(3), factor=2, channel=channel, point=point)
    assert np.array_equal(half, downsample(frame, factor=2, channel=channel, point=point))
    assert np.array_equal(downsample(grey, factor=2, point=point), half)
    y = frame[..., 1].copy()
    grey, half = downsample_in_bands(y, BandPool(2), factor=2, channel=channel, point=point)
    assert grey is y and np.array_equal(half, downsample(y, factor=2, point=point))


def test_particles_on_the_band_seams_are_found_once_as_on_one_thread():
    # 1456x1088: the working image is 728x544; discs centred on every seam of 2, 3 and 4 bands,
    # of radius 1 to 10 px, and pairs touching across a seam
    width, height = 1456, 1088
    rows = {r for threads in (2, 3, 4) for r in _seams(height // 2, threads)}
    discs = []
    for i, r in enumerate(sorted(rows)):
        y = 2 * r  # full-resolution row of the seam
        for j, radius in enumerate((1.0, 2.0, 4.0, 7.0, 10.0)):
            discs.append((80.0 + 260 * j + 17 * i, y + (j % 3 - 1) * 0.5, radius, 60 + 25 * j))
        discs += [(1380.0, y - 4.0, 4.0, 90), (1380.0, y + 4.0, 4.0, 120)]  # touching across it
    frames = [scene((width, height), discs, background=b, seed=s)
              for s, b in enumerate(("flat", "gradient", "texture", "texture"))]
    one = _run(frames, 1)
    on_seams = [d for d in discs if d[2] >= 2.0 and d[3] >= 60]
    for found in one:  # the reference finds them, each once
        near = [np.hypot(*(found.centres - (x, y)).T).min() for x, y, _, _ in on_seams]
        assert np.max(near) < 3.0
    _check_equal(frames)


def test_a_frame_full_of_particles_is_detected_alike():
    scene_ = make_scene("dense", rng=np.random.default_rng(5), size=(1456, 1088))
    frames = []
    for _ in range(6):
        frames.append(scene_.render())
        scene_.step()
    _check_equal(frames)
    assert min(len(f) for f in _run(frames[:1], 2)) > 300


def test_a_moving_view_and_new_scenes_are_detected_alike_frame_after_frame():
    # the view pans over textured ground (the frame alone vets the learnt background's candidates),
    # then cuts to unrelated ground (the model starts again from a single frame)
    rng = np.random.default_rng(7)
    ground = (40 + 60 * np.clip(rng.normal(0.5, 0.25, (700, 1100)), 0, 1)).astype(np.uint8)
    ground = cv2.GaussianBlur(ground, (0, 0), 3)
    frames = []
    for k in range(14):
        x = 20 + 6 * k if k < 10 else 300
        view = ground[40:640, x:x + 800].copy()
        for _ in range(40):
            cx, cy = rng.integers(10, 790), rng.integers(10, 590)
            cv2.circle(view, (int(cx), int(cy)), int(rng.integers(1, 5)), 220, -1)
        frames.append(cv2.cvtColor(view, cv2.COLOR_GRAY2BGR))
    frames[12] = cv2.flip(frames[12], 0)
    _check_equal(frames)
    _check_equal(frames[:4], ContrastParams(memory=0))  # single-frame: every frame from itself


def test_the_background_learnt_on_two_threads_is_one_threads_to_the_last_bit():
    rng = np.random.default_rng(8)
    ground = cv2.GaussianBlur((40 + 60 * rng.random((640, 900))).astype(np.uint8), (0, 0), 3)
    models = []
    detectors = [make_detector("contrast", threads=t) for t in (1, 2)]
    for detector in detectors:
        models.append(detector.reset.__self__)  # the BackgroundModel the detector's stages share
    for k in range(20):  # still, then panning
        x = 10 if k < 10 else 10 + 5 * (k - 10)
        view = ground[20:620, x:x + 800].copy()
        for cx, cy in rng.integers(10, [790, 590], (30, 2)):
            cv2.circle(view, (int(cx), int(cy)), 2, 200, -1)
        for detector in detectors:
            detector.detect(view)
        one, two = models
        for name in ("background", "base", "limit", "noise", "_previous", "_persist", "_deficit"):
            assert np.array_equal(getattr(one, name), getattr(two, name)), (k, name)
        assert (one._frames, one._moved_ago, one._next) == (two._frames, two._moved_ago, two._next)


def test_grey_frames_odd_sizes_and_the_lamps_light_are_detected_alike():
    grey = [cv2.cvtColor(scene((801, 601), [(400.0, 300.0, 3.0, 90), (100.0, 151.0, 5.0, 60)], seed=s),
                         cv2.COLOR_BGR2GRAY) for s in range(4)]
    _check_equal(grey)  # not whole 2x2 blocks: pooled whole, the rest in bands
    frames = [scene((800, 600), [(400.0, 300.0, 3.0, 90), (600.0, 301.0, 5.0, 60)], seed=s) for s in range(4)]
    light = np.ones((600, 800), np.float32)
    light[250:350, 100:200] = 0.3
    _check_equal(frames, light=light)


@pytest.mark.parametrize("threads", [0, -1, MAX_THREADS + 1, 2.0, True])
def test_a_bad_number_of_threads_is_refused(threads):
    with pytest.raises(ValueError) as err:
        BandPool(threads)
    assert str(err.value) == (f"threads: got {threads!r}, allowed 1..{MAX_THREADS} ({MAX_THREADS // 4} CPUs here, "
                              "four threads each)")
    with pytest.raises(ValueError, match="threads: got"):
        make_detector("contrast", threads=threads)


def test_a_detector_without_bands_runs_on_one_thread_whatever_is_asked():
    frame = scene((320, 240), [(100.0, 100.0, 3.0, 90)])
    assert _same(make_detector("seed", threads=4).detect(frame), make_detector("seed").detect(frame))


def test_an_error_in_a_band_is_raised_in_the_caller():
    def fail(rows):
        if rows.shape[0] < 300:
            raise RuntimeError("band failed")
        return rows

    with pytest.raises(RuntimeError, match="band failed"):
        BandPool(3).filter(fail, np.zeros((300, 10), np.uint8), 2, np.empty((300, 10), np.uint8))
