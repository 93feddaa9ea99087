"""How well does a particle's brightness tell its distance?  (the twin issue's per-particle depth)

At a 12 cm camera-projector baseline the hole for a particle at unknown depth
must cover its whole epipolar segment, near..far.  A lamp-lit particle's
flux -- the light it sends back, summed over its image, the default
detector's score -- falls as exp(-2 c Z) / Z**4 (the lamp's inverse square,
times the image's area for a particle the camera resolves or the camera's own
inverse square for one it does not; water attenuation out and back), so it
could give Z -- if albedo, size, defocus and motion blur do not spread it too
much.  This script measures that on the simulator, against its true depths:

1. the default detector runs on realistic presets (800x600); detections are
   matched to truth (within max(truth radius, 2 px));
2. the photometric constant A in  flux = A * lamp(x, y) * exp(-2 c Z) / Z**4
   is fitted (median of log A) on the first half of the frames -- what a
   photometric calibration would give -- with the lamp profile and c taken from
   the scene (a calibration would measure both on a flat target);
3. on the held-out second half, depth is inverted from each flux; reported:
   relative error p10/p50/p90, share within +-20 %, and the epipolar segment
   the p10..p90 interval leaves at the given baseline, against the full
   near..far segment.  (A particle clipped at white keeps a flux too: its
   wings still grow with the light.)

A second cue cancels albedo, size and distance: a coded flash.  Even frames
are exposed under a uniform flash, odd ones under a ramp across the projector's
columns, level * (floor + (1 - floor) * u / (W - 1)); the ratio of a particle's
brightness in a ramp frame to the frame before gives the column u that lights
it, hence its disparity.  The second table reports |u error| in projector
pixels, from the detector's fluxes and from the simulator's true peaks (the
best any brightness measure could do while particles spin and wobble).

    python scripts/depth_from_brightness.py [--frames 60] [--baseline-m 0.12]
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy.spatial import cKDTree

from antiscatter.detection import make_detector
from antiscatter.simulate import make_scene
from antiscatter.twin import TwinGeometry


def collect(preset: str, frames: int, seed: int) -> dict[str, np.ndarray]:
    """(score, true depth, lamp factor, frame index) of every detection matched to a particle."""
    scene = make_scene(preset, rng=np.random.default_rng(seed), size=(800, 600))
    detector = make_detector("contrast")
    cone = scene._cone  # the lamp profile (a calibration would measure it on a flat target)
    rows = []
    for k in range(frames):
        scene.step()
        image = scene.render()
        truth = scene.truth()
        found = detector.detect(image)
        if k < 10 or not len(found) or not len(truth.ids):
            continue  # the learnt background settles over the first frames
        distance, index = cKDTree(truth.centres).query(found.centres)
        ok = distance < np.maximum(truth.radii[index], 2.0)
        x = np.clip(np.rint(found.centres[ok, 0]).astype(int), 0, cone.shape[1] - 1)
        y = np.clip(np.rint(found.centres[ok, 1]).astype(int), 0, cone.shape[0] - 1)
        rows.append(np.column_stack([found.scores[ok], truth.depths[index[ok]], cone[y, x],
                                     np.full(int(ok.sum()), k)]))
    score, depth, lamp, frame = np.concatenate(rows).T
    return {"score": score, "depth": depth, "lamp": np.maximum(lamp, 1e-3), "frame": frame,
            "attenuation": float(scene.config.attenuation[1])}


def invert(ratio: np.ndarray, attenuation: float, near: float = 0.2, far: float = 5.0) -> np.ndarray:
    """Z with exp(-2 c Z) / Z**4 = ratio (monotonic in Z), by table lookup."""
    zs = np.linspace(near, far, 4000)
    model = np.exp(-2 * attenuation * zs) / zs ** 4
    return np.interp(-ratio, -model, zs)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--baseline-m", type=float, default=0.12)
    parser.add_argument("--presets", default="bubbles,snow,sand,mixed")
    args = parser.parse_args()
    geometry = TwinGeometry(baseline_m=args.baseline_m)
    fb = geometry.projector_focal * geometry.baseline_m  # disparity (projector px) = fb / Z
    full = fb * (1 / geometry.near_m - 1 / geometry.far_m)
    print(f"baseline {geometry.baseline_m} m: full near..far epipolar segment {full:.0f} projector px")
    print(f"{'preset':<9}{'matched':>8}{'p10':>8}{'p50':>8}{'p90':>8}{'+-20%':>8}"
          f"{'segment px (median)':>21}{'x shorter':>11}")
    for preset in args.presets.split(","):
        d = collect(preset, args.frames, seed=1)
        fit = d["frame"] < 10 + (args.frames - 10) / 2
        test = ~fit
        log_a = np.log(d["score"] / d["lamp"]) + 2 * d["attenuation"] * d["depth"] + 4 * np.log(d["depth"])
        a = np.exp(np.median(log_a[fit]))
        estimate = invert(d["score"][test] / d["lamp"][test] / a, d["attenuation"])
        rel = estimate / d["depth"][test] - 1
        p10, p50, p90 = np.percentile(rel, [10, 50, 90])
        # the interval that holds the true depth 80 % of the time: Z in [est / (1 + p90), est / (1 + p10)]
        z_lo = np.clip(estimate / (1 + p90), geometry.near_m, geometry.far_m)
        z_hi = np.clip(estimate / (1 + p10), geometry.near_m, geometry.far_m)
        segment = fb * (1 / z_lo - 1 / z_hi)
        print(f"{preset:<9}{int(test.sum()):>8}{p10:>+8.2f}{p50:>+8.2f}{p90:>+8.2f}"
              f"{(np.abs(rel) < 0.2).mean():>8.2f}{np.median(segment):>21.0f}{full / np.median(segment):>11.1f}")
    print()
    print("coded flash (uniform, then ramp): |projector column error| px, median and p80")
    print(f"{'preset':<9}{'pairs':>7}{'detected':>10}{'p80':>7}{'true peaks':>12}{'p80':>7}")
    for preset in args.presets.split(","):
        e = ramp_errors(preset, args.frames, geometry)
        d, t = e["detected"], e["true"]
        print(f"{preset:<9}{len(d):>7}{np.median(d):>10.0f}{np.percentile(d, 80):>7.0f}"
              f"{np.median(t):>12.0f}{np.percentile(t, 80):>7.0f}")


def ramp_errors(preset: str, frames: int, geometry: TwinGeometry, *, floor: float = 0.2,
                level: float = 0.25) -> dict[str, np.ndarray]:
    """|u estimate - true u| (projector px) per particle seen in a uniform frame and the ramp frame after it."""
    import cv2

    width = geometry.projector_size[0]
    scene = make_scene(preset, rng=np.random.default_rng(1), size=geometry.camera_size)
    detectors = {"uniform": make_detector("contrast"), "ramp": make_detector("contrast")}  # a background each
    ramp = np.tile((level * (floor + (1 - floor) * np.arange(width) / (width - 1))).astype(np.float32),
                   (geometry.projector_size[1], 1))
    to_camera = np.linalg.inv(geometry.plane_mapping(geometry.background_m))
    backgrounds = {"uniform": np.full(geometry.camera_size[::-1], level, np.float32),
                   "ramp": cv2.warpPerspective(ramp, to_camera, geometry.camera_size, flags=cv2.INTER_LINEAR)}
    previous: dict[str, dict[int, float]] = {"detected": {}, "true": {}}
    errors: dict[str, list[float]] = {"detected": [], "true": []}
    for k in range(frames):
        scene.step()
        p = scene.particles()
        u, _ = geometry.to_projector(p["X"], p["Y"], p["Z"])
        kind = "uniform" if k % 2 == 0 else "ramp"
        factor = (np.full(len(u), level) if kind == "uniform"
                  else level * (floor + (1 - floor) * np.clip(u, 0, width - 1) / (width - 1)))
        image = scene.render(light=(factor, backgrounds[kind]))
        truth = scene.truth()
        found = detectors[kind].detect(image)
        if k < 10 or not len(found) or not len(truth.ids):
            continue
        distance, index = cKDTree(truth.centres).query(found.centres)
        ok = distance < np.maximum(truth.radii[index], 2.0)
        ids = truth.ids[index[ok]].tolist()
        where = {pid: j for j, pid in enumerate(p["ids"].tolist())}
        for source, values in (("detected", found.scores[ok]), ("true", truth.peaks[index[ok]])):
            if kind == "uniform":
                previous[source] = dict(zip(ids, values.tolist()))
                continue
            for pid, value in zip(ids, values.tolist()):
                if pid in previous[source] and pid in where and previous[source][pid] > 0:
                    u_est = (width - 1) * (value / previous[source][pid] - floor) / (1 - floor)
                    errors[source].append(abs(u_est - u[where[pid]]))
    return {k: np.asarray(v) for k, v in errors.items()}


if __name__ == "__main__":
    main()
