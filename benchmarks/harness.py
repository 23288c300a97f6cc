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
