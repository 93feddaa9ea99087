"""Gray-code calibration against the twin's exact geometry, the hardware rig's logic, and bad files."""

import json

import cv2
import numpy as np
import pytest

from antiscatter.calibration import (Calibration, HardwareRig, TwinRig, calibrate_planes, decode_plane,
                                     fit_homography, load_calibration, mapping_error_px)
from antiscatter.errors import UsageError
from antiscatter.twin import TwinGeometry

SIZE, PROJECTOR = (400, 300), (640, 400)


def geometry(baseline):
    return TwinGeometry(camera_size=SIZE, projector_size=PROJECTOR, baseline_m=baseline)


@pytest.mark.parametrize("noise", [1.0, 8.0])
def test_recovers_a_known_homography_on_a_flat_target(noise):
    g = geometry(0.0)
    rig = TwinRig(g, 1.0, noise=noise)
    camera, projector = decode_plane(rig.capture, PROJECTOR, step=6)
    assert len(camera) > 1000
    H, fit = fit_homography(camera, projector)
    error = mapping_error_px(H, g.plane_mapping(1.0), SIZE, PROJECTOR)
    assert error["max_px"] < 1.0  # goal: under one projector pixel
    assert fit < 1.0


def test_recovers_a_known_baseline_from_two_depths():
    g = geometry(0.12)
    calibration = calibrate_planes({0.5: TwinRig(g, 0.5).capture, 2.0: TwinRig(g, 2.0, rng=np.random.default_rng(1)).capture},
                                   camera_size=SIZE, projector_size=PROJECTOR, camera_focal_px=g.camera_focal, step=6)
    assert calibration.baseline_m == pytest.approx(0.12, rel=0.02)
    assert calibration.projector_focal_px == pytest.approx(g.projector_focal, rel=0.01)
    for depth in (0.4, 1.0, 3.0):  # the depth model holds between and beyond the measured planes
        assert mapping_error_px(calibration.mapping_at(depth), g.plane_mapping(depth), SIZE, PROJECTOR)["max_px"] < 1.5


class LoopbackOutput:
    """A light output whose pattern the loopback camera sees (the hardware path, without hardware)."""

    def __init__(self):
        self.shown = None
        self.count = 0

    def show(self, pattern, frame=None, detections=None):
        self.shown = pattern
        self.count += 1

    def close(self):
        pass


class LoopbackCamera:
    def __init__(self, rig, output):
        self.rig, self.output, self.size = rig, output, SIZE

    def read(self):
        from antiscatter.sources.base import Frame
        return Frame(cv2.cvtColor(self.rig.capture(self.output.shown), cv2.COLOR_GRAY2BGR), 0, 0)


def test_hardware_rig_shows_each_pattern_and_captures_after_settling():
    g = geometry(0.0)
    output = LoopbackOutput()
    rig = HardwareRig(LoopbackCamera(TwinRig(g, 1.0), output), [output], settle=2)
    calibration = calibrate_planes({1.0: rig.capture}, camera_size=SIZE, projector_size=PROJECTOR, step=8)
    assert output.count > 20  # every Gray-code pattern plus white and black went out
    assert mapping_error_px(calibration.homography, g.plane_mapping(1.0), SIZE, PROJECTOR)["max_px"] < 1.0


def test_save_and_load_round_trip(tmp_path):
    H = np.array([[2.0, 0, 5], [0, 2, 3], [0, 0, 1]])
    Calibration(SIZE, PROJECTOR, H, 1.0, ((1.0, H),), 0.1, 300.0, 600.0, (0.3,)).save(tmp_path / "c.json")
    loaded = load_calibration(tmp_path / "c.json")
    np.testing.assert_allclose(loaded.homography, H)
    assert loaded.baseline_m == 0.1 and loaded.camera_size == SIZE
    assert loaded.mapping_at(2.0)[0, 2] == pytest.approx(5 + 600 * 0.1 * (1 / 1.0 - 1 / 2.0))


@pytest.mark.parametrize("content, message", [
    ("not json", "not a calibration file"),
    ('{"version": 2}', "version: expected 1"),
    ('{"version": 1, "camera_size": [400, 300], "projector_size": [640, 400], "working_depth_m": 1}',
     "missing key 'homography'"),
    ('{"version": 1, "camera_size": [400, 300], "projector_size": [640, 400], "working_depth_m": 1, '
     '"homography": [[1, 0], [0, 1]]}', "homography: expected an invertible 3x3 matrix"),
    ('{"version": 1, "camera_size": [400, -3], "projector_size": [640, 400], "working_depth_m": 1, '
     '"homography": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}', "two positive integers"),
    ('{"version": 1, "camera_size": [400, 300], "projector_size": [640, 400], "working_depth_m": 1, '
     '"homography": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "baseline_m": NaN}', "baseline_m: got nan, allowed a finite"),
    ('{"version": 1, "camera_size": [400, 300], "projector_size": [640, 400], "working_depth_m": 1, '
     '"homography": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "camera_focal_px": 0}', "camera_focal_px: got 0.0, allowed a number > 0"),
    ('{"version": 1, "camera_size": [400, 300], "projector_size": [640, 400], "working_depth_m": 1, '
     '"homography": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "planes": [{"depth_m": 0.5, "homography": '
     '[[1, 0, 0], [0, 1, 0], [0, 0, 1]]}, {"depth_m": 0.5, "homography": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}]}',
     "planes: depth_m \\[0.5, 0.5\\], allowed distinct distances > 0"),
])
def test_bad_calibration_files_are_rejected(tmp_path, content, message):
    path = tmp_path / "bad.json"
    path.write_text(content)
    with pytest.raises(UsageError, match=message):
        load_calibration(path)


def test_calibrate_command_and_its_use_in_run_and_twin(tmp_path, cli):
    out = tmp_path / "cal.json"
    result = cli("calibrate", str(out), "--twin", "--size", "400x300", "--projector-size", "640x400",
                 "--baseline-m", "0.12")
    assert result.code == 0, result.err
    assert "baseline 0.12" in result.out and "against the twin's true geometry" in result.out
    data = json.loads(out.read_text())
    assert data["version"] == 1 and abs(data["baseline_m"] - 0.12) < 0.003
    run = cli("run", "--frames", "3", "--output", "none", "--size", "400x300", "--preset", "bubbles",
              "--calibration", str(out), "--output", f"files:{tmp_path / 'p'}")
    assert run.code == 0, run.err
    assert cv2.imread(str(tmp_path / "p" / "0.png"), cv2.IMREAD_UNCHANGED).shape == (400, 640)
    # made for another camera size: every hole would land in the wrong place (it ran before)
    other = cli("run", "--frames", "3", "--size", "320x240", "--calibration", str(out), "--output", "none",
                "--detections", str(tmp_path / "d.csv"))
    assert other.code == 2 and "made for camera 400x300 and projector 640x400; this run has camera 320x240" in other.err
    assert len(other.err.strip().splitlines()) == 1 and not (tmp_path / "d.csv").exists()
    twin = cli("twin", "--frames", "4", "--size", "400x300", "--projector-size", "640x400", "--preset", "bubbles",
               "--calibration", str(out), "--json")
    assert twin.code == 0, twin.err
    assert json.loads(twin.out)["calibration_error"]["max_px"] < 1.0
    bad = cli("twin", "--frames", "2", "--calibration", str(out))  # made for another camera size
    assert bad.code == 2 and "made for camera" in bad.err
    missing = cli("run", "--calibration", str(tmp_path / "none.json"))
    assert missing.code == 2 and "no such calibration file" in missing.err


def test_dense_decoding_agrees_with_opencvs_decoder():
    from antiscatter.calibration import decode_dense, gray_code_patterns

    geometry = TwinGeometry(camera_size=(200, 150), projector_size=(320, 200), baseline_m=0.0)
    rig = TwinRig(geometry, 1.0, noise=2.0)
    code, patterns, white, black = gray_code_patterns(geometry.projector_size)
    captures = [rig.capture(p) for p in patterns]
    lit, dark = rig.capture(white), rig.capture(black)
    column, row = decode_dense(captures, lit, dark, geometry.projector_size)
    code.setWhiteThreshold(5)
    code.setBlackThreshold(40)
    checked = 0
    for y in range(5, 150, 13):
        for x in range(5, 200, 17):
            error, pixel = code.getProjPixel(captures, x, y)
            if not error and np.isfinite(column[y, x]):
                assert (column[y, x], row[y, x]) == (pixel[0], pixel[1])
                checked += 1
    assert checked > 25  # every pixel both decoded agrees exactly
    truth = cv2.perspectiveTransform(np.array([[[100.0, 75.0]]]), rig.truth)[0, 0]
    assert abs(column[75, 100] - truth[0]) <= 1 and abs(row[75, 100] - truth[1]) <= 1


def test_board_calibration_recovers_intrinsics_baseline_and_mapping():
    from antiscatter.calibration import Board, BoardRig, calibrate_board, twin_board_poses

    geometry = TwinGeometry(baseline_m=0.12)  # the defaults of 'calibrate --twin --board 9x6:0.04'
    board = Board(9, 6, 0.04)
    rigs = [BoardRig(geometry, r, t, board=board, rng=np.random.default_rng(i))
            for i, (r, t) in enumerate(twin_board_poses(8, board=board))]
    calibration = calibrate_board([rig.capture for rig in rigs], board=board, camera_size=geometry.camera_size,
                                  projector_size=geometry.projector_size)
    stereo = calibration.stereo
    assert stereo.camera_matrix[0, 0] == pytest.approx(geometry.camera_focal, rel=0.01)
    assert stereo.projector_matrix[0, 0] == pytest.approx(geometry.projector_focal, rel=0.01)
    assert calibration.baseline_m == pytest.approx(0.12, abs=0.002)
    np.testing.assert_allclose(stereo.rotation, np.eye(3), atol=0.01)  # the twin's axes are parallel
    for depth in (0.5, 1.0, 2.0):
        error = mapping_error_px(calibration.mapping_at(depth), geometry.plane_mapping(depth),
                                 geometry.camera_size, geometry.projector_size)
        assert error["max_px"] < 1.0, (depth, error)


def test_board_calibration_file_round_trip_and_needs_three_poses(tmp_path, cli):
    from antiscatter.calibration import Board, calibrate_board

    path = tmp_path / "board.json"
    result = cli("calibrate", str(path), "--twin", "--board", "7x5:0.05", "--poses", "5", "--size", "480x360")
    assert result.code == 0, result.err
    assert "baseline 0.1" in result.out and "against the twin's true geometry" in result.out
    loaded = load_calibration(path)
    assert loaded.stereo is not None and loaded.baseline_m == pytest.approx(0.12, abs=0.003)
    np.testing.assert_allclose(loaded.mapping_at(1.0), loaded.stereo.plane_mapping(1.0))
    bad = cli("calibrate", str(tmp_path / "x.json"), "--twin", "--board", "9x6")
    assert bad.code == 2 and "expected COLSxROWS:SQUARE_M" in bad.err
    blank = lambda pattern: np.zeros((120, 160), np.uint8)  # noqa: E731 - a camera seeing nothing
    with pytest.raises(UsageError, match="at least 3 are needed"):
        calibrate_board([blank] * 3, board=Board(), camera_size=(160, 120), projector_size=(320, 200))
