"""The KMS output's logic against a fake pykms that behaves like kms++ (dumb buffers, atomic flips, events)."""

import enum
import os
import tempfile
import time
import types

import cv2
import numpy as np
import pytest

from antiscatter.errors import UsageError
from antiscatter.outputs.kms import KmsOutput, load_pykms

W, H, STRIDE = 40, 20, 40 * 4 + 32


class EventType(enum.Enum):
    VBLANK = 1
    FLIP_COMPLETE = 2


class Card:
    def __init__(self):
        self.read_fd, self.write_fd = os.pipe()
        self.fd = self.read_fd
        self.events = []
        self.on_screen = None
        self.commits = []

    def read_events(self):
        os.read(self.read_fd, 1)
        events, self.events = self.events, []
        return events

    def flip(self, fb, data):
        self.on_screen = fb
        self.events.append(types.SimpleNamespace(type=EventType.FLIP_COMPLETE, seq=len(self.commits),
                                                 time=time.monotonic(), data=data))
        os.write(self.write_fd, b"x")


class DumbFramebuffer:
    next_id = 100

    def __init__(self, card, width, height, fourcc):
        assert fourcc == "XR24"
        self.id = DumbFramebuffer.next_id
        DumbFramebuffer.next_id += 1
        self.file = tempfile.TemporaryFile()
        self.file.truncate(STRIDE * height)
        self.height = height

    def fd(self, plane):
        return self.file.fileno()

    def size(self, plane):
        return STRIDE * self.height

    def stride(self, plane):
        return STRIDE

    def offset(self, plane):
        return 0

    def pixels(self):
        self.file.seek(0)
        raw = np.frombuffer(self.file.read(), np.uint8).reshape(self.height, STRIDE)
        return raw[:, : W * 4].reshape(self.height, W, 4)


class AtomicReq:
    def __init__(self, card):
        self.card, self.props = card, []

    def add(self, obj, prop, value=None):
        self.props.append((obj, prop, value))

    def commit_sync(self, allow_modeset=False):
        self.card.commits.append(("sync", self.props))
        return 0

    def commit(self, data=0, allow_modeset=False):
        self.card.commits.append(("async", self.props))
        fb_id = [v for _, p, v in self.props if p == "FB_ID"][0]
        self.card.flip(fb_id, data)
        return 0


def fake_pykms():
    mode = types.SimpleNamespace(hdisplay=W, vdisplay=H, to_blob=lambda card: types.SimpleNamespace(id=7))
    connector = types.SimpleNamespace(get_default_mode=lambda: mode)
    resources = types.SimpleNamespace(reserve_connector=lambda: connector,
                                      reserve_crtc=lambda conn: types.SimpleNamespace(id=3),
                                      reserve_primary_plane=lambda crtc: types.SimpleNamespace(id=5))
    return types.SimpleNamespace(Card=Card, ResourceManager=lambda card: resources,
                                 DumbFramebuffer=DumbFramebuffer, AtomicReq=AtomicReq, DrmEventType=EventType)


def test_double_buffered_flips_with_exact_pixels_and_flip_times():
    out = KmsOutput(pykms=fake_pykms())
    card = out.card
    assert card.commits[0][0] == "sync"  # the mode set
    patterns = [np.full((H, W), v, np.uint8) for v in (10, 200, 77)]
    patterns[1][5, 7] = 0
    shown_on = []
    for p in patterns:
        before = time.monotonic_ns()
        out.show(p)
        shown_on.append(card.on_screen)
    assert shown_on == [out.buffers[1].id, out.buffers[0].id, out.buffers[1].id]  # alternating
    expected = np.dstack([patterns[2]] * 3 + [np.full((H, W), 255, np.uint8)])
    np.testing.assert_array_equal(out.buffers[1].pixels(), expected)
    assert out.buffers[0].pixels()[5, 7, 0] == 0  # the second pattern, in the other buffer
    out.close()
    assert out.flips >= 3 and out.presented_ns >= before
    assert (out.buffers[out.front].pixels()[..., :3] == 0).all()  # lamp off at the end


def test_restore_puts_the_pattern_back_only_when_the_display_can_take_it_now():
    out = KmsOutput(pykms=fake_pykms())
    card = out.card
    pattern = np.full((H, W), 90, np.uint8)
    out.show(pattern)
    out.flash(np.full((H, W), 255, np.uint8))
    commits = len(card.commits)
    out.restore(pattern)  # the flash's flip has completed (the fake completes at once)
    assert len(card.commits) == commits + 1 and out.buffers[out.front].pixels()[0, 0, 0] == 90
    out.flash(np.full((H, W), 255, np.uint8))
    card.read_events()  # as if the flip were still under way: no event to be read yet
    out.pending = True
    commits = len(card.commits)
    out.restore(pattern)  # no waiting: the flash stays on
    assert len(card.commits) == commits and out.pending
    out.pending = False
    out.close()


def test_pattern_scaled_to_the_display_mode():
    out = KmsOutput(pykms=fake_pykms())
    out.show(np.array([[255, 0], [0, 255]], np.uint8))
    screen = out.buffers[out.front].pixels()[..., 0]
    assert screen[0, 0] == 255 and screen[0, W - 1] == 0 and screen[H - 1, W - 1] == 255
    out.close()


def test_off_the_pi_kms_needs_pykms():
    try:
        import pykms  # noqa: F401
    except ImportError:
        with pytest.raises(UsageError, match="output 'kms' needs the pykms module"):
            load_pykms()


REFRESH_NS = 1_000_000_000 // 120


class VirtualCard(Card):
    """A 120 Hz display in virtual time (``clock``, a one-item list of ns): a flip lands at the first
    vertical blank after it was asked for, and reading its event moves the clock on to then (as
    waiting for it would).  ``landed`` keeps each flip's time and the least value it showed."""

    clock: list = [0]
    buffers: dict = {}

    cards: list = []

    def __init__(self):
        super().__init__()
        self.landed = []
        self.images = []  # what each flip showed
        VirtualCard.cards.append(self)

    def flip(self, fb, data):
        lands = (self.clock[0] // REFRESH_NS + 1) * REFRESH_NS
        image = VirtualCard.buffers[fb].pixels()[..., 0].copy()
        self.landed.append((lands, int(image.min())))
        self.images.append(image)
        self.events.append(types.SimpleNamespace(type=EventType.FLIP_COMPLETE, seq=len(self.commits),
                                                 time=lands / 1e9, data=data))
        os.write(self.write_fd, b"x")

    def read_events(self):
        events = super().read_events()
        for event in events:
            self.clock[0] = max(self.clock[0], int(round(event.time * 1e9)))
        return events


class RegisteredFramebuffer(DumbFramebuffer):
    """A dumb buffer of any size, found by its id."""

    def __init__(self, card, width, height, fourcc):
        super().__init__(card, width, height, fourcc)
        self.width, self.pitch = width, width * 4 + 32
        self.file.truncate(self.pitch * height)
        VirtualCard.buffers[self.id] = self

    def size(self, plane):
        return self.pitch * self.height

    def stride(self, plane):
        return self.pitch

    def pixels(self):
        self.file.seek(0)
        raw = np.frombuffer(self.file.read(), np.uint8).reshape(self.height, self.pitch)
        return raw[:, : self.width * 4].reshape(self.height, self.width, 4)


@pytest.mark.parametrize("lag_ns, every, slow", [(0, 1, None), (REFRESH_NS, 1, None), (12_000_000, 1, None),
                                                 (14_000_000, 2, None), (12_000_000, 1, 45)])
def test_the_camera_locked_to_the_projector_takes_its_exposures_under_the_lifted_holes(tmp_path, monkeypatch,
                                                                                      lag_ns, every, slow):
    # a free-running 60 Hz camera, its clock 50 ppm fast, its exposures 5.1 ms into a refresh at
    # first, each new frame duration applied 3 frames late, its frames 16.56 ms at the shortest;
    # processing takes 5 ms.  Two discs cross the view.  The loop pulls the exposures to the middle
    # of a refresh's light and shows each lifted pattern at the flip whose light covers the next
    # exposure it can reach: with no display lag that is every frame, taken under it -- the twin's
    # locked camera; with a projector that lags a refresh (a DLP formatting one frame while it
    # shows the last) the last frame's light goes out ahead, at the flip after the read; lagging
    # 12 ms, each frame's light goes out after its pattern, before the next frame is read, for the
    # exposure after that -- every frame is taken, each under the light it was told; lagging 14 ms
    # the pattern and that light no longer both fit, and every other frame is.  ``slow``: that frame
    # takes 4 ms longer (12 ms lag: its light misses its flip; the loop takes up the chain again,
    # and each frame between is told the light it really had).
    import collections
    import csv
    import io

    from conftest import draw_discs

    import antiscatter.outputs.kms as kms_module
    import antiscatter.runtime as runtime
    import antiscatter.system as system
    from antiscatter.config import load_config
    from antiscatter.runtime import run
    from antiscatter.sources.base import Frame, FrameSource

    clock = VirtualCard.clock = [1_000_000_000]
    exposure, period, latency = 4_000_000, 2 * REFRESH_NS, 5_000_000
    pykms = fake_pykms()
    pykms.Card, pykms.DumbFramebuffer = VirtualCard, RegisteredFramebuffer
    display = types.SimpleNamespace(hdisplay=320, vdisplay=200, to_blob=lambda card: types.SimpleNamespace(id=7))
    resources = pykms.ResourceManager(None)
    resources.reserve_connector().get_default_mode = lambda: display
    monkeypatch.setattr(kms_module, "load_pykms", lambda: pykms)
    monkeypatch.setitem(kms_module.KmsOutput.__init__.__kwdefaults__, "clock", lambda: clock[0])
    process = runtime._Pipeline.process

    told = []  # the light the detector is told the next exposure gets, after each frame processed

    def processed_in_virtual_time(self, *args, **kwargs):  # processing takes `latency`
        rec = process(self, *args, **kwargs)
        clock[0] += latency + (4_000_000 if len(told) == slow else 0)
        told.append(None)
        return rec

    def light_told(light, *args, **kwargs):
        told[-1] = cv2.resize(light, (320, 200), interpolation=cv2.INTER_NEAREST)
        return camera_light(light, *args, **kwargs)

    camera_light = system.camera_light
    monkeypatch.setattr(runtime._Pipeline, "process", processed_in_virtual_time)
    monkeypatch.setattr(system, "camera_light", light_told)

    class VirtualCamera(FrameSource):
        live, size, shortest_frame_ns = True, (160, 120), 16_560_000

        def __init__(self):
            self.next_start = clock[0] + 5_100_000
            self.requested, self.durations = period, collections.deque([period] * 3)
            self.exposures, self.made = [], 0

        def set_frame_duration_ns(self, ns):
            self.requested = ns

        def read(self):
            while True:  # frames that ended before they were asked for are gone (no queue)
                start, end = self.next_start, self.next_start + exposure
                self.durations.append(self.requested)
                self.next_start = start + round(self.durations.popleft() * (1 + 50e-6))
                self.made += 1
                if end > clock[0]:
                    break
            if len(self.exposures) == 90:
                return None
            self.exposures.append((start, end, self.made))
            clock[0] = end + 500_000  # read half a millisecond after it ends
            k = len(self.exposures)
            image = draw_discs(self.size, [(30.0 + k, 50.0, 5.0), (120.0 - k, 80.0, 4.0)])
            return Frame(image, len(self.exposures) - 1, start + exposure // 2, exposure)

    metrics = tmp_path / "m.csv"
    config = load_config(overrides={"source": {"spec": "camera", "camera_lock": True, "camera_exposure_ms": 4.0},
                                    "output": {"outputs": ("kms", f"files:{tmp_path / 'p'}")},
                                    "run": {"metrics": str(metrics)},
                                    "pattern": {"display_lag_ms": lag_ns / 1e6},
                                    "track": {"latency_ms": 5.0},  # (the loop's own clock is not virtual)
                                    # (every lifted hole at dim_level; the detector told each light)
                                    # (a lag beyond a refresh: auto would take dim holes unlocked)
                                    "light": {"levels": "fixed", "compensate": True,
                                              "strategy": "pulse" if every == 2 else "auto"}})
    assert config.light.strategy == "pulse"  # auto, with the camera locked
    camera = VirtualCamera()
    out = io.StringIO()
    summary = run(config, source=camera, log=io.StringIO(), out=out)
    # every other frame: said at the end, with what does better
    assert ("note: the locked loop processed" in out.getvalue()) == (every == 2)
    # each flip's light: from its flip + the lag, and the least value it showed
    light = [(t + lag_ns, least) for t, least in VirtualCard.cards[-1].landed]
    rows = list(csv.DictReader(metrics.open()))
    assert summary.frames == len(rows) and summary.frames + summary.dropped == 90
    # locked within 20 frames: from then on the camera's frames are processed every frame (every
    # other with a lag of more than a refresh: the one between is read but skipped as stale; with
    # no lag or one refresh's, none skipped, none gone while the loop was busy), each exposed whole
    # inside a refresh of lifted holes
    processed = {int(r["Capture Timestamp (ns)"]) for r in rows[20:]}
    settled = [e for e in camera.exposures if e[0] + exposure // 2 in processed]
    assert len(settled) == len(processed)
    made = [m for _, _, m in settled]
    lifted = round(config.light.dim_level * 255)
    dark = [i for i, (start, end, _) in enumerate(settled)  # exposures not whole under lifted holes
            if not ([least for t, least in light if t <= start][-1] >= lifted
                    and end <= min([t for t, _ in light if t > start], default=end))]
    if slow is None:
        assert made == list(range(made[0], made[0] + every * len(made), every))
        if every == 1:
            assert all(int(r["Dropped Frames"]) == 0 for r in rows[20:])
        assert dark == []  # the holes lifted
    else:  # a frame lost to the slow one, one taken under the pattern as the chain starts again
        assert sum(b - a - 1 for a, b in zip(made, made[1:])) <= 1 and len(dark) <= 1, (str(made), dark)
    # the detector is told the light each exposure was taken under (with the light ahead, the one
    card = VirtualCard.cards[-1]
    # that went out before the frame before it was processed); and the files output keeps that
    # light as flash-N.png for frame N
    for k, ((start, end, _), j) in enumerate(zip(settled, range(20, len(rows)))):
        under = max(i for i, (t, _) in enumerate(light) if t <= start)
        assert np.array_equal(told[j - 1], card.images[under]), j
        if k not in dark:
            kept = cv2.imread(str(tmp_path / "p" / f"flash-{rows[j]['Frame']}.png"), cv2.IMREAD_UNCHANGED)
            assert np.array_equal(cv2.resize(kept, (320, 200), interpolation=cv2.INTER_NEAREST), card.images[under])
    # ... and between exposures the holes dark: the pattern (its holes at 0) follows each light
    assert sum(least == 0 for _, least in light[40:]) >= len(light[40:]) // 2 - 1
    errors = [abs(float(r["Exposure Phase Error (s)"])) for r in rows[20:]]
    assert max(errors) < 0.05 / 120


@pytest.mark.parametrize("lag_ms", [0.0, 3.0, 1000 / 120, 12.0, 35.0, 60.0])
def test_the_display_lag_measured_by_the_camera(lag_ms):
    # a 60 Hz camera, 15 ms exposures at an odd phase, looking at what a 120 Hz projector lights
    # lag_ms after each flip; the light it gathers is the share of its exposure lit, plus noise
    from antiscatter.lock import display_lag
    from antiscatter.sources.base import Frame

    clock = VirtualCard.clock = [1_000_000_000]
    pykms = fake_pykms()
    pykms.Card, pykms.DumbFramebuffer = VirtualCard, RegisteredFramebuffer
    out = KmsOutput(pykms=pykms, clock=lambda: clock[0])
    card = VirtualCard.cards[-1]
    lag, exposure, rng = round(lag_ms * 1e6), 15_000_000, np.random.default_rng(0)

    def light(t):  # the value on the scene at t: the last flip that is light by then
        return max([(when, v) for when, v in card.landed if when + lag <= t] or [(0, 0)])[1]

    class Camera:
        def __init__(self):
            self.start, self.count = clock[0] + 3_700_000, 0

        def read(self):
            while self.start + exposure <= clock[0]:  # ended before it was asked for: gone
                self.start += 16_666_667
            start, self.start = self.start, self.start + 16_666_667
            clock[0] = start + exposure
            lit = np.mean([light(start + exposure * (i + 0.5) / 300) for i in range(300)]) / 255
            image = np.clip(20 + 200 * lit + rng.normal(0, 1.5, (24, 32)), 0, 255).astype(np.uint8)
            self.count += 1
            return Frame(image, self.count, start + exposure // 2, exposure)

    result = display_lag(Camera(), out, refresh_ns=REFRESH_NS, trials=9)
    assert result["lag_ms"] == pytest.approx(lag_ms, abs=0.15)
    assert result["spread_ms"][1] - result["spread_ms"][0] < 0.3 and len(result["trials_ms"]) >= 4


@pytest.mark.parametrize("lag_ms, told_ms, obeys, ok", [
    (0.0, 0.0, True, True),  # locks, every exposure lit whole by the white shown for it
    (1000 / 120, 1000 / 120, True, True),  # a projector lagging a refresh, told so
    (4.0, 0.0, True, False),  # the lag not told: the exposures straddle the light's edge
    (0.0, 0.0, False, False),  # a sensor that ignores its frame durations never locks
])
def test_the_lock_check_sees_whether_each_exposure_is_lit_whole(lag_ms, told_ms, obeys, ok):
    # a free-running 60 Hz camera (clock 50 ppm fast, durations applied 3 frames late, 16.56 ms at
    # the shortest, its exposures 5.1 ms into a refresh at first) looking at what a 120 Hz projector
    # lights lag_ms after each flip; each frame gathers the light over its 4 ms exposure
    import collections

    from antiscatter.cli import format_lock_check
    from antiscatter.lock import lock_check
    from antiscatter.sources.base import Frame

    clock = VirtualCard.clock = [1_000_000_000]
    pykms = fake_pykms()
    pykms.Card, pykms.DumbFramebuffer = VirtualCard, RegisteredFramebuffer
    out = KmsOutput(pykms=pykms, clock=lambda: clock[0])
    card = VirtualCard.cards[-1]
    lag, exposure, period, rng = round(lag_ms * 1e6), 4_000_000, 2 * REFRESH_NS, np.random.default_rng(0)

    def light(t):  # the value on the scene at t: the last flip that is light by then
        return max([(when, v) for when, v in card.landed if when + lag <= t] or [(0, 0)])[1]

    class Camera:
        shortest_frame_ns = 16_560_000

        def __init__(self):
            self.next_start, self.requested = clock[0] + 5_100_000, period
            self.durations, self.count = collections.deque([period] * 3), 0

        def set_frame_duration_ns(self, ns):
            if obeys:
                self.requested = ns

        def read(self):
            while True:  # frames that ended before they were asked for are gone (no queue)
                start, end = self.next_start, self.next_start + exposure
                self.durations.append(self.requested)
                self.next_start = start + round(max(self.durations.popleft(), self.shortest_frame_ns) * (1 + 50e-6))
                if end > clock[0]:
                    break
            clock[0] = end + 500_000
            lit = np.mean([light(start + exposure * (i + 0.5) / 200) for i in range(200)]) / 255
            image = np.clip(20 + 200 * lit + rng.normal(0, 1.5, (24, 32)), 0, 255).astype(np.uint8)
            self.count += 1
            return Frame(image, self.count, start + exposure // 2, exposure)

    result = lock_check(Camera(), out, refresh_ns=REFRESH_NS, period_ns=period, exposure_ns=exposure,
                        lag_ns=round(told_ms * 1e6), frames=120)
    assert result["ok"] is ok, result
    text = format_lock_check(result)  # what the lock-check command prints
    if ok:
        assert result["locked_at"] <= 30 and result["lit_frames"] >= 80 and result["least_lit"] >= 0.95
        assert result["error_us"][1] < 0.05 * REFRESH_NS / 1e3
        assert "passed" in text and "FAILED" not in text
    elif obeys:  # locked, to the wrong moment: about half of each exposure lit
        assert result["locked_at"] is not None and 0.3 < result["median_lit"] < 0.7
        assert "FAILED: exposures lit in part" in text and "display lag" in text
    else:
        assert result["locked_at"] is None and "FAILED" in text and "FrameDurationLimits" in text
