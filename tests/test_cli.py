"""``antiscatter run`` end to end, bad input, and clean stops on signals."""

import csv
import signal
import subprocess
import sys
import time

import av
import cv2
import numpy as np
import pytest

from conftest import draw_discs, numbered_frames, write_ffv1


def antiscatter(*args, cwd=None, timeout=120):
    return subprocess.run([sys.executable, "-m", "antiscatter", *args], capture_output=True,
                          text=True, cwd=cwd, timeout=timeout)


def test_help_is_useful(cli):
    result = cli("--help")
    assert result.code == 0 and "run" in result.out
    result = cli("run", "--help")
    assert result.code == 0
    for flag in ("--crop", "--loop", "--detector", "--output", "--metrics", "--detections",
                 "--frames", "--fps", "--nice", "--config", "framebuffer"):
        assert flag in result.out


def test_run_on_the_builtin_simulator(tmp_path):
    result = antiscatter("run", "--frames", "300", "--output", "none", "--metrics", "m.csv",
                         "--detections", "d.csv", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    rows = list(csv.reader((tmp_path / "m.csv").open()))
    assert len(rows) == 301
    assert rows[0][:2] == ["Capture Duration (s)", "Greyscale Conversion Duration (s)"]
    det = list(csv.DictReader((tmp_path / "d.csv").open()))
    assert len(det) > 1000
    assert "frames: 300 (frame limit 300)" in result.stdout
    assert "Connected Components" in result.stdout and "mean (us)" in result.stdout


@pytest.mark.parametrize("mode", ["single", "processes"])
def test_run_on_two_threads_writes_the_detections_of_one(tmp_path, cli, mode):
    # the simulator at 1456x1088, tracked: the detector's bands, its memory and the tracker's ids alike
    files = {}
    for threads in ("1", "2"):
        files[threads] = tmp_path / f"d{threads}.csv"
        result = cli("run", "sim", "--preset", "fullres", "--frames", "8", "--output", "none", "--track",
                     "--mode", mode, "--threads", threads, "--detections", str(files[threads]))
        assert result.code == 0, result.err
    rows = files["1"].read_text()
    assert rows.count("\n") > 8 * 100 and files["2"].read_text() == rows


def test_run_on_a_frame_folder_finds_the_drawn_particles(tmp_path, cli):
    frames = tmp_path / "frames"
    frames.mkdir()
    discs = [(30.0, 40.0, 5.0), (100.0, 60.0, 8.0)]
    for i in range(3):
        moved = [(x + 3 * i, y, r) for x, y, r in discs]
        cv2.imwrite(str(frames / f"{i}.png"), draw_discs((160, 120), moved))
    result = cli("run", str(frames), "--output", "none", "--detections", str(tmp_path / "d.csv"),
                 "--output", f"files:{tmp_path / 'pat'}")
    assert result.code == 0, result.err
    rows = list(csv.DictReader((tmp_path / "d.csv").open()))
    assert len(rows) == 6
    for row in rows:
        i = int(row["frame"])
        x, y, r = float(row["x"]), float(row["y"]), float(row["radius"])
        distance, radius = min((np.hypot(x - (dx + 3 * i), y - dy), dr) for dx, dy, dr in discs)
        assert distance < 1.0 and radius <= r <= radius + 4  # the hole covers the particle
    pattern = cv2.imread(str(tmp_path / "pat" / "0.png"), cv2.IMREAD_UNCHANGED)
    assert pattern.shape == (800, 1280)
    # default mapping scales 160x120 to 1280x800: particle (30, 40) -> (240, 266.7), black
    assert pattern[267, 240] == 0 and pattern[10, 10] == 255


def test_run_on_a_video_with_crop_and_loop(tmp_path, cli):
    frames = [draw_discs((200, 100), [(150.0, 50.0, 6.0), (20.0, 50.0, 6.0)]) for _ in range(4)]
    video = tmp_path / "clip.mkv"
    write_ffv1(video, frames)
    # memory=0: a disc that never moves is scene to the learning background after about 8 frames
    result = cli("run", str(video), "--crop", "100:200,0:100", "--loop", "--frames", "10", "-p", "memory=0",
                 "--output", "none", "--detections", str(tmp_path / "d.csv"))
    assert result.code == 0, result.err
    rows = list(csv.DictReader((tmp_path / "d.csv").open()))
    assert len(rows) == 10  # one particle inside the crop, ten frames thanks to --loop
    assert all(abs(float(r["x"]) - 50) < 1 and abs(float(r["y"]) - 50) < 1 for r in rows)


def test_config_file_and_param(tmp_path, cli):
    config = tmp_path / "run.toml"
    config.write_text('[run]\nframes = 5\n[output]\noutputs = ["none"]\n[detector]\nname = "seed"\n'
                      '[detector.seed]\nthreshold = 100\n')
    result = cli("run", "--config", str(config), "-p", "equalise=true",
                 "--metrics", str(tmp_path / "m.csv"))
    assert result.code == 0, result.err
    rows = list(csv.DictReader((tmp_path / "m.csv").open()))
    assert len(rows) == 5
    assert all(float(r["Histogram Equalisation Duration (s)"]) > 0 for r in rows)
    assert all(float(r["Binary Thresholding Duration (s)"]) == 0 for r in rows)


def _bad_inputs(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    notimg = tmp_path / "notimg"
    notimg.mkdir()
    (notimg / "0.png").write_text("hello")
    junk = tmp_path / "junk.mp4"
    junk.write_bytes(b"\x00\x01" * 64)
    video = tmp_path / "v.mkv"
    write_ffv1(video, numbered_frames(2, (64, 48)))
    badkey = tmp_path / "bad.toml"
    badkey.write_text("[run]\nspeed = 3\n")
    badtype = tmp_path / "badtype.toml"
    badtype.write_text("[pattern]\nwidth = 'wide'\n")
    thin = tmp_path / "thin"  # frames too small to detect in (they crashed OpenCV, some the interpreter)
    thin.mkdir()
    cv2.imwrite(str(thin / "0.png"), np.zeros((1, 800, 3), np.uint8))
    flat = tmp_path / "flat.mkv"
    write_ffv1(flat, numbered_frames(2, (64, 4)))
    return [
        (["run", str(thin), "--detections", str(tmp_path / "thin.csv")], "0.png: image of 800x1 px: too small, allowed at least 8x8"),
        (["run", str(flat)], "flat.mkv: frames of 64x4 px: too small"),
        (["run", str(video), "--crop", "0:64,0:5"], "v.mkv cropped by --crop: frames of 64x5 px: too small"),
        (["run", "--size", "700x4"], "source sim: frames of 700x4 px: too small, allowed at least 8x8"),
        (["twin", "--size", "700x4"], "--size: camera frames of 700x4 px: too small"),
        (["bench", "--frames", "1", "--sizes", "800x600,4x4"], "--sizes: frames of 4x4 px: too small"),
        (["run", "--projector-size", "1280x100000"], "pattern.height: got 100000, allowed 1..16384"),
        (["evaluate", "--degraded", str(thin / "0.png"), "--clean", str(thin / "0.png")], "image of 800x1 px"),
        (["run", str(tmp_path / "missing")], "no such file or folder"),
        (["run", str(empty)], "no frames in this folder; allowed: <int>.png files, or images"),
        (["run", str(notimg)], "0.png: not a readable image"),
        (["run", str(junk)], "junk.mp4: cannot be"),
        (["run", str(video), "--crop", "0:100,0:10"], "outside the 64x48 frame"),
        (["run", "--detector", "magic"], "unknown detector 'magic'; allowed: contrast, seed"),
        (["run", "webcam:x"], "expected webcam:N"),
        (["run", "--output", "laser"], "unknown output 'laser'"),
        (["run", "--config", str(badkey)], "unknown key run.speed; allowed: frames"),
        (["run", "--config", str(badtype)], "pattern.width: got 'wide', allowed an integer"),
        (["run", "--frames", "-3"], "run.frames: got -3, allowed >= 0"),
        (["run", "--frames", "many"], "argument --frames: invalid int value: 'many'"),
        (["run", "--detector", "seed", "-p", "threshold=999"], "detector.seed.threshold: got 999, allowed 0..255"),
        (["run", "-p", "threshold=999"], "unknown key detector.contrast.threshold"),
        (["run", "--size", "0x10"], "source.size: got '0x10', allowed positive WIDTHxHEIGHT"),
        (["run", "--metrics", str(tmp_path / "no" / "m.csv"), "--output", "none"], "does not exist"),
        (["run", "--record-to", str(tmp_path / "no" / "r.mkv"), "--output", "none"],
         "run.record_to (--record-to) " + str(tmp_path / "no" / "r.mkv") + ": the folder"),
        (["run", "--mapping", str(badkey)], "--mapping"),
        (["run", "--preset", "storm"], "unknown preset 'storm'"),
        (["run", "camera", "--output", "none"], None),  # on the Pi it may open; off it, exit 2
        (["run", "--output", "kms", "--frames", "1"], "kms"),
    ]


def test_bad_inputs_exit_2_with_one_line(tmp_path, cli):
    for args, expected in _bad_inputs(tmp_path):
        result = cli(*args)
        if expected is None:
            try:
                import picamera2  # noqa: F401
                continue
            except ImportError:
                expected = "source 'camera' needs the picamera2 package on a Raspberry Pi"
        if expected == "kms":
            try:
                import pykms  # noqa: F401
                continue
            except ImportError:
                expected = "output 'kms' needs the pykms module"
        assert result.code == 2, (args, result.err)
        lines = result.err.strip().splitlines()
        assert len(lines) == 1, (args, result.err)
        assert expected in lines[0], (args, lines[0])
        assert lines[0].startswith("antiscatter")
    assert not (tmp_path / "thin.csv").exists()  # refused before anything was written


@pytest.mark.parametrize("source, message", [
    ("missing", "no such file or folder"),
    ("junk.avi", "junk.avi: cannot be"),
    ("webcam:63", "webcam:63: no capture device 63 could be opened"),
])
def test_bad_input_in_a_fresh_process_is_one_line_without_traceback(tmp_path, source, message):
    (tmp_path / "junk.avi").write_bytes(b"RIFF" + b"\x00" * 60)
    result = antiscatter("run", source, "--output", "none", cwd=tmp_path)
    assert result.returncode == 2
    assert "Traceback" not in result.stderr
    assert result.stderr.count("\n") == 1, result.stderr
    assert message in result.stderr


def test_source_failing_mid_run_keeps_files_valid(tmp_path):
    frames = tmp_path / "frames"
    frames.mkdir()
    for i in range(3):
        cv2.imwrite(str(frames / f"{i}.png"), draw_discs((64, 48), [(20, 20, 4)]))
    (frames / "3.png").write_text("corrupt")
    result = antiscatter("run", str(frames), "--output", "none", "--output", "files:p.mkv",
                         "--metrics", "m.csv", cwd=tmp_path)
    assert result.returncode == 2
    assert "3.png: not a readable image" in result.stderr
    assert len(list(csv.reader((tmp_path / "m.csv").open()))) == 4
    with av.open(str(tmp_path / "p.mkv")) as container:
        assert sum(1 for _ in container.decode(video=0)) == 3


@pytest.mark.parametrize("mode", ["single", "threads", "processes"])
@pytest.mark.parametrize("signum, code", [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_signal_stops_cleanly_with_complete_files(tmp_path, signum, code, mode):
    shm_before = _shm()
    proc = subprocess.Popen([sys.executable, "-m", "antiscatter", "run", "--output", "files:p.mkv",
                             "--metrics", "m.csv", "--detections", "d.csv", "--fps", "100", "--mode", mode],
                            cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    metrics = tmp_path / "m.csv"
    while time.monotonic() < deadline:
        if metrics.exists() and metrics.stat().st_size > 4096:
            break
        time.sleep(0.05)
    proc.send_signal(signum)
    sent = time.monotonic()
    out, err = proc.communicate(timeout=30)
    assert time.monotonic() - sent < 3  # stops within a frame or two, files closed
    assert not [line for line in out.splitlines() if "Traceback" in line]
    assert proc.returncode == code, err
    assert f"stopped by {signal.Signals(signum).name}" in out
    rows = list(csv.reader(metrics.open()))
    frames = len(rows) - 1
    assert frames > 5 and all(len(r) == len(rows[0]) for r in rows)
    with av.open(str(tmp_path / "p.mkv")) as container:
        decoded = sum(1 for _ in container.decode(video=0))
    assert decoded == frames
    det = (tmp_path / "d.csv").read_text()
    assert det.endswith("\n")
    assert _processes_in(tmp_path) == []  # no orphaned worker process (workers share the cwd)
    leftover = _shm() - shm_before
    if leftover:  # another process on the machine may hold one for a moment: look again
        time.sleep(2)
        leftover &= _shm()
    assert not leftover  # no shared-memory segment left behind


def _processes_in(folder):
    """Live processes whose working directory is ``folder`` (from /proc)."""
    import os
    found = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                if os.readlink(f"/proc/{entry}/cwd") == str(folder):
                    found.append(int(entry))
            except OSError:
                continue
    return found


def _shm():
    import os
    return set(os.listdir("/dev/shm")) if os.path.isdir("/dev/shm") else set()


@pytest.mark.parametrize("args", [
    ["calibrate", "{missing}/c.json", "--twin"],
    ["evaluate", "--scenario", "bubbles", "--frames", "1", "--csv", "{missing}/f.csv"],
    ["evaluate", "--scenario", "bubbles", "--frames", "1", "--plot", "{missing}/p.png"],
    ["bench", "--frames", "1", "--sizes", "64x48", "--plot", "{missing}/b.png"],
    ["twin", "--frames", "1", "--size", "200x150", "--plot", "{missing}/t.png"],
    ["simulate", "{tmp}/sim", "--frames", "1", "--video", "{missing}/v.mkv"],
])
def test_output_in_a_missing_folder_is_refused_before_any_work(tmp_path, cli, args):
    args = [a.format(missing=tmp_path / "missing", tmp=tmp_path) for a in args]
    result = cli(*args)
    assert result.code == 2
    assert len(result.err.strip().splitlines()) == 1 and "does not exist" in result.err
    assert not (tmp_path / "missing").exists() and not (tmp_path / "sim").exists()


def _moving_disc_frames(tmp_path):
    """A folder of 8 frames (160x120, 60 frames/s as a folder is replayed): a disc moving 4 px a frame."""
    frames = tmp_path / "frames"
    frames.mkdir()
    for i in range(8):
        cv2.imwrite(str(frames / f"{i}.png"), draw_discs((160, 120), [(30.0 + 4 * i, 60.0, 5.0)]))
    return frames


def _disc_frames(tmp_path, count=4):
    frames = tmp_path / "frames"
    frames.mkdir()
    for i in range(count):
        cv2.imwrite(str(frames / f"{i}.png"), draw_discs((160, 120), [(30.0 + 3 * i, 40.0, 5.0)]))
    return frames


@pytest.mark.parametrize("revive, keep, identities", [(0, 1, 2), (5, 1, 1), (0, 4, 1)])
def test_track_revive_frames_or_keep_misses_give_a_particle_back_its_id_after_a_gap(tmp_path, cli, revive, keep, identities):
    frames = tmp_path / "frames"
    frames.mkdir()
    for i in range(12):  # a disc moving right, unseen in frames 5-7
        discs = [] if 5 <= i <= 7 else [(30.0 + 4 * i, 60.0, 4.0)]
        cv2.imwrite(str(frames / f"{i:02d}.png"), draw_discs((160, 120), discs))
    config = tmp_path / "c.toml"
    config.write_text(f"[track]\nenabled = true\nmax_misses = 1\nkeep_misses = {keep}\nrevive_frames = {revive}\n")
    result = cli("run", str(frames), "--config", str(config), "--output", "none", "--detections", str(tmp_path / "d.csv"))
    assert result.code == 0, result.err
    rows = list(csv.DictReader((tmp_path / "d.csv").open()))
    assert len(rows) == 9 and len({r["track_id"] for r in rows}) == identities


def test_run_takes_the_trackers_flux_cost_from_the_config(tmp_path, cli):
    # the report's crowded tank: with the flux cost off, tracks compete on distance alone and the
    # identities come out otherwise; the default is the documented 16 px
    def ids(body):
        config = tmp_path / "c.toml"
        config.write_text("[track]\nenabled = true\n" + body)
        out = tmp_path / "d.csv"
        result = cli("run", "--frames", "30", "--config", str(config), "--output", "none", "--detections", str(out))
        assert result.code == 0, result.err
        return [(r["frame"], r["x"], r["y"], r["track_id"]) for r in csv.DictReader(out.open())]

    default, off, explicit = ids(""), ids("flux_cost = 0\n"), ids("flux_cost = 16\n")
    assert [r[:3] for r in off] == [r[:3] for r in default]  # the same detections
    assert off != default and explicit == default


@pytest.mark.parametrize("width", [800, 1600])
def test_run_scales_the_trackers_motion_to_the_frame_width(tmp_path, cli, width):
    frames = tmp_path / "frames"
    frames.mkdir()
    # the same motion in the view: 20 px a frame at 800 wide, 40 at 1600 (a new track's gate is
    # 27 px for 800 px wide frames: unscaled, the wide frames' particle was born again each frame)
    step = 20 * width / 800
    for i in range(6):
        cv2.imwrite(str(frames / f"{i}.png"), draw_discs((width, 120), [(50.0 + step * i, 60.0, 4.0)]))
    config = tmp_path / "c.toml"
    config.write_text("[track]\nenabled = true\n[run]\nfps = 60\n")
    result = cli("run", str(frames), "--config", str(config), "--output", "none", "--detections", str(tmp_path / "d.csv"))
    assert result.code == 0, result.err
    rows = list(csv.DictReader((tmp_path / "d.csv").open()))
    assert len(rows) == 6 and len({r["track_id"] for r in rows}) == 1


def test_predicted_holes_are_drawn_for_the_middle_of_the_time_their_pattern_is_on(tmp_path, cli):
    # a disc moving 4 px a frame at 60 frames/s; with no latency the pattern goes on at the capture
    # and stays a frame period: its hole is where the disc will be half a frame on, 2 px (16
    # projector px at 1280 / 160) ahead of where it was seen
    frames = _moving_disc_frames(tmp_path)

    def hole_x(*extra):
        out = tmp_path / ("pat" + "".join(extra))
        result = cli("run", str(frames), "--track", "--latency-ms", "0", "--output", f"files:{out}", *extra)
        assert result.code == 0, result.err
        dark = cv2.imread(str(out / "7.png"), cv2.IMREAD_UNCHANGED) < 128
        return float(np.nonzero(dark)[1].mean())

    assert hole_x() - hole_x("--no-predict") == pytest.approx(16.0, abs=1.0)


def test_strategy_dim_draws_holes_at_the_dim_level(tmp_path, cli):
    result = cli("run", str(_disc_frames(tmp_path)), "--strategy", "dim", "--dim-level", "0.2",
                 "--output", f"files:{tmp_path / 'pat'}")
    assert result.code == 0, result.err
    pattern = cv2.imread(str(tmp_path / "pat" / "0.png"), cv2.IMREAD_UNCHANGED)
    # particle (30, 40) in a 160x120 frame -> (240, 266.7) on the 1280x800 projector
    assert pattern[267, 240] == 51 and pattern[10, 10] == 255
    assert set(np.unique(pattern)) == {51, 255}


def test_grow_widens_the_big_holes_drawn(tmp_path, cli):
    frames = _disc_frames(tmp_path)

    def dark(*extra):
        out = tmp_path / ("pat" + "".join(extra))
        result = cli("run", str(frames), "--output", f"files:{out}", *extra)
        assert result.code == 0, result.err
        return int((cv2.imread(str(out / "0.png"), cv2.IMREAD_UNCHANGED) == 0).sum())

    plain = dark("--grow", "0")
    assert plain > 0
    # the disc (radius 5 in a 160 px wide frame) is found with a hole of 6-7 px, above 4 x 160 / 800
    # = 0.8 px: it grows by the excess, near doubling its radius -- about 3.5x the dark area
    assert 3.0 < dark("--grow", "1", "--grow-from", "4") / plain < 4.0
    assert dark("--grow", "1", "--grow-from", "100") == plain  # no hole that big: none grows
    assert 2.0 < dark() / plain < 3.0  # by default 0.6 of the excess over 4 px
    bad = cli("run", str(frames), "--grow", "-1")
    assert bad.code == 2 and "grow: got -1.0, allowed a number >= 0" in bad.err and "Traceback" not in bad.err


@pytest.mark.parametrize("strategy", ["dim", "pulse"])
def test_adaptive_levels_give_each_tracked_hole_the_light_its_particle_needs(tmp_path, cli, strategy):
    frames = tmp_path / "frames"
    frames.mkdir()
    for i in range(8):  # a disc moving right; a second one from frame 3 on
        discs = [(30.0 + 3 * i, 40.0, 5.0)] + ([(120.0, 80.0, 3.0)] if i >= 3 else [])
        cv2.imwrite(str(frames / f"{i}.png"), draw_discs((160, 120), discs))

    def holes(*extra):
        out = tmp_path / ("pat" + "".join(extra))
        # a fixed capture-to-light time: measured, it moves the predicted holes with the machine's load
        result = cli("run", str(frames), "--strategy", strategy, "--track", "--dim-level", "0.2", "--latency-ms", "0",
                     "--output", f"files:{out}", *extra)
        assert result.code == 0, result.err
        lit = [cv2.imread(str(out / f"{k}.png"), cv2.IMREAD_UNCHANGED) for k in range(8)]
        if strategy == "dim":
            return lit
        for pattern in lit:  # pulse: dark between exposures
            assert set(np.unique(pattern)) == {0, 255}
        # the holes' light is in the pattern shown while the camera exposes: the next frame's pulse
        return [cv2.imread(str(out / f"flash-{k + 1}.png"), cv2.IMREAD_UNCHANGED) for k in range(7)]

    # (30 + 3k, 40) and (120, 80) in the 160x120 frame -> (240 + 24k, 266.7) and (960, 533.3) on the
    # projector.  These files do not see the light: each particle comes back as bright under its hole
    # as lit, far above what it needs, so once its track is confirmed (third sighting) its hole's
    # level halves each frame -- the most it may fall -- down to the least level, 0.02 (5)
    adaptive = holes("--levels", "adaptive", "--rest", "0")
    assert [int(p[267, 240 + 24 * k]) for k, p in enumerate(adaptive)][:7] == [51, 51, 26, 13, 6, 5, 5]
    assert [int(p[533, 960]) for p in adaptive[3:7]] == [51, 51, 26, 13]  # its own, from frame 3
    # resting (the default): a confirmed track just found is left in the dark through the next
    # exposure; found there all the same (these files), its particle had left its hole -- seen
    # in full light, its level is the target over that flux (the least, 5) -- and it is looked
    # at under its hole the frame after, then rests again
    resting = holes("--levels", "adaptive")
    assert [int(p[267, 240 + 24 * k]) for k, p in enumerate(resting)][:7] == [51, 51, 0, 5, 0, 5, 0]
    assert [int(p[533, 960]) for p in resting[3:7]] == [51, 51, 0, 5]
    fixed = holes("--levels", "fixed")
    assert all(p[267, 240 + 24 * k] == 51 for k, p in enumerate(fixed))
    replay = holes()  # auto: adaptive only with the camera -- these files never saw the light
    assert all(p[267, 240 + 24 * k] == 51 for k, p in enumerate(replay))
    seed = holes("--detector", "seed", "--levels", "adaptive", "--rest", "0")  # its scores are no flux
    assert all(p[267, 240 + 24 * k] == 51 for k, p in enumerate(seed))  # the dim level
    bad = cli("run", str(frames), "--strategy", strategy, "--track", "--min-level", "2", "--output", "none")
    assert bad.code == 2 and "light.min_level: got 2.0, allowed a number 0..1" in bad.err


def test_strategy_flash_shows_a_uniform_flash_before_every_capture(tmp_path, cli):
    video = tmp_path / "light.mkv"
    result = cli("run", str(_disc_frames(tmp_path)), "--strategy", "flash", "--flash-level", "0.5",
                 "--output", f"files:{tmp_path / 'pat'}", "--output", f"files:{video}")
    assert result.code == 0, result.err
    for i in range(4):
        flash = cv2.imread(str(tmp_path / "pat" / f"flash-{i}.png"), cv2.IMREAD_UNCHANGED)
        assert flash.shape == (800, 1280) and (flash == 128).all()
        pattern = cv2.imread(str(tmp_path / "pat" / f"{i}.png"), cv2.IMREAD_UNCHANGED)
        assert pattern.min() == 0 and pattern.max() == 255
    with av.open(str(video)) as container:  # the light over time: flash, last pattern back, new pattern...
        shown = [f.to_ndarray(format="gray") for f in container.decode(video=0)]
    assert len(shown) == 13  # the source's end is found by the read after the last flash
    assert all((s == 128).all() for s in shown[0::3])
    assert (shown[1] == 255).all()  # before the first pattern, the full lamp
    for i in range(4):
        assert shown[3 * i + 2].min() == 0
        if i:  # once the frame is in, the last pattern is back while it is processed
            assert np.array_equal(shown[3 * i + 1], shown[3 * i - 1])


def test_strategy_pulse_lifts_the_last_patterns_holes_only_for_the_capture(tmp_path, cli):
    video = tmp_path / "light.mkv"
    result = cli("run", str(_disc_frames(tmp_path)), "--strategy", "pulse", "--dim-level", "0.2",
                 "--output", f"files:{tmp_path / 'pat'}", "--output", f"files:{video}")
    assert result.code == 0, result.err
    patterns = [cv2.imread(str(tmp_path / "pat" / f"{i}.png"), cv2.IMREAD_UNCHANGED) for i in range(4)]
    pulses = [cv2.imread(str(tmp_path / "pat" / f"flash-{i}.png"), cv2.IMREAD_UNCHANGED) for i in range(4)]
    assert (pulses[0] == 255).all()  # nothing to lift before the first pattern: the full lamp
    for i in range(4):
        # particle (30 + 3i, 40) in a 160x120 frame -> (240 + 24i, 266.7) on the 1280x800 projector
        assert patterns[i][267, 240 + 24 * i] == 0 and set(np.unique(patterns[i])) == {0, 255}
        if i:
            assert np.array_equal(pulses[i], np.maximum(patterns[i - 1], 51))
            assert pulses[i][267, 240 + 24 * (i - 1)] == 51
    with av.open(str(video)) as container:  # pulse, last pattern back, new pattern, pulse...
        shown = [f.to_ndarray(format="gray") for f in container.decode(video=0)]
    assert len(shown) == 13
    for i in range(1, 4):
        assert np.array_equal(shown[3 * i], pulses[i]) and np.array_equal(shown[3 * i + 1], patterns[i - 1])
        assert np.array_equal(shown[3 * i + 2], patterns[i])


@pytest.mark.parametrize("latency, ahead", [("0", 24.0), ("20", 17.6)])
def test_pulse_with_prediction_lifts_holes_drawn_for_the_next_exposures_refresh(tmp_path, cli, latency, ahead):
    # a disc moving 4 px a frame (240 px/s) at 60 frames/s: the pattern's hole is where it will be
    # half a frame after the pattern goes on, the hole lifted for the first exposure under it where
    # it will be in the middle of that exposure's 120 Hz refresh.  No latency: 2 px and 1/60 +
    # 1/240 s on, 5 px -- 3 camera px, 24 projector px, beyond the pattern's; 20 ms, more than a
    # frame: the pattern goes on after the next exposure began, so it is the one after that
    # (2/60 + 1/240 s, 9 px) against 20 ms + 1/120 s (6.8 px): 2.2 camera px, 17.6 projector px
    frames = _moving_disc_frames(tmp_path)
    config = tmp_path / "c.toml"
    config.write_text("[pattern]\nrefresh_hz = 120\n")
    out = tmp_path / "pat"
    result = cli("run", str(frames), "--track", "--latency-ms", latency, "--strategy", "pulse", "--levels", "fixed",
                 "--dim-level", "0.2", "--config", str(config), "--output", f"files:{out}")
    assert result.code == 0, result.err
    pattern = cv2.imread(str(out / "6.png"), cv2.IMREAD_UNCHANGED)
    lifted = cv2.imread(str(out / "flash-7.png"), cv2.IMREAD_UNCHANGED)  # shown for frame 7's exposure
    assert set(np.unique(lifted)) == {51, 255} and set(np.unique(pattern)) == {0, 255}
    shift = np.nonzero(lifted == 51)[1].mean() - np.nonzero(pattern == 0)[1].mean()
    assert shift == pytest.approx(ahead, abs=1.5)


@pytest.mark.parametrize("lag_ms", [0.0, 5.0])
def test_strategy_flash_skips_frames_exposed_before_the_flash(lag_ms):
    from antiscatter.config import load_config
    from antiscatter.runtime import run
    from antiscatter.sources.base import Frame, FrameSource

    exposure = 4_000_000
    refresh = 1_000_000_000 // 120

    class StaleCamera(FrameSource):
        """A free-running camera: every other frame began its exposure just before it was asked
        for (before the flash could be on screen, a display refresh after it was handed over,
        though it ends after); the next begins just after that refresh."""
        live, size = True, (160, 120)

        def __init__(self):
            self.count = 0

        def read(self):
            self.count += 1
            if self.count > 12:
                return None
            now = FrameSource.now_ns()
            # with a display lag the flash is light on the scene that much later still: a frame that
            # begins just after the refresh is then one to skip
            early = now - 1_000_000 if not lag_ms else now + refresh + 1_000_000
            start = early if self.count % 2 else now + refresh + round(lag_ms * 1e6) + 1_000_000
            return Frame(draw_discs(self.size, [(40.0, 40.0, 4.0)]), self.count - 1, start + exposure // 2, exposure)

    config = load_config(overrides={"light": {"strategy": "flash"}, "output": {"outputs": ("none",)},
                                    "pattern": {"refresh_hz": 120.0, "display_lag_ms": lag_ms}})
    camera = StaleCamera()
    summary = run(config, source=camera, log=__import__("io").StringIO(), out=__import__("io").StringIO())
    assert summary.frames == 6 and summary.dropped == 6  # each stale frame skipped, the fresh one used


def test_strategy_coast_tracks_and_flash_needs_single_mode(tmp_path, cli):
    result = cli("run", str(_disc_frames(tmp_path)), "--strategy", "coast", "--output", "none",
                 "--detections", str(tmp_path / "d.csv"))
    assert result.code == 0, result.err
    assert "track_id" in (tmp_path / "d.csv").open().readline()
    for strategy in ("flash", "pulse"):
        bad = cli("run", "--strategy", strategy, "--mode", "threads", "--frames", "3", "--output", "none")
        assert bad.code == 2 and f"{strategy} needs run.mode single" in bad.err and "Traceback" not in bad.err
    bad = cli("run", "--dim-level", "1.5", "--frames", "3", "--output", "none")
    assert bad.code == 2 and "light.dim_level: got 1.5, allowed a number 0..1" in bad.err
    config = tmp_path / "c.toml"
    config.write_text('[light]\nstrategy = "strobe"\n')
    bad = cli("run", "--config", str(config), "--frames", "3", "--output", "none")
    assert bad.code == 2 and "light.strategy: got 'strobe', allowed auto, none, dim, pulse, flash, coast" in bad.err


def test_strategy_auto_dims_and_tracks_on_the_camera_only(tmp_path, cli):
    from antiscatter.config import load_config

    on_vehicle = load_config(overrides={"source": {"spec": "camera"}})
    assert on_vehicle.light.strategy == "dim" and on_vehicle.track.enabled and on_vehicle.light.depth == "fixed"
    threaded = load_config(overrides={"source": {"spec": "camera"}, "run": {"mode": "threads"}})
    assert threaded.light.strategy == "dim"
    replay = load_config()
    assert replay.light.strategy == "none" and not replay.track.enabled and replay.light.depth == "fixed"
    calibration = tmp_path / "cal.json"
    assert cli("calibrate", str(calibration), "--twin", "--size", "160x120").code == 0
    probing = load_config(overrides={"source": {"spec": "camera"}, "pattern": {"calibration": str(calibration)}})
    assert probing.light.depth == "probe"  # a calibration with a baseline: depth probing


@pytest.mark.parametrize("strategy", ["dim", "pulse"])
def test_compensation_tells_the_detector_the_light_of_the_last_pattern(tmp_path, monkeypatch, strategy):
    import dataclasses

    import antiscatter.runtime as runtime
    from antiscatter.config import load_config

    seen = []
    real = runtime.make_detector

    def recording(name, params=None, *, threads=1):
        detector = real(name, params, threads=threads)
        return dataclasses.replace(detector, set_light=lambda light: (seen.append(None if light is None else light.copy()),
                                                                     detector.set_light(light)))

    monkeypatch.setattr(runtime, "make_detector", recording)
    frames = _disc_frames(tmp_path)
    config = load_config(overrides={"source": {"spec": str(frames)}, "output": {"outputs": ("none",)},
                                    "light": {"strategy": strategy, "compensate": True, "dim_level": 0.2}})
    runtime.run(config, log=__import__("io").StringIO(), out=__import__("io").StringIO())
    assert len(seen) == 4 and seen[0].shape == (120, 160)  # the camera's pixels
    # the particle at (30, 40) had a dim hole (pulse: dark, lifted for the exposure): its place is
    # dark in the light map, the rest lit
    assert seen[0][40, 30] == 51 and seen[0][80, 150] == 255
    assert load_config().light.compensate is False  # replays never saw the light
    assert load_config().light.levels == "fixed"  # nor adapted hole levels to it
    assert load_config(overrides={"source": {"spec": "camera"}}).light.levels == "adaptive"
    assert load_config(overrides={"source": {"spec": "camera"}}).light.compensate is False  # no mapping known
    mapped = {"source": {"spec": "camera"}, "pattern": {"mapping": [[8, 0, 0], [0, 6.67, 0], [0, 0, 1]]}}
    assert load_config(overrides=mapped).light.compensate is True


def _probe_scene(tmp_path, cli, discs, count=3):
    """(a twin calibration with a baseline for 160x120 frames, a folder of ``count`` such frames of
    ``discs``), for the depth-probing runs."""
    calibration = tmp_path / "cal.json"
    made = cli("calibrate", str(calibration), "--twin", "--size", "160x120")
    assert made.code == 0, made.err
    frames = tmp_path / "frames"
    frames.mkdir()
    for i in range(count):
        cv2.imwrite(str(frames / f"{i}.png"), draw_discs((160, 120), discs))
    return calibration, frames


def test_depth_probe_draws_each_unknown_particle_over_its_epipolar_segment(tmp_path, cli):
    from antiscatter.calibration import load_calibration

    # right of centre, so the whole segment lands on the projector
    calibration, frames = _probe_scene(tmp_path, cli, [(100.0, 60.0, 3.0)])
    result = cli("run", str(frames), "--strategy", "dim", "--dim-level", "0.2", "--depth", "probe",
                 "--calibration", str(calibration), "--output", f"files:{tmp_path / 'pat'}",
                 "--detections", str(tmp_path / "d.csv"))
    assert result.code == 0, result.err
    assert "track_id" in (tmp_path / "d.csv").open().readline()  # probing tracks particles
    pattern = cv2.imread(str(tmp_path / "pat" / "0.png"), cv2.IMREAD_UNCHANGED)
    cal = load_calibration(calibration)
    # the particle at (100, 60) is seen lit, so its first probe is the far half of its epipolar
    # segment (inverse depth 1/3 .. (1/3 + 1/0.3) / 2, i.e. 3 m .. 0.55 m): dim there, lit nearer
    for depth, level in ((3.0, 51), (1.0, 51), (0.6, 51), (0.3, 255)):
        u, v, w = cal.mapping_at(depth) @ [100.0, 60.0, 1.0]
        assert pattern[int(round(v / w)), int(round(u / w))] == level, depth
    assert (pattern == 51).sum() > 20 * (pattern.shape[1] // 10)  # a segment, not a disc
    bad = cli("run", str(frames), "--depth", "probe", "--strategy", "dim", "--output", "none")
    assert bad.code == 2 and "probe needs a calibration with a baseline" in bad.err
    bad = cli("run", str(frames), "--depth", "probe", "--strategy", "coast", "--calibration", str(calibration),
              "--output", "none")
    assert bad.code == 2 and "probe needs light.strategy dim" in bad.err


@pytest.mark.parametrize("strategy, dark", [("dim", 51), ("pulse", 0)])
def test_depth_probe_leaves_out_the_holes_not_worth_their_light(tmp_path, cli, strategy, dark):
    # three bright bubbles and a faint grain, all of unknown depth: the grain's segment would take
    # more of the scene's light than its share of the backscatter is worth (--min-worth 0.2, the
    # default), so it stays lit; with 0 every hole is drawn (dim: the first probe, the far half of
    # the segment, at the dim level; pulse: between exposures the whole segment dark)
    from antiscatter.calibration import load_calibration

    calibration = tmp_path / "cal.json"
    assert cli("calibrate", str(calibration), "--twin", "--size", "160x120").code == 0
    cal = load_calibration(calibration)
    frames = tmp_path / "frames"
    frames.mkdir()
    image = np.maximum(draw_discs((160, 120), [(30.0, 40.0, 6.0), (70.0, 40.0, 6.0), (110.0, 40.0, 6.0)]),
                       draw_discs((160, 120), [(100.0, 75.0, 1.5)], value=40))
    for i in range(2):
        cv2.imwrite(str(frames / f"{i}.png"), image)

    def at(pattern, x, y, depth):
        u, v, w = cal.mapping_at(depth) @ [x, y, 1.0]
        return pattern[int(round(v / w)), int(round(u / w))]

    for worth, grain in (((), 255), (("--min-worth", "0"), dark)):
        out = tmp_path / f"pat{len(worth)}"
        result = cli("run", str(frames), "--strategy", strategy, "--dim-level", "0.2", "--depth", "probe",
                     "--calibration", str(calibration), "--output", f"files:{out}", *worth)
        assert result.code == 0, result.err
        pattern = cv2.imread(str(out / "0.png"), cv2.IMREAD_UNCHANGED)
        assert [at(pattern, 100.0, 75.0, d) for d in (3.0, 1.0, 0.6)] == [grain] * 3, worth
        assert [at(pattern, 70.0, 40.0, d) for d in (3.0, 1.0, 0.6)] == [dark] * 3, worth
    bad = cli("run", str(frames), "--min-worth", "-1", "--output", "none")
    assert bad.code == 2 and "light.min_worth: got -1.0, allowed a number >= 0" in bad.err


def test_depth_probe_grows_the_dark_intervals_but_not_the_probe_the_camera_sees(tmp_path, cli):
    calibration, frames = _probe_scene(tmp_path, cli, [(40.0, 40.0, 6.0), (110.0, 80.0, 6.0)])

    def unlit(*extra):
        out = tmp_path / ("pat" + "".join(extra))
        result = cli("run", str(frames), "--strategy", "pulse", "--dim-level", "0.2", "--depth", "probe",
                     "--calibration", str(calibration), "--output", f"files:{out}", *extra)
        assert result.code == 0, result.err
        between = cv2.imread(str(out / "1.png"), cv2.IMREAD_UNCHANGED)
        exposed = cv2.imread(str(out / "flash-2.png"), cv2.IMREAD_UNCHANGED)  # under which frame 2 is taken
        return int((between < 255).sum()), int((exposed < 255).sum())

    plain, grown = unlit("--grow", "0"), unlit()
    assert grown[0] > 1.3 * plain[0]  # the whole intervals, dark between exposures, grow
    assert grown[1] == plain[1] > 0  # the probes the camera looks through are drawn as found


@pytest.mark.parametrize("strategy, exposed", [("dim", "{}.png"), ("pulse", "flash-{}.png")])
def test_depth_probe_judges_each_verdict_by_the_pattern_the_exposure_was_taken_under(tmp_path, cli, monkeypatch,
                                                                                   strategy, exposed):
    from antiscatter.probe import DepthProbe

    calibration, frames = _probe_scene(tmp_path, cli, [(100.0, 60.0, 3.0), (40.0, 30.0, 3.0)], count=4)
    seen = []
    real = DepthProbe.observe

    def observe(self, detections, shown, coasting, **kw):
        exposure = kw.get("exposure")
        seen.append(None if exposure is None else exposure.copy())
        return real(self, detections, shown, coasting, **kw)

    monkeypatch.setattr(DepthProbe, "observe", observe)
    result = cli("run", str(frames), "--strategy", strategy, "--dim-level", "0.2", "--depth", "probe",
                 "--calibration", str(calibration), "--output", f"files:{tmp_path / 'pat'}")
    assert result.code == 0, result.err
    assert len(seen) == 4 and seen[0] is None  # the first frame was taken under the plain lamp
    for k in range(1, 4):  # frame k was exposed under what frame k - 1 put out for the capture
        written = cv2.imread(str(tmp_path / "pat" / exposed.format(k if strategy == "pulse" else k - 1)),
                             cv2.IMREAD_UNCHANGED)
        assert np.array_equal(seen[k], written), k
        assert (seen[k] == 51).any()  # holes at the dim level: the probes


def test_depth_probe_with_pulse_keeps_the_whole_interval_dark_and_probes_half_for_the_capture(tmp_path, cli):
    from antiscatter.calibration import load_calibration

    calibration, frames = _probe_scene(tmp_path, cli, [(100.0, 60.0, 3.0)])
    result = cli("run", str(frames), "--strategy", "pulse", "--dim-level", "0.2", "--depth", "probe",
                 "--calibration", str(calibration), "--output", f"files:{tmp_path / 'pat'}")
    assert result.code == 0, result.err
    cal = load_calibration(calibration)
    pattern = cv2.imread(str(tmp_path / "pat" / "0.png"), cv2.IMREAD_UNCHANGED)
    pulse = cv2.imread(str(tmp_path / "pat" / "flash-1.png"), cv2.IMREAD_UNCHANGED)

    def at(image, depth):
        u, v, w = cal.mapping_at(depth) @ [100.0, 60.0, 1.0]
        return image[int(round(v / w)), int(round(u / w))]

    # between exposures the whole segment the particle may be on is dark; for the next capture
    # only the probe's far half is lifted to the dim level, the near part lit
    assert [at(pattern, d) for d in (3.0, 1.0, 0.6, 0.35)] == [0, 0, 0, 0]
    assert [at(pulse, d) for d in (3.0, 1.0, 0.6, 0.3)] == [51, 51, 51, 255]
    assert set(np.unique(pattern)) == {0, 255} and set(np.unique(pulse)) == {51, 255}


def test_the_vehicles_default_configuration_runs_on_a_live_source(tmp_path):
    """Camera as source, nothing else said: dim holes, tracking with prediction, compensation --
    and with a board calibration, depth probing -- on a free-running source, end to end; and the
    same with pulsed holes."""
    import io

    from antiscatter.config import load_config
    from antiscatter.runtime import run
    from antiscatter.sources.base import Frame, FrameSource

    class LiveCamera(FrameSource):
        """A camera exposing on request (as one triggered would): each frame's 1 ms exposure
        begins 1 ms more than a projector refresh (120 Hz) after it is asked for, so a pulse is on
        through it."""
        live, size = True, (160, 120)

        def __init__(self):
            self.count = 0

        def read(self):
            self.count += 1
            if self.count > 20:
                return None
            time.sleep(1 / 120 + 0.002)
            image = draw_discs(self.size, [(60.0 + 2 * self.count, 50.0, 4.0), (110.0, 80.0 - self.count, 3.0)])
            return Frame(image, self.count - 1, FrameSource.now_ns() - 500_000, 1_000_000)

    calibration = tmp_path / "cal.json"
    assert antiscatter("calibrate", str(calibration), "--twin", "--size", "160x120").returncode == 0
    from antiscatter.calibration import load_calibration

    mapping = load_calibration(calibration).homography.tolist()
    calibrated = {"pattern": {"calibration": str(calibration), "mapping": mapping}}
    pulse = {"light": {"strategy": "pulse"}, "track": {"enabled": True}}
    for extra in ({}, calibrated, pulse, {**pulse, **calibrated}):
        config = load_config(overrides={"source": {"spec": "camera"}, "output": {"outputs": (f"files:{tmp_path / 'p'}",)},
                                        "run": {"detections": str(tmp_path / "d.csv")}, **extra})
        pulsed = "light" in extra
        assert config.light.strategy == ("pulse" if pulsed else "dim") and config.track.enabled
        probing = "pattern" in extra
        assert config.light.depth == ("probe" if probing else "fixed") and config.light.compensate == probing
        for stale in (tmp_path / "p").glob("*.png") if (tmp_path / "p").exists() else ():
            stale.unlink()
        log = io.StringIO()
        summary = run(config, source=LiveCamera(), log=log, out=io.StringIO())
        assert summary.frames == 20 and summary.dropped == 0
        # pulsed on a free-running camera: said to read every other frame, and what times it instead
        assert ("reads every other frame" in log.getvalue() and "--camera-lock" in log.getvalue()) == pulsed
        rows = list(csv.DictReader((tmp_path / "d.csv").open()))
        assert len(rows) >= 30 and all(int(r["track_id"]) > 0 for r in rows)
        assert len({r["track_id"] for r in rows}) <= 6  # two particles, few identities
        least = round(config.light.min_level * 255)
        last = cv2.imread(str(tmp_path / "p" / "18.png"), cv2.IMREAD_UNCHANGED)
        # each hole at its own level: this camera's particles come back as bright under their holes
        # as lit (it does not see the light), so once confirmed every hole is at the least level --
        # or, without probing, resting fully dark every other frame (found all the same, each is
        # looked at under its hole the frame after)
        if not pulsed:
            holes = set(np.unique(last)) | set(np.unique(cv2.imread(str(tmp_path / "p" / "17.png"),
                                                                    cv2.IMREAD_UNCHANGED)))
            assert holes == ({least, 255} if probing else {0, least, 255})
            assert not list((tmp_path / "p").glob("flash-*.png"))  # dim: the pattern alone
            continue
        assert last.min() == 0
        # each capture under the last pattern with its holes lifted to their levels; probing, under
        # the probes' halves of the intervals that the pattern keeps dark between exposures
        pulse = cv2.imread(str(tmp_path / "p" / "flash-19.png"), cv2.IMREAD_UNCHANGED)
        pulses = [cv2.imread(str(tmp_path / "p" / f"flash-{k}.png"), cv2.IMREAD_UNCHANGED) for k in (18, 19)]
        assert set(np.unique(pulse)) == {least, 255} if probing else (
            set(np.unique(pulses[0])) | set(np.unique(pulses[1])) == {0, least, 255})
        if probing:
            # (the holes are discs bigger than the intervals here: each half's disc sits at the half's
            # middle, a few pixels from the whole interval's)
            assert (last[pulse == least] == 0).mean() > 0.8 and (pulse == least).sum() <= (last == 0).sum()
        else:  # the same holes lifted to each one's level (a resting one dark), drawn for the exposure's
            # time: where the pattern's are, moved on by the particles' motion since
            held = pulse < 255
            assert 0.7 < held.sum() / (last == 0).sum() < 1.3 and (last[held] == 0).mean() > 0.6


def test_lock_check_command_refuses_bad_settings_and_needs_the_camera(cli):
    for args, message in [(("--frames", "5"), "--frames 5: allowed >= 20"),
                          (("--camera-exposure-ms", "10"), "--camera-exposure-ms 10: allowed 0 < exposure <= one "
                                                           "refresh (8.33 ms at 120 Hz)"),
                          (("--camera-fps", "50"), "--camera-fps 50: allowed a frame period of whole projector"),
                          (("--display-lag-ms", "-2"), "--display-lag-ms -2.0: allowed 0..1000")]:
        bad = cli("lock-check", *args)
        assert bad.code == 2 and message in bad.err and "Traceback" not in bad.err, bad.err
    try:
        import picamera2  # noqa: F401
    except ImportError:  # off the Pi: one line saying what it needs
        off = cli("lock-check")
        assert off.code == 2 and "source 'camera' needs the picamera2 package" in off.err and "Traceback" not in off.err


def test_display_lag_command_needs_the_camera_and_the_projector(cli):
    bad = cli("display-lag", "--trials", "0")
    assert bad.code == 2 and "--trials 0: allowed >= 1" in bad.err and "Traceback" not in bad.err
    try:
        import picamera2  # noqa: F401
    except ImportError:  # off the Pi: one line saying what it needs
        off = cli("display-lag")
        assert off.code == 2 and "source 'camera' needs the picamera2 package" in off.err and "Traceback" not in off.err
