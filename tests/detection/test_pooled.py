"""A frame already at the detector's working resolution (the camera's ISP scaled it): ``Pooled``."""

import cv2
import numpy as np
import pytest

from antiscatter.detection import Pooled, make_detector
from antiscatter.detection.contrast import ContrastParams


def _frame(width=800, height=600, background=30, disc=180):
    """A frame of ``background`` grey with noise and 12 discs of ``disc`` grey, radius 3 px, 60 px
    apart (full-resolution pixels)."""
    rng = np.random.default_rng(5)
    image = rng.normal(background, 2, (height, width)).clip(0, 255).astype(np.uint8)
    centres = [(100.0 + 60 * i, 150.0 + 200 * (i % 3)) for i in range(12)]
    for x, y in centres:
        cv2.circle(image, (int(x), int(y)), 3, disc, -1)
    return image, np.array(centres)


def test_contrast_on_a_pooled_plane_finds_what_it_finds_on_the_full_frame_in_full_resolution_pixels():
    image, centres = _frame()
    plane = cv2.resize(image, (400, 300), interpolation=cv2.INTER_AREA)
    for full in (image, None):
        found = make_detector("contrast", ContrastParams(memory=0)).detect(Pooled(plane, 2, full))
        same = make_detector("contrast", ContrastParams(memory=0, point=0.0)).detect(image)
        np.testing.assert_allclose(found.centres, same.centres)
        np.testing.assert_allclose(found.radii, same.radii)
        assert len(found) == 12
        order = np.argsort(found.centres[:, 0])
        np.testing.assert_allclose(found.centres[order], centres, atol=0.6)  # the discs' centres, full-res px
        assert np.all((found.radii > 3) & (found.radii < 7))


def test_the_lamps_light_map_is_pooled_as_the_isp_pooled_the_frame():
    # a hole in the lamp's light over the frame: its edge in the working image is the ISP's (a 2x2
    # mean), so the map's must be too -- the lores path then finds what point=0 finds on the full frame
    image, _ = _frame(background=150, disc=250)  # bright ground: a rim pooled otherwise stands out
    light = np.full(image.shape, 1.0, np.float32)
    light[101:261, 151:471] = 0.3  # edges inside 2x2 blocks: a mean and a maximum differ there
    lit = (image * light).astype(np.uint8)
    plane = cv2.resize(lit, (400, 300), interpolation=cv2.INTER_AREA)
    on_lores = make_detector("contrast", ContrastParams(memory=0))
    same = make_detector("contrast", ContrastParams(memory=0, point=0.0))
    for detector in (on_lores, same):
        detector.set_light(light)
    found, expected = on_lores.detect(Pooled(plane, 2, lit)), same.detect(lit)
    assert len(found) >= 10
    np.testing.assert_allclose(found.centres, expected.centres)
    np.testing.assert_allclose(found.radii, expected.radii)


def test_working_size_is_the_contrast_detectors_working_resolution():
    assert make_detector("contrast").working_size(1456, 1088) == (728, 544)
    assert make_detector("contrast").working_size(800, 600) == (400, 300)
    assert make_detector("contrast").working_size(600, 400) is None  # factor 1 below 640 px: nothing pooled
    assert make_detector("contrast", ContrastParams(factor=1)).working_size(1456, 1088) is None
    assert make_detector("seed").working_size(1456, 1088) is None
    assert Pooled(np.zeros((544, 728), np.uint8), 2).size == (1456, 1088)


@pytest.mark.parametrize("detector, pooled, message", [
    ("contrast", Pooled(np.zeros((300, 400), np.uint8), 3),
     "pooled plane of 400x300 px at factor 3: detector 'contrast' works on 600x450 px for 1200x900 px frames"),
    ("contrast", Pooled(np.zeros((150, 200), np.uint8), 4),
     "pooled plane of 200x150 px at factor 4: detector 'contrast' works on 400x300 px for 800x600 px frames"),
    ("seed", Pooled(np.zeros((300, 400), np.uint8), 2),
     "pooled plane of 400x300 px at factor 2: detector 'seed' works on whole frames only for 800x600 px frames"),
    ("contrast", Pooled(np.zeros((300, 400), np.float32), 2),
     r"pooled plane of float32 with shape \(300, 400\): allowed uint8, \(h, w\)"),
    ("contrast", Pooled(np.zeros((300, 400), np.uint8), 2, np.zeros((600, 801), np.uint8)),
     r"pooled full plane of shape \(600, 801\): allowed \(600, 800\)"),
])
def test_a_pooled_frame_the_detector_cannot_take_is_refused(detector, pooled, message):
    with pytest.raises(ValueError, match=message):
        make_detector(detector).detect(pooled)
