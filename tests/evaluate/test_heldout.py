"""The held-out material: deterministic, split, truthful, and scored from files as in memory."""

import json
import sys

import numpy as np
import pytest

pytest.importorskip("skimage")

from antiscatter.detection import make_detector  # noqa: E402
from antiscatter.evaluate.heldout import (BACKGROUNDS, MODELS, Case, _Particle, _render, _Sensor,  # noqa: E402
                                          _View, cases, evaluate_case, export_case, light_truth, local_spread,
                                          particle_shape, render_particle, render_still)
from antiscatter.evaluate.metrics import score_frame  # noqa: E402
from antiscatter.evaluate.report import format_heldout, heldout_markdown  # noqa: E402
from antiscatter.evaluate.runs import Matching  # noqa: E402

SMALL = (192, 144)


def _same(a, b):
    (i, image_a, truth_a), (j, image_b, truth_b) = a, b
    assert i == j
    np.testing.assert_array_equal(image_a, image_b)
    for name in ("centres", "radii", "counted", "ids"):
        np.testing.assert_array_equal(getattr(truth_a, name), getattr(truth_b, name))


@pytest.mark.parametrize("kind", ["stills", "pan", "cut", "lamp", "ambient", "video_still"])
def test_the_same_seed_gives_the_same_frames_and_truth(kind):
    first = list(Case("a", "test", kind, SMALL, 3, 7).frames())
    again = list(Case("b", "test", kind, SMALL, 3, 7).frames())
    assert len(first) == len(again) == 3
    for a, b in zip(first, again):
        _same(a, b)
    other = list(Case("a", "test", kind, SMALL, 3, 8).frames())
    assert not np.array_equal(first[0][1], other[0][1])


def test_shuffled_stills_are_the_same_frames_in_another_order():
    plain = [image.tobytes() for _, image, _ in Case("s", "dev", "stills", SMALL, 6, 3).frames()]
    shuffled = [image.tobytes() for _, image, _ in Case("s", "dev", "stills", SMALL, 6, 3, shuffled=True).frames()]
    assert sorted(plain) == sorted(shuffled) and plain != shuffled


def test_dev_and_test_have_disjoint_backgrounds_and_seeds(tmp_path):
    assert not set(BACKGROUNDS["dev"]) & set(BACKGROUNDS["test"])
    dev, test = cases("dev"), cases("test")
    assert [c.name for c in dev] == [c.name for c in test]
    assert {"stills-1456", "stills-800", "pan-1456", "cut-800", "lamp-800", "ambient-800"} <= {c.name for c in dev}
    assert {c.size for c in dev} == {(1456, 1088), (800, 600)}
    assert not {c.seed for c in dev} & {c.seed for c in test}
    assert "msrb" not in cases("test")[0].backgrounds  # without the data folder it is left out
    (tmp_path / "msrb").mkdir()
    (tmp_path / "msrb" / "174710351_orig.png").write_bytes(b"")
    assert "msrb" in cases("test", data=tmp_path)[0].backgrounds
    for split in ("dev", "test"):
        seen = {frame.background for kind in ("stills", "ambient")
                for frame in Case("c", split, kind, SMALL, 6, 1).render()}
        assert seen and seen <= set(BACKGROUNDS[split])


def test_a_lone_gaussian_truth_centre_is_on_its_peak():
    x0, y0, patch = render_particle("spot", 20.37, 15.81, 1.3)
    x, y, radius, peak, inside = light_truth(x0, y0, 50 * patch)
    assert np.hypot(x - 20.37, y - 15.81) < 0.3
    row, col = np.unravel_index(np.argmax(patch), patch.shape)
    assert np.hypot(x - (x0 + col), y - (y0 + row)) < 0.71  # the brightest pixel's centre
    assert radius == pytest.approx(1.177 * np.hypot(1.3, 1 / np.sqrt(12)), abs=0.6)  # half-maximum extent
    assert peak == pytest.approx(50, rel=0.1) and inside == 1.0
    # cut by the frame's edge: the light seen, and its share
    x, y, radius, peak, inside = light_truth(x0, y0, 50 * patch, size=(21, 40))
    assert x < 20.37 and 0.3 < inside < 0.7


def test_truth_centres_land_on_the_rendered_light():
    checked = 0
    for frame in Case("t", "test", "stills", (640, 480), 4, 11).render():
        for (x, y), counted, model, peak in zip(frame.truth.centres, frame.truth.counted, frame.models, frame.peaks):
            if not counted or MODELS[model] in ("ring", "sunlit"):  # a ring's centre is its dim middle
                continue
            row, col = int(round(y)), int(round(x))
            near = frame.light[max(row - 1, 0):row + 2, max(col - 1, 0):col + 2]
            assert near.max() >= 0.25 * peak
            checked += 1
    assert checked > 20


def _on(grey, particles):
    """One noisy frame of ``particles`` (:class:`_Particle`) over an (H, W) grey background, sunlit (no cone)."""
    radiance = np.repeat(grey.astype(np.float32)[..., None], 3, axis=2)
    view = _View("flat", radiance, np.zeros(grey.shape, np.float32), np.zeros(3, np.float32))
    lighting = (np.ones(grey.shape, np.float32), None)
    distractors = np.zeros(grey.shape, bool)
    return _render(0, radiance, distractors, view, lighting, particles, _Sensor(2.0, 0.05, 0),
                   np.random.default_rng(0))


def test_local_spread_is_the_robust_spread_around_the_particle():
    flat = np.full((100, 120), 80.0, np.float32)
    assert local_spread(flat, 60, 50, 3.0) == 0.0
    noise = 80 + 10 * np.random.default_rng(1).standard_normal((100, 120)).astype(np.float32)
    assert local_spread(noise, 60, 50, 5.0) == pytest.approx(10, rel=0.15)  # 21 x 21 px: h = 2 x radius
    # the window: a bright block 6 px from the centre is outside it for a small particle (at least 9 x 9
    # px), inside it for a large one, where it covers under half the window and a robust spread ignores it
    blocked = noise.copy()
    blocked[:, 66:] = 250
    assert local_spread(blocked, 60, 50, 1.0) == pytest.approx(local_spread(noise, 60, 50, 1.0))
    assert local_spread(blocked, 60, 50, 10.0) < 30 < float(blocked[30:71, 40:81].std())
    # cut by the frame's edges; outside it
    assert local_spread(noise, 0, 0, 5.0) == pytest.approx(10, rel=0.3)
    assert local_spread(noise, -50, -50, 5.0) == 0.0


def test_a_particle_is_counted_against_its_surroundings():
    spot = _Particle(1, MODELS.index("spot"), 60.0, 50.0, 0.0, 0.0, 1.5, 20.0, 1.0, {})
    flat = _on(np.full((100, 120), 80.0), [spot])
    assert flat.truth.counted.tolist() == [True] and flat.peaks[0] == pytest.approx(20, rel=0.02)
    assert flat.clutter[0] == 0.0
    assert flat.thresholds[0] == pytest.approx(4 * np.sqrt(2.0 ** 2 + 0.05 * 80))  # the noise, 11.3
    # the same particle on a texture of spread 30: as bright, not counted
    texture = np.clip(80 + 30 * np.random.default_rng(2).standard_normal((100, 120)), 0, 255)
    busy = _on(texture, [spot])
    assert busy.peaks[0] == pytest.approx(flat.peaks[0], abs=1e-4)
    assert busy.clutter[0] == pytest.approx(local_spread(texture.astype(np.float32), 60, 50, busy.truth.radii[0]))
    assert busy.clutter[0] == pytest.approx(30, rel=0.15)
    assert busy.thresholds[0] == busy.clutter[0] and busy.truth.counted.tolist() == [False]
    np.testing.assert_array_equal(busy.truth.centres, flat.truth.centres)  # still in the truth, not considered
    # twice as bright, it stands out of the same texture
    bright = _Particle(1, MODELS.index("spot"), 60.0, 50.0, 0.0, 0.0, 1.5, 60.0, 1.0, {})
    assert _on(texture, [bright]).truth.counted.tolist() == [True]


def test_a_sunlit_flake_is_judged_by_what_it_changes_in_the_frame():
    shape = particle_shape("sunlit", 3.0, np.random.default_rng(3))
    first = _Particle(1, MODELS.index("sunlit"), 60.0, 50.0, 0.0, 0.0, 3.0, 200.0, 0.5, shape)
    second = _Particle(2, MODELS.index("sunlit"), 60.0, 50.0, 0.0, 0.0, 3.0, 200.0, 0.5, shape)
    alone = _on(np.full((100, 120), 120.0), [first])
    assert alone.peaks.tolist() == pytest.approx([0.5 * (200 - 120)], rel=0.01)  # opacity x (flake - background)
    assert alone.truth.counted.tolist() == [True]
    # over another flake: only what it adds to the first one's light
    both = _on(np.full((100, 120), 120.0), [first, second])
    assert both.peaks.tolist() == pytest.approx([40, 0.5 * (200 - 160)], rel=0.01)
    # a whitish flake on a brighter background darkens it: no light added, not in the truth
    assert len(_on(np.full((100, 120), 230.0), [first]).truth.radii) == 0


def test_faint_particles_are_not_counted():
    peaks, thresholds, counted = [], [], []
    for frame in Case("f", "test", "lamp", (320, 240), 6, 4).render():
        peaks += frame.peaks.tolist()
        thresholds += frame.thresholds.tolist()
        counted += frame.truth.counted.tolist()
    peaks, thresholds, counted = np.array(peaks), np.array(thresholds), np.array(counted)
    assert (thresholds >= 8).all() and (frame.thresholds >= frame.clutter).all()
    assert (peaks[counted] > thresholds[counted]).all()
    assert (~counted).sum() > 5 and (peaks <= thresholds).sum() > 5  # the lamp off leaves many unseen
    assert ((peaks <= thresholds) <= ~counted).all()
    # a detection on an uncounted particle is neither found nor a false alarm
    frame = next(iter(Case("f", "test", "lamp", (320, 240), 6, 4).render()))
    t = frame.truth
    faint = ~t.counted
    assert faint.any()
    score = score_frame(0, t.centres, t.radii, t.counted, t.centres[faint], t.radii[faint])
    assert (score.tp, score.fp, score.fn) == (0, 0, int(t.counted.sum()))


def test_particles_lost_in_the_texture_are_not_counted():
    # sunlit grass, as test stills-1456 frame 2: bright, busy texture (local spread about 20-30 grey levels)
    frame = render_still(np.random.default_rng(0), (480, 360), background="grass", split="test", lighting="sun",
                         particles=100)
    counted = frame.truth.counted
    assert (frame.thresholds >= np.maximum(frame.clutter, 8)).all()
    assert (frame.peaks[counted] > frame.thresholds[counted]).all()
    lost = (frame.peaks > 20) & (frame.peaks <= frame.clutter)  # well over the noise, not over the clutter
    assert lost.sum() > 10 and not counted[lost].any()
    assert 0.3 < counted.mean() < 0.9


def test_distractors_are_never_truth():
    frame = render_still(np.random.default_rng(2), (400, 300), background="gravel", particles=0, distractors=3)
    assert len(frame.truth.radii) == 0
    assert frame.distractors.sum() > 60 * 60
    grey = frame.image.mean(axis=2)
    assert grey[frame.distractors].mean() > grey[~frame.distractors].mean()
    frame = render_still(np.random.default_rng(3), (400, 300), background="brick", particles=30, distractors=2)
    assert len(frame.truth.radii) <= 30 and set(frame.truth.ids.tolist()) <= set(range(1, 31))
    assert frame.truth.radii.max() < 40 * 400 / 1456 + 10  # the widest particle, a defocused disc, and its edge


def test_export_scores_as_in_memory(tmp_path, cli):
    case = Case("pan-small", "test", "pan", (320, 240), 4, 5)
    memory = evaluate_case(case, {"contrast": make_detector("contrast")}, Matching())["detectors"]["contrast"]
    folder = export_case(case, tmp_path / "pan-small")
    assert sorted(p.name for p in folder.iterdir()) == ["0.png", "1.png", "2.png", "3.png", "case.json", "gt.txt",
                                                        "truth.csv"]
    truths = [truth for _, _, truth in case.frames()]
    flags = [line.split(",")[6] for line in (folder / "gt.txt").read_text().splitlines()]
    assert flags.count("1") == sum(int(t.counted.sum()) for t in truths) == memory["tp"] + memory["fn"]
    assert flags.count("0") == sum(int((~t.counted).sum()) for t in truths) > 0  # kept, not considered
    assert len((folder / "truth.csv").read_text().splitlines()) == 1 + flags.count("1")
    result = cli("evaluate", str(folder), "--truth", str(folder / "gt.txt"), "--json")
    assert result.code == 0, result.err
    overall = json.loads(result.out)["overall"]
    assert {k: overall[k] for k in ("tp", "fp", "fn")} == {k: memory[k] for k in ("tp", "fp", "fn")}
    assert overall["f1"] == pytest.approx(memory["f1"], abs=1e-12) and memory["tp"] > 0
    # truth.csv holds the counted particles alone: a detection of an uncounted one is a false alarm there
    plain = json.loads(cli("evaluate", str(folder), "--truth", str(folder / "truth.csv"), "--json").out)["overall"]
    assert plain["tp"] == memory["tp"] and plain["fn"] == memory["fn"] and plain["fp"] >= memory["fp"]
    assert cli("run", str(folder), "--output", "none", "--detections", str(tmp_path / "d.csv")).code == 0
    scored = cli("evaluate", "--truth", str(folder / "gt.txt"), "--detections", str(tmp_path / "d.csv"), "--json")
    assert scored.code == 0 and json.loads(scored.out)["overall"]["frames"] == 4
    with pytest.raises(Exception, match="already exists"):
        export_case(case, folder)


def test_heldout_cli_scores_the_detector_and_seed(cli):
    result = cli("evaluate", "--heldout", "dev", "--heldout-frames", "1", "-p", "memory=0")
    assert result.code == 0, result.err
    lines = result.out.splitlines()
    assert lines[0] == "detector contrast (memory=0) and seed"
    header = next(line for line in lines if line.startswith("case"))
    for column in ("contrast P", "contrast R", "contrast F1", "seed P", "seed R", "seed F1", "worst/median"):
        assert column in header
    assert any(line.startswith("stills-1456 ") for line in lines)
    assert any(line.startswith("all ") for line in lines)


def test_heldout_cli_json_and_export(cli, tmp_path):
    result = cli("evaluate", "--heldout", "test", "--heldout-frames", "1", "--detector", "seed", "--json",
                 "--data", str(tmp_path))
    assert result.code == 0, result.err
    data = json.loads(result.out)
    (split,) = data["splits"]
    assert split["split"] == "test" and len(split["cases"]) == 9 and list(split["overall"]) == ["seed"]
    assert "msrb" not in split["backgrounds"]
    assert len(split["cases"][0]["detectors"]["seed"]["frame_ms"]) == 1
    out = tmp_path / "material"
    result = cli("evaluate", "--heldout", "dev", "--heldout-frames", "1", "--heldout-export", str(out))
    assert result.code == 0, result.err
    folders = sorted(p.name for p in (out / "dev").iterdir())
    assert len(folders) == 9 and "pan-1456" in folders
    assert (out / "dev" / "lamp-800" / "0.png").is_file()
    assert (out / "dev" / "lamp-800" / "truth.csv").read_text().startswith("frame,x,y,radius,id\n")
    again = cli("evaluate", "--heldout", "dev", "--heldout-frames", "1", "--heldout-export", str(out))
    assert again.code == 2 and "already exists" in again.err


@pytest.mark.parametrize("args, message", [
    (["--heldout", "train"], "invalid choice: 'train'"),
    (["--heldout", "dev", "--heldout-frames", "0"], "--heldout-frames 0: allowed >= 1"),
    (["--heldout", "dev", "--frames", "3"], "--frames: with --heldout, give --heldout-frames"),
    (["--heldout", "dev", "--csv", "f.csv"], "--csv: does not go with --heldout"),
    (["--heldout", "dev", "--data", "/no/such/folder"], "--data /no/such/folder: no such folder"),
    (["--heldout", "dev", "-p", "colour=1"], "unknown key detector.contrast.colour"),
    (["--scenario", "bubbles", "--heldout-export", "x"], "--heldout-export goes with --heldout"),
    (["--scenario", "bubbles", "--heldout-frames", "2"], "--heldout-frames goes with --heldout or --catalogue"),
    (["--heldout", "dev", "--scenario", "bubbles"], "give exactly one input"),
])
def test_heldout_bad_values(cli, args, message):
    result = cli("evaluate", *args)
    assert result.code == 2
    assert len(result.err.strip().splitlines()) == 1
    assert message in result.err


def test_without_scikit_image_one_line_names_the_extra(cli, monkeypatch):
    monkeypatch.setitem(sys.modules, "skimage", None)
    monkeypatch.setitem(sys.modules, "skimage.data", None)
    result = cli("evaluate", "--heldout", "dev")
    assert result.code == 2
    assert result.err.strip().splitlines() == [
        "antiscatter evaluate: error: the held-out material needs scikit-image: pip install 'antiscatter[eval]'"]
    from antiscatter.evaluate.report import _heldout_section

    md, results = _heldout_section({}, Matching(), None, None, lambda s: None)
    assert results == [] and "pip install 'antiscatter[eval]'" in md[-1]


def test_heldout_tables():
    case = Case("stills-small", "dev", "stills", SMALL, 2, 1)
    row = evaluate_case(case, {"contrast": make_detector("contrast"), "seed": make_detector("seed")}, Matching(),
                        clock=iter(range(0, 10**6, 1000)).__next__)
    assert row["detectors"]["contrast"]["frame_ms"] == [0.001, 0.001]
    result = {"split": "dev", "frames": 2, "counted": row["counted"], "backgrounds": list(case.backgrounds),
              "cases": [row], "overall": row["detectors"]}
    md = heldout_markdown([result])
    assert md[1] == "### dev (gravel, brick, moon, coffee, coins)"
    assert md[3].startswith("| case | frames | counted | contrast P | contrast R | contrast F1 | seed P |")
    assert md[5].startswith("| stills-small | 2 |") and md[6].startswith("| all | 2 |")
    text = format_heldout([result])
    assert text.splitlines()[0].startswith("held-out dev: 1 cases, 2 frames")


def test_bad_cases_are_refused():
    with pytest.raises(ValueError, match="split: got 'train', allowed dev, test"):
        cases("train")
    with pytest.raises(ValueError, match="kind: got 'zoom'"):
        Case("z", "dev", "zoom", SMALL, 2, 1)
    with pytest.raises(ValueError, match="size: got 32x32, allowed at least 64x48"):
        Case("z", "dev", "pan", (32, 32), 2, 1)
    with pytest.raises(ValueError, match="count: got 0, allowed >= 1"):
        Case("z", "dev", "pan", SMALL, 0, 1)
    with pytest.raises(ValueError, match="model: got 'star'"):
        render_particle("star", 1, 1, 1)
