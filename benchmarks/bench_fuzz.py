"""Fuzzing every reader, sniffer and ``describe`` (what ``evmotion info`` runs) on mutated
files: per format the cases run, outcomes, errors by type, findings (must be 0), the
largest per-case peak memory and time.

Cases are the seeds and mutations of ``tests/fuzzing.py`` (cuts of the real samples in
``../shared/data`` and files of evmotion's own writers), case ``k`` of seed ``s`` drawn
from ``numpy.random.default_rng([s, k])``: any case can be re-run alone (``--seed NAME
--first k --cases 1``).

Memory per case: each worker process resets its peak resident set before a case (writing
5 to ``/proc/self/clear_refs``) and reads ``VmHWM`` after it; the row gives the largest
rise over the resident set before the case (``peak_mb``) and the largest peak itself
(``peak_rss_mb``, including the ~200 MB of Python, numpy, numba, h5py). Workers run under
an address-space limit (``RLIMIT_AS``, start + 2 GiB): an allocation past it fails with
MemoryError, which the readers report as a FormatError and the row counts as
``memory_limit_hits``. Time per case is wall time; ``hang`` is a case over 20 s (SIGALRM
in the worker; a batch over its time is also reported as hangs).

Run: ``python benchmarks/bench_fuzz.py [--cases 100000] [--workers 2] [--budget-s 1080]``
(``run.py fuzz`` runs the default, ``--quick`` 100 cases per seed).
"""

from __future__ import annotations

import argparse
import collections
import multiprocessing as mp
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import harness

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))

import fuzzing  # noqa: E402  (the test helpers, one folder over)

SHARED = Path(os.environ.get("EVMOTION_SHARED_DATA", HERE.parents[1] / "shared" / "data"))
BATCH = 200
CASE_TIMEOUT_S = 20.0

_SEEDS: list = []
_DIR: Path | None = None


def _status_kb(key: str) -> int:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith(key):
                return int(line.split()[1])
    return 0


def _reset_peak() -> bool:
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
        return True
    except OSError:
        return False


def _init(seeds, workdir: str) -> None:
    global _SEEDS, _DIR
    _SEEDS = seeds
    _DIR = Path(tempfile.mkdtemp(dir=workdir))
    for seed in seeds:  # load the compiled decoders before timing anything
        fuzzing.run_case(seed.path, seed.fmt)
    vm = _status_kb("VmSize:") * 1024
    if vm:
        resource.setrlimit(resource.RLIMIT_AS, (vm + (2 << 30), resource.RLIM_INFINITY))


def _batch(task: tuple[int, int, int]) -> dict:
    si, first, count = task
    seed = _SEEDS[si]
    agg = {"seed": si, "cases": 0, "kinds": collections.Counter(),
           "errors": collections.Counter(), "peak_kb": 0, "peak_rss_kb": 0, "max_s": 0.0,
           "mem_hits": 0, "findings": [], "stream_only": 0, "clear_refs": True}
    for k in range(first, first + count):
        ops = fuzzing.random_ops(np.random.default_rng([si, k]))
        path = fuzzing.write_case(seed, ops, _DIR / seed.name)
        agg["clear_refs"] &= _reset_peak()
        rss0 = _status_kb("VmRSS:")
        t0 = time.perf_counter()
        out = fuzzing.run_case(path, seed.fmt, timeout_s=CASE_TIMEOUT_S)
        dt = time.perf_counter() - t0
        hwm = _status_kb("VmHWM:")
        agg["cases"] += 1
        agg["kinds"][out.kind] += 1
        if out.kind == "error":
            agg["errors"][out.exc_type] += 1
            if out.exc_type == "MemoryError" or "MemoryError" in out.message:
                agg["mem_hits"] += 1
        if out.notes:
            agg["stream_only"] += 1
        if out.kind in fuzzing.FINDINGS and len(agg["findings"]) < 5:
            agg["findings"].append({"case": k, "kind": out.kind, "type": out.exc_type,
                                    "step": out.step, "message": out.message[:300],
                                    "ops": ops})
        agg["peak_kb"] = max(agg["peak_kb"], hwm - rss0)
        agg["peak_rss_kb"] = max(agg["peak_rss_kb"], hwm)
        agg["max_s"] = max(agg["max_s"], dt)
    return agg


def run(cases: int, workers: int, budget_s: float, only: list[str] | None = None,
        first: int = 0) -> tuple[list[dict], dict]:
    workdir = Path(tempfile.mkdtemp(prefix="evmotion_fuzz_"))
    seeds, missing = fuzzing.make_seeds(workdir / "seeds", SHARED if SHARED.is_dir() else None)
    if only:
        seeds = [s for s in seeds if s.name in only]
    per_seed = -(-cases // len(seeds))
    tasks = [(si, a, min(BATCH, first + per_seed - a)) for a in range(first, first + per_seed,
                                                                      BATCH)
             for si in range(len(seeds))]
    totals = {si: {"cases": 0, "kinds": collections.Counter(), "errors": collections.Counter(),
                   "peak_kb": 0, "peak_rss_kb": 0, "max_s": 0.0, "mem_hits": 0,
                   "findings": [], "stream_only": 0, "clear_refs": True}
              for si in range(len(seeds))}
    t_start = time.perf_counter()
    stopped = False
    ctx = mp.get_context("fork")
    with ctx.Pool(workers, initializer=_init, initargs=(seeds, str(workdir))) as pool:
        pending = collections.deque()
        it = iter(tasks)
        done = 0

        def submit() -> bool:
            task = next(it, None)
            if task is None:
                return False
            pending.append((task, pool.apply_async(_batch, (task,)), time.perf_counter()))
            return True

        for _ in range(2 * workers):
            submit()
        while pending:
            task, res, t_sub = pending.popleft()
            try:
                agg = res.get(timeout=BATCH * CASE_TIMEOUT_S)
            except mp.TimeoutError:
                tot = totals[task[0]]
                tot["cases"] += task[2]
                tot["kinds"]["hang"] += task[2]
                tot["findings"].append({"case": task[1], "kind": "hang",
                                        "message": f"batch of {task[2]} over its time"})
                pool.terminate()
                stopped = True
                break
            tot = totals[agg["seed"]]
            tot["cases"] += agg["cases"]
            for key in ("kinds", "errors"):
                tot[key].update(agg[key])
            for key in ("peak_kb", "peak_rss_kb", "max_s"):
                tot[key] = max(tot[key], agg[key])
            tot["mem_hits"] += agg["mem_hits"]
            tot["stream_only"] += agg["stream_only"]
            tot["clear_refs"] &= agg["clear_refs"]
            tot["findings"] += agg["findings"][:5 - len(tot["findings"])]
            done += agg["cases"]
            if time.perf_counter() - t_start < budget_s:
                submit()
            else:
                stopped = stopped or next(it, None) is not None
    wall = time.perf_counter() - t_start
    rows = []
    for si, seed in enumerate(seeds):
        tot = totals[si]
        findings = sum(tot["kinds"][k] for k in fuzzing.FINDINGS)
        rows.append({
            "seed": seed.name, "format": seed.fmt, "seed_bytes": seed.path.stat().st_size,
            "cases": tot["cases"], "ok": tot["kinds"]["ok"], "errors": tot["kinds"]["error"],
            "findings": findings,
            "leaks": tot["kinds"]["leak"], "unnamed": tot["kinds"]["unnamed"],
            "hangs": tot["kinds"]["hang"],
            "mismatch_or_invalid": tot["kinds"]["mismatch"] + tot["kinds"]["invalid"],
            "errors_by_type": ", ".join(f"{k} {v}" for k, v in tot["errors"].most_common()),
            "streams_though_read_fails": tot["stream_only"],
            "memory_limit_hits": tot["mem_hits"],
            "max_peak_mb": round(tot["peak_kb"] / 1024, 1),
            "max_peak_rss_mb": round(tot["peak_rss_kb"] / 1024, 1),
            "max_case_s": round(tot["max_s"], 3),
            "example_findings": tot["findings"],
        })
    info = {"cases": sum(r["cases"] for r in rows), "wall_s": round(wall, 1),
            "workers": workers, "stopped_by_budget": stopped, "missing_seeds": missing,
            "peak_method": "clear_refs/VmHWM" if all(t["clear_refs"] for t in totals.values())
            else "VmHWM without reset (upper bound)"}
    return rows, info


def main(quick: bool = False, argv: list[str] | None = None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", type=int, default=100_000, help="cases in all (split per seed)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--budget-s", type=float, default=1080.0,
                    help="stop submitting batches after this many seconds")
    ap.add_argument("--seed", action="append", help="only this seed (repeatable)")
    ap.add_argument("--first", type=int, default=0, help="first case index per seed")
    args = ap.parse_args([] if argv is None else argv)
    if quick:
        args.cases = 100 * 13
    rows, info = run(args.cases, args.workers, args.budget_s, args.seed, args.first)
    table = [{k: v for k, v in r.items() if k != "example_findings"} for r in rows]
    total = {"seed": "ALL", "format": "", "cases": info["cases"],
             **{k: sum(r[k] for r in rows) for k in ("ok", "errors", "findings", "leaks",
                                                     "unnamed", "hangs",
                                                     "mismatch_or_invalid",
                                                     "streams_though_read_fails",
                                                     "memory_limit_hits")},
             "max_peak_mb": max(r["max_peak_mb"] for r in rows),
             "max_peak_rss_mb": max(r["max_peak_rss_mb"] for r in rows),
             "max_case_s": max(r["max_case_s"] for r in rows)}
    notes = (f"{info['cases']} cases in {info['wall_s']} s on {info['workers']} worker "
             f"processes{' (stopped by the time budget)' if info['stopped_by_budget'] else ''}"
             f"; peak memory by {info['peak_method']}; seeds without samples: "
             f"{info['missing_seeds'] or 'none'}. Command: python benchmarks/bench_fuzz.py "
             f"--cases {args.cases} --workers {args.workers}. findings = leaks + unnamed + "
             "hangs + mismatch_or_invalid, expected 0.")
    harness.record("fuzz", table + [total], notes)
    examples = {r["seed"]: r["example_findings"] for r in rows if r["example_findings"]}
    if examples:
        print("example findings:", examples)
    return table


if __name__ == "__main__":
    for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_var, "1")
    main(argv=sys.argv[1:])
