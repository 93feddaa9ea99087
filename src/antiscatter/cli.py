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
    return parser


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
