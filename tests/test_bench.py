"""The bench's own reference chain."""

import cv2
import numpy as np
import pytest


@pytest.mark.parametrize("grey", [False, True])
def test_the_chain_floor_finds_known_discs_and_nothing_on_plain_water(grey):
    # the bench's floor does the work it stands for: every disc of a known frame found, centre within
    # a pixel, radius within one and a half; a plain noisy frame gives empty arrays of the normal shape
    from antiscatter.bench import minimal_chain

    rng = np.random.default_rng(3)
    discs = [(100.0, 80.0, 3.0), (300.5, 220.5, 5.0), (520.0, 400.0, 8.0), (700.0, 90.0, 4.0)]
    frame = 40 + 60 * np.linspace(0, 1, 800)[None, :] + rng.normal(0, 1.0, (600, 800))
    plain = np.clip(np.rint(frame), 0, 255).astype(np.uint8)
    lit = frame.copy()
    for x, y, r in discs:
        spot = np.zeros((600, 800), np.float32)
        cv2.circle(spot, (round(x * 16), round(y * 16)), round(r * 16), 120.0, -1, cv2.LINE_AA, 4)
        lit += spot
    image = np.clip(np.rint(lit), 0, 255).astype(np.uint8)
    if not grey:
        image, plain = (cv2.cvtColor(v, cv2.COLOR_GRAY2BGR) for v in (image, plain))
    centres, radii = minimal_chain(image)
    assert len(centres) == len(discs)
    for x, y, r in discs:
        i = int(np.argmin(np.hypot(centres[:, 0] - x, centres[:, 1] - y)))
        assert np.hypot(centres[i, 0] - x, centres[i, 1] - y) < 1.0
        assert radii[i] == pytest.approx(r, abs=1.5)
    centres, radii = minimal_chain(plain)
    assert centres.shape == (0, 2) and radii.shape == (0,)


def _frames_with_discs(count, size=(320, 240)):
    rng = np.random.default_rng(1)
    frames = []
    for i in range(count):
        image = np.full((size[1], size[0], 3), 40, np.uint8)
        for x, y in rng.uniform(20, [size[0] - 20, size[1] - 20], (6, 2)):
            cv2.circle(image, (int(x), int(y)), 3, (220, 220, 220), -1)
        frames.append(image)
    return frames


@pytest.mark.parametrize("kind", ["folder", "video"])
def test_bench_times_any_source_on_its_own_frames(tmp_path, kind):
    from conftest import run_cli, write_ffv1

    frames = _frames_with_discs(4)
    if kind == "folder":
        source = tmp_path / "frames"
        source.mkdir()
        for i, image in enumerate(frames):
            cv2.imwrite(str(source / f"{i:03d}.png"), image)
    else:
        source = tmp_path / "dive.mkv"
        write_ffv1(source, frames)
    result = run_cli("bench", str(source), "--frames", "6", "--distinct", "3", "--json")
    assert result.code == 0, result.err
    import json

    report = json.loads(result.out)
    (entry,) = report["sizes"]
    assert entry["size"] == "320x240" and entry["preset"] == str(source)
    for name in ("seed", "contrast"):
        total = entry["detectors"][name]["total"]
        assert 0 < total["median_us"] <= total["max_us"]
    assert entry["detectors"]["contrast"]["particles_per_frame"] == pytest.approx(6, abs=1)


def test_bench_refuses_a_source_with_sizes_and_a_source_without_frames(tmp_path):
    from conftest import run_cli

    empty = tmp_path / "empty"
    empty.mkdir()
    result = run_cli("bench", "sim", "--sizes", "800x600")
    assert result.code == 2 and "goes without --sizes" in result.err
    result = run_cli("bench", str(empty), "--frames", "2")
    assert result.code == 2 and "Traceback" not in result.err and str(empty) in result.err


def test_bench_on_threads_times_the_threaded_detector_and_finds_what_one_thread_finds(monkeypatch):
    from conftest import run_cli

    import antiscatter.bench as bench_module

    asked = []
    real = bench_module.make_detector

    def spy(name, params=None, *, threads=1):
        asked.append((name, threads))
        return real(name, params, threads=threads)

    monkeypatch.setattr(bench_module, "make_detector", spy)
    counts = {}
    for threads in ("1", "2"):
        result = run_cli("bench", "--sizes", "800x600", "--frames", "4", "--distinct", "3", "--threads", threads,
                         "--detectors", "contrast", "--json")
        assert result.code == 0, result.err
        import json

        report = json.loads(result.out)
        assert report["opencv_threads"] == int(threads)
        counts[threads] = report["sizes"][0]["detectors"]["contrast"]["particles_per_frame"]
    assert asked == [("contrast", 1), ("contrast", 2)] and counts["2"] == counts["1"] > 0
