"""What Dask costs per run of ``map_windows`` on 2 local workers, apart from the work.

The windows of ``bench_cluster``'s recording (35 of 20 000 events) go to a
``distributed.LocalCluster`` of 2 worker processes with 1 thread each (as in
``bench_cluster``: ``MALLOC_TRIM_THRESHOLD_`` unset, Dask's profiler on), but each window
only sleeps 63 ms (the time of an egomotion window there) and returns an array: the CPU
then used by this process (the client, and the cluster's scheduler and nannies) and by
the worker processes is all overhead, and a window's time does not depend on the load of
the shared machine, so the batches are those of a quiet machine. Cases: windows batched
per task (``evmotion.parallel.BATCH_TARGET_S``) returning 3 kB (an egomotion result without
IWEs) or 695 kB (one with both 240 x 180 IWEs, as every result had before they were left
out of windows without a PNG panel), and one window a task. The cases take turns within
each round, on one cluster; medians over the rounds.

``python benchmarks/run.py cluster_overhead [--quick]``
"""

from __future__ import annotations

import contextlib
import os
import statistics
import tempfile
import time
from pathlib import Path

import harness

WINDOW_S = 0.063
CASES = {  # name -> (bytes returned per window, batched)
    "batched, 3 kB results": (3_000, True),
    "batched, 695 kB results": (694_824, True),
    "one window a task, 3 kB results": (3_000, False),
}


def _nap(events, nbytes: int):
    """A window's stand-in: sleeps WINDOW_S (no CPU) and returns ``nbytes`` of array."""
    import numpy as np

    time.sleep(WINDOW_S)
    return np.zeros(nbytes // 8)


@contextlib.contextmanager
def _target(seconds: float):
    import evmotion.parallel as parallel

    saved, parallel.BATCH_TARGET_S = parallel.BATCH_TARGET_S, seconds
    try:
        yield
    finally:
        parallel.BATCH_TARGET_S = saved


def main(quick: bool = False) -> list[dict]:
    import functools

    import dask
    from distributed import Client, LocalCluster, get_task_stream

    from bench_cluster import NO_TRIM, _cpu_s, recording
    from evmotion.events import make_windows
    from evmotion.io import read_events
    from evmotion.parallel import BATCH_TARGET_S, map_windows

    repeat = 3 if quick else 8
    with tempfile.TemporaryDirectory(prefix="bench_cluster_overhead_") as d:
        ev = read_events(recording(Path(d)))
    windows = make_windows(ev, n_events=20000, min_events=10)
    fns = {k: functools.partial(_nap, nbytes=nb) for k, (nb, _) in CASES.items()}
    runs: dict[str, list[tuple]] = {k: [] for k in CASES}
    loads = []
    with dask.config.set(NO_TRIM):
        cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                               dashboard_address=":0",
                               env={"OMP_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"})
    with cluster, Client(cluster.scheduler_address, set_as_default=False) as client:
        pids = list(client.run(os.getpid).values())
        for k in CASES:  # warm-up: imports in the workers
            map_windows(fns[k], ev, windows, scheduler=client, progress=False)
        order = list(CASES)
        for r in range(repeat):
            loads.append(os.getloadavg()[0])
            for k in order[r % len(order):] + order[:r % len(order)]:
                batched = CASES[k][1]
                with _target(BATCH_TARGET_S if batched else 0.0), \
                        get_task_stream(client) as stream:
                    c0, w0, t0 = time.process_time(), _cpu_s(pids), time.perf_counter()
                    out = map_windows(fns[k], ev, windows, scheduler=client, progress=False)
                    wall = time.perf_counter() - t0
                    client_cpu, workers_cpu = time.process_time() - c0, _cpu_s(pids) - w0
                if not all(o.ok for o in out):
                    raise RuntimeError(next(o.error for o in out if not o.ok))
                runs[k].append((wall, client_cpu, workers_cpu, len(stream.data)))
    rows = []
    for k, vals in runs.items():
        wall, client_cpu, workers_cpu, tasks = (statistics.median(v) for v in zip(*vals, strict=True))
        rows.append({"case": k, "windows": len(windows), "repeat": repeat, "tasks": tasks,
                     "wall_s": wall,
                     # 18 of the 35 windows one after the other: the least any run can take
                     "least_wall_s": -(-len(windows) // 2) * WINDOW_S,
                     "client_cpu_s": client_cpu, "workers_cpu_s": workers_cpu,
                     "load1_per_round": [round(v, 2) for v in loads]})
        print(rows[-1], flush=True)
    harness.record(
        "cluster_overhead", rows,
        notes="map_windows on a distributed.LocalCluster of 2 worker processes x 1 thread "
              "(MALLOC_TRIM_THRESHOLD_ unset, Dask's profiler on), the 35 windows of "
              "bench_cluster's recording, each only sleeping 63 ms and returning an array of "
              "the size given: client_cpu_s (this process: client, scheduler, nannies) and "
              "workers_cpu_s are Dask's overhead alone, load-insensitive batching (a "
              "window's time does not depend on the machine's load). tasks: Dask tasks "
              "of a run. 'batched, 695 kB results' is what every egomotion result weighed "
              "before the IWEs were left out of windows without a PNG panel. The machine's "
              f"{os.cpu_count()} cores are shared with other jobs: load1_per_round is the "
              "1-minute load average before each round; medians over the rounds.")
    return rows


if __name__ == "__main__":
    main(quick=False)
