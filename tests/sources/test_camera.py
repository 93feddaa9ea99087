import numpy as np
import pytest

from antiscatter.errors import UsageError
from antiscatter.sources.camera import CameraSource, load_picamera2


class FakeRequest:
    def __init__(self, image, stamp):
        self.image, self.stamp, self.released = image, stamp, False

    def make_array(self, name):
        assert name == "main"
        return self.image

    def get_metadata(self):
        return {"SensorTimestamp": self.stamp, "ExposureTime": 1000}

    def release(self):
        self.released = True


class FakePicamera2:
    """Hands out real numpy frames and metadata like Picamera2 does."""

    instances: list["FakePicamera2"] = []

    def __init__(self):
        self.config = None
        self.started = self.closed = False
        self.requests = []
        self.set = []
        FakePicamera2.instances.append(self)

    def create_video_configuration(self, main, buffer_count, queue, controls):
        return {"main": main, "buffer_count": buffer_count, "queue": queue, "controls": controls}

    def configure(self, config):
        self.config = config

    def start(self):
        self.started = True

    def capture_request(self):
        n = len(self.requests)
        w, h = self.config["main"]["size"]
        if self.config["main"]["format"] == "YUV420":
            stride = (w + 63) // 64 * 64  # padded rows, as the ISP delivers them
            image = np.full((h * 3 // 2, stride), 200, np.uint8)
            image[:h, :w] = (np.arange(w)[None, :] + n) % 256  # Y plane
        else:
            image = np.full((h, w, 3), n, np.uint8)
        request = FakeRequest(image, 1_000_000_000 + n * 16_666_667)
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
        assert stream == "main"
        self.request = request

    def __enter__(self):
        FakeMappedArray.entered += 1
        self.array = self.request.image
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
