"""Per-window commands on a Dask cluster: ``--scheduler`` on 2 local workers against the
serial local run, end to end (read, estimate, write) through ``evmotion.cli.main``.

A simulated recording (``evmotion.sim``, translation scene, 240 x 180, 1 s, ~650k
events) is cut into windows of ``--window-events``; each case runs the same command
``repeat`` times in turn serial / local ``--workers 2`` / ``--scheduler`` on a
``distributed.LocalCluster`` of 2 worker processes with 1 thread each, after one warm-up
run of each (numba kernels compiled or loaded from the cache in every process). Ratios are
per-round serial time over the other's, medians over the rounds; the 1-minute load average
(``os.getloadavg``) is recorded before every round, since this machine's cores are shared,
with the speed-up 2 processes get over 1 on pure CPU work at that moment (the ceiling any
2-worker run could reach then). Egomotion's ~60 ms windows go several to a Dask task
(``evmotion.parallel.BATCH_TARGET_S``); each round also runs it with one window a task, as
before batching (``single_*``), and on a cluster whose workers keep Dask's profiler on
(``profiler_on_*``). The workers of the other runs have the configuration docs/cluster.rst
recommends (``worker.yaml``: no ``MALLOC_TRIM_THRESHOLD_``, profiler off). Each run records
the CPU this
process used (the client, and the LocalClusters' schedulers and nannies, which live here).

A second part checks the numba cache on workers: a cluster whose workers point
``NUMBA_CACHE_DIR`` at an empty folder runs egomotion once (each worker compiles the
kernels on its first window, which the per-window ``compile_s`` shows), then its workers
are restarted (new processes, same folder) and run it again (the kernels load from the
cache: no compile).

``python benchmarks/run.py cluster [--quick]``
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import io
import json
import multiprocessing as mp
import os
import statistics
import tempfile
import time
from pathlib import Path

import harness

CASES = {
    "egomotion": ["egomotion", "{rec}", "--warp", "affine", "--reg", "divergence",
                  "--window-events", "20000", "--max-png", "0", "--json", "--out", "{out}"],
    "flow multicm": ["flow", "{rec}", "--method", "multicm", "--window-events", "20000",
                     "--json", "--out", "{out}.h5"],
}
WORKERS = 2
QUIET = 1.8
# Dask's nanny starts workers with MALLOC_TRIM_THRESHOLD_=65536, which stops glibc from
# adapting its mmap threshold: every large temporary array is mapped and zeroed afresh
NO_TRIM = {"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}
# Dask's worker profiler samples the task thread's stack every 10 ms from the worker's
# event loop, which must take the GIL the estimate holds: off in docs/cluster.rst's
# worker.yaml, which this is
NO_PROFILER = {**NO_TRIM, "distributed.worker.profile.enabled": False}
# Dask's periodic work on an idle LocalCluster of 2 workers (10 s, measured 2026-11-28):
# 0.045 s of CPU a second in the process holding the scheduler and nannies and 0.02 in
# each worker, mostly the event loops' 20 ms tick and the nannies' 100 ms memory monitor;
# 0.008 and 0.003 with these intervals. Two busy workers on 2 cores lose what it takes.
QUIET_LOOP = {"distributed.admin.tick.interval": "1s",
              "distributed.admin.system-monitor.interval": "2s",
              "distributed.worker.memory.monitor-interval": "1s"}
# docs/cluster.rst's worker.yaml
DOCS = {**NO_PROFILER, **QUIET_LOOP}


def recording(folder: Path) -> Path:
    from evmotion.io import write_events
    from evmotion.sim import simulate

    sim = simulate("translation", duration_s=1.0, sensor_size=(180, 240), seed=0,
                   show_progress=False)
    path = folder / "rec.h5"
    write_events(path, sim.events)
    return path


def _cli(argv: list[str]) -> tuple[float, dict, float]:
    """Wall time of one command, its JSON summary (progress bars swallowed) and the CPU
    seconds of this process meanwhile (all its threads: with ``--scheduler`` the client,
    and the LocalCluster's scheduler and nannies, which live in this process)."""
    from evmotion.cli import main

    out, err = io.StringIO(), io.StringIO()
    t0, c0 = time.perf_counter(), time.process_time()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(argv)
    seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    if rc != 0:
        raise RuntimeError(f"{' '.join(argv)} failed: {err.getvalue()[-500:]}")
    return seconds, json.loads(out.getvalue()), cpu


def _argv(case: str, rec: Path, out: Path, extra: list[str]) -> list[str]:
    return [a.format(rec=rec, out=out) for a in CASES[case]] + extra


def _estimates(doc: dict) -> list:
    drop = {"seconds", "compile_s", "estimate_s"}
    return [{k: v for k, v in w.items() if k not in drop} for w in doc["windows"]]


def _spin(n: int) -> int:
    """Pure-Python CPU work (no I/O, no memory traffic): the machine's share for us."""
    acc = 0
    for i in range(n):
        acc = (acc + i * i) % 1_000_003
    return acc


def _pair(pool: cf.Executor, argvs: list[list[str]]) -> float:
    """Wall time of the command run by the 2 pool processes at once, one copy each."""
    t0 = time.perf_counter()
    list(pool.map(_cli, argvs))
    return time.perf_counter() - t0


def _ceiling(pool: cf.Executor, n: int = 3_000_000) -> float:
    """Speed-up of 2 processes over 1 on two equal pieces of pure CPU work, right now: the
    most any 2-worker run could reach on this machine at this moment."""
    t0 = time.perf_counter()
    _spin(n)
    _spin(n)
    one = time.perf_counter() - t0
    t0 = time.perf_counter()
    list(pool.map(_spin, [n, n]))
    return one / (time.perf_counter() - t0)


@contextlib.contextmanager
def _one_window_a_task():
    """``map_windows`` as before batching: every window its own Dask task."""
    import evmotion.parallel as parallel

    saved, parallel.BATCH_TARGET_S = parallel.BATCH_TARGET_S, 0.0
    try:
        yield
    finally:
        parallel.BATCH_TARGET_S = saved


def _worker_pids(cluster) -> list[int]:
    from distributed import Client

    with Client(cluster) as client:
        return list(client.run(os.getpid).values())


def _cpu_s(pids: list[int]) -> float:
    import psutil  # a dependency of distributed

    return sum(sum(psutil.Process(p).cpu_times()[:2]) for p in pids)


def _speedup(case: str, rec: Path, tmp: Path, variants: dict[str, tuple[dict, bool]],
             repeat: int, pool: cf.Executor, start) -> dict:
    """The serial run and every cluster variant in turn, each round, in an order that
    turns from round to round (so that a change of the machine's load hits them alike).
    ``variants``: name -> (Dask configuration of its workers, batched); unbatched runs
    send every window as its own task, as before batching. ``start(config)`` makes a
    LocalCluster: each cluster run gets its own, started for it, warmed up by one run of
    the command (imports, kernels from the numba cache) and closed after it, so that no
    other cluster's idle scheduler, nannies and workers share the two cores."""
    extra = ["serial", *variants]

    def once(k):
        if k == "serial":
            seconds, doc, used = _cli(_argv(case, rec, tmp / k, []))
            return seconds, doc, used, 0.0
        config, batched = variants[k]
        with start(config) as cluster:
            argv = _argv(case, rec, tmp / k, ["--scheduler", cluster.scheduler_address])
            pids = _worker_pids(cluster)
            with contextlib.nullcontext() if batched else _one_window_a_task():
                _cli(argv)  # warm-up
                c0 = _cpu_s(pids)
                seconds, doc, used = _cli(argv)
            return seconds, doc, used, _cpu_s(pids) - c0

    docs = {k: once(k)[1] for k in extra}  # warm-up (and the estimates compared)
    # The same command, serial, once in each of the 2 pool processes at the same time:
    # 2 x (the round's serial run) / (time of both) is the speed-up 2 processes can get on
    # this very work here (cores shared with another compute process run each estimate
    # slower than an idle machine does), with no Dask at all.
    pair_argvs = [_argv(case, rec, tmp / f"pair{i}", []) for i in range(WORKERS)]
    _pair(pool, pair_argvs)  # warm-up: imports and kernels in the pool processes
    loads, ceilings, pairs = [], [], []
    runs, work, cpu, wcpu = ({k: [] for k in extra} for _ in range(4))
    order = list(extra)
    for r in range(repeat):
        loads.append(os.getloadavg()[0])
        ceilings.append(_ceiling(pool))
        pairs.append(_pair(pool, pair_argvs))
        # the runs' order turns each round: in a fixed order the run that came last was
        # the fastest of the cluster runs (5 % on egomotion, either cluster)
        for k in order[r % len(order):] + order[:r % len(order)]:
            seconds, doc, used, workers_cpu = once(k)
            runs[k].append(seconds)
            work[k].append(sum(w["seconds"] for w in doc["windows"]))
            cpu[k].append(used)
            wcpu[k].append(workers_cpu)
    ser = runs["serial"]
    work_ceilings = [WORKERS * a / b for a, b in zip(ser, pairs, strict=True)]
    row = {"case": case, "windows": len(docs["serial"]["windows"]), "repeat": repeat,
           "serial_s": statistics.median(ser)}
    for k in extra:
        if k == "serial":
            continue
        ratios = [a / b for a, b in zip(ser, runs[k], strict=True)]
        row.update({
            f"{k}_s": statistics.median(runs[k]),
            f"speedup_{k}": statistics.median(ratios),
            f"speedup_{k}_per_round": [round(v, 3) for v in ratios],
            # the estimates' own seconds, summed over the windows (in the workers): what
            # the CPUs gave the work, apart from reading, shipping and writing
            f"{k}_window_s_sum": statistics.median(work[k]),
            # CPU of this process during the cluster run: the client (reading, shipping,
            # writing) and the in-process scheduler and nannies, taken from the 2 cores
            # the workers run on
            f"{k}_client_cpu_s": statistics.median(cpu[k]),
            # CPU of the worker processes during the run: the estimates and whatever else
            # the workers do (receiving tasks, sending results, Dask's profiler)
            f"{k}_workers_cpu_s": statistics.median(wcpu[k]),
            # egomotion windows are independent: the cluster gives the serial estimates;
            # multicm warm-starts within each of the 2 chunks (as --workers 2 does), so
            # the first window of the second chunk starts from zero flow
            f"{k}_equals_serial": _estimates(docs[k]) == _estimates(docs["serial"]),
        })
    row.update({
        "serial_window_s_sum": statistics.median(work["serial"]),
        "load1_per_round": [round(v, 2) for v in loads],
        "two_process_ceiling_per_round": [round(v, 2) for v in ceilings],
        # the speed-up 2 plain processes got on this command in that round (no Dask)
        "workload_ceiling": statistics.median(work_ceilings),
        "workload_ceiling_per_round": [round(v, 3) for v in work_ceilings],
        # the cluster's speed-up over what 2 processes got on pure CPU work in that round
        "speedup_over_ceiling": statistics.median(
            a / b / c for a, b, c in zip(ser, runs["cluster"], ceilings, strict=True)),
    })
    # the rounds where nothing else held a core (2 processes got >= QUIET x on pure CPU
    # work just before): what the cluster reaches on an idle machine
    quiet = [a / b for a, b, c in zip(ser, runs["cluster"], ceilings, strict=True)
             if c >= QUIET]
    row.update({"quiet_rounds": len(quiet),
                "speedup_cluster_quiet_rounds": statistics.median(quiet) if quiet else None})
    return row


def _cold_cache(rec: Path, tmp: Path) -> dict:
    """Compile seconds per window on workers whose numba cache starts empty, then again
    on new worker processes (a new cluster) with the cache the first ones filled."""
    from distributed import LocalCluster

    cache = tempfile.mkdtemp(prefix="numba-cold-", dir=tmp)
    env = {"NUMBA_CACHE_DIR": cache, "OMP_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"}
    row = {"case": "egomotion, workers' numba cache empty, then new workers on it"}
    for key in ("cold", "new_workers"):
        with LocalCluster(n_workers=WORKERS, threads_per_worker=1, processes=True,
                          dashboard_address=":0", env=env) as cluster:
            load = os.getloadavg()[0]
            seconds, doc, _ = _cli(_argv("egomotion", rec, tmp / key,
                                         ["--scheduler", cluster.scheduler_address]))
        comp = [w["compile_s"] for w in doc["windows"]]
        row.update({f"{key}_load1": round(load, 2), f"{key}_s": seconds,
                    f"{key}_compile_s_total": sum(comp),
                    f"{key}_windows_compiling": sum(c > 0.05 for c in comp),
                    f"{key}_windows": len(comp)})
        if key == "cold":
            row["cache_files"] = sum(1 for p in Path(cache).rglob("*") if p.is_file())
    return row


def main(quick: bool = False) -> list[dict]:
    import dask
    from distributed import LocalCluster

    repeat = 3 if quick else 7
    rows = []

    def cluster(config: dict) -> LocalCluster:
        with dask.config.set(config):  # the nannies pass it to their workers at start
            return LocalCluster(n_workers=WORKERS, threads_per_worker=1, processes=True,
                                dashboard_address=":0",
                                env={"OMP_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"})

    with tempfile.TemporaryDirectory(prefix="bench_cluster_") as d, \
            cf.ProcessPoolExecutor(WORKERS, mp_context=mp.get_context("spawn")) as pool:
        list(pool.map(_spin, [1, 1]))  # started before the timing
        tmp = Path(d)
        rec = recording(tmp)
        # the workers docs/cluster.rst recommends; the same with Dask's default loop
        # intervals (its recommendation before QUIET_LOOP), or with Dask's profiler on
        ego = {"cluster": (DOCS, True), "loop_default": (NO_PROFILER, True),
               "single": (DOCS, False), "profiler_on": ({**NO_TRIM, **QUIET_LOOP}, True)}
        rows.append({"workers": "docs/cluster.rst's worker.yaml (MALLOC_TRIM_THRESHOLD_ "
                                "unset, profiler off, QUIET_LOOP intervals); loop_default: "
                                "Dask's tick and monitor intervals; profiler_on: Dask's "
                                "profiler on",
                     **_speedup("egomotion", rec, tmp, ego, repeat, pool, cluster)})
        print(rows[-1], flush=True)
        if not quick:
            rows.append({"workers": "docs/cluster.rst's worker.yaml",
                         **_speedup("flow multicm", rec, tmp,
                                    {"cluster": (DOCS, True),
                                     "loop_default": (NO_PROFILER, True)}, 5, pool, cluster)})
            print(rows[-1], flush=True)
            rows.append({"workers": "Dask's default (MALLOC_TRIM_THRESHOLD_=65536)",
                         **_speedup("flow multicm", rec, tmp, {"cluster": ({}, True)}, 3,
                                    pool, cluster)})
            print(rows[-1], flush=True)
            # the nanny sets its pre-spawn variables in this process too: later workers
            # would inherit them
            os.environ.pop("MALLOC_TRIM_THRESHOLD_", None)
        with dask.config.set(NO_TRIM):
            rows.append(_cold_cache(rec, tmp))
        print(rows[-1], flush=True)
    harness.record(
        "cluster", rows,
        notes=f"End to end CLI runs (read, estimate, write) in this process; cluster: "
              f"distributed.LocalCluster, {WORKERS} worker processes x 1 thread. The machine "
              f"has {os.cpu_count()} cores shared with other jobs: load1_per_round is the "
              "1-minute load average before each round, and a load above the core count "
              "depresses every parallel speed-up; two_process_ceiling_per_round is the "
              "speed-up 2 processes got over 1 on pure CPU work just before each round "
              "(the most any 2-worker run could reach then); workload_ceiling: the speed-up "
              "2 plain processes got on the same command, each running it whole at the same "
              "time as the other (2 x alone / together, no Dask). window_s_sum: the estimates' "
              "own seconds summed over the windows; client_cpu_s: CPU seconds of this "
              "process during a cluster run (client + in-process scheduler and nannies); "
              "workers_cpu_s: CPU seconds of the worker processes during the run. Each "
              "cluster run on a LocalCluster of its own, started, warmed up by one run and "
              "closed around it (no other cluster idling beside it). "
              "Workers configured as docs/cluster.rst's worker.yaml (MALLOC_TRIM_THRESHOLD_ "
              "unset, Dask's profiler off, event-loop tick 1 s, system monitor 2 s, memory "
              "monitor 1 s: QUIET_LOOP; the in-process scheduler and nannies too) unless "
              "the row says otherwise; loop_default: the same with Dask's default "
              "intervals (20 ms, 0.5 s, 0.1 s). "
              "cluster: windows batched per task (BATCH_TARGET_S); single: the same "
              "workers, one window a task, as before batching; profiler_on: batched, on "
              "workers with Dask's profiler on (its default). "
              f"quiet_rounds: rounds whose two-process ceiling was >= {QUIET} (nothing else "
              "held a core). Goal: speed-up >= 1.7 on 2 workers (speedup_cluster, the "
              "median over all rounds).")
    return rows


if __name__ == "__main__":
    main(quick=False)
