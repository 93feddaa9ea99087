"""``antiscatter evaluate`` and ``bench`` end to end, and their bad input."""

import json

import cv2
import numpy as np
import pytest

from antiscatter.evaluate.reference import reference_truth


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    from antiscatter.simulate.export import SimulationRequest, simulate
    out = tmp_path_factory.mktemp("sim")
    simulate(SimulationRequest(out=out, preset="seed", frames=6, seed=1, masks=True))
    return out


def _truth_rows(sim):
    return (sim / "truth.csv").read_text().splitlines()


def test_perfect_detections_score_one(sim, tmp_path, cli):
    rows = [r.split(",") for r in _truth_rows(sim)[1:]]
    lines = ["frame,x,y,radius"] + [f"{r[1]},{r[2]},{r[3]},{r[4]}" for r in rows if float(r[8]) >= 0.5]
    (tmp_path / "d.csv").write_text("\n".join(lines) + "\n")
    result = cli("evaluate", "--truth", str(sim / "truth.csv"), "--detections", str(tmp_path / "d.csv"), "--json")
    assert result.code == 0, result.err
    overall = json.loads(result.out)["overall"]
    assert overall["precision"] == 1.0 and overall["recall"] == 1.0 and overall["f1"] == 1.0
    assert overall["centre_error_mean"] < 1e-3


def test_run_detections_evaluate_against_truth_and_folder_mode_agrees(sim, tmp_path, cli):
    assert cli("run", str(sim), "--output", "none", "--detections", str(tmp_path / "d.csv")).code == 0
    a = cli("evaluate", "--truth", str(sim / "truth.csv"), "--detections", str(tmp_path / "d.csv"), "--json")
    b = cli("evaluate", str(sim), "--json", "--csv", str(tmp_path / "f.csv"))  # the same default detector
    oa, ob = json.loads(a.out)["overall"], json.loads(b.out)["overall"]
    for key in ("tp", "fp", "fn"):
        assert oa[key] == ob[key]
    assert 0 <= ob["cancellation"] <= 1 and 0 <= ob["light_kept"] <= 1
    assert len((tmp_path / "f.csv").read_text().splitlines()) == 7


def test_header_alone_detections_file_is_valid_recall_zero(sim, tmp_path, cli):
    # what run writes when it finds nothing; a zero-byte file is refused (tests/test_bad_input.py)
    (tmp_path / "empty.csv").write_text("frame,x,y,radius\n")
    result = cli("evaluate", "--truth", str(sim / "truth.csv"), "--detections", str(tmp_path / "empty.csv"), "--json")
    assert result.code == 0
    assert json.loads(result.out)["overall"]["recall"] == 0.0


@pytest.mark.parametrize("content, message", [
    ("frame,x,y\n0,1,2\n", "missing column 'radius'"),
    ("frame,x,y,radius\n0,1,2,nan\n", "row 2: radius 'nan' is not a finite number"),
    ("frame,x,y,radius\n0,1,2,3\n0,1,2,-1\n", "row 3: radius '-1' is negative"),
    ("frame,x,y,radius\n999,1,2,3\n", "row 2: frame 999 is not in"),
    ("frame,x,y,radius\nzero,1,2,3\n", "row 2: frame 'zero' is not an integer"),
])
def test_bad_detection_files(sim, tmp_path, cli, content, message):
    (tmp_path / "d.csv").write_text(content)
    result = cli("evaluate", "--truth", str(sim / "truth.csv"), "--detections", str(tmp_path / "d.csv"))
    assert result.code == 2
    assert len(result.err.strip().splitlines()) == 1
    assert message in result.err and "d.csv" in result.err


def _annotations(sim, tmp_path, *, radius=True, ids=True):
    """The simulator's counted truth rewritten as hand annotations: frame,x,y[,radius][,id]."""
    rows = [r.split(",") for r in _truth_rows(sim)[1:]]
    header = ["frame", "x", "y"] + (["radius"] if radius else []) + (["id"] if ids else [])
    lines = [",".join(header)]
    for r in rows:
        if float(r[8]) >= 0.5 and int(r[9]) > 0 and float(r[10]) >= 5:
            lines.append(",".join([r[1], r[2], r[3]] + ([r[4]] if radius else []) + ([r[0]] if ids else [])))
    path = tmp_path / "annotations.csv"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_own_annotated_frames_image_folder_and_video(sim, tmp_path, cli):
    # real footage as users bring it: frames named by a camera, or a video, with hand annotations
    import av

    frames = [cv2.imread(str(sim / f"{i}.png")) for i in range(6)]
    folder = tmp_path / "dive"
    folder.mkdir()
    for i, image in enumerate(frames):
        cv2.imwrite(str(folder / f"GX01_frame{i + 1}.tif"), image)  # lossless, natural order 1..6 -> 0..5
    video = tmp_path / "dive.mkv"
    with av.open(str(video), "w") as container:
        stream = container.add_stream("ffv1", rate=30)
        stream.width, stream.height, stream.pix_fmt = 800, 600, "bgr0"
        for image in frames:
            container.mux(stream.encode(av.VideoFrame.from_ndarray(image, format="bgr24")))
        container.mux(stream.encode())
    annotations = _annotations(sim, tmp_path)
    reference = json.loads(cli("evaluate", str(sim), "--json").out)["overall"]
    for source in (folder, video):
        result = cli("evaluate", str(source), "--truth", str(annotations), "--json")
        assert result.code == 0, result.err
        overall = json.loads(result.out)["overall"]
        # the same frames and the same counted particles: the same matches; detections of the
        # particles the simulator does not count are false alarms against annotations of the rest
        assert overall["tp"] == reference["tp"] and overall["fn"] == reference["fn"]
        assert overall["fp"] >= reference["fp"]
        assert overall["frames"] == 6
    tracked = cli("evaluate", str(video), "--truth", str(annotations), "--track", "--json")
    assert tracked.code == 0, tracked.err
    assert 0 < json.loads(tracked.out)["tracking"]["idf1"] <= 1
    limited = json.loads(cli("evaluate", str(folder), "--truth", str(annotations), "--frames", "2", "--json").out)
    assert limited["overall"]["frames"] == 2


def test_annotations_may_name_the_image_files(sim, tmp_path, cli):
    # annotation tools export per image: the frame column holds the file name
    import shutil

    folder = tmp_path / "dive"
    folder.mkdir()
    for i in range(6):
        shutil.copy(sim / f"{i}.png", folder / f"shot_{i + 1:03d}.png")
    lines = _annotations(sim, tmp_path).read_text().splitlines()
    named = [lines[0]] + [f"shot_{int(r.split(',')[0]) + 1:03d}.png," + r.split(",", 1)[1] for r in lines[1:]]
    (tmp_path / "named.csv").write_text("\n".join(named) + "\n")
    by_name = json.loads(cli("evaluate", str(folder), "--truth", str(tmp_path / "named.csv"), "--json").out)
    by_number = json.loads(cli("evaluate", str(folder), "--truth", str(_annotations(sim, tmp_path)), "--json").out)
    assert by_name["overall"] == by_number["overall"] and by_name["overall"]["tp"] > 0
    (tmp_path / "bad.csv").write_text("frame,x,y\nshot_999.png,1,2\n")
    result = cli("evaluate", str(folder), "--truth", str(tmp_path / "bad.csv"))
    assert result.code == 2 and "row 2: frame 'shot_999.png' is neither a frame number nor the name" in result.err


def test_point_annotations_match_within_min_gate(sim, tmp_path, cli):
    points = _annotations(sim, tmp_path, radius=False, ids=False)
    wide = json.loads(cli("evaluate", str(sim), "--truth", str(points), "--min-gate", "4", "--json").out)
    tight = json.loads(cli("evaluate", str(sim), "--truth", str(points), "--min-gate", "0.5", "--json").out)
    reference = json.loads(cli("evaluate", str(sim), "--json").out)["overall"]  # radii known
    assert wide["overall"]["tp"] >= 0.9 * reference["tp"] > 0
    assert tight["overall"]["tp"] < 0.5 * wide["overall"]["tp"]
    result = cli("evaluate", str(sim), "--truth", str(points), "--track")
    assert result.code == 2 and "tracking figures need particle ids" in result.err
    named = _annotations(sim, tmp_path)
    named.write_text(named.read_text().replace(",id\n", ",track_id\n", 1))  # as run --detections names it
    result = cli("evaluate", str(sim), "--truth", str(named), "--track", "--json")
    assert result.code == 0 and json.loads(result.out)["tracking"]["idf1"] > 0


def _mot(annotations):
    """Plain annotations frame,x,y,radius,id rewritten as MOTChallenge lines (frames from 1, boxes)."""
    lines = []
    for row in annotations.read_text().splitlines()[1:]:
        frame, x, y, r, ident = (float(v) for v in row.split(","))
        lines.append(f"{int(frame) + 1},{int(ident)},{x - r!r},{y - r!r},{2 * r!r},{2 * r!r},1,1,1.0")
    return lines


def test_motchallenge_files_score_as_the_plain_annotations(sim, tmp_path, cli):
    # ground truth from annotation tools (CVAT's "MOT 1.1" export) and other trackers' results
    annotations = _annotations(sim, tmp_path)
    lines = _mot(annotations)
    # boxes to ignore (the considered flag 0, or hardly visible) are neither to be found nor false alarms
    lines += ["2,900,5,5,4,4,0,1,1.0", "3,901,700,20,6,6,1,1,0.1"]
    (tmp_path / "gt.txt").write_text("\n".join(lines) + "\n")
    plain = json.loads(cli("evaluate", str(sim), "--truth", str(annotations), "--track", "--json").out)
    result = cli("evaluate", str(sim), "--truth", str(tmp_path / "gt.txt"), "--track", "--json")
    assert result.code == 0, result.err
    mot = json.loads(result.out)
    assert mot["overall"]["tp"] == plain["overall"]["tp"] > 0
    assert mot["overall"]["fn"] == plain["overall"]["fn"] and mot["overall"]["fp"] == plain["overall"]["fp"]
    assert mot["tracking"]["idf1"] == plain["tracking"]["idf1"]
    # results of another tracker, MOTChallenge lines scored against the simulator's truth
    assert cli("run", str(sim), "--output", "none", "--detections", str(tmp_path / "d.csv")).code == 0
    rows = [r.split(",") for r in (tmp_path / "d.csv").read_text().splitlines()]
    index = {name: i for i, name in enumerate(rows[0])}
    results = [f"{int(r[index['frame']]) + 1},-1,{float(r[index['x']]) - float(r[index['radius']])!r},"
               f"{float(r[index['y']]) - float(r[index['radius']])!r},{2 * float(r[index['radius']])!r},"
               f"{2 * float(r[index['radius']])!r},0.9,-1,-1,-1" for r in rows[1:]]
    (tmp_path / "results.txt").write_text("\n".join(results) + "\n")
    a = json.loads(cli("evaluate", "--truth", str(sim / "truth.csv"), "--detections", str(tmp_path / "d.csv"),
                       "--json").out)["overall"]
    b = cli("evaluate", "--truth", str(sim / "truth.csv"), "--detections", str(tmp_path / "results.txt"), "--json")
    assert b.code == 0, b.err
    assert {k: json.loads(b.out)["overall"][k] for k in ("tp", "fp", "fn")} == {k: a[k] for k in ("tp", "fp", "fn")}


@pytest.mark.parametrize("content, message", [
    ("frame,x\n0,1\n", "missing column 'Frame #'"),
    ("frame,x,y\n0,1,oops\n", "row 2: y 'oops' is not a number"),
    ("frame,x,y\n-1,1,2\n", "row 2: frame -1 is negative"),
    ("frame,x,y,radius\n0,1,2,-3\n", "row 2: radius '-3' is negative"),
    ("frame,x,y\n6,1,2\n", "frame 6 is beyond the last frame of"),
    ("", "empty; expected the header frame,x,y"),
    # MOTChallenge lines (no header)
    ("0,1,10,10,4,4\n", "row 1: frame 0: MOTChallenge frames are numbered from 1"),
    ("1,1.5,10,10,4,4\n", "row 1: id '1.5' is not an integer"),
    ("1,1,10,10,-4,4\n", "row 1: bb_width and bb_height must be >= 0"),
    ("1,1,10,10,4,4\n2,1,10,10,4\n", "row 2: has 5 fields; a MOTChallenge line has at least 6"),
    ("1,1,10,10,4,4\n2,1,10,10,4,oops\n", "row 2: bb_height 'oops' is not a number"),
    ("7,1,10,10,4,4\n", "frame 6 is beyond the last frame of"),
])
def test_bad_annotation_files(sim, tmp_path, cli, content, message):
    (tmp_path / "a.csv").write_text(content)
    result = cli("evaluate", str(sim), "--truth", str(tmp_path / "a.csv"))
    assert result.code == 2, result.err
    assert len(result.err.strip().splitlines()) == 1
    assert message in result.err and "a.csv" in result.err


def test_a_source_without_truth(tmp_path, cli):
    (tmp_path / "0.png").write_bytes(b"")
    result = cli("evaluate", str(tmp_path))
    assert result.code == 2 and "no truth.csv" in result.err and "--truth" in result.err
    result = cli("evaluate", str(tmp_path / "nothing.mkv"), "--truth", str(tmp_path / "a.csv"))
    assert result.code == 2 and "no such folder or video file" in result.err


def test_masks_of_the_wrong_size(sim, tmp_path, cli):
    import shutil
    copy = tmp_path / "copy"
    shutil.copytree(sim, copy)
    cv2.imwrite(str(copy / "masks" / "0.png"), np.zeros((10, 10), np.uint16))
    result = cli("evaluate", str(copy), "--detector", "seed")
    assert result.code == 2 and "mask is 10x10, frame is 800x600" in result.err


def test_inputs_must_be_one(cli, sim):
    result = cli("evaluate")
    assert result.code == 2 and "give exactly one input" in result.err
    result = cli("evaluate", str(sim), "--scenario", "seed")
    assert result.code == 2


def test_reference_truth_from_a_clean_pair():
    clean = np.full((60, 80, 3), 90, np.uint8)
    degraded = clean.copy()
    cv2.circle(degraded, (20, 30), 4, (200, 200, 200), -1)
    cv2.circle(degraded, (60, 15), 2, (180, 180, 180), -1)
    degraded[50, 70] = 255  # a 1-pixel speck: below min_area, ignored
    centres, radii, particle, small = reference_truth(degraded, clean, rise=20, min_area=3)
    order = np.argsort(centres[:, 0])
    np.testing.assert_allclose(centres[order], [[20, 30], [60, 15]], atol=0.01)
    assert radii[order][0] == pytest.approx(np.sqrt((degraded[..., 0] > 150)[:, :40].sum() / np.pi))
    assert small[50, 70] and not particle[50, 70]


def test_real_pair_cli(tmp_path, cli):
    clean = np.full((60, 80, 3), 40, np.uint8)
    degraded = clean.copy()
    cv2.circle(degraded, (20, 30), 5, (255, 255, 255), -1)
    cv2.imwrite(str(tmp_path / "c.png"), clean)
    cv2.imwrite(str(tmp_path / "d.png"), degraded)
    result = cli("evaluate", "--degraded", str(tmp_path / "d.png"), "--clean", str(tmp_path / "c.png"),
                 "--detector", "seed", "--json")
    assert result.code == 0, result.err
    overall = json.loads(result.out)["overall"]
    assert overall["tp"] == 1 and overall["fp"] == 0 and overall["cancellation"] > 0.9


@pytest.mark.parametrize("detector", ["seed", "contrast"])
def test_plot_written(sim, tmp_path, cli, detector):
    # the contrast sweep moves k_expected with k (it must stay at or below k)
    result = cli("evaluate", str(sim), "--detector", detector, "--frames", "3", "--plot", str(tmp_path / "p.png"))
    assert result.code == 0, result.err
    image = cv2.imread(str(tmp_path / "p.png"))
    assert image is not None and image.shape[1] > 800


def test_bench_json_has_every_stage_for_every_detector(cli, tmp_path):
    from antiscatter.detection import DETECTORS, make_detector
    result = cli("bench", "--frames", "5", "--sizes", "320x240,640x480", "--json", "--plot", str(tmp_path / "b.png"))
    assert result.code == 0, result.err
    data = json.loads(result.out)
    assert data["opencv_threads"] == 1 and len(data["sizes"]) == 2
    for entry in data["sizes"]:
        assert entry["copy_floor_us"]["median_us"] > 0
        assert entry["chain_floor_us"]["median_us"] > 0 and entry["chain_speedup_vs_seed"] > 0
        for name in DETECTORS:
            d = entry["detectors"][name]
            assert set(d["stages"]) == {s.name for s in make_detector(name).stages}
            for stage in d["stages"].values():
                assert {"mean_us", "sd_us", "median_us", "p99_us", "max_us"} <= set(stage)
            assert d["total"]["median_us"] > 0
            assert d["x_chain"] == pytest.approx(d["total"]["median_us"] / entry["chain_floor_us"]["median_us"])
        assert entry["detectors"]["seed"]["speedup_vs_seed"] == pytest.approx(1.0)
    assert cv2.imread(str(tmp_path / "b.png")) is not None
    assert data["input"] == "bgr"


def test_bench_plays_its_frames_forwards_and_back_so_nothing_jumps():
    # cycled, every particle jumped back at once each pool's length, and the contrast detector
    # took that for the view turning (a still view then followed every frame)
    from antiscatter.bench import pool_index
    order = [pool_index(k, 5) for k in range(30)]
    assert order[:10] == [0, 1, 2, 3, 4, 3, 2, 1, 0, 1]
    assert all(abs(a - b) == 1 for a, b in zip(order, order[1:]))
    assert [pool_index(k, 1) for k in range(3)] == [0, 0, 0]


def test_bench_on_the_luma_plane(cli):
    result = cli("bench", "--frames", "3", "--sizes", "640x480", "--input", "y", "--json")
    assert result.code == 0, result.err
    data = json.loads(result.out)
    assert data["input"] == "y"
    counts = {name: d["particles_per_frame"] for name, d in data["sizes"][0]["detectors"].items()}
    assert counts["contrast"] > 0 and counts["seed"] >= 0
    bad = cli("bench", "--input", "rgb")
    assert bad.code == 2 and "--input" in bad.err


def test_scoreboard_end_to_end_on_a_tiny_catalogue(tmp_path, cli):
    catalogue = tmp_path / "c.toml"
    catalogue.write_text('version = 3\n[scenario.tiny]\npreset = "seed"\nsize = "200x150"\nframes = 3\nseed = 2\n'
                         '[scenario.tinybubbles]\npreset = "bubbles"\nsize = "200x150"\nframes = 2\nseed = 2\n')
    data = tmp_path / "data" / "msrb"
    data.mkdir(parents=True)
    clean = np.full((40, 40, 3), 50, np.uint8)
    degraded = clean.copy()
    cv2.circle(degraded, (20, 20), 4, (255, 255, 255), -1)
    cv2.imwrite(str(data / "x_orig.png"), clean)
    cv2.imwrite(str(data / "x_task1.png"), degraded)
    report = tmp_path / "score.md"
    result = cli("evaluate", "--catalogue", "--catalogue-file", str(catalogue), "--data", str(tmp_path / "data"),
                 "--report", str(report), "--bench-frames", "3", "--twin-frames", "0")
    assert result.code == 0, result.err
    text = report.read_text()
    assert "catalogue version 3" in text
    assert "| tiny | seed |" in text and "| tinybubbles | seed |" in text and "| real: x_task1 | seed |" in text
    assert "## Latency" in text
    latency = text.split("## Latency")[1].split("## Tracking")[0]
    for size in ("800x600", "1456x1088"):  # BGR frames and the Pi camera's luma plane, each detector
        for kind in ("bgr", "y"):
            assert f"| {size} | {kind} | seed |" in latency and f"| {size} | {kind} | contrast |" in latency
    assert "## Tracking" in text and "| tinybubbles |" in text.split("## Tracking")[1]
    assert "| pred. err +1 (px) | pred. err +2 (px) | pred. err +3 (px) |" in text
    assert "## Closed loop" not in text
    bad = cli("evaluate", "--catalogue", "--catalogue-file", str(catalogue), "--data", str(tmp_path / "data"),
              "--report", str(report), "--bench-frames", "0", "--twin-seeds", "0")
    assert bad.code == 2 and "--twin-seeds 0: allowed >= 1" in bad.err
    for flag, value, message in (("--twin-long-frames", "-1", "--twin-long-frames -1: allowed >= 0"),
                                 ("--twin-long-seeds", "0", "--twin-long-seeds 0: allowed >= 1")):
        bad = cli("evaluate", "--catalogue", "--catalogue-file", str(catalogue), "--data", str(tmp_path / "data"),
                  "--report", str(report), "--bench-frames", "0", flag, value)
        assert bad.code == 2 and message in bad.err


@pytest.mark.parametrize("args, message", [
    (["--margin", "nan"], "--margin: got nan, allowed a number >= 0"),  # it scored every hole's light as kept
    (["--min-gate", "nan"], "--min-gate: got nan, allowed a number >= 0"),
    (["--min-snr", "nan"], "--min-snr: got nan, allowed a number >= 0"),
    (["--min-visibility", "2"], "--min-visibility: got 2.0, allowed 0..1"),
    (["--rise", "nan"], "--rise nan: allowed a number of grey levels >= 0"),
    (["--min-area", "0"], "--min-area 0: allowed >= 1 pixel"),
])
def test_matching_settings_that_are_not_numbers_in_range_are_refused(cli, args, message):
    result = cli("evaluate", "--scenario", "bubbles", "--frames", "1", *args)
    assert result.code == 2 and message in result.err and len(result.err.strip().splitlines()) == 1
