"""Cold start: every CLI command's first run in a fresh process with an empty numba cache.

Each command runs as ``python -m evmotion ...`` through a small driver, in a new process
whose ``NUMBA_CACHE_DIR`` is a new empty folder (a fresh install, a CI runner, a new Dask
worker). Recorded per command: the process' wall time and CPU time (user + sys of the
child, from ``os.wait4``: the machine is shared, so CPU time is the steadier figure), and of
it the time inside numba compilation (``numba:compile`` events, outermost only; wall and
the compiling thread's CPU), the rest being the run. Every command gets a fresh cache, so
each row pays for the kernels it uses, none for another row's.

``python benchmarks/bench_cold_start.py [--src DIR] [--tag NAME] [--only SUBSTR ...]``
times the package under ``DIR/evmotion`` (default this checkout's ``src``; e.g. a
``git worktree`` of an older commit for a before/after table) and writes
``results/cold_start_<tag>.json``; ``--table`` merges the tagged runs into
``results/cold_start.md``/``.json`` (``before`` and ``after`` side by side).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import harness

HERE = Path(__file__).resolve().parent
SRC = HERE.parent / "src"

#: The driver run in each child: times ``evmotion.cli.main`` and numba's compilations.
DRIVER = r'''
import json, os, sys, threading, time
from numba.core import event

state = {"depth": 0, "wall": 0.0, "cpu": 0.0, "n": 0}

class Compiles(event.Listener):
    def on_start(self, ev):
        if threading.current_thread() is threading.main_thread():
            if state["depth"] == 0:
                state["t0"] = (time.perf_counter(), time.thread_time())
            state["depth"] += 1
    def on_end(self, ev):
        if threading.current_thread() is threading.main_thread():
            state["depth"] -= 1
            state["n"] += 1
            if state["depth"] == 0:
                state["wall"] += time.perf_counter() - state["t0"][0]
                state["cpu"] += time.thread_time() - state["t0"][1]

event.register("numba:compile", Compiles())
from evmotion.cli import main
rc = main(sys.argv[2:])
with open(sys.argv[1], "w") as fh:
    json.dump({"rc": rc, "compile_wall_s": state["wall"], "compile_cpu_s": state["cpu"],
               "compilations": state["n"]}, fh)
sys.exit(rc)
'''


def commands(d: Path) -> list[tuple[str, list[str]]]:
    """``(name, argv)`` of every command timed, on the files made in ``d`` (the first
    command simulates the recording the others read)."""
    rec = str(d / "sim.h5")
    gt = str(d / "sim_gt.h5")
    ego = ["egomotion", rec, "--window-events", "30000", "--max-png", "0", "--out",
           str(d / "ego")]
    rows = [
        ("simulate rotation", ["simulate", "rotation", "--duration", "0.1", "--out", rec]),
        ("info", ["info", rec]),
        ("convert h5->npz", ["convert", rec, str(d / "conv.npz")]),
        ("view", ["view", rec, "--window-events", "30000", "--out", str(d / "view.png")]),
    ]
    for warp in ("rotation", "translation", "zoom", "se2", "inplane", "similarity", "affine",
                 "homography"):
        rows.append((f"egomotion {warp}", ego + ["--warp", warp]))
    for warp, reg in (("rotation", "rcad"), ("rotation", "divergence"),
                      ("rotation", "deformation"), ("similarity", "rcad"),
                      ("zoom", "divergence+deformation")):
        rows.append((f"egomotion {warp} --reg {reg}", ego + ["--warp", warp, "--reg", reg]))
    rows += [
        ("landscape zoom --reg divergence",
         ["landscape", rec, "--warp", "zoom", "--reg", "divergence", "--param", "0",
          "--range", "-5", "5", "--steps", "21", "--window-events", "30000",
          "--out", str(d / "land.png")]),
        ("segment rotation", ["segment", rec, "--warp", "rotation", "--window-events",
                              "30000", "--max-windows", "1", "--out", str(d / "seg")]),
        ("flow multicm", ["flow", rec, "--method", "multicm", "--window-events", "30000",
                          "--out", str(d / "mc.h5")]),
        ("flow multicm --time-aware burgers",
         ["flow", rec, "--method", "multicm", "--time-aware", "burgers", "--window-events",
          "30000", "--out", str(d / "mcb.h5")]),
        ("flow triplet", ["flow", rec, "--method", "triplet", "--out", str(d / "tr.h5")]),
        ("flow triplet --dense robust",
         ["flow", rec, "--method", "triplet", "--dense", "robust", "--window-events", "30000",
          "--out", str(d / "trr.npy")]),
        ("eval", ["eval", str(d / "mc.h5"), "--gt", gt]),
    ]
    return rows


def run_cold(src: Path, argv: list[str], work: Path) -> dict:
    """One command in a fresh process with an empty numba cache."""
    cache = Path(tempfile.mkdtemp(prefix="numba-cold-", dir=work))
    stats = work / "stats.json"
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), PYTHONPATH=str(src),
               OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1",
               NUMBA_NUM_THREADS="1")
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-c", DRIVER, str(stats), *argv], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    _, status, ru = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    err = proc.stderr.read()
    proc.stderr.close()
    proc.returncode = os.waitstatus_to_exitcode(status)
    shutil.rmtree(cache, ignore_errors=True)
    if proc.returncode != 0 or not stats.exists():
        return {"rc": proc.returncode, "error": err.strip().splitlines()[-1:] or ["?"]}
    st = json.loads(stats.read_text())
    stats.unlink()
    cpu = ru.ru_utime + ru.ru_stime
    return {"rc": st["rc"], "wall_s": wall, "cpu_s": cpu,
            "compile_wall_s": st["compile_wall_s"], "compile_cpu_s": st["compile_cpu_s"],
            "run_wall_s": wall - st["compile_wall_s"], "run_cpu_s": cpu - st["compile_cpu_s"],
            "compilations": st["compilations"]}


def measure(src: Path, tag: str, only: list[str] | None = None) -> list[dict]:
    rows = []
    with tempfile.TemporaryDirectory(prefix="evm-cold-") as tmp:
        work = Path(tmp)
        for name, argv in commands(work):
            if only and not any(s in name for s in only) and name != "simulate rotation":
                continue
            r = run_cold(src, argv, work)
            rows.append({"command": name, **r})
            print(f"{tag:>7} {name:40s} " + (
                f"wall {r['wall_s']:6.1f} s  cpu {r['cpu_s']:6.1f} s  compile "
                f"{r['compile_wall_s']:6.1f} s" if "wall_s" in r else f"FAILED {r}"),
                flush=True)
    out = harness.RESULTS / f"cold_start_{tag}.json"
    out.write_text(json.dumps({"src": str(src), "tag": tag,
                               "date": time.strftime("%Y-%m-%d %H:%M:%S"), "rows": rows},
                              indent=2))
    return rows


def table() -> list[dict]:
    """``results/cold_start.md``/``.json``: the tagged runs side by side."""
    runs = {}
    for tag in ("before", "after"):
        p = harness.RESULTS / f"cold_start_{tag}.json"
        if p.exists():
            runs[tag] = {r["command"]: r for r in json.loads(p.read_text())["rows"]}
    names = list(dict.fromkeys(n for rs in runs.values() for n in rs))
    rows = []
    for n in names:
        row = {"command": n}
        for tag, rs in runs.items():
            r = rs.get(n, {})
            for k in ("wall_s", "cpu_s", "compile_wall_s", "run_wall_s"):
                if k in r:
                    row[f"{tag} {k}"] = round(r[k], 2)
        rows.append(row)
    harness.record("cold_start", rows, notes=(
        "Each command in a fresh process with an empty NUMBA_CACHE_DIR, one thread "
        "(python -m evmotion via a driver counting numba:compile events). wall/cpu: the "
        "whole process (cpu = user + sys, os.wait4); compile: inside numba compilation "
        "(outermost events); run = wall - compile. before = commit 7c713d1 (a git worktree "
        "on PYTHONPATH), after = this branch; same machine, shared with other jobs (cpu is "
        "the steadier figure)."))
    return rows


def main(quick: bool = False) -> list[dict]:
    measure(SRC, "after", only=["rotation", "multicm"] if quick else None)
    return table()


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--src", default=str(SRC), help="folder holding the evmotion package")
    ap.add_argument("--tag", default="after", choices=["before", "after"])
    ap.add_argument("--only", nargs="*", help="commands whose name contains one of these")
    ap.add_argument("--table", action="store_true", help="only merge the recorded runs")
    args = ap.parse_args()
    if not args.table:
        measure(Path(args.src), args.tag, args.only)
    table()
