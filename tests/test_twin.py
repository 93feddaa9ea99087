"""The digital twin's physics on hand-made cases, and the twin command."""

import itertools
import json

import cv2
import numpy as np
import pytest

from antiscatter.probe import MIN_WORTH
from antiscatter.simulate.scene import KindConfig, RealisticScene, SceneConfig
from antiscatter.twin import TwinGeometry, TwinRun, _mean_over_discs, default_runs, simulate_loop

SIZE = (400, 300)


def test_a_particle_under_full_white_and_all_black_light():
    u, v, r = np.array([100.0, 5000.0]), np.array([80.0, 80.0]), np.array([3.0, 3.0])
    np.testing.assert_allclose(_mean_over_discs(np.ones((200, 300)), u, v, r), [1.0, 0.0])  # 2nd: outside
    np.testing.assert_allclose(_mean_over_discs(np.zeros((200, 300)), u, v, r), [0.0, 0.0])
    half = np.ones((200, 300))
    half[:, 100:] = 0
    # the edge lies between pixels 99 and 100, half a pixel left of the centre: the share of a
    # radius-3 disc left of it is (acos(d) - d sqrt(1 - d^2)) / pi with d = 0.5 / 3
    d = 0.5 / 3
    share = (np.arccos(d) - d * np.sqrt(1 - d * d)) / np.pi
    assert _mean_over_discs(half, np.array([100.0]), np.array([80.0]), np.array([3.0]))[0] == pytest.approx(share, abs=0.03)
    hole = np.ones((200, 300))
    cv2.circle(hole, (150, 100), 10, 0.0, -1)  # a hole that just covers a disc of radius 10 darkens it all
    assert _mean_over_discs(hole, np.array([150.0]), np.array([100.0]), np.array([10.0]))[0] < 0.02


def test_a_particle_weighs_its_brightness_times_its_image_area():
    from antiscatter.twin import backscatter_weight

    scene = one_static_particle()
    g = TwinGeometry(camera_size=SIZE)
    p = scene.particles()
    one = backscatter_weight(scene, g, p)[0]
    assert one == pytest.approx(scene.full_light_brightness()[0] * (g.camera_focal * p["R"][0] / p["Z"][0]) ** 2)
    p["R"] = p["R"] / 10  # a tenth of the size at the same distance: a hundredth of the light
    assert backscatter_weight(scene, g, p)[0] == pytest.approx(one / 100)


def test_disparity_of_a_known_baseline():
    g = TwinGeometry(baseline_m=0.12)
    shift = g.plane_mapping(1.0)[0, 2] - g.plane_mapping(2.0)[0, 2]
    assert shift == pytest.approx(-g.projector_focal * 0.12 * (1 / 1.0 - 1 / 2.0))  # about -92 px
    assert abs(shift) > 90
    # the plane mapping and the point projection agree for a point at that depth
    X, Y, Z = 0.1, -0.05, 1.7
    u_c = g.camera_focal * X / Z + (g.camera_size[0] - 1) / 2
    v_c = g.camera_focal * Y / Z + (g.camera_size[1] - 1) / 2
    H = g.plane_mapping(Z)
    up, vp = g.to_projector(np.array([X]), np.array([Y]), np.array([Z]))
    assert H[0, 0] * u_c + H[0, 2] == pytest.approx(up[0]) and H[1, 1] * v_c + H[1, 2] == pytest.approx(vp[0])
    assert np.allclose(TwinGeometry(baseline_m=0).plane_mapping(0.5), TwinGeometry(baseline_m=0).plane_mapping(3))


def one_static_particle():
    # drifting slowly: a particle that never moves would rightly be learnt as scene by the detector
    bright = KindConfig(count=1, size_mm=(4, 4), depth_m=(0.6, 0.6), speed=(0.05, 0.05), direction_deg=0.0,
                        spread_deg=0.0, albedo=(1, 1))
    config = SceneConfig(bubbles=bright, background="black", read_noise=1.0, shot_noise=0.0, lamp_cone=False,
                         defocus=0.0, exposure_s=0.0)
    scene = RealisticScene(config, size=SIZE, rng=np.random.default_rng(0))
    scene._state["X"][:] = 0.02  # in front of the lens, inside the projector's narrower field
    scene._state["Y"][:] = -0.01
    return scene


def loop(strategy, **kw):
    # a generous margin: the hole covers the whole particle, so the light it gets is exactly the strategy's
    kw.setdefault("margin_px", 12.0)
    return simulate_loop(TwinRun("contrast", "calibrated", strategy, **kw),
                         geometry=TwinGeometry(camera_size=SIZE, baseline_m=0.0), frames=24, latency_ms=5,
                         scene=one_static_particle())


@pytest.mark.parametrize("strategy, per_frame", [("dim", 1), ("pulse", 2)])
def test_one_pattern_a_frame_as_run_draws_them(strategy, per_frame, monkeypatch):
    # run shows one pattern a camera frame (pulse: and the one lifted for the next exposure), each
    # held until the next; the twin measures that, not holes redrawn for each projector refresh
    import antiscatter.system as system

    drawn, real = [], system.render_pattern
    monkeypatch.setattr(system, "render_pattern", lambda *a, **kw: drawn.append(1) or real(*a, **kw))
    frames = 12
    out = simulate_loop(TwinRun("contrast", "calibrated", strategy, predict=True),
                        geometry=TwinGeometry(camera_size=SIZE, baseline_m=0.0, projector_hz=240.0), frames=frames,
                        latency_ms=5, scene=one_static_particle())
    assert out["backscatter_removed"] > 0.5
    # four refreshes a frame at 240 Hz: a pattern a frame, and a lifted one for each exposure after
    # the first pattern is on (pulse)
    assert frames * per_frame - 2 <= len(drawn) <= frames * per_frame


def test_the_naive_loop_flickers_and_removes_about_half():
    out = loop("none")
    removed = [f["removed"] for f in out["series"][4:]]
    assert set(np.round(removed, 2)) <= {0.0, 1.0}  # lit, dark, lit, dark...
    assert np.mean(np.abs(np.diff(removed))) > 0.9
    assert out["backscatter_removed"] == pytest.approx(0.5, abs=0.1)


def test_a_flash_sub_frame_takes_its_share_of_the_light():
    out = loop("flash", flash_level=0.25)
    # in steady state the particle gets the flash (0.25 of one sub-frame in two, as run shows it:
    # grey level 64 of 255) and nothing else
    for f in out["series"][4:]:
        assert f["removed"] == pytest.approx(1 - 64 / 255 / 2, abs=1e-6)


def test_dim_holes_keep_the_particle_found():
    out = loop("dim", dim_level=0.2)
    for f in out["series"][4:]:
        assert f["removed"] == pytest.approx(0.8, abs=1e-6)
    # the steady figures leave the start-up out (here the last 12 of 24 frames): exactly the dim level's
    assert out["steady_from_frame"] == 12 and out["backscatter_removed_steady"] == pytest.approx(0.8, abs=1e-6)
    assert out["backscatter_removed"] < 0.8 - 0.02  # the first frames, under the full lamp, count in the run's
    assert out["scene_light_kept_steady"] == pytest.approx(np.mean([f["kept"] for f in out["series"][12:]]))


def test_pulsed_holes_are_dim_only_while_the_camera_exposes():
    # 120 Hz projector, 60 Hz camera: the hole is lifted to 0.2 in the exposure's refresh and dark
    # in the other, so the particle gets 0.1 of the full light and stays found
    out = loop("pulse", dim_level=0.2)
    for f in out["series"][4:]:
        assert f["removed"] == pytest.approx(1 - 0.2 / 2, abs=1e-6)
    assert out["scene_light_kept"] > loop("flash", flash_level=0.2)["scene_light_kept"] + 0.3


def test_probing_under_pulse_keeps_the_whole_interval_dark_between_exposures():
    # at 12 cm the particle's depth is found by bisection; while a probe covers the half that does
    # not hold it, dim holes leave it fully lit, pulsed ones dark in the refresh the camera skips
    runs = {strategy: simulate_loop(TwinRun("contrast", "probe", strategy, predict=True, margin_px=2.0,
                                            dim_level=0.2, levels="fixed"),
                                    geometry=TwinGeometry(camera_size=SIZE, baseline_m=0.12), frames=30,
                                    latency_ms=5, scene=one_static_particle())
            for strategy in ("dim", "pulse")}
    dim, pulse = ([f["removed"] for f in runs[s]["series"]] for s in ("dim", "pulse"))
    assert min(dim[1:6]) == pytest.approx(0.0, abs=1e-6)  # probing: a probe half leaves it fully lit...
    probing = [p for d, p in zip(dim[1:6], pulse[1:6]) if d < 1e-6]
    assert probing and min(probing) >= 0.5 - 1e-6  # ... and pulsed, it is dark in the refresh the camera skips
    # (settled from frame 14: the track's noise, matched to its slow drift, narrows its hole while
    # its velocity is still settling -- 1-5 % of the particle's light on its edge in frames 7-13;
    # from frame 9 with one noise for every track)
    assert dim[14:] == pytest.approx([0.8] * 16, abs=1e-6) and pulse[14:] == pytest.approx([0.9] * 16, abs=1e-6)
    assert all(p >= d + 0.1 - 1e-6 for d, p in zip(dim[1:], pulse[1:]))
    # each settled hole at its own particle's level (this bright bubble needs a few per cent of the
    # lamp): the probe's verdicts say when it had its hole's light
    for strategy, share in (("dim", 1.0), ("pulse", 0.5)):
        own = simulate_loop(TwinRun("contrast", "probe", strategy, predict=True, margin_px=2.0, dim_level=0.2),
                            geometry=TwinGeometry(camera_size=SIZE, baseline_m=0.12), frames=30, latency_ms=5,
                            scene=one_static_particle())
        removed = [f["removed"] for f in own["series"][14:]]  # (settled, as above)
        assert min(removed) > 1 - 0.2 * share + 0.05 and np.median(removed) >= 1 - 0.05 * share, strategy


def test_probing_draws_only_the_holes_worth_their_light():
    # at 12 cm a particle of unknown depth is searched for along hundreds of projector px of line;
    # the faint ones' segments darken far more of the scene than their share of the backscatter:
    # left out (min_worth, the default), the scene keeps much more light for little backscatter
    def figures(min_worth):
        runs = [simulate_loop(TwinRun("contrast", "probe", "pulse", predict=True, min_worth=min_worth),
                              geometry=TwinGeometry(camera_size=SIZE, baseline_m=0.12), frames=30, latency_ms=5,
                              seed=seed) for seed in (1, 2)]
        return (np.mean([r["backscatter_removed"] for r in runs]), np.mean([r["scene_light_kept"] for r in runs]))

    (every_removed, every_kept), (worth_removed, worth_kept) = figures(0.0), figures(MIN_WORTH)
    assert worth_kept > every_kept + 0.04  # (0.825 -> 0.888 when written)
    assert worth_removed > every_removed - 0.03  # (0.751 -> 0.765)


def test_full_light_run_is_the_reference(cli):
    out = simulate_loop(TwinRun(detector=None), geometry=TwinGeometry(camera_size=SIZE), preset="bubbles", frames=5)
    assert out["backscatter_removed"] == 0 and out["scene_light_kept"] == 1 and not out["calibrated"]


def test_twin_command_json(cli):
    result = cli("twin", "--frames", "6", "--size", "320x240", "--preset", "bubbles", "--json", "--latency-ms", "7")
    assert result.code == 0, result.err
    runs = json.loads(result.out)["runs"]
    required = {"detector", "calibrated", "predict", "strategy", "latency_ms", "baseline_m", "backscatter_removed",
                "scene_light_kept", "backscatter_removed_steady", "scene_light_kept_steady", "steady_from_frame"}
    assert all(required <= set(r) for r in runs)
    assert {r["strategy"] for r in runs} == {"none", "dim", "pulse", "flash", "coast"}
    assert any(r["detector"] == "seed" for r in runs) and any(r["detector"] == "default" for r in runs)
    # tracked dim and pulsed holes at each particle's own level and at the dim level for all, side by side
    assert {(r["strategy"], r["levels"]) for r in runs if r["predict"] and r["strategy"] in ("dim", "pulse")} == {
        (s, lv) for s in ("dim", "pulse") for lv in ("adaptive", "fixed")}
    assert all(r["levels"] is None for r in runs if r["strategy"] not in ("dim", "pulse"))
    # depth probing draws only the holes worth their light, and every hole beside it for comparison
    assert sorted(r["min_worth"] for r in runs if r["mapping"] == "probe") == [0.0] + [MIN_WORTH] * 4
    assert all(r["min_worth"] is None for r in runs if r["mapping"] != "probe")
    # adaptive holes rest after each sighting, as run's -- pulsed ones one frame, dim ones two (they
    # leave their particles light the whole frame); probing never does
    assert {(r["strategy"], r["rest"]) for r in runs if r["levels"] == "adaptive" and r["mapping"] != "probe"} == {
        ("pulse", 1), ("dim", 2)}
    assert all(r["rest"] == 0 for r in runs if r["levels"] == "adaptive" and r["mapping"] == "probe")
    assert all(r["rest"] is None for r in runs if r["levels"] != "adaptive")
    assert all(r["latency_ms"] == 7 and 0 <= r["backscatter_removed"] <= 1 and 0 <= r["scene_light_kept"] <= 1
               for r in runs)
    bad = cli("twin", "--preset", "seed")
    assert bad.code == 2 and "the twin needs 3-D particles" in bad.err
    bad = cli("twin", "--dim-level", "1.5")
    assert bad.code == 2 and "--dim-level 1.5: allowed 0..1" in bad.err and "Traceback" not in bad.err
    # the views do not overlap: every figure would be 0 / 0 (it printed 0.000 for all, full light included)
    bad = cli("twin", "--min-worth", "-1")
    assert bad.code == 2 and "--min-worth -1.0: allowed a number >= 0" in bad.err
    bad = cli("twin", "--rest", "-1")
    assert bad.code == 2 and "--rest -1: allowed a whole number of frames >= 0" in bad.err
    bad = cli("twin", "--latency-ms", "nan")  # a traceback before
    assert bad.code == 2 and "--latency-ms nan: allowed a number >= 0" in bad.err
    bad = cli("twin", "--baseline-m", "inf")
    assert bad.code == 2 and "baseline_m: got inf, allowed a number >= 0" in bad.err
    bad = cli("twin", "--frames", "2", "--baseline-m", "5")
    assert bad.code == 2 and "baseline 5 m: the projector lights none of the camera's view" in bad.err
    # frames so small that no track is searched for: the probe maps no points (OpenCV gives None for none)
    tiny = cli("twin", "--frames", "3", "--size", "9x9", "--json")
    assert tiny.code == 0, tiny.err


def test_twin_dim_level_reaches_the_dim_and_pulsed_runs(cli):
    result = cli("twin", "--frames", "3", "--size", "200x150", "--preset", "bubbles", "--json", "--dim-level", "0.3",
                 "--baseline-m", "0")
    assert result.code == 0, result.err
    runs = json.loads(result.out)["runs"]
    assert {r["dim_level"] for r in runs if r["strategy"] in ("dim", "pulse")} == {0.3}


def test_curves_plot(tmp_path):
    import cv2
    from antiscatter.twin import plot_curves
    curves = plot_curves(str(tmp_path / "t.png"), geometry=TwinGeometry(camera_size=(200, 150)), preset="bubbles",
                         frames=3, latencies_ms=(0.0, 20.0), baselines_m=(0.0, 0.12), currents_m_s=(0.0, 0.5))
    assert set(curves["by_latency"]) == {"seed, identity", "none", "coast+predict", "dim+predict", "pulse+predict",
                                       "flash+predict", "probe+pulse+predict"}
    assert all(len(v) == 2 for v in curves["by_baseline"].values())
    assert all(len(v) == 2 for v in curves["by_speed"].values())
    # a current across the view speeds the particles up in the image
    slow, fast = curves["speed_px_s"]
    assert fast > slow + 50
    assert cv2.imread(str(tmp_path / "t.png")).shape[1] > 1500  # three panels side by side
    assert "by_focus" not in curves  # a pinhole projector has no focus


def test_curves_plot_against_the_projector_focus(tmp_path):
    from antiscatter.twin import plot_curves
    geometry = TwinGeometry(camera_size=(200, 150), projector_aperture_m=0.006)
    curves = plot_curves(str(tmp_path / "f.png"), geometry=geometry, preset="bubbles", frames=3,
                         latencies_ms=(5.0,), baselines_m=(0.0,), currents_m_s=(0.0,), focuses_m=(0.5, 3.0))
    assert curves["focus_m"] == [0.5, 3.0] and all(len(v) == 2 for v in curves["by_focus"].values())
    assert cv2.imread(str(tmp_path / "f.png")).shape[1] > 2000  # a fourth panel


def test_a_current_replaces_the_presets_and_carries_every_particle():
    from antiscatter.errors import UsageError
    from antiscatter.simulate import make_scene
    from antiscatter.twin import particle_speed

    geometry = TwinGeometry()
    still = make_scene("mixed", rng=np.random.default_rng(3), size=(800, 600), current=(0.0, 0.0))
    drift = make_scene("mixed", rng=np.random.default_rng(3), size=(800, 600), current=(0.3, 0.0))
    a, b = still.particles(), drift.particles()
    np.testing.assert_array_equal(a["X"], b["X"])  # the same scene...
    still.step()
    drift.step()
    a, b = still.particles(), drift.particles()
    both, ia, ib = np.intersect1d(a["ids"], b["ids"], return_indices=True)  # not replaced after leaving the view
    assert len(both) > 0.5 * len(a["ids"])
    dx = b["X"][ib] - a["X"][ia]
    # ...each particle 0.3 m/s further across (but the odd one born again elsewhere meanwhile)
    assert np.mean(np.isclose(dx, 0.3 / still.fps, rtol=0, atol=1e-9)) > 0.98
    assert particle_speed(drift, geometry) > particle_speed(still, geometry)
    with pytest.raises(UsageError, match="realistic presets"):
        make_scene("seed", rng=np.random.default_rng(0), current=(0.1, 0.0))


@pytest.mark.parametrize("exposure_s, first_dark_frame", [(0.003, 0), (0.004, 1)])
def test_a_pattern_ready_within_the_frame_goes_on_at_the_next_refresh(exposure_s, first_dark_frame):
    # 120 Hz projector, 60 Hz camera: refreshes at 0 and 8.33 ms of each frame, the flash in the first.
    # Exposure 3 ms + latency 4 ms: ready at 7 ms, the hole is on at 8.33 ms of the same frame;
    # exposure 4 ms + latency 5 ms: ready at 9 ms, too late for it -- on in the next frame.
    latency = 5 if exposure_s == 0.004 else 4
    out = simulate_loop(TwinRun("contrast", "calibrated", "flash", flash_level=0.25, margin_px=12.0),
                        geometry=TwinGeometry(camera_size=SIZE, baseline_m=0.0, exposure_s=exposure_s),
                        frames=6, latency_ms=latency, scene=one_static_particle())
    removed = [f["removed"] for f in out["series"]]
    flash = 64 / 255  # 0.25 as run shows it, an 8-bit grey level
    assert removed[first_dark_frame] == pytest.approx(1 - flash / 2, abs=1e-6)
    if first_dark_frame:
        assert removed[0] == pytest.approx(1 - (flash + 1) / 2, abs=1e-6)  # the full lamp until then


def test_scoreboard_twin_table_has_every_run_at_both_baselines(monkeypatch):
    import antiscatter.twin as twin
    from antiscatter.evaluate.report import _twin_rows

    real = twin.simulate_loop
    monkeypatch.setattr(twin, "simulate_loop", lambda run, **kw: real(run, **{**kw, "geometry": TwinGeometry(
        camera_size=(160, 120), baseline_m=kw["geometry"].baseline_m)}))
    rows = _twin_rows(2, lambda s: None, seeds=2, workers=2)  # the loops in two processes
    assert {r["baseline_m"] for r in rows} == {0.0, 0.12} and {r["latency_ms"] for r in rows} == {5.0, 10.0, 20.0}
    # each row the mean of its own run's scenes, whatever process ran them
    last = default_runs(0.12)[-1]
    here = [twin.simulate_loop(last, geometry=TwinGeometry(baseline_m=0.12), frames=2, latency_ms=20.0, seed=seed)
            for seed in (1, 2)]
    assert rows[-1]["backscatter_removed"] == pytest.approx(np.mean([o["backscatter_removed"] for o in here]))
    assert rows[-1]["scene_light_kept"] == pytest.approx(np.mean([o["scene_light_kept"] for o in here]))
    low, high = (float(v) for v in rows[-1]["removed_range"].split("-"))
    assert low <= rows[-1]["backscatter_removed"] <= high  # the mean of the two scenes lies in their range
    assert any(r["run"] == "full light" and r["backscatter_removed"] == 0 for r in rows)
    assert any(r["run"] == "default, range, flash, predict" for r in rows if r["baseline_m"] == 0.12)


def test_scoreboard_long_table(monkeypatch):
    import dataclasses

    import antiscatter.twin as twin
    from antiscatter.evaluate.report import LONG_RUNS, _long_rows

    real, seen = twin.simulate_loop, []

    def small(run, **kw):
        g = kw["geometry"]
        seen.append((run.mapping, run.strategy, run.predict, g.baseline_m, kw["latency_ms"], kw["frames"],
                     kw["seed"], g.camera_phase, g.camera_lock, g.display_lag_s))
        return real(run, **{**kw, "geometry": dataclasses.replace(kw["geometry"], camera_size=(160, 120))})

    monkeypatch.setattr(twin, "simulate_loop", small)
    rows = _long_rows(3, lambda s: None, seeds=2, workers=1)
    assert [(r["baseline_m"], r["latency_ms"]) for r in rows] == [(b, lat) for b, lat, *_ in LONG_RUNS]
    dim, pulse = "default, calibrated, dim, predict", "default, calibrated, pulse, predict"
    assert [r["run"] for r in rows] == [dim, pulse, dim, pulse, pulse, dim, pulse, pulse, pulse] + [
        "default, probe, dim, predict", "default, probe, pulse, predict", "default, probe, pulse, predict",
        "default, probe, pulse", "default, probe, pulse, predict"]
    assert [r["camera"] for r in rows] == (["locked"] * 2 + ["free"] * 2 + ["as run", "locked"] + ["as run"] * 3
                                           + ["locked"] * 2 + ["as run"] + ["locked"] * 2)
    assert [r["display_lag_ms"] for r in rows] == pytest.approx([0] * 5 + [1000 / 120] * 2 + [12, 14] + [0] * 2
                                                                + [1000 / 120] + [0] * 2)
    # the free-running camera's scenes each at its own phase of the refresh, the locked ones at none;
    # run's locked loop and the lag where the table says
    assert [s[7] for s in seen[4:8]] == [0.0, 0.25, 0.0, 0.25] and {s[7] for s in seen[8:]} == {None}
    assert [s[8] for s in seen[::2]] == [r["camera"] == "as run" for r in rows]
    assert [s[9] for s in seen[::2]] == pytest.approx([r["display_lag_ms"] / 1e3 for r in rows])
    # every loop run as long as asked, over each of the scenes, and each row the mean of its own two
    assert {s[5] for s in seen} == {3} and [s[6] for s in seen] == [1, 2] * len(LONG_RUNS)
    assert seen[-1][:5] == ("probe", "pulse", True, 0.12, 20.0)
    here = [small(twin.TwinRun("contrast", "probe", "pulse", True), geometry=TwinGeometry(baseline_m=0.12),
                  frames=3, latency_ms=20.0, seed=seed) for seed in (1, 2)]
    assert rows[-1]["backscatter_removed"] == pytest.approx(np.mean([o["backscatter_removed"] for o in here]))


def test_scoreboard_lens_table(monkeypatch):
    import dataclasses

    import antiscatter.twin as twin
    from antiscatter.evaluate.report import _lens_rows

    real, seen = twin.simulate_loop, []

    def small(run, **kw):
        seen.append((kw["geometry"].baseline_m, kw["geometry"].projector_aperture_m, kw["geometry"].projector_focus_m))
        return real(run, **{**kw, "geometry": dataclasses.replace(kw["geometry"], camera_size=(160, 120))})

    monkeypatch.setattr(twin, "simulate_loop", small)
    rows = _lens_rows(2, lambda s: None, seeds=1, workers=1)
    lenses = [("pinhole", 0)] + [(f"6 mm, focused at {f} m", grow) for grow in (0, 0.6) for f in (3, 1, 0.5)]
    assert [(r["baseline_m"], r["lens"], r["grow"]) for r in rows] == [(b, *lens) for b in (0.0, 0.12)
                                                                       for lens in lenses]
    assert [r["run"] for r in rows[:7]] == ["default, calibrated, pulse, predict"] * 7
    assert rows[-1]["run"] == "default, probe, pulse, predict"
    assert seen[1] == (0.0, 0.006, 3.0) and seen[-1] == (0.12, 0.006, 0.5)  # each loop under its own lens


def test_a_shorter_exposure_gathers_less_light_and_fast_projectors_run(cli, monkeypatch):
    gathered = {}
    for exposure, hz in ((0.004, 120.0), (0.001, 960.0)):
        scene = one_static_particle()
        real = scene.render
        seen = []
        monkeypatch.setattr(scene, "render", lambda labels=None, *, light=None, real=real, seen=seen:
                            (seen.append(light[0].max()), real(labels, light=light))[1])
        simulate_loop(TwinRun("contrast", "calibrated", "flash", flash_level=1.0), scene=scene, frames=3,
                      geometry=TwinGeometry(camera_size=SIZE, baseline_m=0.0, projector_hz=hz, exposure_s=exposure))
        gathered[exposure] = seen[0]
    assert gathered[0.001] == pytest.approx(gathered[0.004] / 4)
    result = cli("twin", "--frames", "3", "--size", "160x120", "--projector-hz", "480", "--flash-level", "1",
                 "--preset", "bubbles", "--json")
    assert result.code == 0, result.err
    assert all(0 <= r["backscatter_removed"] <= 1 for r in json.loads(result.out)["runs"])
    bad = cli("twin", "--flash-level", "2")
    assert bad.code == 2 and "--flash-level 2.0: allowed 0..1" in bad.err


@pytest.mark.parametrize("strategy, share", [("dim", 1.0), ("pulse", 0.5)])
def test_adaptive_holes_leave_a_bright_particle_only_the_light_it_needs_to_stay_found(strategy, share):
    # tracked (prediction on), the 4 mm bubble 0.6 m away comes back far brighter than the detector
    # needs even at a tenth of the lamp: its hole is turned down to the least level and it stays
    # found every frame (its track never misses)
    runs = {levels: loop(strategy, dim_level=0.2, predict=True, levels=levels, rest=0) for levels in ("fixed", "adaptive")}
    fixed, adaptive = ([f["removed"] for f in runs[lv]["series"][12:]] for lv in ("fixed", "adaptive"))
    assert fixed == pytest.approx([1 - 0.2 * share] * 12, abs=1e-6)
    # at the least level (0.02, 5 grey levels) or a grey level or two above it when the flux came
    # back under target; a miss under the hole would have doubled it (0.04 or more)
    floor = 1 - round(0.02 * 255) / 255 * share
    assert max(adaptive) == pytest.approx(floor, abs=1e-6) and min(adaptive) >= 1 - 0.03 * share
    assert runs["adaptive"]["levels"] == "adaptive" and runs["fixed"]["levels"] == "fixed"
    assert runs["adaptive"]["scene_light_kept"] == pytest.approx(runs["fixed"]["scene_light_kept"], abs=0.01)


@pytest.mark.parametrize("strategy", ["dim", "pulse"])
def test_a_found_particle_rests_in_the_dark_every_other_exposure(strategy):
    # the same bubble, its track confirmed: found under its hole, its hole is left dark through
    # the next exposure (it is not found there, and is not lost), then it is looked at again
    rested, looked = (loop(strategy, dim_level=0.2, predict=True, rest=r) for r in (1, 0))
    series = [f["removed"] for f in rested["series"][12:]]
    floor = round(0.02 * 255) / 255
    # frames dark and at the least level by turns: pulsed, in the exposure's refresh only (the
    # other refresh dark); dim, the whole frame -- one pattern a frame, as run draws it, with the
    # light each hole had when it was drawn
    assert series[::2] == pytest.approx([series[0]] * 6, abs=1e-6)
    lit = floor / 2 if strategy == "pulse" else floor
    assert sorted([series[0], series[1]]) == pytest.approx([1 - lit, 1.0], abs=1e-6)
    assert [f["removed"] for f in looked["series"][12:]] == pytest.approx([1 - floor * (0.5 if strategy == "pulse"
                                                                                         else 1)] * 12, abs=1e-6)
    assert rested["rest"] == 1 and looked["rest"] == 0


def test_projector_defocus_grows_away_from_its_focus():
    pinhole = TwinGeometry()
    assert pinhole.defocus_px(np.array([0.3, 3.0])).tolist() == [0.0, 0.0]
    lens = TwinGeometry(projector_aperture_m=0.006)  # focused at the background, 3 m
    # the cone from a 6 mm aperture through the point in focus at 3 m is 6 mm x |0.5 - 3| / 3 = 5 mm
    # across at 0.5 m, which the projector (focal 1536 px) sees as 5 mm / 0.5 m = 0.01 rad = 15.4 px
    np.testing.assert_allclose(lens.defocus_px(np.array([0.5, 3.0])), [0.5 * 1536 * 0.006 * (2 - 1 / 3), 0.0])
    near = TwinGeometry(projector_aperture_m=0.006, projector_focus_m=0.5)
    assert near.defocus_px(np.array([0.5]))[0] == 0 and near.defocus_px(np.array([3.0]))[0] > 0
    with pytest.raises(ValueError, match="projector_aperture_m: got -1"):
        TwinGeometry(projector_aperture_m=-1)


def test_a_blurred_hole_lets_light_in_at_its_edge():
    hole = np.ones((200, 300))
    cv2.circle(hole, (150, 100), 12, 0.0, -1)
    at = (np.array([150.0]), np.array([100.0]), np.array([5.0]))
    assert _mean_over_discs(hole, *at)[0] == 0.0
    assert _mean_over_discs(hole, *at, np.array([5.0]))[0] == 0.0  # 5 + 5 < 12: still all dark
    leak = _mean_over_discs(hole, *at, np.array([15.0]))[0]
    assert 0.2 < leak < 0.8  # blurred past the hole's edge: part of the lamp's light gets in
    # a straight edge through the centre stays half lit however blurred (the blur is symmetric)
    half = np.ones((200, 300))
    half[:, 150:] = 0
    for blur in (0.0, 4.0, 20.0):
        assert _mean_over_discs(half, np.array([149.5]), np.array([100.0]), np.array([3.0]),
                                np.array([blur]))[0] == pytest.approx(0.5, abs=0.07)
    from antiscatter.twin import _disc_kernel

    assert _disc_kernel(0.3) is None
    kernel = _disc_kernel(4.0)
    assert kernel.shape == (9, 9) and kernel.sum() == pytest.approx(1.0) and kernel[0, 0] == 0


@pytest.mark.parametrize("aperture_m, focus_m, leaks", [(0.03, 0.0, True), (0.03, 0.6, False)])
def test_a_defocused_projector_leaks_light_into_holes_and_focusing_on_the_particle_stops_it(
        aperture_m, focus_m, leaks):
    # the dim holes of test_dim_holes_keep_the_particle_found (0.8 removed, exactly, with a pinhole
    # projector); the particle is 0.6 m away: a 30 mm aperture focused at 3 m blurs its hole by
    # 31 projector px, more than the hole's 12 px margin (not grown) -- focused at 0.6 m, not at all
    out = simulate_loop(TwinRun("contrast", "calibrated", "dim", dim_level=0.2, margin_px=12.0, grow=0.0),
                        geometry=TwinGeometry(camera_size=SIZE, baseline_m=0.0, projector_aperture_m=aperture_m,
                                              projector_focus_m=focus_m),
                        frames=24, latency_ms=5, scene=one_static_particle())
    steady = [f["removed"] for f in out["series"][6:]]
    if leaks:
        assert max(steady) < 0.8 - 0.1
    else:
        np.testing.assert_allclose(steady, 0.8, atol=1e-6)
    assert out["scene_light_kept"] > 0.95  # the blur moves the light, it does not take it away


def test_twin_command_projector_lens(cli):
    result = cli("twin", "--frames", "3", "--size", "200x150", "--preset", "bubbles", "--json",
                 "--projector-aperture-mm", "6", "--projector-focus-m", "0.5")
    assert result.code == 0, result.err
    out = json.loads(result.out)
    assert out["projector_aperture_mm"] == 6 and out["projector_focus_m"] == 0.5
    plain = json.loads(cli("twin", "--frames", "3", "--size", "200x150", "--preset", "bubbles", "--json").out)
    assert plain["projector_aperture_mm"] == 0 and plain["projector_focus_m"] == 3.0  # the background's
    for flag in ("--projector-aperture-mm", "--projector-focus-m"):
        bad = cli("twin", flag, "-2")
        assert bad.code == 2 and f"{flag} -2.0: allowed a number >= 0" in bad.err and "Traceback" not in bad.err


def test_grown_holes_keep_a_blurred_hole_dark_and_the_run_says_so(cli):
    # the defocused hole of test_a_defocused_projector_leaks_light_into_holes...: grown, it covers
    # the particle's blurred light again (the 12 px margin gone, the growth alone must do it)
    def steady(grow):
        out = simulate_loop(TwinRun("contrast", "calibrated", "dim", dim_level=0.2, grow=grow, grow_from=0.0),
                            geometry=TwinGeometry(camera_size=SIZE, baseline_m=0.0, projector_aperture_m=0.02),
                            frames=24, latency_ms=5, scene=one_static_particle())
        return float(np.mean([f["removed"] for f in out["series"][6:]])), out

    leaky, out = steady(0.0)
    tight, grown = steady(3.0)
    assert leaky < 0.8 - 0.1 and tight == pytest.approx(0.8, abs=0.01)
    assert out["grow"] == 0.0 and grown["grow"] == 3.0 and grown["grow_from"] == 0.0
    result = cli("twin", "--frames", "3", "--size", "200x150", "--preset", "bubbles", "--json", "--grow", "0.6")
    runs = json.loads(result.out)["runs"]
    assert all(r["grow"] == 0.6 for r in runs if r["detector"]) and runs[0]["grow"] is None  # full light
    bad = cli("twin", "--grow-from", "-1")
    assert bad.code == 2 and "--grow-from -1.0: allowed a number >= 0" in bad.err


def fast_near_bubble(seed):
    """A bubble 0.35 m away crossing the view at 1.9 m/s (30 px a frame at 400 px wide: farther than
    a new track's gate) among 30 faint flakes 1-1.5 m away drifting a few cm a second."""
    far = KindConfig(count=30, size_mm=(2.0, 3.0), depth_m=(1.0, 1.5), speed=(0.02, 0.04), direction_deg=0.0,
                     spread_deg=20.0, albedo=(1, 1))
    near = KindConfig(count=1, size_mm=(1.0, 1.0), depth_m=(0.35, 0.35), speed=(1.9, 1.9), direction_deg=0.0,
                      spread_deg=0.0, albedo=(1, 1))
    config = SceneConfig(bubbles=near, snow=far, background="black", read_noise=1.0, shot_noise=0.0,
                         lamp_cone=False, defocus=0.0, exposure_s=0.0)
    return RealisticScene(config, size=SIZE, rng=np.random.default_rng(seed))


@pytest.mark.parametrize("seed", [0, 1])
def test_a_fast_near_bubble_keeps_its_track_in_the_loop(seed, monkeypatch):
    # born again in every frame, the bubble took its neighbours' flow and its hole was never where it
    # was; found again beyond the gate (Tracker's far_bright), it keeps one track in the loop.  (Its
    # hole is where it is halfway through each frame; one pattern a frame, as run draws it, cannot
    # keep a speck crossing 30 px in that time dark.)
    import antiscatter.twin as twin
    from antiscatter.config import TrackConfig

    make, geometry = twin.make_tracker, TwinGeometry(camera_size=SIZE, baseline_m=0.0)

    def run(**settings):
        scene, ids = fast_near_bubble(seed), []

        def recording(**kw):
            made = make(TrackConfig(**settings), **kw)
            update = made.update

            def update_and_record(detections, timestamp, **options):
                tracks = update(detections, timestamp, **options)
                p = scene.particles()  # the frame just seen; the bubble is the nearest particle
                near = int(np.argmin(p["Z"]))
                u, v = geometry.to_camera(p["X"][near], p["Y"][near], p["Z"][near])
                if len(detections):
                    off = np.hypot(detections.centres[:, 0] - u, detections.centres[:, 1] - v)
                    if off.min() < 3:
                        ids.append(int(tracks.detection_ids[np.argmin(off)]))
                return tracks
            made.update = update_and_record
            return made

        monkeypatch.setattr(twin, "make_tracker", recording)
        simulate_loop(TwinRun("contrast", "calibrated", "pulse", predict=True), geometry=geometry, frames=40,
                      latency_ms=5, scene=scene)
        return ids

    def longest(ids):  # the most sightings in a row on one track
        runs = [len(list(group)) for _, group in itertools.groupby(ids)]
        return max(runs, default=0)

    found, lost = run(), run(far_bright=0)
    # seen in 6-12 frames of its two or three crossings (less often once its hole is on it): held
    # by one track for 5 sightings or more, against a new one nearly every frame without the far search
    assert len(found) >= 6 and longest(found) >= 5
    assert len(lost) >= 8 and longest(lost) <= 2


def test_dim_holes_rest_two_frames_after_each_look_by_default():
    # a dim hole leaves its particle its level for the whole frame: after each look it stays dark
    # two frames (levels.DIM_REST), a pulsed one a frame
    dim, pulse = (loop(strategy, dim_level=0.2, predict=True) for strategy in ("dim", "pulse"))
    assert dim["rest"] == 2 and pulse["rest"] == 1
    floor = round(0.02 * 255) / 255
    series = [f["removed"] for f in dim["series"][12:]]
    looks = [k for k, r in enumerate(series) if r < 1 - 1e-6]
    assert len(looks) == 4 and np.diff(looks).tolist() == [3, 3, 3]  # a frame at its level in every three
    assert all(series[k] == pytest.approx(1 - floor, abs=1e-6) for k in looks)
    assert all(r == pytest.approx(1.0, abs=1e-6) for k, r in enumerate(series) if k not in looks)  # the rest dark


def test_a_free_running_camera_takes_the_first_frame_exposed_once_the_light_is_on_screen():
    from antiscatter.twin import _FreeRunning

    # 120 Hz display, 60 Hz camera, 4 ms exposures starting half a refresh into the frame, 5 ms latency
    refresh, frame = 1 / 120, 1 / 60
    free = _FreeRunning(refresh, 0.005)
    start = [k * frame + refresh / 2 for k in range(6)]
    # the light handed over at 0 is on screen from the first flip, 8.3 ms: frame 0 (4.2..8.2 ms) is skipped
    assert not free.take(start[0], start[0] + 0.004) and free.take(start[1], start[1] + 0.004)
    lands = free.processed(start[1], start[1] + 0.004)  # read at 24.8 ms: the last pattern back at 25 ms
    assert lands == pytest.approx(4 * refresh)  # ready at 29.8 ms, shown at the flip at 33.3 ms
    assert free.light_at(3 * refresh, True) is False and free.light_at(4 * refresh, False) is False
    assert free.light_at(5 * refresh, False) is True  # the next light handed over then: on a refresh later
    # frame 2 (37.5..41.5 ms) ends after the light was handed over but began before it was on screen
    assert not free.take(start[2], start[2] + 0.004) and free.take(start[3], start[3] + 0.004)
    # a camera that keeps skipping is read all the same after MAX_STALE_FRAMES
    stuck = _FreeRunning(refresh, 0.005)
    assert [stuck.take(0.0, 0.004) for _ in range(4)] == [False, False, False, True]
    # the rule run had while the camera's stamp (the exposure's end) was taken for the capture time
    old = _FreeRunning(refresh, 0.005, skip_before="handed over")
    old.processed(start[1], start[1] + 0.004)
    assert old.take(start[2], start[2] + 0.004)


def test_pulsed_holes_on_a_free_running_camera():
    # the light goes on at a flip, not with the exposure: each exposure used is the first that began
    # once it was on, so every other frame is read; the lifted light stays on from its flip until
    # that frame is read -- here two refreshes in four, so the particle still gets 0.2 / 2
    def run(**kw):
        return simulate_loop(TwinRun("contrast", "calibrated", "pulse", dim_level=0.2, margin_px=12.0),
                             geometry=TwinGeometry(camera_size=SIZE, baseline_m=0.0, camera_phase=0.5), frames=24,
                             latency_ms=5, scene=one_static_particle(), **kw)

    out = run()
    assert out["camera"] == "free" and out["camera_phase"] == 0.5 and out["frames_processed"] == 12
    assert [f["removed"] for f in out["series"][4:]] == pytest.approx([0.9] * 20, abs=1e-6)
    # taking the frame stamped after the light was handed over instead (run's rule before): every
    # other one was exposed under the dark holes, lost the particle, and the loop flickers
    import antiscatter.twin as twin

    real = twin._FreeRunning.__init__
    try:
        twin._FreeRunning.__init__ = lambda self, refresh, latency, **kw: real(self, refresh, latency, "handed over",
                                                                              **kw)
        flicker = run()
    finally:
        twin._FreeRunning.__init__ = real
    removed = [f["removed"] for f in flicker["series"][4:]]
    assert flicker["frames_processed"] == 24 and removed == pytest.approx([0.0, 0.9] * 10, abs=1e-6)


def test_twin_command_free_running_camera(cli):
    result = cli("twin", "--frames", "8", "--size", "200x150", "--preset", "bubbles", "--baseline-m", "0",
                 "--camera-phase", "0.25", "--json")
    assert result.code == 0, result.err
    out = json.loads(result.out)
    assert out["camera_phase"] == 0.25
    runs = [r for r in out["runs"] if r["detector"]]
    assert all(r["camera"] == "free" for r in runs)
    # pulse and flash read every other frame; the others every frame
    assert {r["frames_processed"] for r in runs if r["strategy"] in ("pulse", "flash")} == {4}
    assert {r["frames_processed"] for r in runs if r["strategy"] not in ("pulse", "flash")} == {8}
    bad = cli("twin", "--camera-phase", "1.5", "--frames", "2")
    assert bad.code == 2 and "camera_phase: got 1.5, allowed 0 <= phase < 1" in bad.err and "Traceback" not in bad.err
    # run's locked loop on a projector lagging 14 ms: every other frame for pulse and flash (a
    # refresh: every frame, the light a frame ahead; 12 ms: every frame, the light after the pattern)
    lagged = cli("twin", "--frames", "8", "--size", "200x150", "--preset", "bubbles", "--baseline-m", "0",
                 "--camera-lock", "--display-lag-ms", "14", "--json")
    assert lagged.code == 0, lagged.err
    out = json.loads(lagged.out)
    assert out["camera_lock"] and out["display_lag_ms"] == pytest.approx(14)
    runs = [r for r in out["runs"] if r["detector"]]
    assert {r["camera"] for r in runs} == {"locked, as run"}
    assert {r["frames_processed"] for r in runs if r["strategy"] in ("pulse", "flash")} == {4}
    bad = cli("twin", "--camera-lock", "--camera-phase", "0.5", "--frames", "2")
    assert bad.code == 2 and "camera_lock: the locked camera's exposures sit in the middle" in bad.err
    bad = cli("twin", "--display-lag-ms", "-1", "--frames", "2")
    assert bad.code == 2 and "--display-lag-ms -1.0: allowed a number >= 0" in bad.err


@pytest.mark.parametrize("lag, read, removed", [(0.0, 24, [0.9] * 20), (1 / 120, 24, [0.9] * 20),
                                                (0.012, 24, [0.9] * 20), (0.014, 12, [0.9, 1.0] * 10)])
def test_pulsed_holes_as_run_locks_the_camera(lag, read, removed):
    # run --camera-lock is one thread: each exposure light goes out at the flip whose light covers
    # the next exposure it can reach.  With no display lag (5 ms) that is the next exposure: the
    # locked ideal's figures exactly.  A projector that lags a refresh needs that light before the
    # frame can be processed: the last frame's goes out then, every frame is read.  One that lags
    # 12 ms needs it before the frame is read: each frame's light goes out after its pattern, for
    # the exposure after the next, and every frame is read.  At 14 ms the pattern and that light no
    # longer both fit: every other frame is read, and the lifted holes are on one refresh in four
    def run(**kw):
        return simulate_loop(TwinRun("contrast", "calibrated", "pulse", dim_level=0.2, margin_px=12.0),
                             geometry=TwinGeometry(camera_size=SIZE, baseline_m=0.0, display_lag_s=lag, **kw),
                             frames=24, latency_ms=5, scene=one_static_particle())

    out = run(camera_lock=True)
    assert out["camera"] == "locked, as run" and out["frames_processed"] == read
    assert [f["removed"] for f in out["series"][4:]] == pytest.approx(removed, abs=1e-6)
    if not lag:
        assert [f["removed"] for f in run()["series"]] == [f["removed"] for f in out["series"]]
    with pytest.raises(ValueError, match="camera_lock: the locked camera's exposures sit in the middle"):
        TwinGeometry(camera_lock=True, camera_phase=0.5)


def test_the_twins_camera_rate_and_field_of_view_are_the_scenes():
    # the twin computes each particle's light from its geometry and the detector sees the scene's
    # rendering: both must project a particle to the same pixel and move it a camera frame a step
    from antiscatter.twin import twin_scene

    geometry = TwinGeometry(camera_size=(320, 240), camera_hz=30.0, projector_hz=120.0, hfov_deg=50.0)
    scene = twin_scene(geometry, "mixed", 3)
    assert scene.config.fps == 30.0 and scene.config.hfov_deg == 50.0
    scene.render()
    truth = scene.truth()
    p = scene.particles()
    u, v = geometry.to_camera(p["X"], p["Y"], p["Z"])
    ids = list(p["ids"])
    at = [ids.index(i) for i in truth.ids]
    assert np.allclose(truth.centres, np.column_stack([u[at], v[at]]), atol=1e-6)
    later = scene.particles(ahead_s=1 / 30)
    scene.step()
    now = scene.particles()
    kept = np.isin(now["ids"], later["ids"])
    assert kept.sum() > 10
    same = [list(later["ids"]).index(i) for i in now["ids"][kept]]
    assert np.allclose(now["X"][kept], later["X"][same]) and np.allclose(now["Y"][kept], later["Y"][same])
    # the preset's own camera (63 degrees) would put them elsewhere
    default = TwinGeometry(camera_size=(320, 240))
    u63, _ = default.to_camera(p["X"], p["Y"], p["Z"])
    assert not np.allclose(truth.centres[:, 0], u63[at], atol=1.0)


@pytest.mark.parametrize("key, value, message", [
    ("camera_hz", 0.0, "camera_hz: got 0.0, allowed a number > 0"),
    ("hfov_deg", 180.0, "hfov_deg: got 180.0, allowed 0 < hfov < 180 degrees"),
    ("throw_ratio", -1.0, "throw_ratio: got -1.0, allowed a number > 0"),
    ("background_m", float("nan"), "background_m: got nan, allowed a number > 0"),
])
def test_bad_twin_geometry_is_refused(key, value, message):
    with pytest.raises(ValueError, match=message):
        TwinGeometry(**{key: value})


def test_twin_command_with_its_own_camera_and_projector(cli):
    out = cli("twin", "--frames", "6", "--size", "200x150", "--preset", "bubbles", "--baseline-m", "0",
              "--camera-hz", "40", "--hfov-deg", "50", "--throw-ratio", "1.5", "--background-m", "2.5", "--json")
    assert out.code == 0, out.err
    got = json.loads(out.out)
    assert (got["camera_hz"], got["hfov_deg"], got["throw_ratio"], got["background_m"]) == (40, 50, 1.5, 2.5)
    assert {r["frames_processed"] for r in got["runs"] if r["detector"]} == {6}
    assert all(0 <= r["backscatter_removed"] <= 1 and 0 < r["scene_light_kept"] <= 1 for r in got["runs"])
    bad = cli("twin", "--frames", "2", "--camera-hz", "50")
    assert bad.code == 2 and "projector_hz: got 120.0, allowed a whole multiple of camera_hz (50.0)" in bad.err
    assert "Traceback" not in bad.err and len(bad.err.strip().splitlines()) == 1
    bad = cli("twin", "--frames", "2", "--hfov-deg", "0")
    assert bad.code == 2 and "hfov_deg: got 0.0, allowed 0 < hfov < 180 degrees" in bad.err
