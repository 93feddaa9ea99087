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
