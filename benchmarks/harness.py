"""Benchmark harness: medians, ratios against a reference run in the same process, and
results recorded in ``benchmarks/results/<suite>.json`` and ``.md``.

Each ``benchmarks/bench_*.py`` defines ``main(quick: bool) -> list[dict]`` and calls
:func:`record`. ``python benchmarks/run.py [suite ...]`` runs them.
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import time
from collections.abc import Callable
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"


def single_core() -> None:
    """Pin numba, BLAS and this process to one core, as the speed targets require.

    BLAS takes its thread count when numpy loads: ``run.py`` sets it before importing any
    suite; a suite run on its own should be started with ``OPENBLAS_NUM_THREADS=1``.
    """
    for var in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = "1"
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})


def pin_idlest_core() -> int:
    """:func:`single_core`, then move to the least busy allowed core (CPU time over half a
    second from /proc/stat): on a shared machine the first core may be a neighbour's, whose
    load would be timed too. Returns the core, or -1 where affinity is not supported."""
    single_core()
    if not (hasattr(os, "sched_setaffinity") and Path("/proc/stat").exists()):
        return -1

    def busy():
        out = {}
        for line in Path("/proc/stat").read_text().splitlines():
            if line.startswith("cpu") and line[3].isdigit():
                f = [int(v) for v in line.split()[1:]]
                out[int(line[3:line.index(" ")])] = (sum(f) - f[3] - f[4], sum(f))
        return out

    a = busy()
    time.sleep(0.5)
    b = busy()
    load = {c: (b[c][0] - a[c][0]) / max(b[c][1] - a[c][1], 1) for c in b if c in a}
    cpu = min(load, key=load.get)
    os.sched_setaffinity(0, {cpu})
    return cpu


def timeit(fn: Callable[[], object], *, repeat: int = 20, warmup: int = 2) -> dict:
    """Median, min and max wall time of ``fn()`` in seconds over ``repeat`` runs."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return {"median_s": statistics.median(times), "min_s": min(times), "max_s": max(times),
            "repeat": repeat}


def timeit_rounds(fns: dict[str, Callable[[], object]], *, repeat: int | dict[str, int] = 20,
                  rounds: int = 3, ref: str | None = None) -> dict[str, dict]:
    """:func:`timeit` of each of ``fns`` in turn, ``rounds`` times over (A B C A B C ...),
    so that a change of load on a shared machine reaches every function alike (``repeat``
    runs per round, or per name from a dict). Per name:
    ``median_s`` (the median of its round medians), ``min_s``, and, given ``ref`` (a name),
    ``ratio`` (the median over rounds of its round median over ``ref``'s in that round)
    and ``ratio_min`` (the same with the fastest runs)."""
    reps = repeat if isinstance(repeat, dict) else dict.fromkeys(fns, repeat)
    per = {k: [] for k in fns}
    for _ in range(rounds):
        for k, fn in fns.items():
            per[k].append(timeit(fn, repeat=reps[k]))
    out = {}
    for k, rs in per.items():
        out[k] = {"median_s": statistics.median(r["median_s"] for r in rs),
                  "min_s": min(r["min_s"] for r in rs), "repeat": reps[k] * rounds}
        if ref is not None:
            out[k]["ratio"] = statistics.median(r["median_s"] / q["median_s"]
                                                for r, q in zip(rs, per[ref], strict=True))
            out[k]["ratio_min"] = (out[k]["min_s"]
                                   / min(q["min_s"] for q in per[ref]))
    return out


def record(suite: str, rows: list[dict], notes: str = "") -> Path:
    """Write ``rows`` (list of flat dicts) to results/<suite>.json and a markdown table."""
    RESULTS.mkdir(exist_ok=True)
    meta = {
        "suite": suite,
        "date": time.strftime("%Y-%m-%d %H:%M:%S"),
        "machine": platform.machine(),
        "processor": platform.processor() or platform.machine(),
        "python": platform.python_version(),
        "cpus": os.cpu_count(),
        "notes": notes,
    }
    (RESULTS / f"{suite}.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=2))
    cols: list[str] = []
    for r in rows:
        cols += [k for k in r if k not in cols]
    lines = [f"# {suite}", "", f"{meta['date']}, {meta['processor']}, Python {meta['python']}, "
             f"{meta['cpus']} CPUs. {notes}", "",
             "| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        lines.append("| " + " | ".join(_fmt(r.get(c, "")) for c in cols) + " |")
    out = RESULTS / f"{suite}.md"
    out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return out


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)
