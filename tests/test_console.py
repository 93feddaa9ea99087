"""What the commands show besides their results: progress bars on a terminal only, log records on
stderr with --quiet / --verbose, strict JSON; and the output slips of issue 50 part 7."""

from __future__ import annotations

import io
import json
import logging
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from antiscatter.console import LOGGER, LogStream, configure_logging, json_text, progress, progress_enabled

BAR = "\r"  # tqdm redraws its line with carriage returns; results and log lines never hold one


def _bar_drawn(text: str) -> bool:
    """A bar was drawn: a line redrawn (a carriage return not of the terminal's CR LF) with tqdm's ``|``."""
    import re

    return re.search(r"\r(?!\n)", text) is not None and "|" in text


def _command(args: list[str], cwd: Path, *, tty: bool, screen: tuple[int, int] = (100, 40)) -> tuple[int, str, str]:
    """``antiscatter ARGS`` in a subprocess, stdout a pipe, stderr a terminal (a pty of ``screen``
    columns x rows) or a pipe; returns (exit code, stdout, stderr)."""
    env = {**os.environ, "COLUMNS": "100", "LINES": "40"}
    if not tty:
        proc = subprocess.run([sys.executable, "-m", "antiscatter", *args], cwd=cwd, capture_output=True,
                              text=True, env=env, timeout=300)
        return proc.returncode, proc.stdout, proc.stderr
    import fcntl
    import struct
    import termios

    master, slave = os.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", screen[1], screen[0], 0, 0))
    proc = subprocess.Popen([sys.executable, "-m", "antiscatter", *args], cwd=cwd, stdout=subprocess.PIPE,
                            stderr=slave, env=env)
    os.close(slave)
    chunks = []
    while True:
        try:
            data = os.read(master, 65536)
        except OSError:  # EIO: the child closed its end
            break
        if not data:
            break
        chunks.append(data)
    os.close(master)
    out = proc.stdout.read().decode()
    proc.stdout.close()
    return proc.wait(timeout=300), out, b"".join(chunks).decode(errors="replace")


@pytest.fixture(scope="module")
def sim_folder(tmp_path_factory) -> Path:
    """A small simulator output folder (8 frames at 160x120, masks) to evaluate."""
    folder = tmp_path_factory.mktemp("sim") / "out"
    code, _, err = _command(["simulate", str(folder), "--frames", "8", "--size", "160x120", "--masks"],
                            folder.parent, tty=False)
    assert code == 0, err
    return folder


LONG_COMMANDS = {
    "simulate": lambda tmp, sim: ["simulate", str(tmp / "s"), "--frames", "6", "--size", "96x64"],
    "evaluate": lambda tmp, sim: ["evaluate", str(sim), "--detector", "seed"],
    "bench": lambda tmp, sim: ["bench", "--frames", "5", "--detectors", "seed", "--sizes", "96x64", "--distinct", "2"],
    "bench SOURCE": lambda tmp, sim: ["bench", str(sim), "--frames", "5", "--detectors", "seed", "--distinct", "2"],
    "twin": lambda tmp, sim: ["twin", "--frames", "2", "--size", "96x64", "--baseline-m", "0"],
    "run": lambda tmp, sim: ["run", str(sim / "frames") if (sim / "frames").is_dir() else str(sim), "--output",
                             "none", "--frames", "6"],
    "calibrate": lambda tmp, sim: ["calibrate", "--twin", str(tmp / "c.json"), "--size", "160x120",
                                   "--projector-size", "320x200", "--depths", "1"],
}


@pytest.mark.parametrize("name", list(LONG_COMMANDS))
def test_a_long_command_shows_progress_on_a_terminal_and_not_when_piped(name, sim_folder, tmp_path):
    args = LONG_COMMANDS[name](tmp_path, sim_folder)
    code, out, err = _command(args, tmp_path, tty=True)
    assert code == 0, err
    assert _bar_drawn(err), f"no progress bar on the terminal: {err!r}"
    assert BAR not in out and "it/s" not in out and "%|" not in out  # results stay clean
    for path in tmp_path.glob("*"):  # the piped run writes its files afresh
        if path.is_file():
            path.unlink()
        else:
            import shutil
            shutil.rmtree(path)
    code, out_piped, err = _command(args, tmp_path, tty=False)
    assert code == 0, err
    assert BAR not in err and "%|" not in err and "it/s" not in err, f"a bar on a pipe: {err!r}"
    assert BAR not in out_piped


def test_a_terminal_that_reports_no_size_gets_a_bar_all_the_same(tmp_path):
    """A pty opened without a size (``script``, some CI runners): tqdm hid every bar at 0 rows."""
    code, out, err = _command(["simulate", str(tmp_path / "s"), "--frames", "6", "--size", "96x64"], tmp_path,
                              tty=True, screen=(0, 0))
    assert code == 0 and _bar_drawn(err) and "6/6" in err, err


def test_quiet_silences_the_bar_and_the_notes_but_not_the_results_or_errors(tmp_path):
    args = ["simulate", str(tmp_path / "s"), "--frames", "6", "--size", "96x64"]
    code, out, err = _command(["--quiet", *args], tmp_path, tty=True)
    assert code == 0 and err == ""
    assert out.startswith("wrote 6 frames of preset seed")
    code, out, err = _command(["run", "--frames", "3", "--output", "none", "--quiet"], tmp_path, tty=False)
    assert code == 0 and err == "" and "frames: 3 (frame limit 3)" in out  # the summary is the result
    code, out, err = _command(["-q", "run", "missing.mkv"], tmp_path, tty=False)
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and err.startswith("antiscatter run: error: ") and "missing.mkv" in err


def test_default_and_verbose_log_lines_go_to_stderr(tmp_path):
    code, out, err = _command(["run", "--frames", "3", "--output", "none"], tmp_path, tty=False)
    assert code == 0
    assert err.startswith("antiscatter run: source sim (800x600), detector contrast")
    assert "antiscatter run: source" not in out and "debug:" not in err
    code, out, err = _command(["run", "--frames", "3", "--output", "none", "--verbose"], tmp_path, tty=False)
    assert code == 0
    lines = err.splitlines()
    assert lines[0].startswith("debug: antiscatter.run: antiscatter ") and "arguments {" in lines[0]
    assert lines[-1].startswith("debug: antiscatter.run: exit code 0 after ")
    assert "antiscatter run: source sim" in err and "frames: 3" in out


def test_quiet_and_verbose_are_exclusive(cli):
    result = cli("-q", "-v", "run")
    assert result.code == 2 and result.err.count("\n") == 1 and "not allowed with argument" in result.err


def test_a_warning_passes_quiet(cli, tmp_path, monkeypatch):
    """A warning (the service's missing group) still shows with --quiet, with its prefix."""
    from antiscatter import service

    monkeypatch.setattr(service, "missing_groups", lambda: ["render"])
    config = tmp_path / "a.toml"
    config.write_text("[run]\nframes = 1\n")
    result = cli("--quiet", "service", "install", "--config", str(config), "--unit-dir", str(tmp_path),
                 "--user", "root")
    assert result.code == 0, result.err
    assert result.err.startswith("warning: no group render here: systemd will refuse")


def test_progress_is_off_without_a_terminal_or_with_quiet(monkeypatch):
    class Tty(io.StringIO):
        def isatty(self) -> bool:
            return True

    monkeypatch.setattr(sys, "stderr", Tty())
    with configure_logging(0):
        assert progress_enabled()
        with progress(range(3), desc="x") as bar:
            list(bar)
        assert "3/3" in sys.stderr.getvalue()
        assert progress(range(3), enabled=False).disable  # its own switch: analyse --no-progress
    with configure_logging(-1):
        assert not progress_enabled()
    monkeypatch.setattr(sys, "stderr", io.StringIO())
    with configure_logging(1):
        assert not progress_enabled()
    assert LOGGER.level == logging.NOTSET and LOGGER.propagate  # restored after the command


def test_a_log_stream_turns_lines_into_records(monkeypatch):
    err = io.StringIO()
    monkeypatch.setattr(sys, "stderr", err)
    with configure_logging(0):
        stream = LogStream(LOGGER.getChild("run"))
        stream.write("note: one\nwarning: two\npart")
        stream.write("ial\n")
    assert err.getvalue() == "note: one\nwarning: two\npartial\n"
    err.truncate(0), err.seek(0)
    with configure_logging(-1):
        LogStream(LOGGER).write("note: hidden\nwarning: shown\n")
    assert err.getvalue() == "warning: shown\n"


def _strict(text: str):
    def refuse(name: str):
        raise AssertionError(f"not JSON: {name}")
    return json.loads(text, parse_constant=refuse)


def test_json_text_writes_null_for_nan():
    data = {"a": float("nan"), "b": [1.0, float("inf"), np.float64("nan")], "c": (np.int64(3),), "d": "x"}
    assert _strict(json_text(data)) == {"a": None, "b": [1.0, None, None], "c": [3], "d": "x"}


def test_evaluate_json_is_strict_json_with_a_frame_without_matches(cli, tmp_path):
    """No detection matches: the centre and radius errors have no value (NaN before: invalid JSON)."""
    truth, found = tmp_path / "t.csv", tmp_path / "d.csv"
    truth.write_text("frame,x,y,radius\n0,10,10,3\n1,20,20,3\n")
    found.write_text("frame,x,y,radius\n0,50,50,3\n")
    result = cli("evaluate", "--truth", str(truth), "--detections", str(found), "--json")
    assert result.code == 0, result.err
    data = _strict(result.out)
    assert data["overall"]["centre_error_mean"] is None and data["overall"]["recall"] == 0.0


# -- run's summary: the files written, and what Capture means for the simulator ---------------

def test_run_summary_names_the_files_it_wrote(cli, tmp_path):
    m, d = tmp_path / "m.csv", tmp_path / "d.csv"
    result = cli("run", "--frames", "3", "--output", "none", "--metrics", str(m), "--detections", str(d),
                 "--output", f"files:{tmp_path / 'p'}")
    assert result.code == 0, result.err
    assert result.out.splitlines()[-1] == (f"files written: {m} (per-frame stage timings), {d} (one row per "
                                           f"particle), {tmp_path / 'p'} (the light patterns)")
    result = cli("run", "--frames", "3", "--output", "none")
    assert result.out.splitlines()[-1].startswith("files written: none (--metrics, --detections")


def test_the_simulators_drawing_is_not_counted_as_capture(cli, tmp_path):
    """On the simulator, Capture is ~0 (its drawing took ms at 800x600 before and was in the total)
    and the total is no longer above the end-to-end latency."""
    import csv

    m = tmp_path / "m.csv"
    result = cli("run", "--frames", "8", "--output", "none", "--metrics", str(m), "--preset", "mixed")
    assert result.code == 0, result.err
    rows = list(csv.DictReader(m.open()))
    capture = [float(r["Capture Duration (s)"]) for r in rows]
    assert max(capture) < 1e-4  # (drawing a mixed frame takes several ms)
    total = np.array([float(r["Total frame processing time (s)"]) for r in rows])
    latency = np.array([float(r["End-to-end Latency (s)"]) for r in rows])
    after = np.array([float(r["Background Update Duration (s)"]) for r in rows])  # off the latency path
    assert (total - after <= latency + 1e-4).all()
    assert "the drawing is not counted as Capture" in result.out


def test_timed_read_counts_a_real_sources_wait_and_not_a_synthetic_ones():
    from antiscatter.runtime import _timed_read
    from antiscatter.sources.base import Frame, FrameSource

    class Slow(FrameSource):
        def read(self):
            time.sleep(0.02)
            return Frame(np.zeros((2, 2), np.uint8), 0, self.now_ns())

    class Drawn(Slow):
        synthetic = True

    _, t0, t1 = _timed_read(Slow())
    assert t1 - t0 >= 15_000_000
    _, t0, t1 = _timed_read(Drawn())
    assert t1 - t0 == 0


# -- twin: a header, labelled columns, and a plot a few series a panel --------------------------

def test_twin_prints_a_header_and_labelled_columns(tmp_path):
    code, out, err = _command(["twin", "--frames", "2", "--size", "96x64"], tmp_path, tty=False)
    assert code == 0, err
    lines = out.splitlines()
    assert lines[0] == ("antiscatter twin: preset mixed (seed 1), 2 frames a configuration; camera 96x64 at 60 Hz, "
                        "projector 1280x800 at 120 Hz; baseline 0.12 m, latency 5 ms")
    assert lines[1].startswith("removed: share of the particles' backscatter the pattern withholds")
    assert lines[2].split() == ["detector", "mapping", "strategy", "predict", "removed", "kept", "steady", "from",
                                "removed", "kept", "notes"]
    assert lines[3].split()[:4] == ["full", "light", "none", "none"]
    assert lines[-1].startswith("at a 0.12 m baseline one mapping fits one distance only")
    # every row's figures sit under their titles
    header = lines[2]
    for row in lines[3:-1]:
        removed_at = header.index("removed") + len("removed")
        assert row[removed_at - 5:removed_at].strip().replace(".", "").isdigit()


def test_twin_plot_draws_a_few_series_per_panel_with_a_readable_legend(tmp_path, monkeypatch):
    import antiscatter.bench as bench
    import antiscatter.twin as twin
    from antiscatter.twin import TwinGeometry, plot_curves

    monkeypatch.setattr(twin, "simulate_loop", lambda run, **kw: {"backscatter_removed": 0.5,
                                                                   "scene_light_kept": 0.9, "series": []})
    monkeypatch.setattr(twin, "particle_speed", lambda scene, geometry: 10.0)
    monkeypatch.setattr(twin, "twin_scene", lambda *a, **k: None)
    figures = []
    monkeypatch.setattr(bench, "save_figure", lambda fig, path: figures.append(fig))
    plot_curves(str(tmp_path / "t.png"), geometry=TwinGeometry(camera_size=(96, 64)), frames=1)
    (fig,) = figures
    panels = [ax for ax in fig.axes if ax.get_xlabel() or ax.get_ylabel() or ax.get_title()]
    assert len(panels) == 6  # removed and kept, each against latency, baseline and speed
    for ax in panels:
        assert 1 <= len(ax.get_lines()) <= 7, len(ax.get_lines())
        assert ax.get_legend() is None
    (legend,) = fig.legends
    texts = [t.get_text() for t in legend.get_texts()]
    assert len(texts) == 7 and not any(":" in t for t in texts)  # one entry a configuration
    assert min(t.get_fontsize() for t in legend.get_texts()) >= 9


# -- evaluate's precision-recall plot: threshold labels apart --------------------------------

def test_pr_plot_threshold_labels_do_not_overlap(tmp_path, monkeypatch):
    import antiscatter.bench as bench
    from antiscatter.evaluate.metrics import score_frame
    from antiscatter.evaluate.report import plot_evaluation, spaced_labels

    figures = []
    monkeypatch.setattr(bench, "save_figure", lambda fig, path: figures.append(fig))
    centre, radius = np.array([[5.0, 5.0]]), np.array([2.0])
    score = score_frame(0, centre, radius, np.ones(1, bool), centre, radius)
    # a typical sweep: the high thresholds crowd at full precision
    sweep = [(v, {"recall": r, "precision": p}) for v, r, p in
             [(2, 0.95, 0.40), (3, 0.93, 0.62), (4, 0.90, 0.80), (5, 0.88, 0.90), (6, 0.86, 0.95),
              (7, 0.85, 0.97), (8, 0.845, 0.98), (9, 0.84, 0.985), (10, 0.838, 0.99), (12, 0.835, 0.992)]]
    plot_evaluation(tmp_path / "pr.png", [score], sweep, title="t")
    (fig,) = figures
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    renderer = FigureCanvasAgg(fig).get_renderer()  # (the figure was closed after saving)
    labels = [t for t in fig.axes[0].texts]
    assert 3 <= len(labels) < len(sweep)
    boxes = [t.get_window_extent(renderer) for t in labels]
    for i in range(len(boxes)):
        for j in range(i + 1, len(boxes)):
            assert not boxes[i].overlaps(boxes[j]), (labels[i].get_text(), labels[j].get_text())
    assert {labels[0].get_text(), labels[-1].get_text()} == {"2", "12"}  # the ends are named
    assert spaced_labels(np.empty((0, 2)), gap=0.1) == []
    assert spaced_labels(np.array([[0, 0], [np.nan, 0.5], [0, 1]]), gap=0.1) == [0, 2]


# -- help texts ---------------------------------------------------------------------------------

def _help(cli, *command: str) -> str:
    result = cli(*command, "--help")
    assert result.code == 0
    return " ".join(result.out.split())  # argparse's wrapping undone


def test_run_help_names_kms_the_track_and_light_sections_and_every_detectors_parameters(cli):
    text = _help(cli, "run")
    assert "framebuffer[:/dev/fbN], kms (the projector through DRM/KMS" in text
    assert "[detector.NAME], [track], [light], [pattern], [output], [run] sections" in text
    assert "contrast: k, min_contrast, cell," in text and "seed: threshold, blur_kernel, canny_sigma, equalise" in text
    assert "-q, --quiet" in text and "-v, --verbose" in text


# -- record SOURCE OUT, as run SOURCE -----------------------------------------------------------

@pytest.mark.parametrize("form", [["sim", "{out}"], ["{out}", "--source", "sim"], ["{out}"]])
def test_record_takes_the_source_positionally_or_as_the_old_option(form, cli, tmp_path):
    from conftest import mkv_frames

    out = tmp_path / "r.mkv"
    args = [a.format(out=out) for a in form]
    result = cli("record", *args, "--frames", "3", "--size", "96x64")
    assert result.code == 0, result.err
    assert mkv_frames(out) == 3
    assert "antiscatter record: sim (96x64) -> " in result.err


def test_record_refuses_the_source_given_twice(cli, tmp_path):
    result = cli("record", "sim", str(tmp_path / "r.mkv"), "--source", "camera")
    assert result.code == 2 and result.out == ""
    assert result.err == "antiscatter record: error: SOURCE sim and --source camera: give the source once\n"
    assert not (tmp_path / "r.mkv").exists()


def test_catalogue_warns_when_the_real_images_are_absent(cli, tmp_path):
    """The scoreboard's real-image rows were dropped without a word when ../shared/data was absent."""
    catalogue = tmp_path / "c.toml"
    catalogue.write_text('version = 3\n[scenario.tiny]\npreset = "seed"\nsize = "96x64"\nframes = 2\nseed = 2\n')
    (tmp_path / "data").mkdir()
    result = cli("evaluate", "--catalogue", "--catalogue-file", str(catalogue), "--data", str(tmp_path / "data"),
                 "--report", str(tmp_path / "s.md"), "--bench-frames", "0", "--twin-frames", "0",
                 "--twin-long-frames", "0", "--heldout-frames", "0", "--detector", "seed")
    assert result.code == 0, result.err
    assert f"warning: no real image pairs in {tmp_path / 'data' / 'msrb'} (--data DIR)" in result.err
    assert result.err.splitlines()[-1] == f"wrote {tmp_path / 's.md'}"
    quiet = cli("-q", "evaluate", "--catalogue", "--catalogue-file", str(catalogue), "--data", str(tmp_path / "data"),
                "--report", str(tmp_path / "s.md"), "--bench-frames", "0", "--twin-frames", "0",
                "--twin-long-frames", "0", "--heldout-frames", "0", "--detector", "seed")
    assert quiet.err.startswith("warning: no real image pairs") and quiet.err.count("\n") == 1


def test_run_page_names_every_report_column_the_default_detector_leaves_at_zero():
    """docs/commands/run.md lists the report's stage columns the default detector has no stage for."""
    from antiscatter.cli import DEFAULT_DETECTOR
    from antiscatter.detection import make_detector
    from antiscatter.runtime import REPORT_COLUMNS

    stages = {f"{s.label} Duration (s)" for s in make_detector(DEFAULT_DETECTOR).stages}
    zero = [c for c in REPORT_COLUMNS if c.endswith("Duration (s)") and c != "Capture Duration (s)"
            and c not in stages]
    assert len(zero) == 7
    page = (Path(__file__).parents[1] / "docs" / "commands" / "run.md").read_text()
    section = " ".join(page.split("**Columns a detector does not have.**")[1].split("\n\n")[0].split())
    assert f"default `{DEFAULT_DETECTOR}`" in section and "these seven are always 0" in section
    for column in zero:
        assert f"`{column.replace(' Duration (s)', '')}`" in section, column


def test_the_interval_error_is_given_only_against_an_asked_rate(tmp_path):
    code, out, err = _command(["run", "--size", "96x64", "--output", "none", "--frames", "8"], tmp_path, tty=False)
    assert code == 0, err
    assert "interval error" not in out and "output rate" in out and "(unpaced: --fps sets a rate)" in out
    code, out, err = _command(["run", "--size", "96x64", "--output", "none", "--frames", "8", "--fps", "50"],
                              tmp_path, tty=False)
    assert code == 0, err
    assert "interval error against the --fps period: p50" in out
