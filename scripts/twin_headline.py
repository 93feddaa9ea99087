"""The twin's headline loops (the scoreboard's long runs quoted by the README and the status page),
each the mean over seeds 1..N, on the simulator's own background or on a photograph.

    python scripts/twin_headline.py --frames 300 --seeds 6 > figures.json
    python scripts/twin_headline.py --frames 300 --seeds 6 --background /work/shared/data/msrb/174710351_orig.png

Rows: ``evaluate.report.LONG_RUNS`` picked by index (``--rows``; default the co-located and 12 cm
goal's rows).  Figures: docs/decisions/011-one-system.md.
"""

from __future__ import annotations

import argparse
import json
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace

import numpy as np

#: LONG_RUNS' co-located dim / pulse locked, pulse free-running, pulse as run; 12 cm probing dim / pulse
DEFAULT_ROWS = (0, 1, 3, 4, 9, 10)


def _scene(geometry, preset: str, seed: int, background: str | None):
    """twin.twin_scene, with the preset's background replaced by ``background`` (a path) if given."""
    from antiscatter.simulate import make_scene
    from antiscatter.simulate.scene import RealisticScene

    scene = make_scene(preset, rng=np.random.default_rng(seed), size=geometry.camera_size, background=background)
    if (scene.config.fps, scene.config.hfov_deg) != (geometry.camera_hz, geometry.hfov_deg):
        scene = RealisticScene(replace(scene.config, fps=geometry.camera_hz, hfov_deg=geometry.hfov_deg),
                               size=geometry.camera_size, rng=np.random.default_rng(seed))
    return scene


def _job(job: tuple) -> dict:
    from antiscatter.evaluate.report import FREE_PHASES, LONG_RUNS
    from antiscatter.twin import TwinGeometry, TwinRun, simulate_loop

    row, seed, frames, preset, background = job
    baseline, latency, mapping, strategy, predict, camera, lag = LONG_RUNS[row]
    geometry = TwinGeometry(baseline_m=baseline, camera_lock=camera == "as run",
                            camera_phase=FREE_PHASES[(seed - 1) % len(FREE_PHASES)] if camera == "free" else None,
                            display_lag_s=lag / TwinGeometry.projector_hz)
    out = simulate_loop(TwinRun("contrast", mapping, strategy, predict), geometry=geometry, frames=frames,
                        latency_ms=latency, scene=_scene(geometry, preset, seed, background))
    out.pop("series")
    return {"row": row, "seed": seed, **out}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--seeds", type=int, default=6)
    parser.add_argument("--rows", default=",".join(map(str, DEFAULT_ROWS)), help="LONG_RUNS indices")
    parser.add_argument("--preset", default="mixed")
    parser.add_argument("--background", help="an image replacing the preset's background")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    from antiscatter.evaluate.report import LONG_RUNS

    rows = [int(r) for r in args.rows.split(",")]
    jobs = [(row, seed, args.frames, args.preset, args.background) for row in rows
            for seed in range(1, args.seeds + 1)]
    with ProcessPoolExecutor(args.workers) as pool:
        outs = list(pool.map(_job, jobs))
    table = []
    for row in rows:
        group = [o for o in outs if o["row"] == row]
        baseline, latency, mapping, strategy, predict, camera, lag = LONG_RUNS[row]
        entry = {"row": row, "baseline_m": baseline, "latency_ms": latency,
                 "system": f"{mapping}, {strategy}" + (", predict" if predict else ""), "camera": camera,
                 "display_lag_refreshes": lag, "frames_processed": float(np.mean([o["frames_processed"] for o in group]))}
        for key in ("backscatter_removed", "scene_light_kept", "backscatter_removed_steady",
                    "scene_light_kept_steady"):
            entry[key] = float(np.mean([o[key] for o in group]))
        entry["removed_per_seed"] = [round(o["backscatter_removed"], 4) for o in group]
        table.append(entry)
        print(f"{baseline:<5g} {entry['system']:<28} {camera:<7} removed {entry['backscatter_removed']:.3f} "
              f"kept {entry['scene_light_kept']:.3f} (steady {entry['backscatter_removed_steady']:.3f} / "
              f"{entry['scene_light_kept_steady']:.3f})", file=sys.stderr)
    json.dump({"frames": args.frames, "seeds": args.seeds, "preset": args.preset, "background": args.background,
               "rows": table}, sys.stdout, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
