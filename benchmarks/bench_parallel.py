"""Parallel-runner overhead and scaling: ``map_windows`` against a plain loop in the same run.

Two tasks per window: ``window_fwl`` (one FWL, ~ms: runner overhead dominates) and
``window_scan`` (25 FWLs, a method-sized task). Overhead rows run pinned to one core (``harness.single_core``);
the scaling rows then restore all cores, so their ratio depends on what else runs on the
machine (quote it with the core count).

``python benchmarks/run.py parallel [--quick]``
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing as mp
import os
import shutil
import statistics
import tempfile
import time

import numpy as np

import harness
from evmotion.eval import fwl
from evmotion.events import EventArray
from evmotion.parallel import map_windows

SHAPE = (180, 240)
FLOW = np.full(SHAPE + (2,), 300.0, dtype=np.float32)


def window_fwl(ev: EventArray) -> float:
    """A light task (~ms): the overhead of the runner dominates."""
    return fwl(ev, FLOW)


def window_scan(ev: EventArray) -> float:
    """A method-sized task (tens of ms): the best FWL over a 3x3 grid of constant flows,
    a miniature of a contrast-maximization landscape."""
    best = 0.0
    for u in (-300.0, 0.0, 300.0):
        for v in (-300.0, 0.0, 300.0):
            flow = np.empty(SHAPE + (2,), np.float32)
            flow[..., 0], flow[..., 1] = u, v
            best = max(best, fwl(ev, flow))
    return best


def paired(ref_fn, fn, repeat: int) -> dict:
    """Alternate reference and candidate runs and take the median of the per-pair ratios,
    which cancels most of the drift of a CPU shared with other jobs."""
    ref_fn()
    fn()
    ref_t, t, ratios = [], [], []
    for _ in range(repeat):
        a = time.perf_counter()
        ref_fn()
        b = time.perf_counter()
        fn()
        c = time.perf_counter()
        ref_t.append(b - a)
        t.append(c - b)
        ratios.append((c - b) / (b - a))
    return {"ref_s": statistics.median(ref_t), "median_s": statistics.median(t),
            "ratio": statistics.median(ratios)}


def _recording(n_windows: int, per_window: int, seed: int = 0) -> EventArray:
    rng = np.random.default_rng(seed)
    n = n_windows * per_window
    t = np.sort(rng.integers(0, n_windows * 10_000, n))
    return EventArray(rng.integers(0, SHAPE[1], n), rng.integers(0, SHAPE[0], n), t,
                      rng.integers(0, 2, n), sensor_size=SHAPE)


def main(quick: bool = False) -> list[dict]:
    n_windows, per_window = (6, 10_000) if quick else (16, 30_000)
    repeat = 3 if quick else 7
    ev = _recording(n_windows, per_window)
    wins = ev.windows_by_duration(10_000)
    all_cpus = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None
    rows = []

    def row(name, task, fn, cores):
        p = paired(lambda: [task(ev.window(w)) for w in wins], fn, repeat)
        rows.append({"case": name, "task": task.__name__, "windows": len(wins),
                     "events_per_window": per_window, "cores": cores,
                     "loop_ms_per_window": 1e3 * p["ref_s"] / len(wins),
                     "ms_per_window": 1e3 * p["median_s"] / len(wins),
                     "ratio_vs_loop": p["ratio"]})

    harness.single_core()
    for task in (window_fwl, window_scan):
        row("map_windows workers=1", task,
            lambda task=task: map_windows(task, ev, wins, progress=False), 1)
    tmp = tempfile.mkdtemp(prefix="bench_parallel_")
    try:
        map_windows(window_scan, ev, wins, resume_dir=tmp, progress=False)
        row("map_windows resume, all cached", window_scan,
            lambda: map_windows(window_scan, ev, wins, resume_dir=tmp, progress=False), 1)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)

    if all_cpus is not None and len(all_cpus) > 1:
        os.sched_setaffinity(0, all_cpus)
        k = len(all_cpus)
        for task in (window_fwl, window_scan):
            row(f"map_windows thread workers={k}", task,
                lambda task=task: map_windows(task, ev, wins, workers=k, executor="thread",
                                              progress=False), k)
            row(f"map_windows process workers={k} (new pool per call)", task,
                lambda task=task: map_windows(task, ev, wins, workers=k, executor="process",
                                              progress=False), k)
            with cf.ProcessPoolExecutor(k, mp_context=mp.get_context("fork")) as pool:
                row(f"map_windows process workers={k} (reused pool)", task,
                    lambda task=task: map_windows(task, ev, wins, workers=k, executor=pool,
                                                  progress=False), k)
    harness.record("parallel", rows,
                   notes="Each row alternates a plain loop over the same windows with the "
                         "runner; ratio_vs_loop is the median per-pair ratio (< 1 faster). "
                         "Multi-core rows share the CPUs with other jobs on this machine.")
    return rows


if __name__ == "__main__":
    main(quick=True)
