import numpy as np
import pytest

from antiscatter.errors import UsageError
from antiscatter.outputs import open_output
from antiscatter.outputs.framebuffer import FramebufferOutput, read_geometry


def make_fb(tmp_path, width, height, bpp, stride, fill=0xAA):
    sysfs = tmp_path / "sys" / "fb7"
    sysfs.mkdir(parents=True)
    (sysfs / "virtual_size").write_text(f"{width},{height}\n")
    (sysfs / "bits_per_pixel").write_text(f"{bpp}\n")
    (sysfs / "stride").write_text(f"{stride}\n")
    device = tmp_path / "fb7"
    device.write_bytes(bytes([fill]) * (stride * height))
    return device, sysfs


def expected_rgb565(grey):
    g = grey.astype(np.uint16)
    value = ((g >> 3) << 11) | ((g >> 2) << 5) | (g >> 3)
    return value.astype("<u2").view(np.uint8).reshape(grey.shape[0], -1)


def expected_xrgb8888(grey):
    out = np.empty(grey.shape + (4,), np.uint8)
    out[..., 0] = out[..., 1] = out[..., 2] = grey
    out[..., 3] = 255
    return out.reshape(grey.shape[0], -1)


def pattern(width, height):
    yy, xx = np.mgrid[0:height, 0:width]
    return ((xx * 13 + yy * 29) % 256).astype(np.uint8)


@pytest.mark.parametrize("bpp, expected", [(16, expected_rgb565), (32, expected_xrgb8888)])
def test_writes_exact_bytes_with_stride_padding(tmp_path, bpp, expected):
    width, height = 20, 10
    stride = width * bpp // 8 + 12
    device, sysfs = make_fb(tmp_path, width, height, bpp, stride)
    grey = pattern(width, height)
    out = FramebufferOutput(device, sysfs=sysfs)
    out.show(grey)
    raw = np.frombuffer(device.read_bytes(), np.uint8).reshape(height, stride)
    np.testing.assert_array_equal(raw[:, : width * bpp // 8], expected(grey))
    assert (raw[:, width * bpp // 8:] == 0xAA).all()  # padding untouched
    out.show(255 - grey)  # second frame through the same mapping
    raw = np.frombuffer(device.read_bytes(), np.uint8).reshape(height, stride)
    np.testing.assert_array_equal(raw[:, : width * bpp // 8], expected(255 - grey))
    out.close()
    raw = np.frombuffer(device.read_bytes(), np.uint8).reshape(height, stride)
    assert (raw[:, : width * bpp // 8] == 0).all()  # lamp off at the end


def test_pattern_scaled_to_the_framebuffer_size(tmp_path):
    device, sysfs = make_fb(tmp_path, 8, 4, 32, 32)
    small = np.array([[0, 255, 0, 255], [255, 0, 255, 0]], np.uint8)
    with FramebufferOutput(device, sysfs=sysfs, blank_on_close=False) as out:
        out.show(small)
    raw = np.frombuffer(device.read_bytes(), np.uint8).reshape(4, 8, 4)
    np.testing.assert_array_equal(raw[..., 0], np.kron(small, np.ones((2, 2), np.uint8)))


def test_geometry_read_from_sysfs(tmp_path):
    _, sysfs = make_fb(tmp_path, 1920, 1080, 16, 3840)
    g = read_geometry(sysfs)
    assert (g.width, g.height, g.bits_per_pixel, g.stride) == (1920, 1080, 16, 3840)


def test_unsupported_depth(tmp_path):
    _, sysfs = make_fb(tmp_path, 10, 10, 24, 30)
    with pytest.raises(UsageError, match="bits_per_pixel: 24 is not supported; allowed 16 .RGB565. or 32"):
        read_geometry(sysfs)


def test_missing_device(tmp_path):
    _, sysfs = make_fb(tmp_path, 10, 10, 16, 20)
    with pytest.raises(UsageError, match=r"nofb: no such framebuffer device"):
        FramebufferOutput(tmp_path / "nofb", sysfs=sysfs)


def test_missing_sysfs_geometry(tmp_path):
    with pytest.raises(UsageError, match=r"virtual_size: missing; is fb9 a framebuffer device\?"):
        open_output(f"framebuffer:{tmp_path / 'fb9'}")


def test_no_permission(tmp_path, monkeypatch):
    import os
    device, sysfs = make_fb(tmp_path, 10, 10, 16, 20)

    def refuse(path, flags, *args):
        raise PermissionError(13, "Permission denied", str(path))

    monkeypatch.setattr(os, "open", refuse)
    with pytest.raises(UsageError, match=r"fb7: permission denied \(add the user to the 'video' group\)"):
        FramebufferOutput(device, sysfs=sysfs)
