"""Metrics computed by hand."""

import numpy as np

from antiscatter.evaluate.metrics import hole_mask, prf, score_frame, summarise


def test_metrics_by_hand():
    assert prf(8, 2, 2) == (0.8, 0.8, 0.8000000000000002) or np.allclose(prf(8, 2, 2), (0.8, 0.8, 0.8))
    assert prf(0, 0, 5) == (1.0, 0.0, 0.0)  # an empty detections file: recall 0
    assert prf(0, 0, 0) == (1.0, 1.0, 1.0)
    truth = np.array([[10, 10], [30, 30], [50, 50]], float)
    counted = np.array([True, True, False])  # the third is not counted
    dets = np.array([[10, 11], [50, 50], [70, 70]], float)
    s = score_frame(0, truth, np.array([3.0, 3.0, 3.0]), counted, dets, np.array([4.0, 3.0, 3.0]))
    assert (s.tp, s.fp, s.fn) == (1, 1, 1)  # match to the uncounted particle is neither
    np.testing.assert_allclose(s.centre_errors, [1.0])
    np.testing.assert_allclose(s.radius_errors, [1.0])
    total = summarise([s, s])
    assert (total["tp"], total["fp"], total["fn"]) == (2, 2, 2)
    assert total["precision"] == 0.5 and total["recall"] == 0.5 and total["f1"] == 0.5


def test_pixel_metrics_on_small_masks():
    particle = np.zeros((20, 20), bool)
    particle[5:8, 5:8] = True  # 9 pixels
    particle[15, 15] = True  # 1 pixel, not covered
    s = score_frame(0, np.array([[6, 6], [15, 15]], float), np.array([2.0, 1.0]), np.array([True, True]),
                    np.array([[6.0, 6.0]]), np.array([2.0]), particle_mask=particle)
    holes = hole_mask((20, 20), np.array([[6.0, 6.0]]), np.array([2.0]))
    assert holes[5:8, 5:8].all()
    assert s.particle_px == 10 and s.covered_px == 9
    assert s.background_px == 390 and s.lit_px == 390 - (holes.sum() - 9)
    row = s.row()
    assert row["cancellation"] == 0.9
    assert np.isclose(row["light_kept"], (390 - (holes.sum() - 9)) / 390)
