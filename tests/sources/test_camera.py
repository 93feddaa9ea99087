import cv2
import numpy as np
import pytest

from antiscatter.errors import UsageError
from antiscatter.sources.camera import CameraSource, load_picamera2


def yuv420_buffer(y_plane, *, align=64, pad=255):
    """A YUV420 frame as Picamera2's make_array / MappedArray give it: (h * 3 / 2, stride) uint8,
    the Y plane's rows first, each padded to the stride (``align`` bytes) with junk, then U and V
    (two half-width rows to a row)."""
    h, w = y_plane.shape
    stride = (w + align - 1) // align * align
    buffer = np.full((h * 3 // 2, stride), pad, np.uint8)
    buffer[:h, :w] = y_plane
    buffer[h:, :] = 128  # neutral chroma (its padding included: any value will do)
    return buffer


class FakeRequest:
    def __init__(self, image, stamp, lores=None):
        self.image, self.stamp, self.released = image, stamp, False
        self.arrays = {"main": image, "lores": lores}

    def make_array(self, name):
        assert self.arrays.get(name) is not None, f"no {name} stream configured"
        return self.arrays[name]

    def get_metadata(self):
        return {"SensorTimestamp": self.stamp, "ExposureTime": 1000}

    def release(self):
        self.released = True


class FakePicamera2:
    """Hands out real numpy frames and metadata like Picamera2 does.

    scenes: Y planes (H, W) served in turn as the main stream when its size matches (a rendered
    scene); otherwise a gradient.  A lores stream is the main Y plane scaled by the "ISP" (OpenCV's
    area filter), both in YUV420 buffers with padded rows.  ``configure`` refuses what Picamera2's
    own check does (a lores larger than main, or not YUV)."""

    instances: list["FakePicamera2"] = []
    scenes: list[np.ndarray] = []

    def __init__(self):
        self.config = None
        self.started = self.closed = False
        self.requests = []
        self.set = []
        FakePicamera2.instances.append(self)

    def create_video_configuration(self, main, buffer_count, queue, controls, lores=None):
        return {"main": main, "buffer_count": buffer_count, "queue": queue, "controls": controls, "lores": lores}

    def configure(self, config):
        lores = config.get("lores")
        if lores is not None:  # Picamera2's check_camera_config
            if lores["size"][0] > config["main"]["size"][0] or lores["size"][1] > config["main"]["size"][1]:
                raise RuntimeError("lores stream dimensions may not exceed main stream")
            if lores["format"] not in ("YUV420", "YVU420", "NV12", "NV21"):
                raise RuntimeError("lores stream must be YUV")
        self.config = config

    def start(self):
        self.started = True

    def capture_request(self):
        n = len(self.requests)
        w, h = self.config["main"]["size"]
        lores = None
        if self.config["main"]["format"] == "YUV420":
            scenes = [s for s in FakePicamera2.scenes if s.shape == (h, w)]
            y = scenes[n % len(scenes)] if scenes else ((np.arange(w)[None, :] + n) % 256).astype(np.uint8).repeat(h, 0)
            image = yuv420_buffer(y, pad=200)  # padded rows, as the ISP delivers them
            if self.config.get("lores") is not None:
                size = self.config["lores"]["size"]
                lores = yuv420_buffer(cv2.resize(y, size, interpolation=cv2.INTER_AREA))
        else:
            image = np.full((h, w, 3), n, np.uint8)
        request = FakeRequest(image, 1_000_000_000 + n * 16_666_667, lores)
        self.requests.append(request)
        return request

    camera_controls = {"FrameDurationLimits": (16560, 15000000, 16667)}  # (min, max, default) us, as the IMX296's

    def set_controls(self, controls):
        self.set.append(controls)

    def stop(self):
        self.started = False

    def close(self):
        self.closed = True


class FakeMappedArray:
    """Picamera2's MappedArray: the request's buffer as an array, in place, inside a with block."""

    entered = 0

    def __init__(self, request, stream):
        self.request, self.stream = request, stream

    def __enter__(self):
        FakeMappedArray.entered += 1
        self.array = self.request.make_array(self.stream)
        return self

    def __exit__(self, *exc):
        del self.array


def test_yuv_y_plane_without_conversion_through_mapped_array():
    source = CameraSource(size=(60, 40), fps=120.0, picamera2=FakePicamera2, mapped_array=FakeMappedArray)
    cam = FakePicamera2.instances[-1]
    assert cam.config["main"]["format"] == "YUV420"
    assert cam.config["controls"]["FrameDurationLimits"] == (8333, 8333)
    frame = source.read()
    assert frame.image.shape == (40, 60) and frame.image.dtype == np.uint8
    np.testing.assert_array_equal(frame.image[0], np.arange(60) % 256)  # Y only, padding and UV cut off
    assert FakeMappedArray.entered >= 1 and cam.requests[-1].released
    # SensorTimestamp is the end of the 1 ms exposure: the frame's time is its middle
    assert frame.timestamp_ns == 1_000_000_000 - 500_000 and frame.exposure_ns == 1_000_000
    assert frame.exposure_start_ns == 1_000_000_000 - 1_000_000
    frame.image[0, 0] = 99  # our own copy: the camera buffer went back untouched
    assert cam.requests[0].image[0, 0] == 0
    source.close()


def test_camera_source_configures_and_reads_with_sensor_timestamps():
    source = CameraSource(size=(64, 48), fps=60.0, colour=True, picamera2=FakePicamera2)
    cam = FakePicamera2.instances[-1]
    assert cam.config["main"] == {"size": (64, 48), "format": "RGB888"}
    assert cam.config["controls"]["FrameDurationLimits"] == (16667, 16667)
    assert cam.config["queue"] is False
    first, second = source.read(), source.read()
    assert first.image.shape == (48, 64, 3)
    assert second.image[0, 0, 0] == 1
    assert second.timestamp_ns - first.timestamp_ns == 16_666_667
    assert first.exposure_ns == 1_000_000
    assert all(r.released for r in cam.requests)
    source.close()
    assert cam.closed


def test_off_the_pi_the_camera_needs_picamera2():
    try:
        import picamera2  # noqa: F401
    except ImportError:
        with pytest.raises(UsageError, match="source 'camera' needs the picamera2 package on a Raspberry Pi"):
            load_picamera2()
    else:  # on a Pi the classes load
        assert all(load_picamera2())


def test_a_fixed_exposure_turns_automatic_exposure_and_gain_off():
    # pulse and flash time the lamp to the exposure: it must be short and stay put
    CameraSource(size=(64, 48), fps=60.0, exposure_ms=4.0, gain=2.5, picamera2=FakePicamera2)
    controls = FakePicamera2.instances[-1].config["controls"]
    assert controls == {"FrameDurationLimits": (16667, 16667), "AeEnable": False, "ExposureTime": 4000,
                        "AnalogueGain": 2.5}
    CameraSource(size=(64, 48), fps=60.0, exposure_ms=2.0, picamera2=FakePicamera2)
    assert FakePicamera2.instances[-1].config["controls"]["AnalogueGain"] == 1.0
    CameraSource(size=(64, 48), fps=60.0, picamera2=FakePicamera2)  # automatic by default
    assert FakePicamera2.instances[-1].config["controls"] == {"FrameDurationLimits": (16667, 16667)}


@pytest.mark.parametrize("kw, message", [
    (dict(exposure_ms=20.0), r"camera exposure 20.0 ms: allowed 0 < exposure <= the frame period \(16.67 ms"),
    (dict(exposure_ms=0.0), "camera exposure 0.0 ms"),
    (dict(exposure_ms=4.0, gain=0.5), "camera gain 0.5: allowed 1.0 to 64"),
    (dict(gain=2.0), "camera gain: goes with a fixed exposure"),
])
def test_bad_exposure_settings_are_refused_before_the_camera_opens(kw, message):
    before = len(FakePicamera2.instances)
    with pytest.raises(UsageError, match=message):
        CameraSource(size=(64, 48), fps=60.0, picamera2=FakePicamera2, **kw)
    assert len(FakePicamera2.instances) == before


def test_run_refuses_a_bad_camera_exposure_in_one_line(cli):
    result = cli("run", "camera", "--camera-exposure-ms", "20", "--frames", "1", "--output", "none")
    assert result.code == 2 and len(result.err.strip().splitlines()) == 1
    assert "camera_exposure_ms: got 20.0, allowed 0 (automatic) to the frame period (16.67 ms)" in result.err
    result = cli("run", "camera", "--camera-gain", "2", "--frames", "1", "--output", "none")
    assert result.code == 2 and "camera_gain: got 2.0, goes with a fixed camera_exposure_ms" in result.err


def test_record_takes_the_same_exposure_settings(cli, tmp_path):
    result = cli("record", str(tmp_path / "r.mkv"), "--source", "camera", "--fps", "60", "--camera-exposure-ms", "40")
    assert result.code == 2 and "camera exposure 40.0 ms: allowed 0 < exposure <= the frame period" in result.err
    assert not (tmp_path / "r.mkv").exists()


@pytest.mark.parametrize("fps, exposure, gain", [
    (60.0, 16.667, None), (60.0, 16.668, None), (60.0, 4.0, 64.0), (60.0, 4.0, 64.5), (60.0, 4.0, 0.99),
    (120.0, 8.333, 1.0), (120.0, 8.4, None), (30.0, None, 2.0), (30.0, -1.0, None), (30.0, float("nan"), None)])
def test_the_config_and_the_camera_accept_the_same_exposures(fps, exposure, gain):
    # one rule (exposure_fault) behind both: a config value is refused exactly when the camera
    # would refuse it (0 in the config = automatic exposure / gain 1.0)
    from antiscatter.config import SourceConfig
    from antiscatter.sources.camera import camera_controls

    try:
        camera_controls(fps, exposure, gain)
        camera_ok = True
    except UsageError:
        camera_ok = False
    try:
        SourceConfig(spec="camera", camera_fps=fps, camera_exposure_ms=0.0 if exposure is None else exposure,
                     camera_gain=0.0 if gain is None else gain)
        config_ok = True
    except ValueError:
        config_ok = False
    assert camera_ok == config_ok


def test_the_phase_lock_nudges_the_frame_duration_within_what_the_sensor_can_do():
    source = CameraSource(size=(64, 48), fps=60.0, exposure_ms=4.0, picamera2=FakePicamera2)
    cam = FakePicamera2.instances[-1]
    assert source.shortest_frame_ns == 16_560_000
    source.set_frame_duration_ns(16_766_400)
    assert cam.set == [{"FrameDurationLimits": (16766, 16766)}]  # whole us, as libcamera takes them
    cam.camera_controls = {}
    assert source.shortest_frame_ns == 0  # a camera that does not say: no limit known
    source.close()


# --- the lores stream: the ISP scales the frame to the detector's working resolution ----------------


@pytest.fixture(scope="module")
def scene_planes():
    """Y planes of three consecutive 800x600 frames of the simulator's mixed scene (the camera's grey)."""
    from antiscatter.simulate import make_scene

    scene = make_scene("mixed", rng=np.random.default_rng(3), size=(800, 600))
    planes = []
    for k in range(3):
        if k:
            scene.step()
        planes.append(cv2.cvtColor(scene.render(), cv2.COLOR_BGR2GRAY))
    return planes


@pytest.fixture
def scenes(scene_planes, monkeypatch):
    monkeypatch.setattr(FakePicamera2, "scenes", scene_planes)
    return scene_planes


def test_the_lores_stream_is_asked_for_at_the_working_size_and_read_without_its_padding(scenes):
    source = CameraSource(size=(800, 600), fps=60.0, lores=(400, 300), picamera2=FakePicamera2,
                          mapped_array=FakeMappedArray)
    cam = FakePicamera2.instances[-1]
    assert cam.config["main"] == {"size": (800, 600), "format": "YUV420"}
    assert cam.config["lores"] == {"size": (400, 300), "format": "YUV420"}
    assert cam.config["buffer_count"] == 3 and cam.config["queue"] is False
    frame = source.read()
    assert cam.requests[0].arrays["lores"].shape == (450, 448)  # (h * 3 / 2, stride): padded rows, then U, V
    pooled = frame.pooled
    assert pooled.factor == 2 and pooled.size == (800, 600)
    np.testing.assert_array_equal(pooled.working, cv2.resize(scenes[0], (400, 300), interpolation=cv2.INTER_AREA))
    np.testing.assert_array_equal(frame.image, scenes[0])
    assert pooled.full is frame.image  # the main Y plane, copied once
    assert pooled.working.base is None or pooled.working.base is not cam.requests[0].arrays["lores"]
    assert cam.requests[0].released
    # the same through make_array where MappedArray is not given
    plain = CameraSource(size=(800, 600), fps=60.0, lores=(400, 300), picamera2=FakePicamera2)
    np.testing.assert_array_equal(plain.read().pooled.working, pooled.working)
    source.close()
    plain.close()


def test_lores_detections_are_in_full_resolution_pixels_and_match_the_full_frames(scenes):
    from antiscatter.assignment import match
    from antiscatter.detection import make_detector
    from antiscatter.detection.contrast import ContrastParams

    source = CameraSource(size=(800, 600), fps=60.0, lores=(400, 300), picamera2=FakePicamera2,
                          mapped_array=FakeMappedArray)
    on_lores = make_detector("contrast")
    mean_only = make_detector("contrast", ContrastParams(point=0.0))  # the detector's own 2x2 mean, no maximum
    default = make_detector("contrast")
    assert on_lores.working_size(800, 600) == (400, 300)
    for _ in range(3):
        frame = source.read()
        lores, full = on_lores.detect(frame.pooled), default.detect(frame.image)
        # an area-filtered lores plane is the detector's 2x2 mean: the same particles, exactly
        same = mean_only.detect(frame.image)
        np.testing.assert_array_equal(lores.centres, same.centres)
        np.testing.assert_array_equal(lores.radii, same.radii)
        # against the default pooling (a share of each block's maximum): nearly all, within a pixel
        assert len(full) > 40
        pairs, _, _ = match(full.centres, np.full(len(full), 1.5), lores.centres)
        assert len(pairs) >= 0.9 * max(len(full), len(lores))
        offsets = np.abs(full.centres[pairs[:, 0]] - lores.centres[pairs[:, 1]])
        assert np.median(offsets) < 0.25 and offsets.max() <= 1.5
        assert np.median(np.abs(full.radii[pairs[:, 0]] - lores.radii[pairs[:, 1]])) <= 1.0
    source.close()


@pytest.mark.parametrize("size, lores, message", [
    ((1458, 1088), (729, 544), "camera lores 729x544 beside main 1458x1088: its sides must be even (YUV420)"),
    ((800, 600), (1600, 1200), "larger than the main stream's 800x600 (the ISP only scales down)"),
    ((1457, 1088), (728, 544), "the main stream's 1457x1088 must be a whole multiple of it, 2 or more"),
    ((800, 600), (400, 200), "the main stream's 800x600 must be a whole multiple of it"),
])
def test_a_lores_size_the_isp_cannot_give_is_refused_before_the_camera_opens(size, lores, message):
    before = len(FakePicamera2.instances)
    with pytest.raises(UsageError, match=message.replace("(", r"\(").replace(")", r"\)")):
        CameraSource(size=size, lores=lores, picamera2=FakePicamera2)
    assert len(FakePicamera2.instances) == before
    with pytest.raises(UsageError, match="goes with the grey"):
        CameraSource(size=(800, 600), lores=(400, 300), colour=True, picamera2=FakePicamera2)


def test_a_configuration_the_camera_refuses_is_one_line(monkeypatch):
    def refuse(self, config):
        raise RuntimeError("Configuration failed: lores 400x300")

    monkeypatch.setattr(FakePicamera2, "configure", refuse)
    with pytest.raises(UsageError, match=r"^source 'camera': the camera refused its configuration "
                                         r"\(Configuration failed: lores 400x300\)$"):
        CameraSource(size=(800, 600), lores=(400, 300), picamera2=FakePicamera2)
    assert FakePicamera2.instances[-1].closed


def test_a_lores_size_libcamera_adjusts_is_refused_in_one_line(monkeypatch):
    # Picamera2 only logs an adjusted configuration and writes the sizes it gives into the config
    configure = FakePicamera2.configure

    def adjust(self, config):
        config["lores"]["size"] = (400, 296)
        configure(self, config)

    monkeypatch.setattr(FakePicamera2, "configure", adjust)
    with pytest.raises(UsageError, match=r"^source 'camera': the camera gives main 800x600, lores 400x296, not the "
                                         r"main 800x600 and lores 400x300 asked"):
        CameraSource(size=(800, 600), lores=(400, 300), picamera2=FakePicamera2)
    assert FakePicamera2.instances[-1].closed


@pytest.fixture
def fake_camera(monkeypatch):
    import antiscatter.sources.camera as camera

    monkeypatch.setattr(camera, "load_picamera2", lambda: (FakePicamera2, FakeMappedArray))


def test_run_camera_lores_gives_the_full_frames_detections(cli, tmp_path, scenes, fake_camera):
    # run's whole loop on the lores plane: the detections CSV (full-resolution pixels, tracks) is the
    # one the full frame gives with the detector's pooling at the 2x2 mean alone (point=0)
    common = ("run", "camera", "--size", "800x600", "--frames", "3", "--output", "none", "--fps", "0")
    lores = cli(*common, "--camera-lores", "--detections", str(tmp_path / "lores.csv"))
    assert lores.code == 0, lores.err
    full = cli(*common, "-p", "point=0", "--detections", str(tmp_path / "full.csv"))
    assert full.code == 0, full.err
    assert FakePicamera2.instances[-2].config["lores"] == {"size": (400, 300), "format": "YUV420"}
    assert FakePicamera2.instances[-1].config["lores"] is None
    def without_time(path):  # (the time column is UNIX time, mapped per run: it differs by the mapping)
        return [line.split(",")[:1] + line.split(",")[2:] for line in path.read_text().splitlines()]

    rows = without_time(tmp_path / "lores.csv")
    assert len(rows) > 100 and rows == without_time(tmp_path / "full.csv")


@pytest.mark.parametrize("args, message", [
    (("--size", "1458x1088"), "camera lores 729x544 beside main 1458x1088: its sides must be even (YUV420)"),
    (("--detector", "seed"), "camera_lores: the detector works on whole 728x544 frames"),
    (("-p", "factor=1"), "camera_lores: the detector works on whole 728x544 frames"),
    (("--camera-colour",), "camera_lores: got true with camera_colour true"),
    (("--mode", "processes"), "source.camera_lores: goes with run.mode single or threads"),
])
def test_run_refuses_a_lores_stream_it_cannot_use_in_one_line(cli, args, message, fake_camera):
    result = cli("run", "camera", "--camera-lores", "--frames", "1", "--output", "none", *args)
    assert result.code == 2 and len(result.err.strip().splitlines()) == 1, result.err
    assert message in result.err


def test_off_the_pi_camera_lores_still_says_picamera2_is_needed(cli):
    try:
        import picamera2  # noqa: F401
    except ImportError:
        result = cli("run", "camera", "--camera-lores", "--frames", "1", "--output", "none")
        assert result.code == 2 and len(result.err.strip().splitlines()) == 1
        assert "source 'camera' needs the picamera2 package on a Raspberry Pi" in result.err
