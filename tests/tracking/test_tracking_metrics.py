"""Tracking metrics on hand-made sequences, and tracking end to end."""

import csv
import json

import numpy as np

from antiscatter.evaluate.tracking import PredictionError, tracking_summary


def frames(track_ids_per_frame):
    """Two particles at fixed places; detections exactly on them with the given track ids."""
    truth_ids = np.array([1, 2])
    centres = np.array([[10.0, 10.0], [100.0, 100.0]])
    for ids in track_ids_per_frame:
        present = [i for i, t in enumerate(ids) if t is not None]
        yield (truth_ids, centres, np.array([3.0, 3.0]), np.array([True, True]),
               centres[present], np.array([ids[i] for i in present]))


def test_perfect_tracking():
    s = tracking_summary(frames([(7, 8)] * 5))
    assert s["mota"] == 1.0 and s["idf1"] == 1.0 and s["id_switches"] == 0 and s["fragmentations"] == 0


def test_one_identity_switch():
    s = tracking_summary(frames([(7, 8), (7, 8), (9, 8), (9, 8)]))
    assert s["id_switches"] == 1
    assert s["mota"] == 1 - 1 / 8
    assert s["idf1"] == 2 * 6 / 16  # best pairing: 1-7 or 1-9 (2 frames) and 2-8 (4 frames)


def test_fragmentation_and_misses():
    s = tracking_summary(frames([(7, 8), (None, 8), (7, 8)]))
    assert s["fragmentations"] == 1 and s["id_switches"] == 0
    assert s["mota"] == 1 - 1 / 6


def test_prediction_error_horizons():
    p = PredictionError()
    ids = np.array([1])
    for f in range(6):
        centre = np.array([[10.0 + 2 * f, 0.0]])
        p.add(f, ids, centre, {1: [(k, centre[0] + [2.0 * k + 0.5, 0]) for k in (1, 2, 3)]})
    out = p.summary()
    assert out["+1"]["mean_px"] == 0.5 and out["+3"]["count"] == 3


def test_run_track_writes_track_ids_and_evaluate_scores_them(tmp_path, cli):
    from antiscatter.simulate.export import SimulationRequest, simulate
    simulate(SimulationRequest(out=tmp_path / "sim", preset="bubbles", frames=20, seed=4, size=(400, 300)))
    result = cli("run", str(tmp_path / "sim"), "--track", "--output", "none",
                 "--detections", str(tmp_path / "d.csv"), "--metrics", str(tmp_path / "m.csv"))
    assert result.code == 0, result.err
    rows = list(csv.DictReader((tmp_path / "d.csv").open()))
    assert list(rows[0]) == ["frame", "time", "x", "y", "radius", "track_id"]
    assert all(int(r["track_id"]) >= 1 for r in rows)
    metrics = list(csv.DictReader((tmp_path / "m.csv").open()))
    assert all(float(r["Tracking Duration (s)"]) > 0 for r in metrics)
    result = cli("evaluate", "--truth", str(tmp_path / "sim" / "truth.csv"), "--detections",
                 str(tmp_path / "d.csv"), "--json")
    assert result.code == 0, result.err
    tracking = json.loads(result.out)["tracking"]
    assert tracking["idf1"] > 0.7 and tracking["mota"] > 0.6


def test_evaluate_scenario_with_tracking(cli, tmp_path):
    catalogue = tmp_path / "c.toml"
    catalogue.write_text('version = 1\n[scenario.small]\npreset = "bubbles"\nsize = "400x300"\nframes = 25\nseed = 2\n')
    result = cli("evaluate", "--scenario", "small", "--catalogue-file", str(catalogue), "--track", "--json")
    assert result.code == 0, result.err
    data = json.loads(result.out)
    assert data["tracking"]["idf1"] > 0.8
    assert data["tracking_isolated"]["idf1"] > 0.8
    assert data["tracking_isolated"]["tracked_truth"] <= data["tracking"]["tracked_truth"]
    assert data["prediction"]["+1"]["mean_px"] < 1.5
    assert data["prediction"]["+1"]["mean_px"] <= data["prediction"]["+3"]["mean_px"]


def test_isolated_particles_are_those_whose_footprints_touch_no_other():
    from antiscatter.evaluate.tracking import isolated

    centres = np.array([[10.0, 10.0], [16.0, 10.0], [50.0, 50.0], [60.0, 50.0], [90.0, 90.0]])
    radii = np.array([3.5, 3.0, 4.0, 5.0, 2.0])
    # 6 px apart with radii 3.5 + 3 overlap; 10 px apart with 4 + 5 do not; the last is alone
    assert isolated(centres, radii).tolist() == [False, False, True, True, True]
    assert isolated(centres[:1], radii[:1]).tolist() == [True]
    assert isolated(np.empty((0, 2)), np.empty(0)).shape == (0,)
