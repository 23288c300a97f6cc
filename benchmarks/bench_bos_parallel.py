"""A 1 s, 120-frame schlieren sequence solved over its frame intervals with the parallel
runner (:func:`evmotion.methods.bos.estimate_bos_sequence`, ``workers=1`` vs ``2``).

A simulated plume (120 fps, 1 s: 121 frames, 120 intervals) at two small sizes (100 Adam
iterations per scale) and at Table 6.3's 640x720 (the solver's defaults); each worker
solves a contiguous chunk of intervals, warm-started within the chunk. Rows: wall time,
seconds per interval, speed-up over one worker, the load average of the (shared) machine
before and after, and the mean AEE against the exact flow (so that the chunks' cold starts
are seen to cost no accuracy).

Run: ``python benchmarks/bench_bos_parallel.py``.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import harness
from bench_bos_accuracy import exact_flow


def _cpu_s() -> float:
    """User + system CPU seconds of this process and its finished worker processes."""
    import resource

    a = resource.getrusage(resource.RUSAGE_SELF)
    b = resource.getrusage(resource.RUSAGE_CHILDREN)
    return a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime


def _run(size, duration, iterations) -> list[dict]:
    from evmotion.eval.metrics import event_mask, flow_metrics
    from evmotion.methods.bos import estimate_bos_sequence
    from evmotion.sim.schlieren import simulate_schlieren

    sim = simulate_schlieren("plume", sensor_size=size, duration_s=duration, seed=0)
    f, t = sim.frames.images, sim.frames.t
    n = len(t) - 1
    exact_flow(sim, n // 2)  # raises if the simulator's flow were not the image motion
    rows, base = [], None
    for workers in (1, 2):
        load0 = os.getloadavg()[0]
        cpu0 = _cpu_s()
        start = time.perf_counter()
        its = {} if iterations is None else {"iterations": iterations}
        res = estimate_bos_sequence(sim.events, f, t, workers=workers, data_term="scale",
                                    **its)
        wall = time.perf_counter() - start
        cpu = _cpu_s() - cpu0
        load1 = os.getloadavg()[0]
        aee = []
        for k, r in enumerate(res):
            dt = (int(t[k + 1]) - int(t[k])) * 1e-6
            mask = event_mask(sim.events.slice_time(int(t[k]), int(t[k + 1])), size)
            if mask.any():
                aee.append(flow_metrics(r.flow * dt, sim.gt.flow[k] * dt, mask=mask,
                                        out_px=1.0).aee)
        base = base or wall
        rows.append({"frames": len(t), "intervals": n, "size": f"{size[1]}x{size[0]}",
                     "events": len(sim.events),
                     "iterations_per_scale": iterations or "default",
                     "workers": workers, "wall_s": wall, "s_per_interval": wall / n,
                     "speedup_vs_1_worker": base / wall, "cpu_s": cpu,
                     "cores_used": cpu / wall, "load_before": load0,
                     "load_after": load1, "mean_AEE_px": float(np.mean(aee))})
        print(rows[-1], flush=True)
    return rows


#: (sensor size (H, W), Adam iterations per scale; None: the solver's default)
CASES = (((128, 112), 100), ((256, 224), 100), ((720, 640), None))


def main(quick: bool = False, cases=CASES) -> list[dict]:
    duration = 0.25 if quick else 1.0
    rows = []
    for size, iterations in cases[:1] if quick else cases:
        rows += _run(size, duration, iterations)
    harness.record("bos_parallel" + ("_quick" if quick else ""), rows,
                   "Plume, 120 fps, evmotion.methods.bos.estimate_bos_sequence over every "
                   "frame interval (process pool of evmotion.parallel.map_windows for 2 "
                   "workers: two contiguous chunks, each warm-started). The machine has 2 "
                   "cores shared with other jobs: load_before/after is the 1-min load "
                   "average; a load above 2 means the two workers did not have two free "
                   "cores. cpu_s: CPU seconds of the process and its workers; cores_used = "
                   "cpu_s / wall_s (how much CPU the run got). Equal cpu_s for 1 and 2 "
                   "workers means the parallel runner adds no work; the speed-up is bounded "
                   "by the CPU the shared machine gives.")
    return rows


if __name__ == "__main__":
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    main("--quick" in sys.argv)
