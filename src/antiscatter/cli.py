"""The ``antiscatter`` command line."""

from __future__ import annotations

import argparse
import contextlib
import logging
import math
import signal
import sys
import time
from typing import Any, Sequence

import numpy as np

from . import __version__
from .console import json_text
from .errors import SIGTERM_RECEIVED, RunError, Terminated, UsageError, WriteError, check_output_path

__all__ = ["main", "build_parser"]

#: The detector ``evaluate`` runs when none is named.
DEFAULT_DETECTOR = "contrast"
#: ``run``'s exit code when the source ended before its declared end (a video cut short): the
#: frames read were used and every file is complete, but the input was damaged.
EXIT_DAMAGED = 3


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (exit code 2) instead of usage dumps."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _detector_help() -> str:
    from .detection import DETECTORS
    return "; ".join(f"{name}: {entry.summary}" for name, entry in sorted(DETECTORS.items()))


def _param_help() -> str:
    """Every detector's parameters by name, from the registry (the default detector first)."""
    from dataclasses import fields

    from .detection import DETECTORS
    names = sorted(DETECTORS, key=lambda n: (n != DEFAULT_DETECTOR, n))
    return "; ".join(f"{name}: {', '.join(f.name for f in fields(DETECTORS[name].params))}" for name in names)


def _add_verbosity(parser: argparse.ArgumentParser, default: Any) -> None:
    """``-q/--quiet`` and ``-v/--verbose`` on ``parser``: before the command (``default`` 0) or after it
    (``default`` SUPPRESS, so a command's parser keeps the value given before it)."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument("-q", "--quiet", dest="verbosity", action="store_const", const=-1, default=default,
                       help="only results, warnings and errors: no progress bars or notes")
    group.add_argument("-v", "--verbose", dest="verbosity", action="store_const", const=1, default=default,
                       help="also debug records")


def build_parser() -> argparse.ArgumentParser:
    from .levels import DIM_REST, LEVELS, REST
    from .probe import MIN_WORTH
    from .pattern import GROW, GROW_FROM
    from .strategies import strategy_names

    parser = _Parser(
        prog="antiscatter",
        description="Backscatter-avoiding underwater lighting: find the bright particles in each "
                    "camera frame and light everything except them with a projector.",
        epilog="Run 'antiscatter COMMAND --help' for each command's options.")
    parser.add_argument("--version", action="version", version=f"antiscatter {__version__}")
    _add_verbosity(parser, 0)
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    run = commands.add_parser(
        "run", help="the backscatter cancellation loop (camera/video/frames/simulator -> projector)",
        description="Detect particles in every frame and show a light pattern with holes where they "
                    "are. Stops at --frames, when the source ends, on 'e' in a window, Ctrl-C or "
                    "SIGTERM; every file written is complete. Prints the report's per-stage table. Exit code 0; "
                    "2 for bad input; 3 when a video ended before the frames its container declares (cut "
                    "short or damaged: a warning names it, the frames read were used); 130 / 143 on SIGINT / "
                    "SIGTERM.",
        epilog="Examples:\n"
               "  antiscatter run --frames 300 --output none --metrics m.csv --detections d.csv\n"
               "  antiscatter run frames/ --output files:patterns.mkv\n"
               "  antiscatter run tank.mkv --crop 430:700,0:320 --loop --output window\n"
               "  antiscatter run camera --output framebuffer:/dev/fb0 --fps 60 --nice -20",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    run.add_argument("source", nargs="?", default=None,
                     help="sim (default: the built-in simulator; sim: where a folder named sim is here, "
                          "./sim for that folder), camera (Picamera2), webcam:N, "
                          "a folder of frames (<int>.png, or images named in order: png, jpg, tif, bmp), or a video file")
    run.add_argument("--config", metavar="FILE.toml", help="TOML file with [source], [detector], "
                     "[detector.NAME], [track], [light], [pattern], [output], [run] sections; flags override it")
    g = run.add_argument_group("source")
    g.add_argument("--crop", metavar="X0:X1,Y0:Y1", help="keep columns X0..X1-1 and rows Y0..Y1-1 of a video")
    g.add_argument("--loop", action="store_true", default=None, help="play a video or folder again when it ends")
    g.add_argument("--preset", help="simulator preset for the sim source (default seed: the report's bubbles)")
    g.add_argument("--seed", type=int, help="random seed of the simulator (default 0)")
    g.add_argument("--size", metavar="WxH", help="frame size for sim, camera and webcam")
    g.add_argument("--camera-fps", type=float, help="frame rate asked of the camera (default 60)")
    g.add_argument("--camera-exposure-ms", type=float, help="fixed camera exposure, ms, automatic exposure and "
                   "gain off (default: automatic); pulse and flash need it inside one projector refresh")
    g.add_argument("--camera-gain", type=float, help="analogue gain with a fixed exposure, 1-64 (default 1)")
    g.add_argument("--camera-lock", action="store_true", default=None, help="lock the camera's exposures to the "
                   "projector's refresh in software (frame durations nudged), so pulse or flash lights every "
                   "exposure; needs a fixed --camera-exposure-ms, --output kms and --mode single; --strategy "
                   "auto then pulses")
    g.add_argument("--camera-colour", action="store_true", default=None, help="BGR frames from the camera "
                   "instead of the Y plane of its YUV420 stream (the default: grey without conversion)")
    g.add_argument("--camera-lores", action="store_true", default=None, help="the camera's ISP also scales each "
                   "frame to the detector's working resolution (a lores YUV420 stream) and the detector takes "
                   "that instead of pooling the full frame (off by default: less accurate, see "
                   "docs/decisions/009-lores.md); grey frames, mode single or threads")
    g = run.add_argument_group("detector")
    g.add_argument("--detector", help=f"detector name ({_detector_help()})")
    g.add_argument("-p", "--param", action="append", metavar="KEY=VALUE", default=[],
                   help="a parameter of the chosen detector, e.g. k=6 (contrast) or threshold=180 (seed); "
                        f"repeatable. Parameters: {_param_help()}")
    g = run.add_argument_group("tracking")
    g.add_argument("--track", action="store_true", default=None,
                   help="track particles (Kalman) and draw holes from the tracks; coasting keeps a hole on a "
                        "particle that went dark; the detections CSV gains track_id")
    g.add_argument("--no-predict", dest="predict", action="store_false", default=None,
                   help="with --track: draw holes where particles were, not where they will be")
    g.add_argument("--latency-ms", type=float, help="with --track: predict over this capture-to-light time "
                   "(default: the measured one)")
    g = run.add_argument_group("light strategy (against the closed-loop catch; see antiscatter twin)")
    g.add_argument("--strategy", choices=("auto", *strategy_names()),
                   help="auto (default): dim with tracking on with the camera, else none; none: holes from each "
                        "frame's detections; dim: holes at --dim-level so darkened particles stay visible; "
                        "pulse: holes at --dim-level only while the camera exposes, dark otherwise (mode "
                        "single; best with the camera triggered by the projector); flash: a uniform --flash-level frame before each "
                        "capture, the pattern the rest of the time (mode single); coast: tracked holes stay on "
                        "particles that went dark (turns --track on)")
    g.add_argument("--dim-level", type=float, help="light left in dim holes (pulse: while the camera exposes), 0..1 (default 0.1)")
    g.add_argument("--flash-level", type=float, help="brightness of the detection flash, 0..1 (default 0.25)")
    g.add_argument("--levels", choices=("auto", *LEVELS),
                   help="auto (default): adaptive with the camera, else fixed (files and the simulator do not see "
                        "the light); adaptive: with dim or pulse and tracking, each hole leaves its particle just "
                        "the light the detector needs to see it, between --min-level and --dim-level; fixed: "
                        "--dim-level for every hole")
    g.add_argument("--min-level", type=float, help="the least light an adaptive hole leaves, 0..1 (default 0.02)")
    g.add_argument("--rest", type=int, help="adaptive levels: frames a confirmed track's hole stays fully dark "
                   "after each frame that found its particle, carried along its predicted path (default 1 "
                   "with pulsed holes, 2 with dim ones; 0 = always dimmed; not while probing depth)")
    g.add_argument("--min-worth", type=float, help="depth probing: draw a hole only where the share of the "
                   "backscatter it withholds is at least this many times the share of the scene light it takes "
                   f"(default {MIN_WORTH:g}; 0 = every hole)")
    g.add_argument("--depth", choices=("auto", "fixed", "probe"), help="auto (default): probe where it can "
                   "run, else fixed; fixed: holes at the calibration's working distance; probe: each particle's depth found by bisection along its epipolar "
                   "line under dim holes (needs --strategy dim or pulse and --calibration from two distances)")
    g = run.add_argument_group("pattern")
    g.add_argument("--projector-size", metavar="WxH", help="projector resolution (default 1280x800)")
    g.add_argument("--margin", type=float, help="pixels added to every hole's radius (default 0)")
    g.add_argument("--grow", type=float, help="holes grow in proportion to their size: each radius beyond "
                   "--grow-from by this many times the excess (default 0.6: in the twin about 0.01 of the scene "
                   "light for 0.01-0.02 more backscatter removed, 0.05 under a defocused projector; 0 = off)")
    g.add_argument("--grow-from", type=float, help="camera pixels (for frames 800 px wide; in proportion for "
                   "others) a hole's radius must exceed to grow (default 4)")
    g.add_argument("--calibration", metavar="FILE", help="a calibration from 'antiscatter calibrate': its "
                   "homography maps camera to projector pixels and sets the projector size")
    g.add_argument("--mapping", metavar="FILE", help="3x3 camera-to-projector homography, a text file "
                   "of 3 rows of 3 numbers (default: identity scaled to the projector size)")
    g = run.add_argument_group("output and run")
    g.add_argument("-o", "--output", action="append", metavar="NAME",
                   help="light output, repeatable: framebuffer[:/dev/fbN], kms (the projector through DRM/KMS, "
                        "flips timed), window, files:DIR, files:NAME.mkv, none, auto (default: a window where a "
                        "display exists, else none)")
    g.add_argument("--frames", type=int, help="stop after N frames (default 0 = no limit)")
    g.add_argument("--fps", type=float, help="pace the loop at F frames per second (default 0 = as fast as possible)")
    g.add_argument("--nice", type=int, help="process niceness, -20 (highest priority) .. 19")
    g.add_argument("--mode", choices=("single", "threads", "processes", "processes-pickle"), help="single (default; fastest in bench --modes on the simulator): one thread; threads: capture, processing and "
                   "output overlap in three threads with latest-frame hand-over; processes: detection in a "
                   "worker process fed through shared memory; processes-pickle: the report's design, frames "
                   "pickled through a queue (to measure its cost)")
    g.add_argument("--rt-priority", type=int, metavar="N", help="real-time SCHED_FIFO priority 1..99 "
                   "(a warning without permission)")
    g.add_argument("--cpus", metavar="2,3", help="CPU affinity")
    g.add_argument("--threads", type=int, metavar="N", help="threads detection runs on, 1 to four per CPU "
                   "(default 1): the default detector's frame-wide filters in bands of the frame, and "
                   "OpenCV's own; the same detections on any number")
    g.add_argument("--mlock", action="store_true", default=None, help="lock memory (mlockall)")
    g.add_argument("--web", metavar="[HOST:]PORT", help="serve the control panel (live views, figures, buttons "
                   "Light / Record / Stop) on this port; 127.0.0.1 unless a host is given")
    g.add_argument("--record-to", metavar="FILE.mkv", help="where the panel's Record button writes the input "
                   "frames (default: antiscatter-<date>-<time>.mkv)")
    g.add_argument("--metrics", metavar="CSV", help="per-frame stage timings, the report's columns first")
    g.add_argument("--detections", metavar="CSV", help="one row per particle: frame,time,x,y,radius (time: s)")
    g.add_argument("--mcap", metavar="FILE.mcap", help="every frame as ROS 2 messages in an MCAP file (camera "
                   "image, Detection2DArray with track ids, projector pattern, metrics), stamped with the frame's "
                   "time, for ros2 bag and Foxglove (pip install 'antiscatter[mcap]')")
    sim = commands.add_parser(
        "simulate", help="synthetic frames with exact ground truth (truth.csv, label masks)",
        description="Write OUT/<frame>.png (from 0) and OUT/truth.csv for a simulator preset; the "
                    "same seed gives the same bytes. truth.csv columns: Bubble ID, Frame #, "
                    "X Position, Y Position, Radius (the report's), then Depth (m), Kind, Peak, "
                    "Visibility, Label (the particle's value in masks/<frame>.png, 0 = hidden).",
        epilog="Examples:\n"
               "  antiscatter simulate out --preset seed --frames 120 --seed 1\n"
               "  antiscatter simulate out --preset textured --frames 60 --masks\n"
               "  antiscatter simulate out --scenario mixed --video out/mixed.mkv\n"
               "  antiscatter simulate --list",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    sim.add_argument("out", nargs="?", help="output folder")
    sim.add_argument("--preset", default=None, help="scene preset (default seed; --list shows all)")
    sim.add_argument("--frames", type=int, default=None, help="number of frames (default 120)")
    sim.add_argument("--seed", type=int, default=None, help="random seed (default 0)")
    sim.add_argument("--size", metavar="WxH", help="frame size (default: the preset's)")
    sim.add_argument("--scenario", help="a named scenario of the catalogue (preset, size, frames, seed)")
    sim.add_argument("--catalogue", metavar="FILE.toml", help="scenario catalogue (default: the packaged one)")
    sim.add_argument("--background", metavar="PATH", help="your own image or video as the background "
                     "(realistic presets)")
    sim.add_argument("--masks", action="store_true", help="also write masks/<frame>.png, 16-bit labels")
    sim.add_argument("--video", metavar="OUT.mkv", help="write frames as one lossless FFV1 video instead of PNGs")
    sim.add_argument("--overwrite", action="store_true", help="replace frames already in OUT")
    sim.add_argument("--list", action="store_true", help="list presets and catalogued scenarios, then exit")
    ev = commands.add_parser(
        "evaluate", help="accuracy against ground truth: precision, recall, F1, errors, cancellation",
        description="Score detections against ground truth. Inputs, one of: --truth CSV --detections CSV; "
                    "a SOURCE -- a simulator output folder (runs --detector; pixel metrics where masks/ exist), "
                    "or your own annotated frames (a folder of images or a video file) with --truth CSV "
                    "(frame,x,y[,radius][,id]: frames numbered from 0 in order; or MOTChallenge gt.txt); "
                    "--degraded/--clean real image pairs (files or folders with equal names); --scenario NAME "
                    "(generated in memory); --heldout SPLIT (the held-out material: real photographs with particles "
                    "of its own, dev to tune on and test to judge on; the detector and seed on every case); "
                    "--catalogue (every detector on every catalogued scenario and the real images: writes the "
                    "scoreboard).",
        epilog="Examples:\n"
               "  antiscatter evaluate --truth out/truth.csv --detections d.csv --json\n"
               "  antiscatter evaluate out --detector seed --plot pr.png\n"
               "  antiscatter evaluate dive.mkv --truth annotations.csv --min-gate 4 --track\n"
               "  antiscatter evaluate --degraded ../shared/data/msrb/174710351_task1.png "
               "--clean ../shared/data/msrb/174710351_orig.png\n"
               "  antiscatter evaluate --heldout dev -p memory=0\n"
               "  antiscatter evaluate --heldout both --heldout-export heldout/\n"
               "  antiscatter evaluate --catalogue --data ../shared/data --report docs/scoreboard.md",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    ev.add_argument("folder", nargs="?", metavar="SOURCE",
                    help="a simulator output folder (frames, truth.csv, masks/), or a folder of frames or a "
                         "video file with --truth")
    ev.add_argument("--truth", metavar="CSV", help="truth: the simulator's truth.csv, frame,x,y[,radius][,id] "
                    "(hand annotations; without radius a detection matches within --min-gate), or "
                    "MOTChallenge ground truth (gt.txt, CVAT's 'MOT 1.1' export: boxes as discs, frames from 1)")
    ev.add_argument("--detections", metavar="CSV", help="frame,x,y,radius as 'run --detections' writes, or another "
                    "tracker's MOTChallenge results")
    ev.add_argument("--degraded", metavar="PATH", help="real image(s) with particles")
    ev.add_argument("--clean", metavar="PATH", help="the same image(s) without particles")
    ev.add_argument("--scenario", help="a catalogued scenario, generated in memory")
    ev.add_argument("--catalogue", action="store_true", help="every detector on every scenario and real "
                    "image; writes the scoreboard (--report)")
    ev.add_argument("--heldout", choices=("dev", "test", "both"), help="the held-out material (needs scikit-image: "
                    "pip install 'antiscatter[eval]'): frames from real photographs with particles drawn by a "
                    "renderer of their own; dev and test have disjoint photographs, seeds and particle mixtures "
                    "(tune on dev only). Runs the detector and seed on every case; prints P / R / F1 per case and "
                    "the detector's slowest frame over its median")
    ev.add_argument("--heldout-frames", type=int, metavar="N", help="frames per held-out case (default: each "
                    "case's own, 8-12); with --catalogue, 0 leaves the scoreboard's held-out table out")
    ev.add_argument("--heldout-export", metavar="DIR", help="with --heldout: instead of scoring, write each case as "
                    "DIR/<split>/<case>/: <frame>.png, truth.csv (frame,x,y,radius,id of the counted particles) and "
                    "gt.txt (every particle, MOTChallenge, the uncounted ones not considered: '--truth gt.txt' "
                    "scores as in memory)")
    ev.add_argument("--catalogue-file", metavar="FILE.toml", help="scenario catalogue (default: the packaged one)")
    ev.add_argument("--data", metavar="DIR", help="folder holding msrb/ real images (default ../shared/data "
                    "when it exists)")
    ev.add_argument("--report", metavar="FILE.md", default="docs/scoreboard.md", help="scoreboard path "
                    "(default docs/scoreboard.md)")
    ev.add_argument("--frames", type=int, help="at most N frames per scenario or SOURCE (--heldout: "
                    "--heldout-frames)")
    ev.add_argument("--twin-frames", type=int, default=60, help="frames per closed-loop twin run for the "
                    "scoreboard's twin table (0 = leave it out; default 60)")
    ev.add_argument("--twin-seeds", type=int, default=3, help="scenes (seeds 1..N) the twin table averages "
                    "over (default 3)")
    ev.add_argument("--twin-long-frames", type=int, default=300, help="frames per run of the twin's long-run "
                    "table (the headline loops; 0 = leave it out; default 300, 5 s)")
    ev.add_argument("--twin-long-seeds", type=int, default=6, help="scenes (seeds 1..N) the long-run table "
                    "averages over (default 6)")
    ev.add_argument("--bench-frames", type=int, default=100, help="frames per size for the scoreboard's "
                    "bench table (0 = leave it out; default 100)")
    ev.add_argument("--detector", default=None, help="detector to run (default: the default detector); "
                    "--catalogue runs all")
    ev.add_argument("-p", "--param", action="append", metavar="KEY=VALUE", default=[],
                    help="a parameter of the detector; repeatable")
    ev.add_argument("--min-gate", type=float, default=2.0, help="smallest matching distance, px (default 2)")
    ev.add_argument("--gate-scale", type=float, default=1.0, help="matching distance as a multiple of the "
                    "truth radius (default 1)")
    ev.add_argument("--min-visibility", type=float, default=0.5, help="truth less visible than this is not "
                    "counted (default 0.5)")
    ev.add_argument("--min-snr", type=float, default=5.0, help="truth fainter than this SNR is not counted (Rose criterion) "
                    "(default 5)")
    ev.add_argument("--margin", type=float, default=0.0, help="pixels added to each hole for the pixel metrics")
    ev.add_argument("--rise", type=float, default=20.0, help="real pairs: particle where max-channel "
                    "|degraded - clean| exceeds this (default 20)")
    ev.add_argument("--min-area", type=int, default=3, help="real pairs: smallest particle region, px (default 3)")
    ev.add_argument("--track", action="store_true", help="with --scenario or a SOURCE whose truth has ids: also "
                    "run the tracker and report MOTA, IDF1, identity switches, fragmentation and prediction "
                    "error at +1..+3 frames (a detections CSV with a track_id column gets the tracking "
                    "figures by itself)")
    ev.add_argument("--fps", type=float, help="frame rate of a SOURCE for --track (default: the video's, "
                    "else 60)")
    ev.add_argument("--json", action="store_true", help="print the results as JSON")
    ev.add_argument("--csv", metavar="FILE", help="write per-frame figures")
    ev.add_argument("--plot", metavar="FILE.png", help="precision-recall over the threshold and errors")

    rec = commands.add_parser(
        "record", help="lossless FFV1 recording of the camera (or another source), the light as a plain lamp",
        description="Record frames losslessly (FFV1 in Matroska, encoded in a worker thread with PyAV) from a "
                    "bounded RAM buffer that spills to disk (or stops, --overflow stop) rather than drop a frame. "
                    "Keys on a terminal: l light on/off, r record/pause, e exit. Ctrl-C and SIGTERM leave a "
                    "valid file holding every frame captured. The file plays back as a source of 'run'.",
        epilog="Examples:\n"
               "  antiscatter record camera tank.mkv --size 728x544 --fps 60 --light on --output framebuffer\n"
               "  antiscatter record sim test.mkv --seconds 5 --web 8080\n"
               "  antiscatter record test.mkv --source sim --seconds 5   (the older form)",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    rec.add_argument("source", nargs="?", default=None, metavar="SOURCE", help="camera, webcam:N, a video file "
                     "or sim (default sim), as run takes it")
    rec.add_argument("out", metavar="OUT.mkv", help="the .mkv file to write")
    rec.add_argument("--source", dest="source_option", metavar="SOURCE", help="the source as an option (the older "
                     "form, still accepted): the same as the positional SOURCE")
    rec.add_argument("--size", metavar="WxH", help="capture size (camera, webcam, sim)")
    rec.add_argument("--fps", type=float, default=30.0, help="capture rate; paces sim and video (default 30)")
    rec.add_argument("--seconds", type=float, default=0.0, help="stop after S seconds (default: no limit)")
    rec.add_argument("--frames", type=int, default=0, help="stop after N frames (default: no limit)")
    rec.add_argument("--light", choices=("on", "off"), default="on", help="the lamp at the start (default on)")
    rec.add_argument("--paused", action="store_true", help="start without recording (r or the panel starts it)")
    rec.add_argument("-o", "--output", action="append", metavar="NAME",
                     help="light output(s) driven as a plain lamp: framebuffer[:/dev/fbN], kms, none (default)")
    rec.add_argument("--buffer-mb", type=float, default=512.0, help="RAM for frames waiting to be encoded (default 512)")
    rec.add_argument("--overflow", choices=("spill", "stop"), default="spill",
                     help="when the buffer is full: spill to disk in order (default) or stop recording")
    rec.add_argument("--camera-colour", action="store_true", help="BGR from the camera instead of the Y plane")
    rec.add_argument("--camera-exposure-ms", type=float, help="fixed camera exposure, ms (automatic exposure and "
                     "gain off; default: automatic)")
    rec.add_argument("--camera-gain", type=float, help="analogue gain with a fixed exposure, 1-64 (default 1)")
    rec.add_argument("--web", metavar="[HOST:]PORT", help="serve the control panel (127.0.0.1 unless a host is given)")
    rec.add_argument("--overwrite", action="store_true", help="replace an existing file (default: refused, a "
                     "recording is never overwritten)")
    rec.add_argument("--mcap", metavar="FILE.mcap", help="also every recorded frame as a ROS 2 CompressedImage "
                     "(PNG) with the recorder's figures, in an MCAP file (pip install 'antiscatter[mcap]')")

    an = commands.add_parser(
        "analyse", help="survey footage on Dask: particles per frame, second and litre, size spectra, turbidity",
        description="Run every frame of videos and frame folders through the default detector (single-frame) on "
                    "a Dask cluster, one task a chunk of frames (videos cut at keyframes), and write per file and "
                    "over all: Parquet tables (frames, particles, time bins, ESD size spectra), summary.csv and "
                    "plots. Finished chunks are kept in OUT/chunks/: a stopped run resumes. Exit code 0; 2 for "
                    "bad input; 3 when an input could not be read (named in the summary and skipped) or was "
                    "damaged partway; 130 on Ctrl-C.",
        epilog="Examples:\n"
               "  antiscatter analyse dives/*.mkv --out survey/\n"
               "  antiscatter analyse @files.txt frames/ --out survey/ --workers 2 --near-m 0.3 --far-m 1.2\n"
               "  antiscatter analyse dives/*.mkv --out survey/ --scheduler tcp://10.0.0.5:8786",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    an.add_argument("inputs", nargs="+", metavar="INPUT", help="video files, frame folders, globs (quoted), "
                    "@list.txt (one of those a line)")
    an.add_argument("--out", required=True, metavar="DIR", help="folder to write (made if absent)")
    an.add_argument("--config", metavar="FILE.toml", help="an [analyse] section whose keys are the flags' names "
                    "with underscores (hfov_deg = 63, near_m = 0.3, ...); flags override it")
    an.add_argument("--workers", type=int, help="local Dask worker processes (default: one per core)")
    an.add_argument("--scheduler", metavar="ADDRESS", help="an existing Dask scheduler, e.g. tcp://host:8786 "
                    "(default: a local cluster)")
    an.add_argument("--chunk-frames", type=int, help="frames per task, about; chunks start at keyframes (default 300)")
    an.add_argument("--fps", type=float, help="frame rate of frame folders (default 60; videos: their timestamps)")
    an.add_argument("--bin-s", type=float, help="time bin, seconds (default 10)")
    an.add_argument("--hfov-deg", type=float, help="the camera's horizontal field of view, degrees (default 63)")
    an.add_argument("--vfov-deg", type=float, help="vertical field of view, degrees (default: from hfov and "
                    "the frame's aspect)")
    an.add_argument("--near-m", type=float, help="nearest distance counted, m (default 0.3)")
    an.add_argument("--far-m", type=float, help="farthest distance counted, m (default 1.5)")
    an.add_argument("--reference-m", type=float, help="distance at which pixels are sized, m (default: the middle "
                    "of near..far)")
    an.add_argument("--classes-mm", metavar="LOW:HIGH", help="ESD range of the UVP size classes, mm (default: "
                    "one pixel to 100 pixels across)")
    an.add_argument("--no-plots", dest="plots", action="store_false", help="write no PNG figures")
    an.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")

    tw = commands.add_parser(
        "twin", help="closed-loop digital twin: backscatter removed and scene light kept, per configuration",
        description="Run the system in a simulated loop of camera, processing latency and projector "
                    "(pinhole camera and projector -- or a projector lens --, baseline, projector refreshes) and "
                    "report how much light "
                    "the pattern withholds from particles and keeps on the scene, for full light, seed and "
                    "default detectors with identity mapping, and the default detector with the exact "
                    "geometric (calibrated) mapping under each strategy (none, dim, pulse, flash, coast) with and "
                    "without prediction.")
    tw.add_argument("--preset", default="mixed", help="simulator preset (default mixed)")
    tw.add_argument("--frames", type=int, default=90, help="camera frames per configuration (default 90)")
    tw.add_argument("--seed", type=int, default=1, help="random seed (default 1)")
    tw.add_argument("--size", default="800x600", metavar="WxH", help="camera frame size (default 800x600)")
    tw.add_argument("--baseline-m", type=float, default=0.12, help="camera-projector baseline, m (default 0.12; "
                    "0 = co-located through a beamsplitter)")
    tw.add_argument("--latency-ms", type=float, default=5.0, help="processing latency for all runs (default 5)")
    tw.add_argument("--projector-hz", type=float, default=120.0, help="projector refresh (default 120)")
    tw.add_argument("--camera-hz", type=float, default=60.0, help="camera frame rate; the projector's refresh a "
                    "whole multiple of it (default 60)")
    tw.add_argument("--hfov-deg", type=float, default=63.0, help="the camera's horizontal field of view, degrees "
                    "(default 63: the IMX296 behind a 6 mm lens)")
    tw.add_argument("--throw-ratio", type=float, default=1.2, help="the projector's throw ratio, distance / image "
                    "width (default 1.2)")
    tw.add_argument("--background-m", type=float, default=3.0, help="distance of the background surface, m "
                    "(default 3)")
    tw.add_argument("--exposure-ms", type=float, help="camera exposure (default 4, or one projector refresh if "
                    "shorter); the light a frame gathers scales with it")
    tw.add_argument("--camera-phase", type=float, metavar="F", help="a free-running camera, each exposure starting "
                    "F (0..1) of a projector refresh after one's light begins (a flip plus the display lag); pulse "
                    "and flash then run as run does on it (the frames exposed before the light is on screen "
                    "skipped, the light on until the frame is read); default: the camera locked to the projector, "
                    "each exposure at a refresh's start")
    tw.add_argument("--camera-lock", action="store_true", help="with pulse and flash, the loop run --camera-lock "
                    "runs once its lock holds (one thread: each exposure light at the flip whose light covers the "
                    "next exposure it can reach) instead of the locked ideal")
    tw.add_argument("--display-lag-ms", type=float, default=0.0, help="how long after a flip its image is light on "
                    "the scene, ms (default 0; a DLP projector that formats a frame while it shows the last lags "
                    "a refresh)")
    tw.add_argument("--flash-level", type=float, default=0.25, help="brightness of the detection flash in the "
                    "flash runs, 0..1 (default 0.25; with a fast projector a full 1.0 flash is short)")
    tw.add_argument("--dim-level", type=float, default=0.1, help="light left in dim and pulsed holes, 0..1 "
                    "(default 0.1, as run)")
    tw.add_argument("--min-worth", type=float, default=MIN_WORTH, help="depth probing: a hole is drawn only where "
                    "the share of the backscatter it withholds is at least this many times the share of the scene "
                    f"light it takes (default {MIN_WORTH:g}, as run; one probing run always draws every hole)")
    tw.add_argument("--rest", type=int, help="adaptive levels: frames a confirmed track's hole stays "
                    f"fully dark after each frame that found its particle (default {REST} with pulsed holes, "
                    f"{DIM_REST} with dim ones, as run; 0 = always dimmed; not while probing)")
    tw.add_argument("--grow", type=float, default=GROW, help="holes grow in proportion to their size, as run --grow "
                    f"(default {GROW:g}, as run; 0 = off)")
    tw.add_argument("--grow-from", type=float, default=GROW_FROM, help=f"as run --grow-from (default {GROW_FROM:g})")
    tw.add_argument("--projector-size", default="1280x800", metavar="WxH", help="projector size (default 1280x800)")
    tw.add_argument("--projector-aperture-mm", type=float, default=0.0, help="projector lens aperture diameter, mm "
                    "(default 0: a pinhole projector, sharp at every depth; an ML550-class lens, about 12 mm at "
                    "f/2, is about 6): the pattern is sharp only at --projector-focus-m and blurred elsewhere")
    tw.add_argument("--projector-focus-m", type=float, default=0.0, help="distance the projector is focused at, m "
                    "(default 0: the background's, 3 m)")
    tw.add_argument("--plot", metavar="FILE.png", help="also draw backscatter removed and scene light kept "
                    "against latency, against baseline and against particle speed (a current across the view), "
                    "and with a projector lens against the distance it is focused at")
    tw.add_argument("--calibration", metavar="FILE", help="use this calibration for the calibrated runs (default: "
                    "the twin's exact geometry); its error against the true geometry is reported")
    tw.add_argument("--json", action="store_true", help="print {\"runs\": [...]}")

    ca = commands.add_parser(
        "calibrate", help="camera-to-projector calibration with Gray-code stripes on a flat target",
        description="Project the Gray-code sequence on a flat target, capture it, decode which projector pixel "
                    "lit each camera pixel and fit the camera-to-projector homography; with the target at two "
                    "depths, also the baseline and the depth-aware mapping. --twin calibrates the digital twin "
                    "and reports the error against its true geometry; otherwise the projector output and the "
                    "camera source are used (you are asked to place the target at each depth).")
    ca.add_argument("out", help="calibration file to write (JSON), for run/twin --calibration")
    ca.add_argument("--twin", action="store_true", help="calibrate the digital twin instead of hardware")
    ca.add_argument("--depths", default="0.5,2.0", help="target distances in metres (default 0.5,2.0)")
    ca.add_argument("--board", metavar="COLSxROWS:SQUARE_M", help="calibrate fully with a checkerboard instead "
                    "of a plain target (Moreno-Taubin: camera and projector intrinsics and their pose, "
                    "stereoCalibrate), e.g. 9x6:0.04 = 9 x 6 inner corners, 4 cm squares")
    ca.add_argument("--poses", type=int, default=8, help="with --board: board poses (default 8, at least 3)")
    ca.add_argument("--baseline-m", type=float, default=0.12, help="twin: camera-projector baseline (default 0.12)")
    ca.add_argument("--size", default="800x600", metavar="WxH", help="camera frame size (default 800x600)")
    ca.add_argument("--projector-size", default="1280x800", metavar="WxH", help="projector size (default 1280x800)")
    ca.add_argument("--hfov-deg", type=float, default=63.0, help="camera horizontal field of view (default 63)")
    ca.add_argument("--source", default="camera", help="hardware: frame source (default camera)")
    ca.add_argument("-o", "--output", action="append", metavar="NAME", help="hardware: the projector output "
                    "(default framebuffer)")
    ca.add_argument("--step", type=int, default=8, help="decode every Nth camera pixel (default 8)")

    dl = commands.add_parser(
        "display-lag", help="the projector's lag from a flip to its light on the scene, measured with the camera",
        description="Show black, then white, on the projector (output kms, whose flips are timed) while the "
                    "camera looks at what it lights, and time the white's onset inside the camera's exposures "
                    "against the flip: the value for [pattern] display_lag_ms, which pulse, flash and "
                    "--camera-lock count.")
    dl.add_argument("--size", default="728x544", metavar="WxH", help="camera frame size (default 728x544)")
    dl.add_argument("--camera-fps", type=float, default=60.0, help="camera frame rate (default 60)")
    dl.add_argument("--camera-exposure-ms", type=float, default=15.0, help="fixed camera exposure, ms (default 15: "
                    "near the frame period, so the onset falls inside an exposure)")
    dl.add_argument("--refresh-hz", type=float, default=120.0, help="the projector's refresh rate (default 120)")
    dl.add_argument("--trials", type=int, default=12, help="black-to-white trials (default 12)")

    lc = commands.add_parser(
        "lock-check", help="whether the camera locks to the projector as --camera-lock needs, seen by the camera",
        description="Run the camera lock of run --camera-lock with the camera looking at what the projector "
                    "(output kms) lights: white at the flip whose light covers each next exposure, black after. "
                    "Once the lock holds, every exposure must be lit whole; one lit in part says the sensor's "
                    "timestamps or the display lag are off, no lock that the frame durations are not applied. "
                    "Exit 0 when it passes, 1 when it does not.")
    lc.add_argument("--size", default="728x544", metavar="WxH", help="camera frame size (default 728x544)")
    lc.add_argument("--camera-fps", type=float, default=60.0, help="camera frame rate (default 60)")
    lc.add_argument("--camera-exposure-ms", type=float, default=4.0,
                    help="fixed camera exposure, ms, inside one refresh (default 4)")
    lc.add_argument("--refresh-hz", type=float, default=120.0, help="the projector's refresh rate (default 120)")
    lc.add_argument("--display-lag-ms", type=float, default=0.0,
                    help="[pattern] display_lag_ms, as measured by display-lag (default 0)")
    lc.add_argument("--frames", type=int, default=240, help="frames to run the lock for (default 240)")

    be = commands.add_parser(
        "bench", help="per-stage latency of every detector, side by side (the report's table 1)",
        description="Time every detector's stages on the same frames, interleaved: the simulator's at 800x600 "
                    "and 1456x1088, or any SOURCE run takes; report mean, sd, median, p99 and max in "
                    "microseconds, throughput relative to seed, and the frame-copy and chain floors.")
    be.add_argument("source", nargs="?", metavar="SOURCE",
                    help="time on this source's frames instead of the simulator's: a folder of frames, a video "
                         "file or sim (its first --distinct frames, played forwards and back)")
    be.add_argument("--distinct", type=int, default=20, help="different frames in the pool: read from SOURCE, or "
                    "rendered per size (default 20)")
    be.add_argument("--frames", type=int, default=200, help="frames timed per size (default 200)")
    be.add_argument("--detectors", help="comma-separated names (default: all)")
    be.add_argument("--sizes", help="simulator frame sizes (default 800x600,1456x1088; not with SOURCE)")
    be.add_argument("--threads", type=int, default=1, help="OpenCV threads, 1 to four per CPU (default 1, as one "
                    "Pi core)")
    be.add_argument("--input", choices=("bgr", "y"), default="bgr", help="frames as bgr (video, simulator, "
                    "webcam; default) or y: the luma plane alone, as the Pi camera's YUV420 stream gives it")
    be.add_argument("--modes", action="store_true", help="instead: the simulator through every execution "
                    "mode of run (single, threads): throughput, end-to-end latency p50/p99/max, drops")
    be.add_argument("--vehicle", action="store_true", help="with --modes: run as on the vehicle (auto with the "
                    "camera: tracking with prediction, dim holes at their own levels), not as for files")
    be.add_argument("--json", action="store_true", help="print the results as JSON")
    be.add_argument("--plot", metavar="FILE.png", help="per-stage box plot")

    from .service import add_service_parser
    add_service_parser(commands)
    for command in commands.choices.values():  # also after the command: antiscatter evaluate ... --quiet
        _add_verbosity(command, argparse.SUPPRESS)
    return parser


def _logger(command: str):
    """The logger of a command's diagnostics (``antiscatter.COMMAND``): notes on stderr, not its results."""
    from .console import LOGGER

    return LOGGER.getChild(command)


def _size_arg(text: str, flag: str) -> tuple[int, int]:
    """``WxH`` from a flag, or a one-line UsageError naming the flag."""
    from .config import parse_size

    try:
        return parse_size(text, key=flag)
    except ValueError as exc:
        raise UsageError(str(exc)) from None


def _frame_size_arg(text: str, flag: str) -> tuple[int, int]:
    """``WxH`` of camera frames from a flag, within the frame-size limits every command shares
    (:func:`~antiscatter.detection.check_frame_size`), or a one-line UsageError naming the flag."""
    from .detection import check_frame_size

    size = _size_arg(text, flag)
    check_frame_size(*size, what=f"{flag}: frames", error=UsageError)
    return size


def _projector_size_arg(text: str, flag: str = "--projector-size") -> tuple[int, int]:
    """``WxH`` of the projector from a flag, each side within ``MAX_PROJECTOR_SIDE`` as ``run`` allows."""
    from .config import MAX_PROJECTOR_SIDE

    size = _size_arg(text, flag)
    if max(size) > MAX_PROJECTOR_SIDE:
        raise UsageError(f"{flag} {text}: too large, allowed each side 1..{MAX_PROJECTOR_SIDE}")
    return size


def _detector_from(args: argparse.Namespace):
    from .config import build_section, parse_param
    from .detection import detector_entry, make_detector

    name = args.detector or DEFAULT_DETECTOR
    entry = detector_entry(name)
    values = dict(parse_param(p, entry.params, detector=name) for p in args.param)
    params = build_section(entry.params, values, prefix=f"detector.{name}")
    return name, params, make_detector(name, params)


def _evaluate(args: argparse.Namespace) -> int:
    from pathlib import Path

    from .evaluate import Matching, evaluate_pairs, summarise
    from .evaluate.reference import msrb_pairs, pair_files
    from .evaluate.report import format_summary, plot_evaluation, scoreboard, sweep_detector, write_frame_csv
    from .simulate.catalogue import load_catalogue

    csv_pair = bool(args.detections or (args.truth and not args.folder))  # scored as they are
    modes = [csv_pair, bool(args.folder), bool(args.degraded or args.clean), bool(args.scenario),
             bool(args.catalogue), bool(args.heldout)]
    if sum(modes) != 1:
        raise UsageError("give exactly one input: --truth with --detections, a SOURCE (with --truth unless it "
                         "is a simulator output folder), --degraded with --clean, --scenario NAME, --heldout SPLIT, "
                         "or --catalogue")
    if args.heldout_export and not args.heldout:
        raise UsageError("--heldout-export goes with --heldout SPLIT (the split or splits to write)")
    if args.heldout_frames is not None and not (args.heldout or args.catalogue):
        raise UsageError("--heldout-frames goes with --heldout or --catalogue")
    if args.fps is not None and not (args.fps > 0 and np.isfinite(args.fps)):
        raise UsageError(f"--fps {args.fps}: allowed a positive number")
    if args.frames is not None and args.frames <= 0:
        raise UsageError(f"--frames {args.frames}: allowed a positive number")
    if args.csv:
        check_output_path(args.csv, "--csv")
    if args.plot:
        from .bench import plot_suffixes
        check_output_path(args.plot, "--plot", suffixes=plot_suffixes())
    if not (math.isfinite(args.rise) and args.rise >= 0):
        raise UsageError(f"--rise {args.rise}: allowed a number of grey levels >= 0")
    if args.min_area < 1:
        raise UsageError(f"--min-area {args.min_area}: allowed >= 1 pixel")
    m = Matching(min_gate=args.min_gate, gate_scale=args.gate_scale, min_visibility=args.min_visibility,
                 min_snr=args.min_snr, margin=args.margin)
    title = ""
    sweep = None
    if args.catalogue:
        from .detection import DETECTORS

        version, scenarios = load_catalogue(args.catalogue_file)
        data_dir = _data_dir(args)
        if args.heldout_frames is not None and args.heldout_frames < 0:
            raise UsageError(f"--heldout-frames {args.heldout_frames}: allowed >= 0 (0 leaves the table out)")
        real = msrb_pairs(data_dir / "msrb") if (data_dir / "msrb").is_dir() else []
        detectors = [args.detector] if args.detector else list(DETECTORS)
        if args.twin_frames < 0:
            raise UsageError(f"--twin-frames {args.twin_frames}: allowed >= 0 (0 leaves the table out)")
        if args.twin_seeds < 1:
            raise UsageError(f"--twin-seeds {args.twin_seeds}: allowed >= 1")
        if args.twin_long_frames < 0:
            raise UsageError(f"--twin-long-frames {args.twin_long_frames}: allowed >= 0 (0 leaves the table out)")
        if args.twin_long_seeds < 1:
            raise UsageError(f"--twin-long-seeds {args.twin_long_seeds}: allowed >= 1")
        report = check_output_path(args.report, "--report")  # before the long work; no folder is made
        if not real:  # (after every check: bad input stays one line)
            _logger("evaluate").warning(f"no real image pairs in {data_dir / 'msrb'} (--data DIR): the scoreboard's "
                                        "real-image rows are left out")
        bench_results = None
        if args.bench_frames:  # BGR frames (files, the simulator, webcams) and the Pi camera's Y plane
            from .bench import bench
            bench_results = [bench(detectors=detectors, frames=args.bench_frames, input=kind) for kind in ("bgr", "y")]
        markdown, data = scoreboard(scenarios=scenarios, catalogue_version=version, detectors=detectors,
                                    real_pairs=real, matching=m, bench_results=bench_results,
                                    frames_limit=args.frames, log=_logger("evaluate").info,
                                    twin_frames=args.twin_frames, twin_seeds=args.twin_seeds,
                                    twin_long_frames=args.twin_long_frames, twin_long_seeds=args.twin_long_seeds,
                                    heldout=args.heldout_frames != 0, heldout_frames=args.heldout_frames or None,
                                    heldout_data=data_dir)
        from .writing import write_whole

        write_whole(report, markdown.encode())
        print(json_text(data) if args.json else markdown)
        _logger("evaluate").info(f"wrote {report}")
        return 0
    extra: dict = {}
    if args.track and not (args.scenario or args.folder):
        raise UsageError("--track goes with --scenario or a SOURCE (a detections CSV with track_id is scored for "
                         "tracking by itself)")
    if args.heldout:
        return _evaluate_heldout(args, m)
    if csv_pair:
        if not (args.truth and args.detections):
            raise UsageError("--truth and --detections go together")
        from .evaluate.runs import read_csv_pair, score_csv_pair
        from .evaluate.tracking import tracking_summary

        truth, found, frames_range = read_csv_pair(Path(args.truth), Path(args.detections), m)  # read once
        scores = score_csv_pair(truth, found, frames_range, m)
        title = f"{args.detections} against {args.truth}"
        has_ids = any((v[2] >= 0).any() for v in found.values())
        if has_ids:
            if any(t.ids is None or (t.ids < 0).any() for t in truth.values()):
                raise UsageError(f"{args.truth}: tracking figures need the 'Bubble ID' column")
            empty_t = (np.empty(0, np.int64), np.empty((0, 2)), np.empty(0), np.empty(0, bool))
            empty_d = (np.empty((0, 2)), np.empty(0), np.empty(0, np.int64))
            extra["tracking"] = tracking_summary(
                ((truth[f].ids, truth[f].centres, truth[f].radii, truth[f].counted) if f in truth else empty_t)
                + (found.get(f, empty_d)[0], found.get(f, empty_d)[2]) for f in frames_range)
    else:
        name, params, detector = _detector_from(args)
        if args.folder:
            from .evaluate import evaluate_source
            from .evaluate.runs import evaluate_source_tracking

            source = Path(args.folder)
            if not source.exists():
                raise UsageError(f"{source}: no such folder or video file")
            truth_path = Path(args.truth) if args.truth else None
            run = lambda d: evaluate_source(source, d, m, truth_path, args.frames)  # noqa: E731
            title = f"detector {name} on {source}" + (f" against {truth_path}" if truth_path else "")
            if args.track:
                extra.update(evaluate_source_tracking(source, detector, m, truth_path, fps=args.fps,
                                                      limit=args.frames))
        elif args.scenario:
            from .evaluate.runs import evaluate_scenario

            _, scenarios = load_catalogue(args.catalogue_file)
            if args.scenario not in scenarios:
                raise UsageError(f"unknown scenario {args.scenario!r}; allowed: {', '.join(scenarios)}")
            s = scenarios[args.scenario]
            frames = min(s.frames, args.frames) if args.frames else s.frames
            run = lambda d: evaluate_scenario(s.preset, s.size, frames, s.seed, {"d": d}, m)["d"]  # noqa: E731
            title = f"detector {name} on scenario {s.name} ({frames} frames)"
            if args.track:
                from .evaluate.runs import evaluate_tracking, scenario_truth_frames
                from .simulate import make_scene

                fps = make_scene(s.preset, rng=np.random.default_rng(0), size=(8, 8)).fps
                extra.update(evaluate_tracking(scenario_truth_frames(s.preset, s.size, frames, s.seed, m),
                                               detector, m, fps=fps))
        else:
            if not (args.degraded and args.clean):
                raise UsageError("--degraded and --clean go together")
            pairs = pair_files(Path(args.degraded), Path(args.clean))
            run = lambda d: evaluate_pairs(pairs, d, m, rise=args.rise, min_area=args.min_area)  # noqa: E731
            title = f"detector {name} on {len(pairs)} real image pair(s)"
        scores = run(detector)
        if args.plot:
            sweep = sweep_detector(name, params, run)
    summary = summarise(scores)
    if args.csv:
        write_frame_csv(scores, args.csv)
    if args.plot:
        plot_evaluation(args.plot, scores, sweep, title=title)
    if args.json:
        print(json_text({"input": title, "overall": summary, **extra, "frames": [s.row() for s in scores]}))
    else:
        print(format_summary(summary, title=title))
        if "tracking" in extra:
            t = extra["tracking"]
            print(f"  tracking: MOTA {t['mota']:.3f}, IDF1 {t['idf1']:.3f}, identity switches "
                  f"{t['id_switches']}, fragmentations {t['fragmentations']}")
        if "tracking_isolated" in extra:
            t = extra["tracking_isolated"]
            print(f"  tracking of the particles that overlap no other: MOTA {t['mota']:.3f}, IDF1 {t['idf1']:.3f}")
        if "prediction" in extra:
            print("  prediction error: " + ", ".join(
                f"{k} frames {v['mean_px']:.2f} px (p95 {v['p95_px']:.2f})" for k, v in extra["prediction"].items()))
    return 0


def _data_dir(args: argparse.Namespace):
    """The folder holding msrb/: ``--data`` (it must exist), else ../shared/data."""
    from pathlib import Path

    data_dir = Path(args.data) if args.data else Path("../shared/data")
    if args.data and not data_dir.is_dir():
        raise UsageError(f"--data {data_dir}: no such folder")
    return data_dir


def _evaluate_heldout(args: argparse.Namespace, m) -> int:
    """``evaluate --heldout``: the detector and seed on the held-out material, or its export."""
    import time
    from pathlib import Path

    from .detection import make_detector
    from .evaluate.heldout import SPLITS, cases, evaluate_heldout, export, require_skimage
    from .evaluate.report import format_heldout

    if args.frames is not None:
        raise UsageError("--frames: with --heldout, give --heldout-frames (frames per case)")
    for flag, value in (("--csv", args.csv), ("--plot", args.plot)):
        if value:
            raise UsageError(f"{flag}: does not go with --heldout (--json gives every case and frame time)")
    if args.heldout_frames is not None and args.heldout_frames < 1:
        raise UsageError(f"--heldout-frames {args.heldout_frames}: allowed >= 1 with --heldout")
    splits = SPLITS if args.heldout == "both" else (args.heldout,)
    data_dir = _data_dir(args)
    require_skimage()
    if args.heldout_export:
        out = Path(args.heldout_export)
        if out.exists() and not out.is_dir():
            raise UsageError(f"--heldout-export {out}: is a file, expected a folder")
        if not out.parent.is_dir():
            raise UsageError(f"--heldout-export {out}: the folder {out.parent} does not exist")
        for split in splits:
            for case in cases(split):
                if (out / split / case.name).exists():
                    raise UsageError(f"--heldout-export {out}: {out / split / case.name} already exists; "
                                     "allowed a new folder")
        for split in splits:
            written = export(split, out, frames=args.heldout_frames, data=data_dir)
            print(f"wrote {len(written)} cases of held-out {split} to {out / split}: "
                  + ", ".join(path.name for path in written))
        return 0
    name, params, detector = _detector_from(args)
    detectors = {name: detector}
    if name != "seed":
        detectors["seed"] = make_detector("seed")
    results = []
    for split in splits:
        start = time.perf_counter_ns()
        result = evaluate_heldout(split, detectors, m, frames=args.heldout_frames, data=data_dir)
        result["seconds"] = (time.perf_counter_ns() - start) / 1e9
        results.append(result)
    title = f"detector {name}" + (f" ({', '.join(args.param)})" if args.param else "") + " and seed"
    if args.json:
        print(json_text({"input": f"held-out {args.heldout}", "detector": name, "params": list(args.param),
                         "matching": vars(m), "splits": results}))
    else:
        print(format_heldout(results, title=title))
    return 0


def _bench(args: argparse.Namespace) -> int:

    from .bench import bench, format_bench, plot_bench
    from .detection import DETECTORS, check_threads, detector_entry

    if args.frames <= 0:
        raise UsageError(f"--frames {args.frames}: allowed a positive number")
    check_threads(args.threads, f"--threads {args.threads}", error=UsageError)
    if args.vehicle and not args.modes:
        raise UsageError("--vehicle: goes with --modes (the per-stage bench times the detectors alone)")
    if not 2 <= args.distinct <= 1000:
        raise UsageError(f"--distinct {args.distinct}: allowed 2..1000 frames")
    if args.source is not None and (args.sizes or args.modes):
        raise UsageError(f"SOURCE {args.source}: goes without --sizes and --modes (its frames have their own size)")
    if args.plot:
        from .bench import plot_suffixes
        check_output_path(args.plot, "--plot", suffixes=plot_suffixes())
    names = [n.strip() for n in args.detectors.split(",")] if args.detectors else list(DETECTORS)
    for n in names:
        detector_entry(n)
    sizes = []
    for text in (args.sizes or "800x600,1456x1088").split(","):
        w, h = _frame_size_arg(text.strip(), "--sizes")
        sizes.append((w, h, "fullres" if w * h > 800 * 600 else "mixed"))
    if args.modes:
        from .bench import bench_modes, format_modes, machine_description

        modes = bench_modes(frames=args.frames, sizes=tuple(sizes), detector=names[0] if args.detectors else "contrast",
                            vehicle=args.vehicle)
        print(json_text({"machine": machine_description(), "modes": modes}) if args.json
              else format_modes(modes))
        return 0
    result = bench(detectors=names, frames=args.frames, threads=args.threads, sizes=tuple(sizes),
                   input=args.input, source=args.source, distinct=args.distinct)
    if args.plot:
        plot_bench(result, args.plot)
    print(json_text(result.as_dict()) if args.json else format_bench(result))
    return 0


def _calibrate(args: argparse.Namespace) -> int:
    import math

    from .calibration import TwinRig, calibrate_planes, mapping_error_px
    from .twin import TwinGeometry

    try:
        depths = [float(d) for d in args.depths.split(",")]
    except ValueError:
        raise UsageError(f"--depths {args.depths!r}: expected distances in metres, e.g. 0.5,2.0") from None
    size = _frame_size_arg(args.size, "--size")
    projector = _projector_size_arg(args.projector_size)
    if not depths or not all(math.isfinite(d) and d > 0 for d in depths) or len(set(depths)) != len(depths):
        raise UsageError(f"--depths {args.depths!r}: allowed distinct positive distances in metres")
    if args.step < 1:
        raise UsageError(f"--step {args.step}: allowed >= 1")
    try:  # the twin's own checks of the field of view and the baseline, for hardware too
        TwinGeometry(camera_size=size, projector_size=projector, baseline_m=args.baseline_m, hfov_deg=args.hfov_deg)
    except ValueError as exc:
        key, _, why = str(exc).partition(":")
        raise UsageError(f"--{key.replace('_', '-')}:{why}") from None
    if not args.twin and not sys.stdin.isatty():
        raise UsageError("asks for each target placement and waits for Enter: needs an interactive terminal on "
                         "stdin (--twin calibrates the digital twin without one)")
    check_output_path(args.out, "calibrate")
    focal = (size[0] / 2) / math.tan(math.radians(args.hfov_deg) / 2)
    if args.board:
        return _calibrate_board(args, size, projector)
    if args.twin:
        geometry = TwinGeometry(camera_size=size, projector_size=projector, baseline_m=args.baseline_m,
                                hfov_deg=args.hfov_deg)
        captures = {d: TwinRig(geometry, d, rng=np.random.default_rng(i)).capture for i, d in enumerate(depths)}
        calibration = calibrate_planes(captures, camera_size=size, projector_size=projector,
                                       camera_focal_px=focal, step=args.step)
    else:
        with _hardware_rig(args, size) as (rig, camera_size):
            captures = {}
            for d in depths:
                input(f"place the flat target {d:g} m in front of the camera, then press Enter ")
                captures[d] = rig.capture  # captured in calibrate_planes, in depth order
            calibration = calibrate_planes(captures, camera_size=camera_size, projector_size=projector,
                                           camera_focal_px=focal, step=args.step)
    calibration.save(args.out)
    print(f"wrote {args.out}: fit error (median, projector px) "
          + ", ".join(f"{d:g} m {e:.2f}" for (d, _), e in zip(calibration.planes, calibration.errors_px))
          + (f"; baseline {calibration.baseline_m:.4f} m" if calibration.baseline_m is not None else ""))
    if args.twin:
        for d in sorted(set(depths) | {calibration.working_depth_m}):
            error = mapping_error_px(calibration.mapping_at(d), geometry.plane_mapping(d), size, projector)
            print(f"  against the twin's true geometry at {d:.2f} m: mean {error['mean_px']:.2f} px, "
                  f"max {error['max_px']:.2f} px")
    return 0


@contextlib.contextmanager
def _hardware_rig(args: argparse.Namespace, size: tuple[int, int]):
    """(the vehicle's projector and camera as a calibration rig, the camera's frame size); the
    outputs and the source are closed however calibration ends."""
    from .calibration import HardwareRig
    from .outputs import open_output
    from .sources import open_source

    with open_source(args.source, size=size) as source:
        outputs = [open_output(o) for o in (args.output or ["framebuffer"])]
        try:
            yield HardwareRig(source, outputs), source.size
        finally:
            for o in outputs:
                o.close()


def _parse_board(text: str):
    from .calibration import Board

    try:
        corners, square = text.lower().split(":")
        cols, rows = (int(v) for v in corners.split("x"))
        board = Board(cols, rows, float(square))
    except ValueError:
        board = None
    if board is None or min(board.cols, board.rows) < 3 or not board.square_m > 0:
        raise UsageError(f"--board {text!r}: expected COLSxROWS:SQUARE_M with at least 3 x 3 inner corners and "
                         "a square size in metres, e.g. 9x6:0.04")
    return board


def _calibrate_board(args: argparse.Namespace, size: tuple[int, int], projector: tuple[int, int]) -> int:
    """``calibrate --board``: the full stereo calibration (twin or hardware)."""
    from .calibration import BoardRig, calibrate_board, mapping_error_px, twin_board_poses
    from .twin import TwinGeometry

    board = _parse_board(args.board)
    if args.poses < 3:
        raise UsageError(f"--poses {args.poses}: allowed >= 3")
    if args.twin:
        geometry = TwinGeometry(camera_size=size, projector_size=projector, baseline_m=args.baseline_m,
                                hfov_deg=args.hfov_deg)
        rigs = [BoardRig(geometry, r, t, board=board, rng=np.random.default_rng(i))
                for i, (r, t) in enumerate(twin_board_poses(args.poses, board=board, baseline_m=args.baseline_m))]
        calibration = calibrate_board([rig.capture for rig in rigs], board=board, camera_size=size,
                                      projector_size=projector)
    else:
        with _hardware_rig(args, size) as (rig, camera_size):
            def posed(k: int):
                asked = []

                def capture(pattern: np.ndarray) -> np.ndarray:
                    if not asked:  # calibrate_board starts each pose with its first capture
                        asked.append(True)
                        input(f"pose {k + 1} of {args.poses}: hold the board tilted a new way, wholly in view "
                              "and lit, then press Enter ")
                    return rig.capture(pattern)
                return capture

            calibration = calibrate_board([posed(k) for k in range(args.poses)], board=board,
                                          camera_size=camera_size, projector_size=projector)
    calibration.save(args.out)
    s = calibration.stereo
    print(f"wrote {args.out}: reprojection rms camera {calibration.errors_px[0]:.2f} px, projector "
          f"{calibration.errors_px[1]:.2f} px, pair {calibration.errors_px[2]:.2f} px; focal lengths camera "
          f"{s.camera_matrix[0, 0]:.1f} px, projector {s.projector_matrix[0, 0]:.1f} px; baseline "
          f"{calibration.baseline_m:.4f} m")
    if args.twin:
        print(f"  twin truth: focal lengths {geometry.camera_focal:.1f} px, {geometry.projector_focal:.1f} px; "
              f"baseline {geometry.baseline_m:.4f} m")
        for d in (0.5, 1.0, 2.0):
            error = mapping_error_px(calibration.mapping_at(d), geometry.plane_mapping(d), size, projector)
            print(f"  against the twin's true geometry at {d:.2f} m: mean {error['mean_px']:.2f} px, "
                  f"max {error['max_px']:.2f} px")
    return 0


def _twin(args: argparse.Namespace) -> int:
    import dataclasses

    from .config import parse_size
    from .detection import check_frame_size
    from .simulate import PRESETS
    from .twin import TwinGeometry, default_runs, simulate_loop

    if args.preset not in PRESETS or args.preset == "seed":
        allowed = ", ".join(p for p in PRESETS if p != "seed")
        raise UsageError(f"--preset {args.preset!r}: allowed a realistic preset ({allowed}); the twin needs 3-D particles")
    if args.frames <= 0:
        raise UsageError(f"--frames {args.frames}: allowed a positive number")
    if not (math.isfinite(args.latency_ms) and args.latency_ms >= 0):
        raise UsageError(f"--latency-ms {args.latency_ms}: allowed a number >= 0")
    if args.plot:
        from .bench import plot_suffixes
        check_output_path(args.plot, "--plot", suffixes=plot_suffixes())
    for key in ("flash_level", "dim_level"):
        if not 0 <= getattr(args, key) <= 1:
            raise UsageError(f"--{key.replace('_', '-')} {getattr(args, key)}: allowed 0..1")
    if not (math.isfinite(args.min_worth) and args.min_worth >= 0):
        raise UsageError(f"--min-worth {args.min_worth}: allowed a number >= 0 (0 = every hole drawn)")
    if args.rest is not None and args.rest < 0:
        raise UsageError(f"--rest {args.rest}: allowed a whole number of frames >= 0")
    for key in ("projector_aperture_mm", "projector_focus_m", "grow", "grow_from", "display_lag_ms"):
        value = getattr(args, key)
        if not (math.isfinite(value) and value >= 0):
            raise UsageError(f"--{key.replace('_', '-')} {value}: allowed a number >= 0")
    try:
        size = parse_size(args.size, key="--size")
        check_frame_size(*size, what="--size: camera frames")
        projector = _projector_size_arg(args.projector_size)
        exposure = (args.exposure_ms / 1e3 if args.exposure_ms is not None
                    else min(0.004, 1.0 / args.projector_hz) if args.projector_hz > 0 else 0.004)
        geometry = TwinGeometry(camera_size=size, projector_size=projector, baseline_m=args.baseline_m,
                                projector_hz=args.projector_hz, camera_hz=args.camera_hz, exposure_s=exposure,
                                hfov_deg=args.hfov_deg, throw_ratio=args.throw_ratio, background_m=args.background_m,
                                projector_aperture_m=args.projector_aperture_mm / 1e3,
                                projector_focus_m=args.projector_focus_m, camera_phase=args.camera_phase,
                                camera_lock=args.camera_lock, display_lag_s=args.display_lag_ms / 1e3)
    except ValueError as exc:
        raise UsageError(f"twin: {exc}") from None
    calibration = None
    extra = {}
    if args.calibration:
        from .calibration import load_calibration, mapping_error_px

        calibration = load_calibration(args.calibration, sizes=(geometry.camera_size, geometry.projector_size),
                                       user="the twin")
        extra["calibration_error"] = mapping_error_px(calibration.homography,
                                                      geometry.plane_mapping(calibration.working_depth_m),
                                                      geometry.camera_size, geometry.projector_size)
    from .console import progress, write

    configurations = default_runs(args.baseline_m)
    if not args.json:
        print(f"antiscatter twin: preset {args.preset} (seed {args.seed}), {args.frames} frames a configuration; "
              f"camera {size[0]}x{size[1]} at {geometry.camera_hz:g} Hz, projector {projector[0]}x{projector[1]} at "
              f"{geometry.projector_hz:g} Hz; baseline {args.baseline_m:g} m, latency {args.latency_ms:g} ms")
        if calibration is not None:
            error = extra["calibration_error"]
            print(f"calibration {args.calibration}: error at {calibration.working_depth_m:.2f} m: mean "
                  f"{error['mean_px']:.2f}, max {error['max_px']:.2f} projector px")
        print("removed: share of the particles' backscatter the pattern withholds; kept: share of the scene light "
              "it keeps; steady: the same from that frame on (tracks settled)")
        print(_TWIN_HEADER)
    runs = []
    with progress(total=len(configurations) * args.frames, desc="twin") as bar:
        for run in configurations:
            run = dataclasses.replace(run, flash_level=args.flash_level, dim_level=args.dim_level, rest=args.rest,
                                      min_worth=args.min_worth if run.min_worth else 0.0, grow=args.grow,
                                      grow_from=args.grow_from)
            result = simulate_loop(run, geometry=geometry, preset=args.preset, frames=args.frames, seed=args.seed,
                                   latency_ms=args.latency_ms, calibration=calibration, on_frame=bar.update)
            result.pop("series")
            runs.append(result)
            if not args.json:
                write(format_twin_row(result, args.frames))
    if not args.json and args.baseline_m > 0 and any(r["mapping"] == "probe" for r in runs):
        print(f"at a {args.baseline_m:g} m baseline one mapping fits one distance only: holes drawn for the "
              "calibration's working distance miss particles nearer or farther (the calibrated rows); depth "
              "probing (the probe rows) finds each particle's distance; 0 = co-located through a beamsplitter")
    if args.plot:
        from .twin import plot_curves

        extra["curves"] = plot_curves(args.plot, geometry=geometry, preset=args.preset, frames=args.frames,
                                      seed=args.seed, dim_level=args.dim_level, flash_level=args.flash_level)
        if not args.json:
            print(f"wrote {args.plot}")
    if args.json:
        print(json_text({"preset": args.preset, "frames": args.frames, "baseline_m": args.baseline_m,
                         "latency_ms": args.latency_ms, "camera_hz": geometry.camera_hz,
                         "projector_hz": geometry.projector_hz, "hfov_deg": geometry.hfov_deg,
                         "throw_ratio": geometry.throw_ratio, "background_m": geometry.background_m,
                         "camera_phase": args.camera_phase,
                         "camera_lock": args.camera_lock, "display_lag_ms": args.display_lag_ms,
                         "projector_aperture_mm": args.projector_aperture_mm,
                         "projector_focus_m": args.projector_focus_m or geometry.background_m,
                         **extra, "runs": runs}))
    return 0


#: Column titles of ``twin``'s table (see :func:`format_twin_row`).
_TWIN_HEADER = (f"{'detector':<10} {'mapping':<10} {'strategy':<8} {'predict':<7} {'removed':>7} {'kept':>6}  "
                f"{'steady from':>11} {'removed':>7} {'kept':>6}  notes")


def format_twin_row(result: dict[str, Any], frames: int) -> str:
    """One configuration's row of ``twin``'s table: removed and kept over all frames, then steady."""
    notes = f"{result['levels']} levels" if result["levels"] else ""  # dim and pulse only
    if result["min_worth"] == 0:
        notes += ", every hole"  # probing without the holes' worth rule
    if result["frames_processed"] < frames and result["detector"]:  # a free-running camera's skips
        notes = ", ".join(filter(None, (notes, f"{result['frames_processed']} frames read")))
    return (f"{result['detector'] or 'full light':<10} {result['mapping']:<10} {result['strategy']:<8} "
            f"{'yes' if result['predict'] else 'no':<7} {result['backscatter_removed']:>7.3f} "
            f"{result['scene_light_kept']:>6.3f}  {'frame ' + str(result['steady_from_frame']):>11} "
            f"{result['backscatter_removed_steady']:>7.3f} {result['scene_light_kept_steady']:>6.3f}  {notes}").rstrip()


def _record(args: argparse.Namespace) -> int:
    from pathlib import Path

    from .record.command import RecordRequest, record

    if args.source is not None and args.source_option is not None:
        raise UsageError(f"SOURCE {args.source} and --source {args.source_option}: give the source once")
    source = next((s for s in (args.source, args.source_option) if s is not None), "sim")
    size = None
    if args.size:
        size = _size_arg(args.size, "--size")
    for name, value in (("--fps", args.fps), ("--seconds", args.seconds), ("--frames", args.frames),
                        ("--buffer-mb", args.buffer_mb)):
        if not (math.isfinite(value) and value >= 0):
            raise UsageError(f"{name} {value}: allowed a number >= 0")
    request = RecordRequest(out=Path(args.out), source=source, size=size, fps=args.fps,
                            seconds=args.seconds, frames=args.frames, light=args.light == "on",
                            paused=args.paused, outputs=tuple(args.output or ("none",)),
                            buffer_mb=args.buffer_mb, overflow=args.overflow, web=args.web or "",
                            colour=args.camera_colour, exposure_ms=args.camera_exposure_ms, gain=args.camera_gain,
                            overwrite=args.overwrite, mcap=Path(args.mcap) if args.mcap else None)
    from .console import LOGGER, LogStream

    summary = record(request, log=LogStream(LOGGER.getChild("record")))  # type: ignore[arg-type]
    if summary["reason"].startswith("stopped by SIGINT"):
        return 130
    if summary["reason"].startswith("stopped by SIGTERM"):
        return 143
    return 0


def _analyse(args: argparse.Namespace) -> int:
    """``analyse``: flags over an ``[analyse]`` section of --config; exit code 0, or 3 when an input was skipped."""
    import tomllib
    from dataclasses import fields
    from pathlib import Path

    from .analyse.command import AnalyseRequest, analyse
    from .analyse.volume import VolumeModel

    settings: dict[str, Any] = {}
    if args.config:
        try:
            with open(args.config, "rb") as handle:
                section = tomllib.load(handle).get("analyse", {})
        except FileNotFoundError:
            raise UsageError(f"--config {args.config}: no such file") from None
        except (tomllib.TOMLDecodeError, UnicodeDecodeError, IsADirectoryError) as exc:
            raise UsageError(f"--config {args.config}: not a TOML file ({str(exc).splitlines()[0]})") from None
        settings.update(section)
    for name in ("workers", "scheduler", "chunk_frames", "fps", "bin_s", "hfov_deg", "vfov_deg", "near_m", "far_m",
                 "reference_m", "classes_mm"):
        if getattr(args, name) is not None:
            settings[name] = getattr(args, name)
    volume_keys = {f.name for f in fields(VolumeModel)}
    request_keys = {f.name for f in fields(AnalyseRequest)} - {"inputs", "out", "volume", "progress", "plots"}
    unknown = sorted(set(settings) - volume_keys - request_keys)
    if unknown:
        raise UsageError(f"[analyse] {unknown[0]}: unknown key; allowed: {', '.join(sorted(volume_keys | request_keys))}")
    if isinstance(settings.get("classes_mm"), list):  # classes_mm = [0.5, 50] in the TOML file
        settings["classes_mm"] = tuple(settings["classes_mm"])
    if isinstance(settings.get("classes_mm"), str):
        try:
            low, high = (float(v) for v in settings["classes_mm"].split(":"))
        except ValueError:
            raise UsageError(f"--classes-mm {settings['classes_mm']}: expected LOW:HIGH in mm, e.g. 0.5:50") from None
        settings["classes_mm"] = (low, high)
    try:
        volume = VolumeModel(**{k: v for k, v in settings.items() if k in volume_keys})
        request = AnalyseRequest(inputs=tuple(args.inputs), out=Path(args.out), volume=volume, progress=args.progress,
                                 plots=args.plots, **{k: v for k, v in settings.items() if k in request_keys})
    except (ValueError, TypeError) as exc:
        raise UsageError(str(exc)) from None
    from .console import LOGGER, LogStream

    return analyse(request, log=LogStream(LOGGER.getChild("analyse")))["exit_code"]  # type: ignore[arg-type]


def _simulate(args: argparse.Namespace) -> int:
    from pathlib import Path

    from .simulate import PRESETS
    from .simulate.catalogue import load_catalogue
    from .simulate.export import SimulationRequest, simulate

    version, scenarios = load_catalogue(args.catalogue)
    if args.list:
        print("presets:")
        for name, entry in PRESETS.items():
            print(f"  {name:<10} {entry.default_size[0]}x{entry.default_size[1]}  {entry.summary}")
        print(f"scenarios (catalogue version {version}):")
        for s in scenarios.values():
            print(f"  {s.name:<10} preset {s.preset}, {s.size[0]}x{s.size[1]}, {s.frames} frames, seed {s.seed}")
        return 0
    if not args.out:
        raise UsageError("the output folder OUT is required (or --list)")
    preset, frames, seed, size = "seed", 120, 0, None
    if args.scenario:
        if args.scenario not in scenarios:
            raise UsageError(f"unknown scenario {args.scenario!r}; allowed: {', '.join(scenarios)}")
        s = scenarios[args.scenario]
        preset, frames, seed, size = s.preset, s.frames, s.seed, s.size
    preset = args.preset or preset
    if preset not in PRESETS:
        raise UsageError(f"unknown preset {preset!r}; allowed: {', '.join(PRESETS)}")
    frames = args.frames if args.frames is not None else frames
    seed = args.seed if args.seed is not None else seed
    if args.size:
        size = _frame_size_arg(args.size, "--size")
    request = SimulationRequest(out=Path(args.out), preset=preset, frames=frames, seed=seed, size=size,
                                background=args.background, masks=args.masks,
                                video=Path(args.video) if args.video else None, overwrite=args.overwrite)
    try:
        result = simulate(request)
    except (OSError, WriteError) as exc:  # a full disk: one line; the staging folder is gone
        from .writing import write_failed

        failed = exc if isinstance(exc, OSError) else OSError(0, exc.reason)
        raise write_failed(args.out, failed, "nothing written (the partial output removed)") from None
    where = args.video if args.video else f"{args.out}/<frame>.png"
    print(f"wrote {result['frames']} frames of preset {preset} (seed {seed}) to {where}, "
          f"{result['particles']} truth rows to {args.out}/truth.csv"
          + (f", masks to {args.out}/masks" if args.masks else "")
          + f" ({result['fps']:.0f} frames/s)")
    return 0


def _run_config(args: argparse.Namespace):
    from .config import load_config, parse_param
    from .detection import DETECTORS, check_threads

    if args.threads is not None:
        check_threads(args.threads, f"--threads {args.threads}", error=UsageError)

    overrides: dict[str, dict[str, Any]] = {
        "source": {"spec": args.source, "crop": args.crop, "loop": args.loop, "preset": args.preset,
                   "seed": args.seed, "size": args.size, "camera_fps": args.camera_fps,
                   "camera_colour": args.camera_colour, "camera_exposure_ms": args.camera_exposure_ms,
                   "camera_gain": args.camera_gain, "camera_lock": args.camera_lock,
                   "camera_lores": args.camera_lores},
        "detector": {"name": args.detector},
        "pattern": {"margin": args.margin, "grow": args.grow, "grow_from": args.grow_from},
        "track": {"enabled": args.track, "predict": args.predict, "latency_ms": args.latency_ms},
        "light": {"strategy": args.strategy, "dim_level": args.dim_level, "flash_level": args.flash_level,
                  "depth": args.depth, "levels": args.levels, "min_level": args.min_level,
                  "rest": args.rest, "min_worth": args.min_worth},
        "output": {"outputs": tuple(args.output) if args.output else None},
        "run": {"frames": args.frames, "fps": args.fps, "nice": args.nice,
                "metrics": args.metrics, "detections": args.detections, "mode": args.mode,
                "rt_priority": args.rt_priority, "cpus": args.cpus, "mlock": args.mlock,
                "web": args.web, "record_to": args.record_to,
                "mcap": args.mcap, "threads": args.threads},
    }
    if args.projector_size:
        w, h = _size_arg(args.projector_size, "--projector-size")
        overrides["pattern"].update(width=w, height=h)
    if args.mapping and args.calibration:
        raise UsageError("--mapping and --calibration both set the mapping: give one")
    if args.mapping:
        overrides["pattern"]["mapping"] = _read_mapping(args.mapping)
    if args.calibration:
        from .calibration import load_calibration

        calibration = load_calibration(args.calibration)
        overrides["pattern"].update(mapping=calibration.homography.tolist(), width=calibration.projector_size[0],
                                    height=calibration.projector_size[1], calibration=args.calibration)
    base = load_config(args.config, overrides)
    if not args.param:
        return base
    name = base.detector.name
    params = dict(parse_param(p, DETECTORS[name].params, detector=name) for p in args.param)
    return load_config(args.config, overrides, params)


def _read_mapping(path: str) -> list[list[float]]:
    import warnings

    import numpy as np
    from pathlib import Path

    file = Path(path)
    if not file.is_file():
        raise UsageError(f"--mapping {path}: no such file")
    try:
        with warnings.catch_warnings():  # numpy's warning of an empty file would come before our one line
            warnings.simplefilter("ignore")
            matrix = np.loadtxt(file, dtype=np.float64, ndmin=2)
    except (ValueError, UnicodeDecodeError):
        raise UsageError(f"--mapping {path}: not a text file of numbers; expected 3 rows of 3 numbers") from None
    if matrix.shape != (3, 3):
        raise UsageError(f"--mapping {path}: got a {matrix.shape[0]}x{matrix.shape[1]} matrix, expected 3x3")
    return matrix.tolist()


def _display_lag(args: argparse.Namespace) -> int:
    """``display-lag``: the camera times the projector's light against its flips."""
    from .lock import display_lag
    from .outputs import open_output
    from .sources import open_source

    if args.trials < 1:
        raise UsageError(f"--trials {args.trials}: allowed >= 1")
    if not (math.isfinite(args.refresh_hz) and args.refresh_hz > 0):
        raise UsageError(f"--refresh-hz {args.refresh_hz}: allowed a number > 0")
    size = _size_arg(args.size, "--size")
    with open_source("camera", size=size, fps=args.camera_fps, exposure_ms=args.camera_exposure_ms) as source, \
            open_output("kms") as display:
        result = display_lag(source, display, refresh_ns=int(round(1e9 / args.refresh_hz)), trials=args.trials)
    low, high = result["spread_ms"]
    print(f"display lag: {result['lag_ms']:.2f} ms (median of {len(result['trials_ms'])} trials, {low:.2f} to "
          f"{high:.2f} ms); put display_lag_ms = {result['lag_ms']:.2f} under [pattern]")
    return 0


def _lock_check(args: argparse.Namespace) -> int:
    """``lock-check``: the camera lock, judged by the light each exposure gathers."""
    from .lock import lock_check
    from .outputs import open_output
    from .sources import open_source

    if args.frames < 20:
        raise UsageError(f"--frames {args.frames}: allowed >= 20 (the lock takes up to 30 to hold)")
    if not (math.isfinite(args.refresh_hz) and args.refresh_hz > 0):
        raise UsageError(f"--refresh-hz {args.refresh_hz}: allowed a number > 0")
    refresh_ms = 1e3 / args.refresh_hz
    if not 0 < args.camera_exposure_ms <= refresh_ms:
        raise UsageError(f"--camera-exposure-ms {args.camera_exposure_ms:g}: allowed 0 < exposure <= one refresh "
                         f"({refresh_ms:.2f} ms at {args.refresh_hz:g} Hz)")
    if not (math.isfinite(args.camera_fps) and args.camera_fps > 0):
        raise UsageError(f"--camera-fps {args.camera_fps}: allowed a number > 0")
    turns = args.refresh_hz / args.camera_fps
    if abs(turns - round(turns)) > 1e-3 or round(turns) < 1:
        raise UsageError(f"--camera-fps {args.camera_fps:g}: allowed a frame period of whole projector refreshes "
                         f"(--refresh-hz {args.refresh_hz:g})")
    if not (math.isfinite(args.display_lag_ms) and 0 <= args.display_lag_ms <= 1000):
        raise UsageError(f"--display-lag-ms {args.display_lag_ms}: allowed 0..1000")
    size = _size_arg(args.size, "--size")
    with open_source("camera", size=size, fps=args.camera_fps, exposure_ms=args.camera_exposure_ms) as source, \
            open_output("kms") as display:
        result = lock_check(source, display, refresh_ns=int(round(1e9 / args.refresh_hz)),
                            period_ns=int(round(1e9 / args.camera_fps)),
                            exposure_ns=int(round(args.camera_exposure_ms * 1e6)),
                            lag_ns=int(round(args.display_lag_ms * 1e6)), frames=args.frames)
    print(format_lock_check(result))
    return 0 if result["ok"] else 1


def format_lock_check(result: dict) -> str:
    """The lock check's verdict in a few lines."""
    if result["locked_at"] is None:
        return (f"lock check: FAILED -- the exposures never held within 5 % of a refresh of their target in "
                f"{result['frames']} frames: the sensor does not seem to apply FrameDurationLimits frame by frame "
                "(or its timestamps drift against the display's flips)")
    median, p99 = result["error_us"]
    lines = [f"lock check: locked after {result['locked_at']} of {result['frames']} frames; phase error median "
             f"{median:.1f} us, p99 {p99:.1f} us"]
    if result["lit_frames"]:
        lines.append(f"  {result['whole']} of {result['lit_frames']} exposures after it lit whole by the white shown "
                     f"for them (lit share median {result['median_lit']:.3f}, least {result['least_lit']:.3f})")
    if result["ok"]:
        lines.append("  passed: --camera-lock can time pulse and flash to the exposures")
    elif result["locked_at"] > result["frames"] // 2:
        lines.append("  FAILED: the lock took more than half the frames to hold")
    else:
        lines.append("  FAILED: exposures lit in part straddle the light's edge -- the display lag (measure it with "
                     "display-lag) or the sensor's timestamp (taken as its exposure's end) is off")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the console script; returns the exit code.

    SIGTERM unwinds every command as Ctrl-C does (files finished, staging removed; exit code 143)
    until a command installs its own stop (run and record stop at the next frame).
    """
    try:
        previous = signal.signal(signal.SIGTERM, _terminate)
    except ValueError:  # not the main thread: the caller's handlers stay
        previous = None
    try:
        return _main(argv)
    except BaseException as exc:  # (before a command began, or in a library's import it re-raised as another)
        if not _caused_by_sigterm(exc):
            raise
        print("antiscatter: stopped by SIGTERM", file=sys.stderr)
        return 143
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def _terminate(signum: int, frame: object) -> None:
    SIGTERM_RECEIVED.set()
    raise Terminated


def _caused_by_sigterm(exc: BaseException | None) -> bool:
    """Whether ``exc`` is :class:`Terminated` or was raised from it (a library import that wraps
    whatever interrupted it, e.g. in an ImportError)."""
    seen = 0
    while exc is not None and seen < 32:
        if isinstance(exc, Terminated):
            return True
        exc, seen = exc.__cause__ or exc.__context__, seen + 1
    return False


def _main(argv: Sequence[str] | None) -> int:
    from .console import configure_logging

    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    with configure_logging(args.verbosity):
        log = _logger(args.command)
        if log.isEnabledFor(logging.DEBUG):  # --verbose: what ran, for a bug report
            import platform

            import cv2
            log.debug(f"antiscatter {__version__}, Python {platform.python_version()}, numpy {np.__version__}, "
                      f"OpenCV {cv2.__version__}; arguments {vars(args)}")
        started = time.perf_counter_ns()
        code = _command(args)
        log.debug(f"exit code {code} after {(time.perf_counter_ns() - started) / 1e9:.2f} s")
        return code


def _command(args: argparse.Namespace) -> int:
    """Run the parsed command; bad input, a failure partway and a stop each end in one line on stderr."""
    from .console import LOGGER

    log = LOGGER.getChild(args.command)
    try:
        if args.command == "run":
            from .console import LogStream
            from .runtime import run
            summary = run(_run_config(args), log=LogStream(log))  # type: ignore[arg-type]
            if summary.stop_reason == "stopped by SIGINT":
                return 130
            if summary.stop_reason == "stopped by SIGTERM":
                return 143
            return EXIT_DAMAGED if summary.damaged else 0
        if args.command == "simulate":
            return _simulate(args)
        if args.command == "evaluate":
            return _evaluate(args)
        if args.command == "bench":
            return _bench(args)
        if args.command == "analyse":
            return _analyse(args)
        if args.command == "record":
            return _record(args)
        if args.command == "twin":
            return _twin(args)
        if args.command == "calibrate":
            return _calibrate(args)
        if args.command == "display-lag":
            return _display_lag(args)
        if args.command == "lock-check":
            return _lock_check(args)
        if args.command == "service":
            from .service import service_main
            return service_main(args)
    except UsageError as exc:
        log.error(f"antiscatter {args.command}: error: {exc}")
        return 2
    except RunError as exc:  # failed partway (a dead detector process): files complete up to it
        log.error(f"antiscatter {args.command}: error: {exc}")
        return 1
    except Terminated:
        log.error(f"antiscatter {args.command}: stopped by SIGTERM")
        return 143
    except KeyboardInterrupt:
        log.error(f"antiscatter {args.command}: interrupted")
        return 130
    except BrokenPipeError:
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
