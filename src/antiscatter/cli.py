"""The ``antiscatter`` command line."""

from __future__ import annotations

import argparse
import sys
from typing import Any, Sequence

from . import __version__
from .errors import UsageError

__all__ = ["main", "build_parser"]


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (exit code 2) instead of usage dumps."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _detector_help() -> str:
    from .detection import DETECTORS
    return "; ".join(f"{name}: {entry.summary}" for name, entry in sorted(DETECTORS.items()))


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="antiscatter",
        description="Backscatter-avoiding underwater lighting: find the bright particles in each "
                    "camera frame and light everything except them with a projector.",
        epilog="Run 'antiscatter COMMAND --help' for each command's options.")
    parser.add_argument("--version", action="version", version=f"antiscatter {__version__}")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    run = commands.add_parser(
        "run", help="the backscatter cancellation loop (camera/video/frames/simulator -> projector)",
        description="Detect particles in every frame and show a light pattern with holes where they "
                    "are. Stops at --frames, when the source ends, on 'e' in a window, Ctrl-C or "
                    "SIGTERM; every file written is complete. Prints the report's per-stage table.",
        epilog="Examples:\n"
               "  antiscatter run --frames 300 --output none --metrics m.csv --detections d.csv\n"
               "  antiscatter run frames/ --output files:patterns.mkv\n"
               "  antiscatter run tank.mkv --crop 430:700,0:320 --loop --output window\n"
               "  antiscatter run camera --output framebuffer:/dev/fb0 --fps 60 --nice -20",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    run.add_argument("source", nargs="?", default=None,
                     help="sim (default: the built-in simulator), camera (Picamera2), webcam:N, "
                          "a folder of <int>.png frames, or a video file")
    run.add_argument("--config", metavar="FILE.toml", help="TOML file with [source], [detector], "
                     "[detector.NAME], [pattern], [output], [run] sections; flags override it")
    g = run.add_argument_group("source")
    g.add_argument("--crop", metavar="X0:X1,Y0:Y1", help="keep columns X0..X1-1 and rows Y0..Y1-1 of a video")
    g.add_argument("--loop", action="store_true", default=None, help="play a video or folder again when it ends")
    g.add_argument("--preset", help="simulator preset for the sim source (default seed: the report's bubbles)")
    g.add_argument("--seed", type=int, help="random seed of the simulator (default 0)")
    g.add_argument("--size", metavar="WxH", help="frame size for sim, camera and webcam")
    g.add_argument("--camera-fps", type=float, help="frame rate asked of the camera (default 60)")
    g = run.add_argument_group("detector")
    g.add_argument("--detector", help=f"detector name ({_detector_help()})")
    g.add_argument("-p", "--param", action="append", metavar="KEY=VALUE", default=[],
                   help="a parameter of the chosen detector, e.g. threshold=180 or equalise=true "
                        "(seed: threshold, blur_kernel, canny_sigma, equalise); repeatable")
    g = run.add_argument_group("pattern")
    g.add_argument("--projector-size", metavar="WxH", help="projector resolution (default 1280x800)")
    g.add_argument("--margin", type=float, help="pixels added to every hole's radius (default 0)")
    g.add_argument("--mapping", metavar="FILE", help="3x3 camera-to-projector homography, a text file "
                   "of 3 rows of 3 numbers (default: identity scaled to the projector size)")
    g = run.add_argument_group("output and run")
    g.add_argument("-o", "--output", action="append", metavar="NAME",
                   help="light output, repeatable: framebuffer[:/dev/fbN], window, files:DIR, "
                        "files:NAME.mkv, none, auto (default: a window where a display exists, else none)")
    g.add_argument("--frames", type=int, help="stop after N frames (default 0 = no limit)")
    g.add_argument("--fps", type=float, help="pace the loop at F frames per second (default 0 = as fast as possible)")
    g.add_argument("--nice", type=int, help="process niceness, -20 (highest priority) .. 19")
    g.add_argument("--metrics", metavar="CSV", help="per-frame stage timings, the report's columns first")
    g.add_argument("--detections", metavar="CSV", help="one row per particle: frame,x,y,radius")
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
    return parser


def _simulate(args: argparse.Namespace) -> int:
    from pathlib import Path

    from .config import parse_size
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
        try:
            size = parse_size(args.size, key="--size")
        except ValueError as exc:
            raise UsageError(str(exc)) from None
    request = SimulationRequest(out=Path(args.out), preset=preset, frames=frames, seed=seed, size=size,
                                background=args.background, masks=args.masks,
                                video=Path(args.video) if args.video else None, overwrite=args.overwrite)
    result = simulate(request)
    where = args.video if args.video else f"{args.out}/<frame>.png"
    print(f"wrote {result['frames']} frames of preset {preset} (seed {seed}) to {where}, "
          f"{result['particles']} truth rows to {args.out}/truth.csv"
          + (f", masks to {args.out}/masks" if args.masks else "")
          + f" ({result['fps']:.0f} frames/s)")
    return 0


def _run_config(args: argparse.Namespace):
    from .config import load_config, parse_param, parse_size
    from .detection import DETECTORS

    overrides: dict[str, dict[str, Any]] = {
        "source": {"spec": args.source, "crop": args.crop, "loop": args.loop, "preset": args.preset,
                   "seed": args.seed, "size": args.size, "camera_fps": args.camera_fps},
        "detector": {"name": args.detector},
        "pattern": {"margin": args.margin},
        "output": {"outputs": tuple(args.output) if args.output else None},
        "run": {"frames": args.frames, "fps": args.fps, "nice": args.nice,
                "metrics": args.metrics, "detections": args.detections},
    }
    if args.projector_size:
        try:
            w, h = parse_size(args.projector_size, key="--projector-size")
        except ValueError as exc:
            raise UsageError(str(exc)) from None
        overrides["pattern"].update(width=w, height=h)
    if args.mapping:
        overrides["pattern"]["mapping"] = _read_mapping(args.mapping)
    base = load_config(args.config, overrides)
    if not args.param:
        return base
    name = base.detector.name
    params = dict(parse_param(p, DETECTORS[name].params, detector=name) for p in args.param)
    return load_config(args.config, overrides, params)


def _read_mapping(path: str) -> list[list[float]]:
    import numpy as np
    from pathlib import Path

    file = Path(path)
    if not file.is_file():
        raise UsageError(f"--mapping {path}: no such file")
    try:
        matrix = np.loadtxt(file, dtype=np.float64, ndmin=2)
    except ValueError:
        raise UsageError(f"--mapping {path}: not a text file of numbers; expected 3 rows of 3 numbers") from None
    if matrix.shape != (3, 3):
        raise UsageError(f"--mapping {path}: got a {matrix.shape[0]}x{matrix.shape[1]} matrix, expected 3x3")
    return matrix.tolist()


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the console script; returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    try:
        if args.command == "run":
            from .runtime import run
            summary = run(_run_config(args))
            if summary.stop_reason == "stopped by SIGINT":
                return 130
            if summary.stop_reason == "stopped by SIGTERM":
                return 143
            return 0
        if args.command == "simulate":
            return _simulate(args)
    except UsageError as exc:
        print(f"antiscatter {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"antiscatter {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
