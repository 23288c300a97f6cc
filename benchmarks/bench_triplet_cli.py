"""Triplet matching from the command line against the library (issue: CLI at the library's
speed): ``evmotion flow evt3.raw --method triplet`` end to end (read, match, write) in fresh
processes, against a fresh process that reads the same file and runs the matcher.

Rates are *marginal*: (events of the 1.2 M-event file - events of a 30k-event cut of it) /
(time of the one - time of the other), so that start-up (imports, numba's cache) cancels.
Nothing is pinned (the shared machine's scheduler places each process); NUMBA/BLAS/Blosc
threads 1; medians of ``repeat`` runs, the variants interleaved (A B C A B C ...) so that a
change of load reaches all alike; CPU time (user + sys of the child) beside wall time and
the 1-minute load average at each run's start. "before" runs the same commands on the code
this tree started from (``EVMOTION_BEFORE_SRC``: a ``src`` folder, e.g. an export of the
base commit, described by ``EVMOTION_BEFORE_LABEL``); a row checks that its per-event output
equals this tree's column for column.
``--dense robust`` and ``--dense lsq``: time and size on the full file.

``python benchmarks/run.py triplet_cli [--quick]``
"""

from __future__ import annotations

import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import harness

HERE = Path(__file__).resolve().parent
SRC = HERE.parent / "src"
# an older tree to compare with (optional): its rows and the identity row are left out
# without it
BEFORE_SRC = Path(os.environ["EVMOTION_BEFORE_SRC"]) if os.environ.get("EVMOTION_BEFORE_SRC") \
    else None
BEFORE_LABEL = os.environ.get("EVMOTION_BEFORE_LABEL", "the code this tree started from")
DATA = Path(os.environ.get("EVMOTION_SHARED_DATA", HERE.parents[1] / "shared" / "data"))
SMALL = 30_000

LIBRARY = """
import json, sys, time
t0 = time.perf_counter()
import evmotion.io as eio
from evmotion.methods.triplet import TripletMatcher
m, n, t_loop = None, 0, 0.0
for c in eio.iter_events(sys.argv[1], chunk_events=1_000_000):
    a = time.perf_counter()
    if m is None:
        m = TripletMatcher(c.sensor_size)
    m.process(c)
    n += len(c)
    t_loop += time.perf_counter() - a
print(json.dumps({"events": n, "match_s": t_loop}))
"""


def _run(argv: list[str], src: Path) -> tuple[float, float, str, float]:
    """Wall and CPU seconds of a fresh Python process running ``argv``, its stdout and the
    1-minute load average when it started."""
    env = {**os.environ, "PYTHONPATH": str(src), "NUMBA_NUM_THREADS": "1",
           "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "BLOSC_NTHREADS": "1"}
    load = os.getloadavg()[0]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, *argv], env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if p.returncode:
        raise RuntimeError(f"{argv}: exit {p.returncode}: {p.stderr.strip()[-500:]}")
    cpu_s = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu_s, p.stdout, load


def _size(path: Path) -> int:
    if path.suffix == ".flo":
        return sum(p.stat().st_size for p in path.parent.glob(f"{path.stem}*.flo"))
    return path.stat().st_size


def main(quick: bool = False) -> list[dict]:
    for var in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ[var] = "1"
    raw = DATA / "formats" / "evt3.raw"
    if not raw.exists():
        print(f"{raw} not found; nothing to measure", file=sys.stderr)
        return []
    sys.path.insert(0, str(SRC))
    from evmotion.io import evt3

    repeat = 1 if quick else 5
    tmp = Path(tempfile.mkdtemp(prefix="bench_triplet_cli-"))
    events = evt3.read(raw)
    files = {"big": raw, "small": tmp / "small.raw"}
    evt3.write(files["small"], events[:SMALL])
    n_ev = {"big": len(events), "small": SMALL}

    def cli(out: str, *extra: str):
        return lambda f, o: ["-m", "evmotion", "flow", str(f), "--method", "triplet",
                             "--out", str(o.with_name(o.name + out)), *extra]

    def library(f, o):
        return ["-c", LIBRARY, str(f)]

    variants = {  # name: (source tree, argv builder, output suffix)
        "after: library read + match": (SRC, library, None),
        "before: library read + match": (BEFORE_SRC, library, None),
        "after: --out x.h5 (per event)": (SRC, cli(".h5"), ".h5"),
        "before: --out x.h5 (per event)": (BEFORE_SRC, cli(".h5"), ".h5"),
        "after: --out x.npz (per event)": (SRC, cli(".npz"), ".npz"),
        "after: --dense mean --out x.h5 (windows)": (SRC, cli(".h5", "--dense", "mean"), ".h5"),
    }
    variants = {k: v for k, v in variants.items() if v[0] is not None}
    times = {(v, f): [] for v in variants for f in ("small", "big")}
    outputs = {}
    for src, argv, _ in variants.values():  # warm the numba caches of both trees
        _run(argv(files["small"], tmp / "warm"), src)
    for _ in range(repeat):
        for name, (src, argv, suffix) in variants.items():
            for f in ("small", "big"):
                o = tmp / f"{abs(hash(name))}_{f}"
                wall, cpu_s, _, load = _run(argv(files[f], o), src)
                times[(name, f)].append((wall, cpu_s, load))
                if suffix:
                    outputs[(name, f)] = o.with_name(o.name + suffix)
    rows = []
    lib = {}
    dn = n_ev["big"] - n_ev["small"]
    for name in variants:
        tree = name.split(":")[0]
        med = {f: [statistics.median(r[i] for r in times[(name, f)]) for i in range(3)]
               for f in ("small", "big")}
        rate = dn / max(med["big"][0] - med["small"][0], 1e-9) / 1e6
        cpu_rate = dn / max(med["big"][1] - med["small"][1], 1e-9) / 1e6
        # other jobs only ever add CPU time (caches, frequency): the fastest runs too
        fast = {f: min(r[1] for r in times[(name, f)]) for f in ("small", "big")}
        cpu_rate_min = dn / max(fast["big"] - fast["small"], 1e-9) / 1e6
        if "library" in name:
            lib[tree] = {"wall": rate, "cpu": cpu_rate}
        loads = [r[2] for f in ("small", "big") for r in times[(name, f)]]
        big_out = outputs.get((name, "big"))
        rows.append({
            "case": name, "repeat": repeat,
            "small_wall_s": med["small"][0], "big_wall_s": med["big"][0],
            "small_cpu_s": med["small"][1], "big_cpu_s": med["big"][1],
            "marginal_Mev_per_s": rate, "cpu_marginal_Mev_per_s": cpu_rate,
            "cpu_marginal_min_Mev_per_s": cpu_rate_min,
            "ratio_to_library": rate / lib[tree]["wall"] if tree in lib else None,
            "cpu_ratio_to_library": cpu_rate / lib[tree]["cpu"] if tree in lib else None,
            "load_avg_min": min(loads), "load_avg_median": statistics.median(loads),
            "load_avg_max": max(loads),
            "output_MB_big": _size(big_out) / 1e6 if big_out else None,
        })
    if BEFORE_SRC is not None:
        rows.append(_identical(outputs[("after: --out x.h5 (per event)", "big")],
                               outputs[("before: --out x.h5 (per event)", "big")]))
    rows.extend(_dense(files, n_ev, tmp, min(repeat, 3)))
    notes = (f"Prophesee EVT3 1280x720 ({n_ev['big']} events, 10.8 s) and a {SMALL}-event "
             f"cut of it; fresh processes, nothing pinned, NUMBA/BLAS/Blosc threads 1; "
             f"medians of {repeat} runs, interleaved. marginal = (events big - events small) "
             "/ (time big - time small): start-up cancels. ratio_to_library: marginal rate "
             "over the library's (read + TripletMatcher in a fresh process) of the same tree "
             "in the same run; cpu_* the same from the children's CPU time (the 2-core "
             "machine is shared by other jobs: CPU time excludes their work, wall time does "
             "not); cpu_marginal_min: the same from the fastest runs (other jobs only add "
             "CPU time); load_avg_*: the 1-minute load average at the start of the row's "
             "runs. "
             + (f"before = {BEFORE_SRC} ({BEFORE_LABEL}). The identity row "
                "compares every column of the before and after per-event .h5 of the full "
                "file. " if BEFORE_SRC is not None else "No before tree this run. ") +
             "Earlier figures against main's code (commit 968b339 of this file): main's CLI "
             "wrote gzip dense windows at 0.21 M ev/s CPU marginal, and --dense robust took "
             "14.0 s on a 120k-event cut (the issue: 438 s and 1.59 GB on the full file).")
    harness.record("triplet_cli", rows, notes)
    return rows


def _identical(after: Path, before: Path) -> dict:
    """Every column of two per-event flow files equal (values and dtypes)?"""
    from evmotion.io.eventflow import EVENT_FLOW_COLUMNS, read_event_flow

    a, b = read_event_flow(after), read_event_flow(before)
    same = len(a) == len(b) and all(
        a[k].dtype == b[k].dtype and np.array_equal(a[k], b[k]) for k, _ in EVENT_FLOW_COLUMNS)
    return {"case": "per-event .h5 of the full file, after == before (every column)",
            "identical": bool(same), "events": len(a)}


def _dense(files, n_ev, tmp, repeat) -> list[dict]:
    rows = []
    for dense in ("robust", "lsq"):
        out = tmp / f"dense_{dense}.h5"
        argv = ["-m", "evmotion", "flow", str(files["big"]), "--method", "triplet", "--dense",
                dense, "--out", str(out), "--json"]
        runs = [_run(argv, SRC) for _ in range(repeat)]
        n_win = json.loads(runs[-1][2])["windows"]
        wall = statistics.median(r[0] for r in runs)
        rows.append({"case": f"after: --dense {dense} --out x.h5 ({n_ev['big']} events)",
                     "repeat": repeat, "big_wall_s": wall,
                     "big_cpu_s": statistics.median(r[1] for r in runs), "windows": n_win,
                     "ms_per_window": wall / n_win * 1e3,
                     "load_avg_median": statistics.median(r[3] for r in runs),
                     "output_MB_big": _size(out) / 1e6})
    return rows


if __name__ == "__main__":
    main(quick="--quick" in sys.argv)
