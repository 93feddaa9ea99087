import numpy as np

from antiscatter.detections import Detections
from antiscatter.pattern import map_to_projector, render_pattern, scale_mapping


def test_holes_drawn_black_at_detections_on_white():
    d = Detections([[20, 30], [70.5, 10.5]], [5, 3])
    p = render_pattern(d, size=(100, 50))
    assert p.shape == (50, 100) and p.dtype == np.uint8
    yy, xx = np.mgrid[0:50, 0:100]
    inside = ((xx - 20) ** 2 + (yy - 30) ** 2 <= 4 ** 2) | ((xx - 70.5) ** 2 + (yy - 10.5) ** 2 <= 2 ** 2)
    outside = ((xx - 20) ** 2 + (yy - 30) ** 2 > 6 ** 2) & ((xx - 70.5) ** 2 + (yy - 10.5) ** 2 > 4 ** 2)
    assert (p[inside] == 0).all()
    assert (p[outside] == 255).all()


def test_margin_grows_holes():
    d = Detections([[50, 25]], [4])
    dark = lambda margin: int((render_pattern(d, size=(100, 50), margin=margin) == 0).sum())
    # rasterised discs: area within 15% of pi r^2
    assert abs(dark(0) / (np.pi * 16) - 1) < 0.15
    assert abs(dark(3) / (np.pi * 49) - 1) < 0.15


def test_empty_detections_give_full_light_and_reuse_buffer():
    buf = np.zeros((10, 20), np.uint8)
    out = render_pattern(Detections.empty(), size=(20, 10), out=buf)
    assert out is buf and (buf == 255).all()


def test_scaled_mapping_moves_and_scales_holes():
    h = scale_mapping((640, 400), (1280, 800))
    centres, radii = map_to_projector(Detections([[100, 50]], [4]), h)
    np.testing.assert_allclose(centres, [[200, 100]])
    np.testing.assert_allclose(radii, [8])


def test_homography_radius_keeps_local_area():
    # a homography with a translation and anisotropic scale: radius scales by sqrt(sx*sy)
    h = np.array([[2.0, 0, 10], [0, 0.5, -5], [0, 0, 1]])
    centres, radii = map_to_projector(Detections([[10, 20]], [3]), h)
    np.testing.assert_allclose(centres, [[30, 5]])
    np.testing.assert_allclose(radii, [3.0])
