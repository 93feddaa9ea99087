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


def test_camera_light_puts_each_hole_back_where_the_camera_sees_its_particle():
    from antiscatter.pattern import camera_light

    camera, projector = (640, 480), (1280, 800)
    mapping = np.array([[1.9, 0.1, 12.0], [0.05, 1.6, -8.0], [1e-5, 2e-5, 1.0]])  # camera -> projector
    holes = Detections([[100.0, 80.0], [500.0, 400.0]], [8.0, 8.0])
    pattern = render_pattern(holes, size=projector, mapping=mapping, hole=51)
    light = camera_light(pattern, np.linalg.inv(mapping), camera)
    assert light.shape == (480, 640) and light.dtype == np.uint8
    yy, xx = np.mgrid[0:480, 0:640]
    for x, y in holes.centres:
        near = np.hypot(xx - x, yy - y)
        assert (light[near < 6] == 51).all() and (light[(near > 10) & (near < 30)] == 255).all()
    # outside the projector's field: full, no pattern there to explain
    assert camera_light(pattern, np.linalg.inv(mapping) @ np.diag([0.25, 0.25, 1.0]), camera)[400, 600] == 255
    as_float = camera_light(pattern.astype(np.float32) / 255, np.linalg.inv(mapping), camera)
    assert np.abs(as_float.astype(int) - light).max() <= 1


def test_holes_grow_in_proportion_beyond_a_size():
    from antiscatter.pattern import grow_holes

    holes = Detections([[10, 10], [50, 50], [90, 90]], [2.0, 4.0, 10.0], track_ids=[7, 8, 9])
    assert grow_holes(holes, grow=0.0, start=4.0, frame_width=800) is holes  # off
    grown = grow_holes(holes, grow=0.5, start=4.0, frame_width=800)
    np.testing.assert_allclose(grown.radii, [2.0, 4.0, 13.0])  # only the excess over 4 px grows
    np.testing.assert_array_equal(grown.centres, holes.centres)
    assert grown.track_ids.tolist() == [7, 8, 9]
    # the threshold is for frames 800 px wide: at 1600 px the same particle is twice the pixels
    np.testing.assert_allclose(grow_holes(holes, grow=0.5, start=4.0, frame_width=1600).radii, [2.0, 4.0, 11.0])
    assert len(grow_holes(Detections.empty(), grow=1.0, start=0.0, frame_width=800)) == 0
