"""Parallel-runner overhead and scaling: ``map_windows`` against a plain loop in the same run.

Workload per window: the FWL of a constant flow (two bilinear IWEs and a flow lookup), a
typical evaluation step. Overhead rows run pinned to one core (``harness.single_core``);
the scaling rows then restore all cores, so their ratio depends on what else runs on the
machine (quote it with the core count).

``python benchmarks/run.py parallel [--quick]``
"""

from __future__ import annotations

import os
import shutil
import tempfile

import numpy as np

import harness
from evmotion.eval import fwl
from evmotion.events import EventArray
from evmotion.parallel import map_windows

SHAPE = (180, 240)
FLOW = np.full(SHAPE + (2,), 300.0, dtype=np.float32)


def window_fwl(ev: EventArray) -> float:
    return fwl(ev, FLOW)


def _recording(n_windows: int, per_window: int, seed: int = 0) -> EventArray:
    rng = np.random.default_rng(seed)
    n = n_windows * per_window
    t = np.sort(rng.integers(0, n_windows * 10_000, n))
    return EventArray(rng.integers(0, SHAPE[1], n), rng.integers(0, SHAPE[0], n), t,
                      rng.integers(0, 2, n), sensor_size=SHAPE)


def main(quick: bool = False) -> list[dict]:
    n_windows, per_window = (16, 10_000) if quick else (48, 30_000)
    repeat = 3 if quick else 5
    ev = _recording(n_windows, per_window)
    wins = ev.windows_by_duration(10_000)
    all_cpus = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None
    rows = []

    def row(name, fn, ref=None, cores=1, rep=repeat):
        t = harness.timeit(fn, repeat=rep, warmup=1)
        r = {"case": name, "windows": len(wins), "events_per_window": per_window,
             "cores": cores, "median_s": t["median_s"],
             "ms_per_window": 1e3 * t["median_s"] / len(wins)}
        if ref is not None:
            r["ratio_vs_loop"] = t["median_s"] / ref
        rows.append(r)
        return t["median_s"]

    harness.single_core()
    ref = row("plain loop (reference)", lambda: [window_fwl(ev.window(w)) for w in wins])
    row("map_windows workers=1", lambda: map_windows(window_fwl, ev, wins, progress=False), ref)
    tmp = tempfile.mkdtemp(prefix="bench_parallel_")
    try:
        map_windows(window_fwl, ev, wins, resume_dir=tmp, progress=False)
        row("map_windows resume, all cached",
            lambda: map_windows(window_fwl, ev, wins, resume_dir=tmp, progress=False), ref)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)

    if all_cpus is not None and len(all_cpus) > 1:
        os.sched_setaffinity(0, all_cpus)
        k = len(all_cpus)
        ref_all = row("plain loop (reference, unpinned)",
                      lambda: [window_fwl(ev.window(w)) for w in wins], cores=k)
        row(f"map_windows thread workers={k}",
            lambda: map_windows(window_fwl, ev, wins, workers=k, executor="thread",
                                progress=False), ref_all, cores=k)
        row(f"map_windows process workers={k}",
            lambda: map_windows(window_fwl, ev, wins, workers=k, executor="process",
                                progress=False), ref_all, cores=k)
    harness.record("parallel", rows,
                   notes="FWL per window; ratio < 1 is faster than the plain loop. "
                         "Multi-core rows share the CPUs with other jobs on this machine.")
    return rows


if __name__ == "__main__":
    main(quick=True)
