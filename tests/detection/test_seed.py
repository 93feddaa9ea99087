import numpy as np
import pytest

from antiscatter.detection import DETECTORS, detect, make_detector
from antiscatter.detection.seed import SeedParams, canny_auto, threshold
from antiscatter.errors import UsageError
from conftest import draw_discs

DISCS = [(40.0, 40.0, 3.0), (120.3, 45.7, 6.0), (200.5, 60.25, 10.0), (80.0, 140.0, 20.0),
         (220.0, 160.0, 4.0)]


def test_isolated_discs_found_within_one_pixel():
    image = draw_discs((280, 200), DISCS)
    found = detect(image, "seed")
    assert len(found) == len(DISCS)
    for x, y, r in DISCS:
        distance = np.hypot(found.centres[:, 0] - x, found.centres[:, 1] - y)
        i = int(np.argmin(distance))
        assert distance[i] <= 1.0
        assert abs(found.radii[i] - r) <= 1.0


def test_grey_input_gives_same_result_as_bgr():
    image = draw_discs((280, 200), DISCS)
    a = detect(image)
    b = detect(image[..., 0].copy())
    np.testing.assert_allclose(a.centres, b.centres)


def test_dim_particles_below_threshold_are_missed_and_threshold_parameter_works():
    image = draw_discs((100, 100), [(50, 50, 6)], value=180)
    assert len(detect(image)) == 0
    assert len(detect(image, threshold=150)) == 1


def test_empty_frame_gives_empty_detections_of_normal_shape():
    found = detect(np.zeros((60, 80, 3), np.uint8))
    assert found.centres.shape == (0, 2)
    assert found.radii.shape == (0,)


def test_stage_chain_is_the_reports():
    names = [s.name for s in make_detector("seed").stages]
    assert names == ["greyscale", "blur", "threshold", "canny", "contours", "circles"]
    names = [s.name for s in make_detector("seed", SeedParams(equalise=True)).stages]
    assert names == ["greyscale", "blur", "equalise", "canny", "contours", "circles"]


def test_equalise_design_lights_up_texture():
    # the report's first design: equalisation turns faint texture into edges
    rng = np.random.default_rng(0)
    texture = (rng.random((100, 100)) * 40).astype(np.uint8)
    image = np.dstack([texture] * 3)
    assert len(detect(image)) == 0
    assert len(detect(image, equalise=True)) > 5


def test_threshold_is_strictly_above_level():
    image = np.array([[199, 200, 201]], np.uint8)
    assert threshold(image, level=200).tolist() == [[0, 0, 255]]


def test_canny_thresholds_follow_the_median():
    binary = np.zeros((50, 50), np.uint8)
    binary[20:30, 20:30] = 255
    edges = canny_auto(binary, sigma=0.33)
    assert edges[20:30, 20:30].any()
    assert not edges[:10, :10].any()


@pytest.mark.parametrize("kwargs, message", [
    ({"threshold": 256}, "threshold: got 256, allowed 0..255"),
    ({"blur_kernel": 4}, "blur_kernel: got 4, allowed an odd integer >= 1"),
    ({"canny_sigma": 2.0}, "canny_sigma: got 2.0, allowed 0..1"),
])
def test_bad_params_rejected(kwargs, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        SeedParams(**kwargs)


def test_unknown_detector():
    with pytest.raises(UsageError, match="unknown detector 'nope'; allowed: contrast, seed"):
        make_detector("nope")
    assert "seed" in DETECTORS
