"""The KMS output's logic against a fake pykms that behaves like kms++ (dumb buffers, atomic flips, events)."""

import enum
import os
import tempfile
import time
import types

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
