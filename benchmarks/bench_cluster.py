"""Per-window commands on a Dask cluster: ``--scheduler`` on 2 local workers against the
serial local run, end to end (read, estimate, write) through ``evmotion.cli.main``.

A simulated recording (``evmotion.sim``, translation scene, 240 x 180, 0.5 s, ~324k
events) is cut into windows of ``--window-events``; each case runs the same command
``repeat`` times in turn serial / local ``--workers 2`` / ``--scheduler`` on a
``distributed.LocalCluster`` of 2 worker processes with 1 thread each, after one warm-up
run of each (numba kernels compiled or loaded from the cache in every process). Ratios are
per-round serial time over the other's, medians over the rounds; the 1-minute load average
(``os.getloadavg``) is recorded before every round, since this machine's cores are shared.

A second part checks the numba cache on workers: a cluster whose workers point
``NUMBA_CACHE_DIR`` at an empty folder runs egomotion once (each worker compiles the
kernels on its first window, which the per-window ``compile_s`` shows), then its workers
are restarted (new processes, same folder) and run it again (the kernels load from the
cache: no compile).

``python benchmarks/run.py cluster [--quick]``
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import statistics
import tempfile
import time
from pathlib import Path

import harness

CASES = {
    "egomotion": ["egomotion", "{rec}", "--warp", "affine", "--reg", "divergence",
                  "--window-events", "20000", "--max-png", "0", "--json", "--out", "{out}"],
    "flow multicm": ["flow", "{rec}", "--method", "multicm", "--window-events", "40000",
                     "--json", "--out", "{out}.h5"],
}
WORKERS = 2


def _recording(folder: Path) -> Path:
    from evmotion.io import write_events
    from evmotion.sim import simulate

    sim = simulate("translation", duration_s=0.5, sensor_size=(180, 240), seed=0,
                   show_progress=False)
    path = folder / "rec.h5"
    write_events(path, sim.events)
    return path


def _cli(argv: list[str]) -> tuple[float, dict]:
    """Wall time of one command and its JSON summary (progress bars swallowed)."""
    from evmotion.cli import main

    out, err = io.StringIO(), io.StringIO()
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(argv)
    seconds = time.perf_counter() - t0
    if rc != 0:
        raise RuntimeError(f"{' '.join(argv)} failed: {err.getvalue()[-500:]}")
    return seconds, json.loads(out.getvalue())


def _argv(case: str, rec: Path, out: Path, extra: list[str]) -> list[str]:
    return [a.format(rec=rec, out=out) for a in CASES[case]] + extra


def _estimates(doc: dict) -> list:
    drop = {"seconds", "compile_s", "estimate_s"}
    return [{k: v for k, v in w.items() if k not in drop} for w in doc["windows"]]


def _speedup(case: str, rec: Path, tmp: Path, address: str, repeat: int) -> dict:
    runs = {"serial": [], "--scheduler": []}
    extra = {"serial": [], "--scheduler": ["--scheduler", address]}
    docs = {k: _cli(_argv(case, rec, tmp / k.strip("-").replace(" ", ""), extra[k]))[1]
            for k in runs}  # warm-up
    loads = []
    for _ in range(repeat):
        loads.append(os.getloadavg()[0])
        for k in runs:
            runs[k].append(_cli(_argv(case, rec, tmp / k.strip("-").replace(" ", ""),
                                      extra[k]))[0])
    ser = runs["serial"]
    n_windows = len(docs["serial"]["windows"])
    return {
        "case": case, "windows": n_windows, "repeat": repeat,
        "serial_s": statistics.median(ser),
        "cluster_s": statistics.median(runs["--scheduler"]),
        "speedup_cluster": statistics.median(a / b for a, b in zip(ser, runs["--scheduler"],
                                                                    strict=True)),
        "speedup_cluster_per_round": [round(a / b, 3) for a, b in
                                      zip(ser, runs["--scheduler"], strict=True)],
        "load1_per_round": [round(v, 2) for v in loads],
        # egomotion windows are independent: the cluster gives the serial estimates;
        # multicm warm-starts within each of the 2 chunks (as --workers 2 does), so the
        # first window of the second chunk starts from zero flow
        "cluster_equals_serial": _estimates(docs["--scheduler"]) == _estimates(docs["serial"]),
    }


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
            seconds, doc = _cli(_argv("egomotion", rec, tmp / key,
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
    from distributed import LocalCluster

    repeat = 3
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_cluster_") as d:
        tmp = Path(d)
        rec = _recording(tmp)
        env = {"OMP_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"}
        with LocalCluster(n_workers=WORKERS, threads_per_worker=1, processes=True,
                          dashboard_address=":0", env=env) as cluster:
            for case in (["egomotion"] if quick else list(CASES)):
                rows.append(_speedup(case, rec, tmp, cluster.scheduler_address, repeat))
                print(rows[-1], flush=True)
        rows.append(_cold_cache(rec, tmp))
        print(rows[-1], flush=True)
    harness.record(
        "cluster", rows,
        notes=f"End to end CLI runs (read, estimate, write) in this process; cluster: "
              f"distributed.LocalCluster, {WORKERS} worker processes x 1 thread. The machine "
              f"has {os.cpu_count()} cores shared with other jobs: load1_per_round is the "
              "1-minute load average before each round, and a load above the core count "
              "depresses every parallel speed-up. Goal: speed-up >= 1.7 on 2 workers.")
    return rows


if __name__ == "__main__":
    main(quick=False)
