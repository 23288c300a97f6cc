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

``--warm BEFORE_SRC`` checks that warm speed is unchanged: bench_cmax's evaluation rows
(cost + gradient, 30k events at 346x260, the warps whose kernels were split per case, each
penalty, at bench_cmax's ordinary and collapsing parameters) and its 4-DOF estimate, timed
in child processes with a warm cache, before and after in turn (three rounds, each child
pinned to the idlest core), into ``results/cold_start_warm.md``/``.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
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
          "--out", str(d / "trr.h5")]),
        ("eval", ["eval", str(d / "mc.h5"), "--gt", gt]),
        ("flow dnn", ["flow", rec, "--method", "dnn", "--window-events", "30000",
                      "--out", str(d / "dnn.h5")]),
        ("flow multicm --init dnn",
         ["flow", rec, "--method", "multicm", "--init", "dnn", "--window-events", "30000",
          "--out", str(d / "mcd.h5")]),
        ("train (one step)", ["train", "--sim-windows", "2", "--batch-size", "2", "--epochs",
                              "1", "--max-steps", "1", "--val-sim", "1",
                              "--out", str(d / "train")]),
        ("simulate schlieren", ["simulate", "schlieren", "--scene", "plume", "--size",
                                "180x160", "--duration", "0.05", "--out", str(d / "bos")]),
        ("bos", ["bos", str(d / "bos"), "--out", str(d / "bos.h5")]),
        ("kymogram", ["kymogram", str(d / "bos"), "--col", "80", "--out", str(d / "k.png")]),
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


def measure(src: Path, tag: str, only: list[str] | None = None, label: str | None = None
            ) -> list[dict]:
    """Time the commands (those named in ``only``, and the simulation
    they read) into ``results/cold_start_<tag>.json``, saved after each command; rows of
    other commands already there are kept. ``label`` names the tree measured (a commit)."""
    out = harness.RESULTS / f"cold_start_{tag}.json"
    old = json.loads(out.read_text())["rows"] if out.exists() else []
    rows = [r for r in old if only and r["command"] not in only
            and r["command"] != "simulate rotation"]
    with tempfile.TemporaryDirectory(prefix="evm-cold-") as tmp:
        work = Path(tmp)
        for name, argv in commands(work):
            if only and name not in only and name != "simulate rotation":
                continue
            r = run_cold(src, argv, work)
            rows.append({"command": name, **r})
            print(f"{tag:>7} {name:40s} " + (
                f"wall {r['wall_s']:6.1f} s  cpu {r['cpu_s']:6.1f} s  compile cpu "
                f"{r['compile_cpu_s']:6.1f} s" if "wall_s" in r else f"FAILED {r}"),
                flush=True)
            out.write_text(json.dumps({"src": str(src), "tag": tag, "label": label or str(src),
                                       "date": time.strftime("%Y-%m-%d %H:%M:%S"),
                                       "rows": rows}, indent=2))
    return rows


def table() -> list[dict]:
    """``results/cold_start.md``/``.json``: the tagged runs side by side."""
    runs, labels = {}, {"before": "commit 7c713d1", "after": "this branch"}
    for tag in ("before", "after"):
        p = harness.RESULTS / f"cold_start_{tag}.json"
        if p.exists():
            run = json.loads(p.read_text())
            runs[tag] = {r["command"]: r for r in run["rows"]}
            labels[tag] = run.get("label", labels[tag])
    names = list(dict.fromkeys(n for rs in runs.values() for n in rs))
    rows = []
    for n in names:
        row = {"command": n}
        for tag, rs in runs.items():
            r = rs.get(n, {})
            for k in ("wall_s", "cpu_s", "compile_cpu_s", "run_cpu_s", "compile_wall_s"):
                if k in r:
                    row[f"{tag} {k}"] = round(r[k], 2)
        rows.append(row)
    harness.record("cold_start", rows, notes=(
        "Each command in a fresh process with an empty NUMBA_CACHE_DIR, one thread "
        "(python -m evmotion via a driver counting numba:compile events). wall/cpu: the "
        "whole process (cpu = user + sys, os.wait4); compile: inside numba compilation "
        "(outermost events; compile_cpu: the compiling thread's CPU time); run = total - "
        f"compile. before = {labels['before']} (a git worktree on PYTHONPATH), after = "
        f"{labels['after']}; same machine, shared with other jobs (cpu is the steadier "
        "figure)."))
    return rows


#: The child of :func:`warm_ab`: times bench_cmax's rows with the package on its path.
WARM_CHILD = r'''
import json, sys
from functools import partial
import numpy as np
sys.path.insert(0, sys.argv[2])
import harness
from bench_cmax import COLLAPSE_THETA, WARP_THETA, _events
from evmotion.core.warps import make_warp
from evmotion.events import EventArray
from evmotion.methods.egomotion import CMaxCost, estimate_egomotion

harness.pin_idlest_core()
shape = (260, 346)
x, y, dt, p, _ = _events(30_000, shape)
K = np.array([[shape[1] * 0.8, 0, shape[1] / 2], [0, shape[1] * 0.8, shape[0] / 2], [0, 0, 1.0]])
out = {}
for wname in ("rotation", "similarity", "se2", "inplane", "zoom", "translation"):
    warp = make_warp(wname, shape, K=K)
    for motion, th in (("ordinary", WARP_THETA[wname]), ("collapse", COLLAPSE_THETA[wname])):
        if th is None:
            continue
        for reg in (None, "rcad", "divergence", "deformation"):
            c = CMaxCost(warp, x, y, dt, shape, "variance", reg, weight=1.0, polarity=p)
            r = harness.timeit(partial(c.value_grad, np.asarray(th, float)), repeat=30)
            out[f"{wname} {motion} {reg or 'none'}"] = r["min_s"], r["median_s"]
x, y, dt, p, t = _events(30_000, shape, seed=1)
ev = EventArray(x.astype(np.float32), y.astype(np.float32), t, p, sensor_size=shape,
                validate=False)
r = harness.timeit(lambda: estimate_egomotion(ev, "similarity", regularizer="rcad",
                                              kernel="bilinear", maps=False), repeat=7)
out["estimate similarity rcad bfgs"] = r["min_s"], r["median_s"]
with open(sys.argv[1], "w") as fh:
    json.dump(out, fh)
'''


def warm_ab(before_src: Path, rounds: int = 3, label: str = "commit 7c713d1") -> list[dict]:
    """Warm speed before and after, in child processes timed in turn (see the module
    docstring)."""
    runs = {"before": [], "after": []}
    with tempfile.TemporaryDirectory(prefix="evm-warm-") as tmp:
        out = Path(tmp, "out.json")
        for _ in range(rounds):
            for tag, src in (("before", before_src), ("after", SRC)):
                env = dict(os.environ, PYTHONPATH=str(src), OMP_NUM_THREADS="1",
                           OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
                env.pop("NUMBA_CACHE_DIR", None)  # each checkout's own warm cache
                subprocess.run([sys.executable, "-c", WARM_CHILD, str(out), str(HERE)],
                               env=env, check=True)
                runs[tag].append(json.loads(out.read_text()))
    rows = []
    for name in runs["after"][0]:
        b_min = min(r[name][0] for r in runs["before"])
        a_min = min(r[name][0] for r in runs["after"])
        b_med = statistics.median(r[name][1] for r in runs["before"])
        a_med = statistics.median(r[name][1] for r in runs["after"])
        rows.append({"row": name, "before ms (min)": b_min * 1e3, "after ms (min)": a_min * 1e3,
                     "after/before (min)": a_min / b_min,
                     "before ms (median)": b_med * 1e3, "after ms (median)": a_med * 1e3,
                     "after/before (median)": a_med / b_med})
    harness.record("cold_start_warm", rows, notes=(
        f"Warm speed, before ({label}) and after (this branch), {rounds} rounds of one "
        "child process each in turn, each pinned to the idlest core (harness."
        "pin_idlest_core), warm numba cache. Rows: bench_cmax's cost + gradient of 30k events "
        "at 346x260 (variance, weight 1, ordinary and collapsing parameters), ms per "
        "evaluation: min over rounds of the fastest of 30 runs, and median over rounds of the "
        "medians; last row a whole similarity + RCAD BFGS estimate (bench_cmax's). The machine "
        "is shared with other jobs: the min is the steadier figure."))
    return rows


def main(quick: bool = False) -> list[dict]:
    measure(SRC, "after", only=["egomotion rotation", "flow multicm"] if quick else None)
    return table()


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--src", default=str(SRC), help="folder holding the evmotion package")
    ap.add_argument("--tag", default="after", choices=["before", "after"])
    ap.add_argument("--only", nargs="*", help="only these commands (names as in the table)")
    ap.add_argument("--table", action="store_true", help="only merge the recorded runs")
    ap.add_argument("--label", help="what --src holds, for the table (e.g. 'commit abc1234')")
    ap.add_argument("--warm", metavar="BEFORE_SRC", help="warm speed before/after instead")
    args = ap.parse_args()
    if args.warm:
        warm_ab(Path(args.warm), label=args.label or "commit 7c713d1")
        sys.exit(0)
    if not args.table:
        measure(Path(args.src), args.tag, args.only, args.label)
    table()
