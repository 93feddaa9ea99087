"""Tables, plots and the scoreboard report."""

from __future__ import annotations

import datetime as _dt
import math
import os
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..console import progress
from ..detection import DETECTORS, make_detector, with_sensitivity
from ..writing import CsvFile
from .metrics import FrameScore, summarise

__all__ = ["format_summary", "write_frame_csv", "plot_evaluation", "scoreboard", "format_heldout", "heldout_markdown"]

_COLUMNS = (("precision", "precision", "{:.3f}"), ("recall", "recall", "{:.3f}"), ("f1", "F1", "{:.3f}"),
            ("centre_error_mean", "centre err (px)", "{:.2f}"), ("centre_error_p95", "p95 (px)", "{:.2f}"),
            ("radius_bias", "radius bias (px)", "{:+.2f}"), ("cancellation", "cancellation", "{:.3f}"),
            ("light_kept", "light kept", "{:.3f}"))


def _fmt(value: Any, pattern: str) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    return pattern.format(value)


def format_summary(summary: dict[str, float], *, title: str = "") -> str:
    """A readable block of the overall figures."""
    lines = [title] if title else []
    lines.append(f"frames {summary['frames']}, truth {summary['truth']}, detections {summary['detections']}: "
                 f"TP {summary['tp']}, FP {summary['fp']}, FN {summary['fn']}")
    for key, label, pattern in _COLUMNS:
        if key in summary:
            lines.append(f"  {label:<18}{_fmt(summary[key], pattern)}")
    return "\n".join(lines)


def write_frame_csv(scores: list[FrameScore], path: str | Path) -> None:
    """One row per frame: counts, precision, recall, F1, centre error (and pixel metrics)."""
    rows = [s.row() for s in scores]
    header = list(rows[0]) if rows else ["frame", "tp", "fp", "fn", "precision", "recall", "f1"]
    with CsvFile(path, header) as out:  # whole rows only, however a full disk cuts it
        out.writerows([row.get(key, "") for key in header] for row in rows)


def plot_evaluation(path: str | Path, scores: list[FrameScore],
                    sweep: list[tuple[float, dict[str, float]]] | None = None, *, title: str = "") -> None:
    """Precision-recall over the detector's threshold (when swept), centre-error histogram, F1 per frame."""
    from ..bench import _pyplot, save_figure

    plt = _pyplot()
    panels = 3 if sweep else 2
    fig, axes = plt.subplots(1, panels, figsize=(5 * panels, 4))
    ax = axes[0]
    if sweep:
        recall = [s["recall"] for _, s in sweep]
        precision = [s["precision"] for _, s in sweep]
        ax.plot(recall, precision, "o-")
        for i in spaced_labels(np.column_stack([recall, precision]), gap=0.06):
            ax.annotate(f"{sweep[i][0]:g}", (recall[i], precision[i]), xytext=(4, 4), textcoords="offset points",
                        fontsize=8)
        ax.set_xlabel("recall")
        ax.set_ylabel("precision")
        ax.set_xlim(0, 1.02)
        ax.set_ylim(0, 1.02)
        ax.set_title("precision-recall over the threshold")
        ax = axes[1]
    errors = np.concatenate([s.centre_errors for s in scores]) if scores else np.empty(0)
    ax.hist(errors, bins=30, color="tab:blue")
    ax.set_xlabel("centre error (px)")
    ax.set_ylabel("matched particles")
    ax.set_title("centre error")
    ax = axes[-1]
    ax.plot([s.frame for s in scores], [s.row()["f1"] for s in scores], ".-")
    ax.set_xlabel("frame")
    ax.set_ylabel("F1")
    ax.set_ylim(0, 1.02)
    ax.set_title("F1 per frame")
    fig.suptitle(title)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def spaced_labels(points: np.ndarray, *, gap: float) -> list[int]:
    """Indices of the points to label so that no two labels crowd: the first, then the last, then the
    others in order, each only when it lies at least ``gap`` (data units; the PR plot's axes span
    0..1) from every point labelled before it (a point without a value, NaN, is never labelled).

    Parameters
    ----------
    points : (N, 2) float array
        The points in drawing order (recall, precision).
    gap : float
        Least distance between two labelled points.

    Returns
    -------
    list of int
        Indices into ``points``, ascending.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if len(points) == 0:
        return []
    order = [0, len(points) - 1] + list(range(1, len(points) - 1))
    chosen: list[int] = []
    for i in order:
        if i in chosen:
            continue
        finite = np.isfinite(points[i]).all()
        if finite and all(np.hypot(*(points[i] - points[j])) >= gap for j in chosen):
            chosen.append(i)
    return sorted(chosen)


def sweep_detector(name: str, params: Any, evaluate: Callable[[Any], list[FrameScore]]) -> list[tuple[float, dict]]:
    """Summaries of ``evaluate(detector)`` over the detector's sensitivity sweep."""
    entry = DETECTORS[name]
    key, values = entry.sweep
    if not key:
        return []
    out = []
    for value in progress(values, desc=f"sweep {key}", unit="value"):
        detector = make_detector(name, with_sensitivity(name, params, value))
        out.append((value, summarise(evaluate(detector))))
    return out


def _table(rows: list[dict[str, Any]], columns: list[tuple[str, str, str]]) -> list[str]:
    lines = ["| " + " | ".join(label for _, label, _ in columns) + " |",
             "|" + "|".join("---" for _ in columns) + "|"]
    for row in rows:
        lines.append("| " + " | ".join(_fmt(row.get(key), pattern) if pattern else str(row.get(key, ""))
                                       for key, _, pattern in columns) + " |")
    return lines


def _heldout_columns(names: list[str]) -> list[tuple[str, str, str]]:
    """Columns of the held-out tables: the case, then P / R / F1 of each detector, then each
    detector but ``seed`` (the report's fixed pipeline) its slowest frame over its median frame."""
    columns = [("case", "case", ""), ("frames", "frames", "{}"), ("counted", "counted", "{}")]
    for name in names:
        columns += [(f"{name}:precision", f"{name} P", "{:.3f}"), (f"{name}:recall", f"{name} R", "{:.3f}"),
                    (f"{name}:f1", f"{name} F1", "{:.3f}")]
    timed = [name for name in names if name != "seed"] or names[:1]
    return columns + [(f"{name}:worst_over_median", f"{name} worst/median time", "{:.1f}") for name in timed]


def _heldout_rows(result: dict[str, Any]) -> list[dict[str, Any]]:
    """One flat row per case of an :func:`~antiscatter.evaluate.heldout.evaluate_heldout` result,
    and one ("all") over the split's frames."""
    rows = []
    for case in result["cases"] + [{"case": "all", "frames": result["frames"], "counted": result["counted"],
                                     "detectors": result["overall"]}]:
        row = {"case": case["case"], "frames": case["frames"], "counted": case["counted"]}
        for name, figures in case["detectors"].items():
            row.update({f"{name}:{key}": figures[key] for key in ("precision", "recall", "f1", "worst_over_median")})
        rows.append(row)
    return rows


def format_heldout(results: list[dict[str, Any]], *, title: str = "") -> str:
    """A plain-text table per split of :func:`~antiscatter.evaluate.heldout.evaluate_heldout`
    results (with "seconds": generating and scoring it, when known)."""
    lines = [title] if title else []
    for result in results:
        names = list(result["overall"])
        took = f"; generated and scored in {result['seconds']:.1f} s" if "seconds" in result else ""
        lines.append(f"held-out {result['split']}: {len(result['cases'])} cases, {result['frames']} frames, "
                     f"{result['counted']} counted particles; backgrounds {', '.join(result['backgrounds'])}{took}")
        columns = _heldout_columns(names)
        cells = [[label for _, label, _ in columns]]
        cells += [[_fmt(row.get(key), pattern) if pattern else str(row.get(key, "")) for key, _, pattern in columns]
                  for row in _heldout_rows(result)]
        widths = [max(len(row[i]) for row in cells) for i in range(len(columns))]
        for row in cells:
            lines.append("  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(row, widths))))
        lines.append("")
    lines.append("worst/median time: the detector's slowest frame over its median frame in the case (all: the "
                 "largest of the cases')")
    return "\n".join(lines)


def heldout_markdown(results: list[dict[str, Any]]) -> list[str]:
    """Markdown lines: a table per split of :func:`~antiscatter.evaluate.heldout.evaluate_heldout` results."""
    md: list[str] = []
    for result in results:
        md += ["", f"### {result['split']} ({', '.join(result['backgrounds'])})", ""]
        md += _table(_heldout_rows(result), _heldout_columns(list(result["overall"])))
    return md


def _heldout_section(detectors: dict[str, Any], matching: Any, frames: int | None, data: Path | None,
                     log: Callable[[str], None]) -> tuple[list[str], list[dict[str, Any]]]:
    """The scoreboard's held-out section and its results (none without scikit-image)."""
    from ..errors import UsageError
    from .heldout import SPLITS, evaluate_heldout

    md = ["", "## Held-out material (`antiscatter evaluate --heldout both`)", "",
          "Frames built from real photographs (scikit-image's sample images and the MSRB photograph) with "
          "particles drawn by a renderer of their own (not the simulator's sprites): spots, defocused discs, "
          "rings, textured flakes, specks and sunlit flakes, with lit objects and lines that are not particles. "
          "Dev and test have disjoint photographs, seeds and particle mixtures: tune on dev only; a change "
          "that helps dev but not test is not kept (docs/decisions/002-heldout-material.md). Each case resets "
          "the detector at its start. Counted: peak over the background above max(8, 4 x noise sigma, the "
          "local spread of the particle-free frame around it) grey levels, half its light in the frame. "
          "Worst/median time: the detector's slowest frame over its median frame in the case (all: the "
          "largest of the cases')."]
    try:
        results = [evaluate_heldout(split, detectors, matching, frames=frames, data=data, log=log) for split in SPLITS]
    except UsageError as exc:
        return md + ["", f"Left out: {exc}."], []
    return md + heldout_markdown(results), results


def scoreboard(*, scenarios: dict[str, Any], catalogue_version: int, detectors: list[str],
               real_pairs: list[tuple[str, Path, Path]], matching: Any, bench_results: list[Any] | None,
               frames_limit: int | None = None, log: Callable[[str], None] = lambda s: None,
               tracking: bool = True, twin_frames: int = 0, twin_seeds: int = 3,
               twin_long_frames: int = 0, twin_long_seeds: int = 6, heldout: bool = False,
               heldout_frames: int | None = None, heldout_data: Path | None = None) -> tuple[str, dict]:
    """Run every detector on every scenario and real pair; return (markdown, data).

    heldout: also every detector on the held-out dev and test material (needs scikit-image; the
    section says so when it is missing), ``heldout_frames`` frames per case (None: each case's
    own), ``heldout_data`` the folder holding the MSRB photograph;
    tracking: also the tracker's figures (default detector) on every scenario;
    twin_frames: also the closed-loop twin's table (0 = leave it out), each figure the mean over
    ``twin_seeds`` scenes (seeds 1..twin_seeds) with the range of backscatter removed;
    twin_long_frames: with it, the headline loops run that long (0 = leave them out) over
    ``twin_long_seeds`` scenes.
    """
    from .runs import evaluate_pairs, evaluate_scenario

    built = {name: make_detector(name) for name in detectors}
    accuracy = []
    for s in scenarios.values():
        frames = min(s.frames, frames_limit) if frames_limit else s.frames
        log(f"scenario {s.name}: {s.preset} {s.size[0]}x{s.size[1]}, {frames} frames")
        scores = evaluate_scenario(s.preset, s.size, frames, s.seed, built, matching)
        for name in detectors:
            accuracy.append({"scene": s.name, "detector": name, "frames": frames, **summarise(scores[name])})
    for label, degraded, clean in real_pairs:
        log(f"real image {label}")
        for name in detectors:
            scores = evaluate_pairs([(degraded, clean)], built[name], matching)
            accuracy.append({"scene": f"real: {label}", "detector": name, "frames": 1, **summarise(scores)})
    columns = [("scene", "scene", ""), ("detector", "detector", ""), ("truth", "truth", "{}"),
               ("precision", "precision", "{:.3f}"), ("recall", "recall", "{:.3f}"), ("f1", "F1", "{:.3f}"),
               ("centre_error_mean", "centre err (px)", "{:.2f}"), ("radius_bias", "radius bias (px)", "{:+.2f}"),
               ("cancellation", "cancellation", "{:.3f}"), ("light_kept", "light kept", "{:.3f}")]
    md = ["# antiscatter scoreboard", "",
          f"Generated by `antiscatter evaluate --catalogue` on {_dt.date.today().isoformat()} "
          f"(scenario catalogue version {catalogue_version}). Regenerate it whenever a detector changes.", "",
          "Matching: a detection counts when its centre is within max("
          f"{matching.gate_scale:g} x truth radius, {matching.min_gate:g} px) of a particle (optimal "
          "one-to-one assignment). Counted truth: visibility >= "
          f"{matching.min_visibility:g}, SNR >= {matching.min_snr:g}; the rest is neither to be found nor a "
          "false alarm. Cancellation = share of counted particle pixels inside a hole; light kept = share "
          f"of background pixels left lit (holes = detected discs + {matching.margin:g} px).", "",
          "Real images: MSRB (Kaneko et al., APSIPA ASC 2023; photographs CC BY-NC-SA 2.0), truth = regions "
          "of max-channel |degraded - clean| > 20 of 3 px or more.", "", "## Accuracy", ""]
    md += _table(accuracy, columns)
    data = {"catalogue_version": catalogue_version, "matching": vars(matching), "accuracy": accuracy}
    if heldout:
        section, data["heldout"] = _heldout_section(built, matching, heldout_frames, heldout_data, log)
        md += section
    if bench_results:  # one BenchResult per input (BGR frames, the luma plane)
        first = bench_results[0]
        md += ["", "## Latency (`antiscatter bench`)", "", f"Machine: {first.machine}; "
               f"{first.threads} OpenCV thread(s); {first.frames} frames per size, detectors "
               "interleaved. Times in microseconds per frame. Input: BGR frames (video files, the simulator, "
               "webcams) or the luma plane alone (`--input y`: the Pi camera's YUV420 stream, no colour "
               "conversion); each input its own run. The chain floor is `bench.minimal_chain`, the least a "
               "local-contrast detector does (one channel, 2x2 pooling, a coarse background, one threshold, one "
               "labelling pass with centroids), timed in the same run.", ""]
        rows = []
        for result in bench_results:
            for entry in result.sizes:
                for name, d in entry["detectors"].items():
                    t = d["total"]
                    rows.append({"size": entry["size"], "input": result.input, "detector": name,
                                 "mean": t["mean_us"], "sd": t["sd_us"], "median": t["median_us"], "p99": t["p99_us"],
                                 "max": t["max_us"], "speedup": d["speedup_vs_seed"], "x_floor": d["x_floor"],
                                 "floor": entry["copy_floor_us"]["median_us"],
                                 "chain": entry["chain_floor_us"]["median_us"], "x_chain": d["x_chain"]})
        md += _table(rows, [("size", "size", ""), ("input", "input", ""), ("detector", "detector", ""),
                            ("mean", "mean", "{:.0f}"),
                            ("sd", "sd", "{:.0f}"), ("median", "median", "{:.0f}"), ("p99", "p99", "{:.0f}"),
                            ("max", "max", "{:.0f}"), ("speedup", "x seed's throughput", "{:.2f}"),
                            ("floor", "copy floor", "{:.0f}"), ("x_floor", "x floor", "{:.1f}"),
                            ("chain", "chain floor", "{:.0f}"), ("x_chain", "x chain floor", "{:.1f}")])
        data["bench"] = [result.as_dict() for result in bench_results]
    if tracking:
        md += ["", "## Tracking (default detector + Kalman tracker)", "",
               "Against the simulator's particle ids; prediction error = distance between a confirmed track's "
               "constant-velocity prediction and where its particle is 1, 2 and 3 frames later.", ""]
        rows = _tracking_rows(scenarios, matching, frames_limit, log)
        md += _table(rows, [("scene", "scene", ""), ("mota", "MOTA", "{:.3f}"), ("idf1", "IDF1", "{:.3f}"),
                            ("idf1_isolated", "IDF1, particles overlapping none", "{:.3f}"),
                            ("id_switches", "ID switches", "{}"), ("fragmentations", "fragmentations", "{}"),
                            ("pred1", "pred. err +1 (px)", "{:.2f}"), ("pred2", "pred. err +2 (px)", "{:.2f}"),
                            ("pred3", "pred. err +3 (px)", "{:.2f}")])
        data["tracking"] = rows
    if twin_frames:
        from ..pattern import GROW, GROW_FROM
        from ..twin import steady_from

        md += ["", "## Closed loop (`antiscatter twin`)", "",
               f"Preset mixed, 800x600 camera at 60 Hz (4 ms exposure), 1280x800 projector at 120 Hz, "
               f"{twin_frames} frames per run, each figure the mean over {twin_seeds} scenes (seeds "
               f"1-{twin_seeds}; \"range\": the lowest and highest removed among them). Removed = backscatter "
               "withheld from particles (each weighted by the light it sends back: brightness times image "
               "area), kept = scene light left on (1 = full lamp), over the whole run and, \"steady\", from frame "
               f"{steady_from(twin_frames)} on (after the detector's warm-up and the first "
               "tracks' confirmation). Holes drawn with the twin's exact geometry at the working "
               "depth (\"calibrated\"), stretched over each particle's disparity range (\"range\"), or "
               "at each track's depth found by bisection under dim or pulsed holes (\"probe\"), each grown with "
               "its size as run grows it (`--grow`). With a mapping other "
               "than identity the detector is told the light its exposure got (compensation).", ""]
        rows = _twin_rows(twin_frames, log, seeds=twin_seeds)
        md += _table(rows, [("baseline_m", "baseline (m)", "{:g}"), ("latency_ms", "latency (ms)", "{:g}"),
                            ("run", "system", ""), *_TWIN_FIGURES])
        data["twin"] = rows
        md += ["", "### A projector with a lens, and holes grown with their size", "",
               "The same loops (5 ms, pulsed holes with prediction) with the projector's pattern sharp only at "
               "the distance it is focused at (`twin --projector-aperture-mm 6 --projector-focus-m F`: a "
               f"{LENS_APERTURE_MM:g} mm aperture, an ML550-class lens, about 12 mm at f/2; a particle at depth "
               "Z gets its hole blurred by a disc 1536 px x A |1/F - 1/Z| across), with holes grown as by "
               f"default (each radius beyond {GROW_FROM:g} px by {GROW:g} times the excess) and not grown "
               "(`--grow 0`). The pinhole rows with grown holes are the table's above.", ""]
        rows = _lens_rows(twin_frames, log, seeds=twin_seeds)
        md += _table(rows, [("baseline_m", "baseline (m)", "{:g}"), ("run", "system", ""),
                            ("lens", "projector", ""), ("grow", "grow", "{:g}"), *_TWIN_FIGURES])
        data["twin_lens"] = rows
        if twin_long_frames:
            md += ["", "### Long runs", "",
                   f"The headline loops over {twin_long_frames} frames ({twin_long_frames / 60:g} s) each, the mean "
                   f"over {twin_long_seeds} scenes (seeds 1-{twin_long_seeds}): a lamp runs for hours, and in a "
                   f"{twin_frames}-frame run the start-up (the first frame lit in full before any pattern is "
                   "ready, the detector's warm-up, the first tracks' confirmation) is a large share of the "
                   "light. \"Steady\" is from frame "
                   f"{steady_from(twin_long_frames)} on, as above. Camera \"locked\": each exposure at the "
                   "start of a refresh (the trigger on the projector's vsync, or `run --camera-lock`); \"free\": "
                   "a free-running camera, scene k's exposures starting "
                   + ", ".join(f"{p:g}" for p in FREE_PHASES) + " of a refresh in (k = 1, 2, ...), pulse run as "
                   "`run` runs it there (`twin --camera-phase`); \"as run\": locked, the loop `run --camera-lock` "
                   "runs (one thread; `twin --camera-lock`). Display lag: from a flip to its light on the scene "
                   "(`--display-lag-ms`; a DLP projector formatting one frame while it shows the last lags a "
                   "refresh).", ""]
            rows = _long_rows(twin_long_frames, log, seeds=twin_long_seeds)
            md += _table(rows, [("baseline_m", "baseline (m)", "{:g}"), ("latency_ms", "latency (ms)", "{:g}"),
                                ("run", "system", ""), ("camera", "camera", ""),
                                ("display_lag_ms", "display lag (ms)", "{:.3g}"), *_TWIN_FIGURES])
            data["twin_long"] = rows
    return "\n".join(md) + "\n", data


#: the twin tables' figure columns (:func:`_group_figures`'s keys)
_TWIN_FIGURES = [("backscatter_removed", "removed", "{:.3f}"), ("scene_light_kept", "kept", "{:.3f}"),
                 ("backscatter_removed_steady", "removed, steady", "{:.3f}"),
                 ("scene_light_kept_steady", "kept, steady", "{:.3f}"), ("removed_range", "removed, range", "")]


def _tracking_rows(scenarios: dict[str, Any], matching: Any, frames_limit: int | None,
                   log: Callable[[str], None]) -> list[dict[str, Any]]:
    from ..simulate import make_scene
    from .runs import evaluate_tracking, scenario_truth_frames

    rows = []
    for s in scenarios.values():
        frames = min(s.frames, frames_limit) if frames_limit else s.frames
        log(f"tracking {s.name}")
        fps = make_scene(s.preset, rng=np.random.default_rng(0), size=(8, 8)).fps
        out = evaluate_tracking(scenario_truth_frames(s.preset, s.size, frames, s.seed, matching),
                                make_detector("contrast"), matching, fps=fps)
        t, p = out["tracking"], out["prediction"]
        rows.append({"scene": s.name, "mota": t["mota"], "idf1": t["idf1"],
                     "idf1_isolated": out["tracking_isolated"]["idf1"], "id_switches": t["id_switches"],
                     "fragmentations": t["fragmentations"], "pred1": p["+1"]["mean_px"],
                     "pred2": p["+2"]["mean_px"], "pred3": p["+3"]["mean_px"]})
    return rows


def _twin_rows(frames: int, log: Callable[[str], None], *, seeds: int = 3,
               workers: int | None = None) -> list[dict[str, Any]]:
    """The twin table's rows: every default run at both baselines and three latencies, each the mean
    over ``seeds`` scenes, the loops spread over ``workers`` processes (default: one per CPU this
    process may use; the loops are independent, and one at a time took most of an hour)."""
    from ..twin import default_runs

    jobs = [(run, baseline, latency, seed, frames, 0.0, 0.0)
            for baseline in (0.0, 0.12) for latency in (5.0, 10.0, 20.0)
            for run in default_runs(baseline) for seed in range(1, seeds + 1)]
    return _loop_rows(jobs, seeds, log, workers)


def _loop_rows(jobs: list[tuple], seeds: int, log: Callable[[str], None],
               workers: int | None) -> list[dict[str, Any]]:
    """A row per run of ``jobs`` (``_twin_job``'s tuples, each run's ``seeds`` scenes in a row): its
    baseline, latency, name and figures over its scenes."""
    rows = []
    for job, group in _twin_groups(jobs, seeds, log, workers):
        run, baseline, latency = job[:3]
        rows.append({"baseline_m": baseline, "latency_ms": latency, "run": _run_name(run, group[0]),
                     **_group_figures(group)})
    return rows


#: the long-run table's loops: (baseline m, latency ms, run's mapping, strategy, predict, camera,
#: display lag in refreshes) -- the co-located goal's strategies on a camera locked to the
#: projector (the ideal), on a free-running one (``free``: scene k's exposures FREE_PHASES[k % 4]
#: of a refresh in) and locked as ``run --camera-lock`` runs it (``as run``), without and with a
#: projector lagging a refresh, 12 ms (the light after the pattern) and 14 ms (past its reach:
#: every other frame); the 12 cm goal's, and the prediction's gain at 20 ms
LONG_RUNS = ((0.0, 5.0, "calibrated", "dim", True, "locked", 0), (0.0, 5.0, "calibrated", "pulse", True, "locked", 0),
             (0.0, 5.0, "calibrated", "dim", True, "free", 0), (0.0, 5.0, "calibrated", "pulse", True, "free", 0),
             (0.0, 5.0, "calibrated", "pulse", True, "as run", 0),
             (0.0, 5.0, "calibrated", "dim", True, "locked", 1), (0.0, 5.0, "calibrated", "pulse", True, "as run", 1),
             (0.0, 5.0, "calibrated", "pulse", True, "as run", 1.44), (0.0, 5.0, "calibrated", "pulse", True, "as run", 1.68),
             (0.12, 5.0, "probe", "dim", True, "locked", 0), (0.12, 5.0, "probe", "pulse", True, "locked", 0),
             (0.12, 5.0, "probe", "pulse", True, "as run", 1),
             (0.12, 20.0, "probe", "pulse", False, "locked", 0), (0.12, 20.0, "probe", "pulse", True, "locked", 0))
FREE_PHASES = (0.0, 0.25, 0.5, 0.75)


def _long_rows(frames: int, log: Callable[[str], None], *, seeds: int = 6,
               workers: int | None = None) -> list[dict[str, Any]]:
    """The long-run table's rows: each of ``LONG_RUNS`` over ``frames`` frames, the mean over
    ``seeds`` scenes."""
    from ..twin import TwinGeometry, TwinRun

    refresh = 1 / TwinGeometry.projector_hz  # the twin's projector refresh, the lag's unit (s)
    jobs = [(TwinRun("contrast", mapping, strategy, predict), baseline, latency, seed, frames, 0.0, 0.0,
             {"camera_phase": FREE_PHASES[(seed - 1) % len(FREE_PHASES)] if camera == "free" else None,
              "camera_lock": camera == "as run", "display_lag_s": lag * refresh})
            for baseline, latency, mapping, strategy, predict, camera, lag in LONG_RUNS
            for seed in range(1, seeds + 1)]
    rows = _loop_rows(jobs, seeds, log, workers)
    for row, entry in zip(rows, LONG_RUNS):
        row["camera"], row["display_lag_ms"] = entry[5], entry[6] * refresh * 1e3
    return rows


#: the scoreboard's projector lens: aperture (mm) and the distances it is focused at (m)
LENS_APERTURE_MM = 6.0
LENS_FOCUS_M = (3.0, 1.0, 0.5)


def _lens_rows(frames: int, log: Callable[[str], None], *, seeds: int = 3,
               workers: int | None = None) -> list[dict[str, Any]]:
    """The lens table's rows: co-located pulsed holes and, at 12 cm, pulsed depth probing, with
    prediction at 5 ms, under a pinhole projector with holes not grown, and under one of
    ``LENS_APERTURE_MM`` focused at each of ``LENS_FOCUS_M`` with holes grown (``GROW``, as by
    default) and not."""
    from dataclasses import replace

    from ..pattern import GROW, GROW_FROM
    from ..twin import TwinRun

    runs = ((0.0, TwinRun("contrast", "calibrated", "pulse", True)),
            (0.12, TwinRun("contrast", "probe", "pulse", True)))
    aperture = LENS_APERTURE_MM / 1e3
    lenses = [(0.0, 0.0, 0.0)] + [(aperture, f, grow) for grow in (0.0, GROW) for f in LENS_FOCUS_M]
    jobs = [(replace(run, grow=grow, grow_from=GROW_FROM), baseline, 5.0, seed, frames, aperture, focus)
            for baseline, run in runs for aperture, focus, grow in lenses for seed in range(1, seeds + 1)]
    rows = []
    for job, group in _twin_groups(jobs, seeds, log, workers):
        run, baseline, _, _, _, aperture, focus = job
        lens = f"{aperture * 1e3:g} mm, focused at {focus:g} m" if aperture else "pinhole"
        rows.append({"baseline_m": baseline, "run": _run_name(run, group[0]), "lens": lens, "grow": run.grow,
                     **_group_figures(group)})
    return rows


def _twin_groups(jobs: list[tuple], seeds: int, log: Callable[[str], None], workers: int | None):
    """Run the loops ``jobs`` (``_twin_job``'s tuples, each run's ``seeds`` scenes in a row) over
    ``workers`` processes (default: one per CPU this process may use); yields (a run's first job,
    its scenes' results)."""
    if workers is None:
        workers = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    log(f"twin: {len(jobs)} loops of {jobs[0][4]} frames on {workers} process(es)")
    if workers > 1:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(workers) as pool:
            outs = list(progress(pool.map(_twin_job, jobs), total=len(jobs), desc="twin", unit="loop"))
    else:
        outs = [_twin_job(job) for job in progress(jobs, desc="twin", unit="loop")]
    for at in range(0, len(jobs), seeds):
        yield jobs[at], outs[at:at + seeds]


def _run_name(run: Any, out: dict[str, Any]) -> str:
    """A twin table's name for a run (its first scene's result ``out``)."""
    return ("full light" if run.detector is None else
            f"{out['detector']}, {out['mapping']}, {out['strategy']}"
            + (", predict" if out["predict"] else "")
            + (", fixed levels" if run.levels == "fixed" else "")
            + (", every hole" if out.get("min_worth") == 0 else ""))


def _group_figures(group: list[dict[str, Any]]) -> dict[str, Any]:
    """The mean figures over one run's scenes, and the range of removed among them."""
    keys = [key for key, _, _ in _TWIN_FIGURES if key != "removed_range"]
    removed = [o["backscatter_removed"] for o in group]
    return {**{key: float(np.mean([o[key] for o in group])) for key in keys},
            "removed_range": f"{min(removed):.3f}-{max(removed):.3f}"}


def _twin_job(job: tuple) -> dict[str, Any]:
    """One closed loop of a twin table (a process of its own), without its per-frame series."""
    from ..twin import TwinGeometry, simulate_loop

    run, baseline, latency, seed, frames, aperture, focus, *timing = job  # (timing: the camera's, the display's)
    out = simulate_loop(run, geometry=TwinGeometry(baseline_m=baseline, projector_aperture_m=aperture,
                                                   projector_focus_m=focus, **(timing[0] if timing else {})),
                        frames=frames, latency_ms=latency, seed=seed)
    out.pop("series")
    return out
