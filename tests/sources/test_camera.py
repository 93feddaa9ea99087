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
        image = np.full((h, w, 3), n, np.uint8)
        request = FakeRequest(image, 1_000_000_000 + n * 16_666_667)
        self.requests.append(request)
        return request

    def stop(self):
        self.started = False

    def close(self):
        self.closed = True


def test_camera_source_configures_and_reads_with_sensor_timestamps():
    source = CameraSource(size=(64, 48), fps=60.0, picamera2=FakePicamera2)
    cam = FakePicamera2.instances[-1]
    assert cam.config["main"] == {"size": (64, 48), "format": "RGB888"}
    assert cam.config["controls"]["FrameDurationLimits"] == (16667, 16667)
    assert cam.config["queue"] is False
    first, second = source.read(), source.read()
    assert first.image.shape == (48, 64, 3)
    assert second.image[0, 0, 0] == 1
    assert second.timestamp_ns - first.timestamp_ns == 16_666_667
    assert all(r.released for r in cam.requests)
    source.close()
    assert cam.closed


def test_off_the_pi_the_camera_needs_picamera2():
    try:
        import picamera2  # noqa: F401
    except ImportError:
        with pytest.raises(UsageError, match="source 'camera' needs the picamera2 package on a Raspberry Pi"):
            load_picamera2()
    else:  # on a Pi the class loads
        assert load_picamera2() is not None
