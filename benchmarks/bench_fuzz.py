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
in the worker), or a case whose worker made no progress for ``STALL_S`` (stuck in C code,
where no alarm reaches: the parent kills that worker); ``crash`` is a case whose worker
process died (a segfault in a C library). After either the pool is restarted and the case
is named.

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
STALL_S = CASE_TIMEOUT_S + 30.0  # no new case for this long: the worker is stuck in C code

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
    _DIR = Path(workdir) / f"worker{os.getpid()}"
    _DIR.mkdir()
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
    progress = _DIR / "progress"
    for k in range(first, first + count):
        # the case under way, for the parent to name if this process dies (a segfault)
        progress.write_text(f"{si} {k}")
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
    progress.unlink()
    return agg


def _merge(tot: dict, agg: dict) -> None:
    tot["cases"] += agg["cases"]
    for key in ("kinds", "errors"):
        tot[key].update(agg[key])
    for key in ("peak_kb", "peak_rss_kb", "max_s"):
        tot[key] = max(tot[key], agg[key])
    tot["mem_hits"] += agg["mem_hits"]
    tot["stream_only"] += agg["stream_only"]
    tot["clear_refs"] &= agg["clear_refs"]
    tot["findings"] += agg["findings"][:5 - len(tot["findings"])]


def _run_pool(todo: collections.deque, seeds, workdir: Path, workers: int, t_start: float,
              budget_s: float) -> tuple[list[dict], list[tuple[int, int, str]]]:
    """Run tasks from ``todo`` (removing those done) on a fresh pool until it is empty,
    the budget is spent or a worker dies (or is killed for making no progress). Returns
    the batch results and, after a death, ``(seed, case, kind)`` for each dead worker's
    case, kind "hang" for a killed worker, else "crash"; the unfinished tasks go back on
    ``todo``, a dead worker's resumed after its case."""
    done: list[dict] = []
    ctx = mp.get_context("fork")
    pool = ctx.Pool(workers, initializer=_init, initargs=(seeds, str(workdir)))
    started = {p.pid for p in pool._pool}
    pending: dict = {}
    dead: set[int] = set()
    stalled: set[int] = set()
    try:
        while todo or pending:
            while todo and len(pending) < 2 * workers and \
                    time.perf_counter() - t_start < budget_s:
                task = todo.popleft()
                pending[task] = pool.apply_async(_batch, (task,))
            if not pending or time.perf_counter() - t_start > budget_s + 300:
                break  # (the second: a worker stuck outside Python; its cases are not run)
            for task, res in list(pending.items()):
                if res.ready():
                    done.append(res.get())
                    del pending[task]
            # Pool replaces a dead worker silently and never finishes its task
            dead = {p for p in started if not Path(f"/proc/{p}").exists()
                    or _zombie(p)}
            if dead:
                break
            started |= {p.pid for p in pool._pool}
            stalled |= _kill_stalled(workdir)
            time.sleep(0.05)
    finally:
        pool.terminate()
        pool.join()
    crashed = []
    for prog in workdir.glob("worker*/progress"):
        pid = int(prog.parent.name.removeprefix("worker"))
        text = prog.read_text().split()
        prog.unlink()
        if len(text) != 2:  # killed by terminate() while writing it: its task is pending
            continue
        si, k = int(text[0]), int(text[1])
        for task in [t for t in pending if t[0] == si and t[1] <= k < t[1] + t[2]]:
            del pending[task]
            if pid in dead:
                crashed.append((si, k, "hang" if pid in stalled else "crash"))
                # the cases before it ran but their results died with the worker
                for part in ((si, task[1], k - task[1]),
                             (si, k + 1, task[1] + task[2] - k - 1)):
                    if part[2] > 0:
                        todo.appendleft(part)
            else:
                todo.appendleft(task)
    todo.extendleft(pending)  # submitted, not finished: run again
    return done, crashed


def _kill_stalled(workdir: Path) -> set[int]:
    """Kill the workers whose current case started more than ``STALL_S`` ago; their pids."""
    killed = set()
    now = time.time()
    for prog in workdir.glob("worker*/progress"):
        try:
            stuck = now - prog.stat().st_mtime > STALL_S
        except FileNotFoundError:
            continue
        if stuck:
            pid = int(prog.parent.name.removeprefix("worker"))
            try:
                os.kill(pid, 9)
            except ProcessLookupError:
                continue
            killed.add(pid)
    return killed


def _zombie(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(") ")[1][0] in "ZX"
    except (OSError, IndexError):
        return True


def run(cases: int | None, workers: int, budget_s: float, only: list[str] | None = None,
        first: int = 0, per_seed: int | None = None) -> tuple[list[dict], dict]:
    workdir = Path(tempfile.mkdtemp(prefix="evmotion_fuzz_"))
    seeds, missing = fuzzing.make_seeds(workdir / "seeds", SHARED if SHARED.is_dir() else None)
    if only:
        seeds = [s for s in seeds if s.name in only]
    per_seed = per_seed or -(-cases // len(seeds))
    tasks = [(si, a, min(BATCH, first + per_seed - a)) for a in range(first, first + per_seed,
                                                                      BATCH)
             for si in range(len(seeds))]
    totals = {si: {"cases": 0, "kinds": collections.Counter(), "errors": collections.Counter(),
                   "peak_kb": 0, "peak_rss_kb": 0, "max_s": 0.0, "mem_hits": 0,
                   "findings": [], "stream_only": 0, "clear_refs": True}
              for si in range(len(seeds))}
    t_start = time.perf_counter()
    stopped = False
    todo = collections.deque(tasks)
    while todo:
        done, crashed = _run_pool(todo, seeds, workdir, workers, t_start, budget_s)
        for agg in done:
            _merge(totals[agg["seed"]], agg)
        for si, k, kind in crashed:
            tot = totals[si]
            tot["cases"] += 1
            tot["kinds"][kind] += 1
            ops = fuzzing.random_ops(np.random.default_rng([si, k]))
            tot["findings"].append({"case": k, "kind": kind, "ops": ops, "message": (
                f"no progress for {STALL_S:g} s: stuck outside Python, killed"
                if kind == "hang" else "the worker process died (segfault?)")})
        if time.perf_counter() - t_start >= budget_s:
            stopped = bool(todo)
            break
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
            "hangs": tot["kinds"]["hang"], "crashes": tot["kinds"]["crash"],
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
    rows, info = run(args.cases, args.workers, args.budget_s, args.seed, args.first,
                     per_seed=100 if quick else None)
    table = [{k: v for k, v in r.items() if k != "example_findings"} for r in rows]
    total = {"seed": "ALL", "format": "", "cases": info["cases"],
             **{k: sum(r[k] for r in rows) for k in ("ok", "errors", "findings", "leaks",
                                                     "unnamed", "hangs", "crashes",
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
             "hangs + crashes + mismatch_or_invalid, expected 0.")
    harness.record("fuzz", table + [total], notes)
    examples = {r["seed"]: r["example_findings"] for r in rows if r["example_findings"]}
    if examples:
        print("example findings:", examples)
    return table


if __name__ == "__main__":
    for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_var, "1")
    main(argv=sys.argv[1:])
