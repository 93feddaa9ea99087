"""``antiscatter analyse``: drawn particles of known number and size, through Dask, chunked and resumed."""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import time
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest

from conftest import draw_discs

pytest.importorskip("dask.distributed")
pq = pytest.importorskip("pyarrow.parquet")

from antiscatter.analyse import AnalyseRequest, VolumeModel, analyse, esd_classes, frustum_litres, metres_per_pixel
from antiscatter.analyse.inputs import plan_chunks, probe, read_chunk
from antiscatter.analyse.work import chunk_key, equivalent_diameters, load_result, measure_frame, save_result

SIZE = (160, 120)


def scene(index: int, seed: int) -> tuple[np.ndarray, list[tuple[float, float, float]]]:
    """A noisy grey frame with 2..6 separate discs of radius 3, 5 or 8 px; and the discs (x, y, r)."""
    rng = np.random.default_rng((seed, index))
    count = 2 + index % 5
    discs = [(12 + 28 * k + rng.uniform(0, 4), 25 + rng.uniform(0, 70), (3.0, 5.0, 8.0)[(k + index) % 3])
             for k in range(count)]
    image = draw_discs(SIZE, discs, background=30, value=200).astype(np.int16)
    image += rng.normal(0, 2, image.shape).round().astype(np.int16)
    return np.clip(image, 0, 255).astype(np.uint8), discs


def write_video(path: Path, frames: int, seed: int, *, gop: int = 4, fps: int = 30) -> list[list]:
    """An FFV1 video of :func:`scene` frames with a keyframe every ``gop`` frames; returns each frame's discs."""
    import av

    truth = []
    with av.open(str(path), mode="w", format="matroska") as container:
        stream = container.add_stream("ffv1", rate=Fraction(fps))
        stream.width, stream.height, stream.pix_fmt = SIZE[0], SIZE[1], "bgr0"
        stream.codec_context.gop_size = gop
        for i in range(frames):
            image, discs = scene(i, seed)
            truth.append(discs)
            for packet in stream.encode(av.VideoFrame.from_ndarray(image, format="bgr24")):
                container.mux(packet)
        for packet in stream.encode(None):
            container.mux(packet)
    return truth


@pytest.fixture(scope="module")
def videos(tmp_path_factory) -> tuple[list[Path], list[list]]:
    folder = tmp_path_factory.mktemp("videos")
    paths = [folder / "a.mkv", folder / "b.mkv"]
    truths = [write_video(paths[0], 20, 1), write_video(paths[1], 16, 2)]
    return paths, truths


@pytest.fixture(scope="module")
def client():
    from dask.distributed import Client, LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=":0") as cluster, \
            Client(cluster) as c:
        yield c


def run(paths, out: Path, client, **settings) -> dict:
    request = AnalyseRequest(tuple(str(p) for p in paths), out, progress=False, plots=False, bin_s=0.25, **settings)
    return analyse(request, client=client, log=open(os.devnull, "w"), out=open(os.devnull, "w"))


def saved(chunks: Path) -> list[Path]:
    """The chunk results saved whole (not the temporary files they are written through)."""
    return [p for p in chunks.glob("*.npz") if not p.name.startswith(".")] if chunks.is_dir() else []


def read(out: Path, name: str) -> dict:
    return pq.read_table(out / f"{name}.parquet").to_pydict()


# -- the volume model, by hand ------------------------------------------------------------------------


def test_frustum_volume_by_hand():
    # 90 x 90 degrees: the cross-section at d is 2d x 2d, so V = 4 (far^3 - near^3) / 3 m^3
    assert frustum_litres(90, 90, 0.0, 1.0) == pytest.approx(4 / 3 * 1000)
    assert frustum_litres(90, 90, 1.0, 2.0) == pytest.approx(4 * 7 / 3 * 1000)
    # 60 x 40 degrees, 0.5 .. 1.5 m: 4 tan(30) tan(20) (3.375 - 0.125) / 3 m^3
    assert frustum_litres(60, 40, 0.5, 1.5) == pytest.approx(4 * 0.577350 * 0.363970 * 3.25 / 3 * 1000, rel=1e-5)


def test_pixel_size_and_vertical_view_by_hand():
    assert metres_per_pixel(90, 1000, 1.0) == pytest.approx(0.002)  # 2 m across 1000 px
    model = VolumeModel(hfov_deg=90, near_m=0.5, far_m=1.5)  # reference: the middle, 1 m
    assert model.mm_per_pixel(1000) == pytest.approx(2.0)
    assert model.vfov_for(800, 600) == pytest.approx(math.degrees(2 * math.atan(0.75)))  # 73.74 degrees
    assert model.litres(800, 800) == pytest.approx(frustum_litres(90, 90, 0.5, 1.5))
    assert VolumeModel(hfov_deg=90, near_m=0.5, far_m=1.5, reference_m=2.0).mm_per_pixel(1000) == pytest.approx(4.0)


def test_uvp_classes():
    bounds = esd_classes(1.0, 2.0)  # the UVP grid 0.001 mm * 2^(k/3): 0.813, 1.02, 1.29, 1.63, 2.05 mm
    np.testing.assert_allclose(bounds, 0.001 * 2 ** (np.arange(29, 34) / 3))
    assert bounds[0] <= 1.0 and bounds[-1] >= 2.0
    np.testing.assert_allclose(bounds[1:] / bounds[:-1], 2 ** (1 / 3))


@pytest.mark.parametrize("kwargs, message", [
    ({"hfov_deg": 0}, "hfov_deg: got 0, allowed 0 < hfov_deg < 180"),
    ({"near_m": 2.0, "far_m": 1.0}, "near_m, far_m: got 2.0, 1.0, allowed 0 <= near_m < far_m"),
    ({"reference_m": -1.0}, "reference_m: got -1.0, allowed >= 0 (0 = the range's middle)"),
])
def test_volume_model_bad_values(kwargs, message):
    with pytest.raises(ValueError) as info:
        VolumeModel(**kwargs)
    assert str(info.value) == message


def test_equivalent_diameters_of_drawn_discs():
    discs = [(30.3, 40.7, 3.0), (80.0, 60.0, 6.0), (130.5, 30.2, 10.0)]
    grey = draw_discs(SIZE, discs, background=30, value=200)[..., 0]
    found = equivalent_diameters(grey, np.array([d[:2] for d in discs]), np.array([d[2] + 2 for d in discs]))
    drawn = [2 * math.sqrt(np.count_nonzero(draw_discs(SIZE, [d])[..., 0]) / math.pi) for d in discs]
    np.testing.assert_allclose(found, drawn, rtol=0.01)  # the drawn footprint's equivalent diameter
    np.testing.assert_allclose(found, [2 * d[2] for d in discs], atol=1.0)  # (OpenCV draws r + 0.5)


def test_brightness_and_background_of_a_frame():
    image = np.full((120, 160), 30, np.uint8)
    image[50:60, 50:60] = 200  # a particle lifts the mean, not the background
    brightness, background = measure_frame(image)
    assert brightness == pytest.approx(30 + 100 * 170 / (120 * 160))
    assert background == 30.0
    assert measure_frame(np.dstack([image] * 3)) == (brightness, background)


# -- chunks, Dask, resuming ---------------------------------------------------------------------------


def test_chunks_start_at_keyframes_and_decode_alone(videos):
    source = probe(videos[0][0], fps=60)
    assert source.frames == 20 and source.keyframes.tolist() == [0, 4, 8, 12, 16]
    np.testing.assert_allclose(source.times_s, np.arange(20) / 30, atol=1e-3)
    chunks = plan_chunks(source, 6)
    assert [(c.start, c.stop) for c in chunks] == [(0, 8), (8, 12), (12, 20)]
    whole = dict(read_chunk(plan_chunks(source, 100)[0]))
    for chunk in chunks:
        for index, image in read_chunk(chunk):
            np.testing.assert_array_equal(image, whole[index])


def test_local_cluster_counts_every_particle(videos, client, tmp_path):
    paths, truths = videos
    result = run(paths, tmp_path / "out", client, chunk_frames=6)
    assert result["exit_code"] == 0
    frames = read(tmp_path / "out", "frames")
    expected = [len(d) for truth in truths for d in truth]
    assert frames["particles"] == expected
    assert frames["file"] == [str(paths[0])] * 20 + [str(paths[1])] * 16
    np.testing.assert_allclose(frames["background"], 30, atol=0.5)  # the drawn background, noise averaged
    np.testing.assert_allclose(frames["turbidity_index"], np.asarray(frames["background"]) / 255)
    particles = read(tmp_path / "out", "particles")
    drawn = np.sort([2 * math.sqrt(np.count_nonzero(draw_discs(SIZE, [disc])[..., 0]) / math.pi)
                     for truth in truths for discs in truth for disc in discs])  # each footprint's ESD, px
    np.testing.assert_allclose(np.sort(particles["diameter_px"]), drawn, rtol=0.03)
    rows = {r["file"]: r for r in result["rows"]}
    model = VolumeModel()
    assert rows["ALL"]["particles"] == sum(expected)
    assert rows["ALL"]["per_litre"] == pytest.approx(sum(expected) / (36 * model.litres(*SIZE)))
    assert rows[str(paths[0])]["per_second"] == pytest.approx(sum(expected[:20]) / (20 / 30), rel=0.01)
    bins = read(tmp_path / "out", "bins")
    whole = [i for i, f in enumerate(bins["file"]) if f == str(paths[0])]
    assert sum(bins["frames"][i] for i in whole) == 20 and len(whole) == 3  # 0.25 s bins of 30 fps
    spectra = read(tmp_path / "out", "spectra")
    total = sum(c for f, b, c in zip(spectra["file"], spectra["bin"], spectra["count"]) if f == "ALL" and b == -1)
    assert total == sum(expected)
    assert (tmp_path / "out" / "summary.csv").read_text().splitlines()[0].startswith("file,status,reason,frames")


def test_a_frame_folder_is_timed_by_fps_and_chunked_anywhere(client, tmp_path):
    import cv2

    folder = tmp_path / "frames"
    folder.mkdir()
    for i in range(9):
        cv2.imwrite(str(folder / f"{i}.png"), scene(i, 5)[0])
    result = run([folder], tmp_path / "out", client, chunk_frames=4, fps=12.0)
    assert result["exit_code"] == 0
    frames = read(tmp_path / "out", "frames")
    assert frames["particles"] == [2 + i % 5 for i in range(9)]
    np.testing.assert_allclose(frames["time_s"], np.arange(9) / 12.0)
    assert len(saved(tmp_path / "out" / "chunks")) == 3  # 0-3, 4-7, 8: every frame of a folder is a keyframe
    row = next(r for r in result["rows"] if r["file"] == str(folder))
    assert row["per_second"] == pytest.approx(sum(frames["particles"]) / (9 / 12.0))


def test_results_do_not_depend_on_chunking_or_scheduler(videos, client, tmp_path):
    paths, _ = videos
    run(paths, tmp_path / "one", client, chunk_frames=100)  # one chunk a file
    run(paths, tmp_path / "many", client, chunk_frames=3)  # a chunk a keyframe
    assert len(saved(tmp_path / "one" / "chunks")) == 2
    assert len(saved(tmp_path / "many" / "chunks")) == 9
    from dask.distributed import Client, LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=":0") as cluster, \
            Client(cluster) as single:
        run(paths, tmp_path / "single", single, chunk_frames=5)
    for name in ("frames", "particles", "bins", "spectra"):
        one = read(tmp_path / "one", name)
        assert read(tmp_path / "many", name) == one, name
        assert read(tmp_path / "single", name) == one, name


def test_an_existing_cluster_at_its_address_gives_the_same_tables(videos, client, tmp_path, cli):
    from dask.distributed import LocalCluster

    paths, _ = videos
    run(paths, tmp_path / "here", client, chunk_frames=100)
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, protocol="tcp", host="127.0.0.1",
                      dashboard_address=":0") as cluster:
        result = cli("analyse", *map(str, paths), "--out", str(tmp_path / "there"), "--scheduler",
                     cluster.scheduler_address, "--chunk-frames", "7", "--bin-s", "0.25", "--no-progress",
                     "--no-plots")
    assert result.code == 0, result.err
    assert "local Dask cluster" not in result.err
    for name in ("frames", "particles", "bins", "spectra"):
        assert read(tmp_path / "there", name) == read(tmp_path / "here", name), name


def test_saved_chunks_are_not_computed_again(videos, client, tmp_path):
    paths, truths = videos
    out = tmp_path / "out"
    run(paths, out, client, chunk_frames=8)
    source = probe(paths[0], fps=60)
    first = plan_chunks(source, 8)[0]
    key = chunk_key(first)
    saved = load_result(out / "chunks", key)
    saved["particles"] = saved["particles"] + 1000  # a marker only a loaded result can carry
    save_result(out / "chunks", key, saved)
    (out / "chunks" / f"{chunk_key(plan_chunks(source, 8)[1])}.npz").unlink()  # this one is computed again
    run(paths, out, client, chunk_frames=8)
    counts = read(out, "frames")["particles"]
    expected = [len(d) for d in truths[0]]
    assert counts[:8] == [n + 1000 for n in expected[:8]]
    assert counts[8:20] == expected[8:20]
    assert (out / "chunks" / f"{chunk_key(plan_chunks(source, 8)[1])}.npz").is_file()


def test_killed_run_resumes_where_it_stopped(tmp_path):
    paths = [tmp_path / f"v{i}.mkv" for i in range(2)]
    for i, path in enumerate(paths):
        write_video(path, 40, 10 + i, gop=1)
    out = tmp_path / "out"
    args = [sys.executable, "-m", "antiscatter", "analyse", *map(str, paths), "--out", str(out), "--workers", "1",
            "--chunk-frames", "1", "--no-plots", "--no-progress"]
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    chunks = out / "chunks"
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and not len(saved(chunks)) >= 3:
        time.sleep(0.005)
    proc.send_signal(signal.SIGTERM)
    proc.communicate(timeout=60)
    done = len(saved(chunks))
    assert proc.returncode == 143 and 3 <= done < 80, (proc.returncode, done)
    assert not list(chunks.glob(".*"))  # no partial result left behind
    again = subprocess.run(args, capture_output=True, text=True, timeout=120)
    assert again.returncode == 0, again.stderr
    assert f"{done} already done" in again.stderr
    assert len(saved(chunks)) == 80
    assert sum(read(out, "frames")["particles"]) == sum(2 + i % 5 for i in range(40)) * 2


def test_corrupt_file_is_named_skipped_and_sets_the_exit_code(videos, tmp_path, cli):
    paths, truths = videos
    bad = tmp_path / "broken.mkv"
    bad.write_bytes(b"\x1a\x45\xdf\xa3" + b"not a video" * 50)
    listing = tmp_path / "list.txt"
    listing.write_text(f"# the survey\n{paths[1]}\nbroken.mkv\n")
    glob = str(paths[0].parent / "a*.mkv")
    result = cli("analyse", glob, f"@{listing}", "--out", str(tmp_path / "out"), "--workers", "1", "--no-progress",
                 "--bin-s", "0.5")
    assert result.code == 3, result.err
    assert f"skipped {bad}: cannot be read as a video" in result.out
    summary = (tmp_path / "out" / "summary.csv").read_text().splitlines()
    assert [line.split(",")[:2] for line in summary[1:]] == [
        [str(paths[0]), "ok"], [str(paths[1]), "ok"], [str(bad), "skipped"], ["ALL", "incomplete"]]
    assert int(summary[-1].split(",")[5]) == sum(len(d) for truth in truths for d in truth)
    assert (tmp_path / "out" / "timeseries.png").stat().st_size > 0
    assert (tmp_path / "out" / "spectrum.png").stat().st_size > 0


def test_a_video_cut_short_is_used_and_reported_damaged(client, tmp_path):
    whole = tmp_path / "whole.mkv"
    write_video(whole, 40, 7, gop=1)
    cut = tmp_path / "cut.mkv"
    cut.write_bytes(whole.read_bytes()[: whole.stat().st_size // 2])
    result = run([cut], tmp_path / "out", client, chunk_frames=100)
    assert result["exit_code"] == 3
    row = next(r for r in result["rows"] if r["file"] == str(cut))
    assert row["status"] == "damaged" and 10 < row["frames"] < 40
    assert row["reason"] == (f"ended after {row['frames']} of the 40 frames its container declares (cut short or "
                             "damaged); the frames read were used")
    assert read(tmp_path / "out", "frames")["particles"] == [2 + i % 5 for i in range(row["frames"])]


@pytest.mark.parametrize("args, message", [
    (["missing.mkv", "--out", "o"], "missing.mkv: no such file or folder"),
    (["nothing*.mkv", "--out", "o"], "nothing*.mkv: the pattern matches no file or folder"),
    (["@nolist.txt", "--out", "o"], "@nolist.txt: cannot read the list file"),
    (["{video}", "--out", "o", "--near-m", "2", "--far-m", "1"], "near_m, far_m: got 2.0, 1.0"),
    (["{video}", "--out", "o", "--workers", "-1"], "workers: got -1, allowed >= 0 (0 = one per core)"),
    (["{video}", "--out", "o", "--classes-mm", "5"], "--classes-mm 5: expected LOW:HIGH in mm"),
    (["{video}", "--out", "{video}"], "--out {video}: exists and is not a folder"),
    (["{video}", "--out", "o", "--scheduler", "nonsense"], "--scheduler nonsense: cannot reach it (missing port"),
])
def test_bad_input_is_one_line_and_exit_code_2(videos, tmp_path, cli, monkeypatch, args, message):
    monkeypatch.chdir(tmp_path)
    video = str(videos[0][0])
    result = cli("analyse", *[a.format(video=video) for a in args])
    assert result.code == 2
    assert message.format(video=video) in result.err and result.err.count("\n") == 1
    assert not (tmp_path / "o").exists()  # nothing written


def test_unknown_config_key_is_refused(videos, tmp_path, cli):
    config = tmp_path / "a.toml"
    config.write_text("[analyse]\nhfov_deg = 70\nnear = 0.2\n")
    result = cli("analyse", str(videos[0][0]), "--out", str(tmp_path / "o"), "--config", str(config))
    assert result.code == 2 and "[analyse] near: unknown key; allowed: bin_s" in result.err


def test_core_import_does_not_load_the_extras():
    code = ("import sys, antiscatter.cli, antiscatter.runtime, antiscatter.analyse, antiscatter.mcap_out; "
            "print(sorted(m for m in ('dask', 'distributed', 'pyarrow', 'mcap', 'mcap_ros2', 'tqdm') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_missing_extra_names_the_install_command(tmp_path, cli, monkeypatch):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "pyarrow" else real(name, *a))
    result = cli("analyse", str(tmp_path), "--out", str(tmp_path / "o"))
    assert result.code == 2
    assert "analyse needs pyarrow: pip install 'antiscatter[analysis]'" in result.err


def test_the_progress_bar_is_not_written_to_a_redirected_log(videos, tmp_path, client, monkeypatch):
    """With progress on (the default) and stderr not a terminal, no bar reaches the log or stderr
    (tqdm wrote it to the log before, whatever it was)."""
    import io
    import sys

    err, log = io.StringIO(), io.StringIO()
    monkeypatch.setattr(sys, "stderr", err)
    request = AnalyseRequest((str(videos[0][0]),), tmp_path / "o", progress=True, plots=False, bin_s=0.25)
    analyse(request, client=client, log=log, out=io.StringIO())
    assert "chunk" in log.getvalue()  # its notes are there
    assert "|" not in log.getvalue() and "\r" not in log.getvalue() and err.getvalue() == ""
