import numpy as np
import pytest

from antiscatter import Detections


def test_empty_has_normal_shapes():
    d = Detections.empty()
    assert d.centres.shape == (0, 2)
    assert d.radii.shape == (0,)
    assert d.scores.shape == (0,)
    assert d.track_ids.shape == (0,)
    assert len(d) == 0


def test_defaults_and_selection():
    d = Detections([[1, 2], [3, 4]], [5, 6])
    assert d.track_ids.tolist() == [-1, -1]
    assert np.isnan(d.scores).all()
    picked = d[np.array([False, True])]
    assert picked.centres.tolist() == [[3.0, 4.0]]
    assert picked.radii.tolist() == [6.0]


def test_mismatched_lengths_rejected():
    with pytest.raises(ValueError, match="radii: expected 2 values to match centres, got 1"):
        Detections([[1, 2], [3, 4]], [5])
