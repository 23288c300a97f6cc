"""Schlieren simulator speed (one core): events/s and frames/s per scene.

For each scene of :data:`evmotion.sim.schlieren.BOS_SCENES`, the whole
:func:`~evmotion.sim.schlieren.simulate_schlieren` call (air field, magnitude scaling,
frames with exposure, events through the project's event model) at the thesis' ROI size
720x640 (H x W) and at a test size 96x96, default parameters, magnitude 2 px; wall time
and process CPU time (the machine is shared). ``sim_frames_per_s`` counts simulated frames
(with their events) per second of wall time. Also the background renderer (numba, binned
dots) against its plain-numpy reference (every dot) in points per second.
Run: ``python benchmarks/run.py bos_sim`` or ``python benchmarks/bench_bos_sim.py [--quick]``.
"""

from __future__ import annotations

import os
import sys
import time

import numpy as np

try:
    from benchmarks import harness
except ImportError:  # run as a script
    import harness

from evmotion.sim.schlieren import BOS_SCENES, make_background, simulate_schlieren


def _one(scene, size, n_intervals, magnitude=2.0):
    c0, t0 = time.process_time(), time.perf_counter()
    sim = simulate_schlieren(scene, sensor_size=size, duration_s=n_intervals / 120.0, seed=0,
                             magnitude_px=magnitude)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    n_ev, n_fr = len(sim.events), len(sim.frames)
    return {"scene": scene, "size_HxW": f"{size[0]}x{size[1]}", "frames": n_fr,
            "events": n_ev, "wall_s": wall, "cpu_s": cpu,
            "events_per_s": n_ev / wall, "events_per_cpu_s": n_ev / cpu,
            "sim_frames_per_s": n_fr / wall, "events_per_interval": n_ev / (n_fr - 1),
            "steps": sim.stats["n_steps"], "exposure_samples": sim.gt.meta["exposure_samples"]}


def main(quick: bool = False) -> list[dict]:
    harness.pin_idlest_core()
    simulate_schlieren("plume", sensor_size=(32, 32), duration_s=2 / 120)  # compile
    rows = []
    big = 3 if quick else 6
    for scene in sorted(BOS_SCENES):
        rows.append(_one(scene, (720, 640), big))
        rows.append(_one(scene, (96, 96), 12))
    bg = make_background((96, 96), seed=0)
    rng = np.random.default_rng(0)
    pts = rng.uniform(0, 96, (2, 20_000))
    tn = harness.timeit(lambda: bg.radiance(pts[0], pts[1]), repeat=5, warmup=1)
    tr = harness.timeit(lambda: bg.radiance_reference(pts[0, :2000], pts[1, :2000]),
                        repeat=3, warmup=0)
    rows.append({"scene": "background render", "size_HxW": "96x96",
                 "events": "", "wall_s": tn["median_s"],
                 "Mpoints_per_s": 20_000 / tn["median_s"] / 1e6,
                 "numpy_Mpoints_per_s": 2000 / tr["median_s"] / 1e6,
                 "speedup_vs_numpy": (20_000 / tn["median_s"]) / (2000 / tr["median_s"])})
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    harness.record("bos_sim", rows, notes=(
        f"one core; 720x640: {big} frame intervals at 120 fps, 96x96: 12 intervals; "
        f"magnitude 2 px (largest inter-frame displacement), default dots (0.06 /px², "
        f"radius 1 px), exposure half the frame period, C = 0.2; load average {load:.1f} "
        "at the end (shared machine: CPU seconds are the steadier figure)."))
    return rows


if __name__ == "__main__":
    main(quick="--quick" in sys.argv)
