"""The multi-process mode: shared-memory ring, identical results, crash propagation, clean-up."""

import csv
import io
import os

import numpy as np
import pytest

from antiscatter.config import load_config
from antiscatter.parallel import DetectorProcess, FrameRing
from antiscatter.runtime import run


def shm_names():
    return set(os.listdir("/dev/shm")) if os.path.isdir("/dev/shm") else set()


def test_ring_round_trip_is_byte_exact_across_processes():
    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 256, (48, 64, 3), dtype=np.uint8) for _ in range(6)]
    ring = FrameRing((48, 64, 3), np.uint8, slots=3)
    try:
        other = FrameRing((48, 64, 3), np.uint8, slots=3, name=ring.name)  # as the worker opens it
        for i, f in enumerate(frames):
            ring.write(i % 3, f[:, :, :])
            np.testing.assert_array_equal(other.view(i % 3), f)
        other.close()
    finally:
        ring.close()
    assert ring.name not in shm_names()


def test_detector_process_gives_the_same_particles_as_in_process():
    from antiscatter.detection import make_detector
    from antiscatter.simulate import make_scene
    scene = make_scene("bubbles", rng=np.random.default_rng(1), size=(320, 240))
    images = []
    for _ in range(5):
        images.append(scene.render())
        scene.step()
    local = make_detector("contrast")
    expected = [local.detect(im) for im in images]
    for transport in ("shm", "pickle"):
        worker = DetectorProcess("contrast", None, images[0], transport=transport)
        try:
            got = {}
            for i, im in enumerate(images):
                worker.submit(i, im)
                while worker.full:
                    result = worker.receive(timeout=5)
                    if result:
                        got[result[0]] = result[1]
            while len(got) < len(images):
                result = worker.receive(timeout=5)
                if result:
                    got[result[0]] = result[1]
        finally:
            worker.close()
        for i, e in enumerate(expected):
            np.testing.assert_allclose(got[i].centres, e.centres)
            np.testing.assert_allclose(got[i].radii, e.radii)


@pytest.mark.parametrize("mode", ["processes", "processes-pickle"])
def test_processes_mode_end_to_end_matches_single(tmp_path, mode):
    def detections(m):
        path = tmp_path / f"{m}.csv"
        config = load_config(overrides={"output": {"outputs": ("none",)},
                                        "run": {"mode": m, "frames": 30, "detections": str(path)}})
        summary = run(config, log=io.StringIO(), out=io.StringIO())
        assert summary.frames == 30
        return path.read_text()
    before = shm_names()
    assert detections(mode) == detections("single")
    assert not (shm_names() - before)


def test_a_crash_in_the_detector_process_stops_the_run(tmp_path, monkeypatch):
    from antiscatter.detection.contrast import chain as contrast  # the module whose stage calls downsample

    def broken(image, **params):
        raise RuntimeError("worker exploded")

    monkeypatch.setattr(contrast, "downsample", broken)  # inherited by the forked worker
    before = shm_names()
    config = load_config(overrides={"output": {"outputs": ("none",)},
                                    "run": {"mode": "processes", "frames": 10,
                                            "metrics": str(tmp_path / "m.csv")}})
    with pytest.raises(RuntimeError, match="detector process: RuntimeError: worker exploded"):
        run(config, log=io.StringIO(), out=io.StringIO())
    assert not (shm_names() - before)
    assert len(list(csv.reader((tmp_path / "m.csv").open()))) == 1  # a complete header, no half rows
