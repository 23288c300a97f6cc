"""Run time against sensor size at a fixed event count (probe DB: the same 4,292 events took
15 s of ``estimate_egomotion(ev, "translation")`` on 4096x4096 against 0.01 s on 60x80, 10.6
s of it in the checks of the estimate; multicm 23 s).

The simulated translation of a 120x160 scene (0.05 s, 21,472 events) is placed unchanged
(offset x + 500, y + 300) on 1280x720 and 4096x4096 sensors, beside the middle 30k-event
window of the shared Prophesee recording (``../shared/data/formats/evt3.raw``, 1280x720).
Per case: ``estimate_egomotion(ev, "translation")`` with its defaults (checks on, maps
on), its wall time and the checks' own (``timings["diagnose"]``), and ``estimate_flow``
(multicm) on the sparse 4096x4096 case.

The code before and after runs in the same benchmark, in fresh processes taking turns
(before, after, before, ...): "before" is a ``git worktree`` of ``--before`` (default
:data:`BEFORE`, the commit before the change) on ``PYTHONPATH``, "after" this checkout's
``src``. Times are medians over the rounds of each process's median; the verdicts (valid,
collapsed, poor fit, explained share, contrast and chance gains) of both are listed and
must agree.

    python benchmarks/run.py large_sensor [--quick]
    python benchmarks/bench_large_sensor.py [--quick] [--before COMMIT]
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import harness

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("EVMOTION_SHARED_DATA", ROOT.parent / "shared" / "data"))
#: The commit before the change (probe DB's report was against it).
BEFORE = "affbead"

_CHILD = r"""
import json, statistics, sys, time, warnings
import numpy as np
from evmotion.events import EventArray
from evmotion.methods.egomotion import estimate_egomotion
from evmotion.methods.multicm import estimate_flow
from evmotion.sim import simulate
warnings.simplefilter("ignore")
repeat, data, flow_reps = int(sys.argv[1]), sys.argv[2], int(sys.argv[3])
ev = simulate("translation", duration_s=0.05, sensor_size=(120, 160), seed=0,
              show_progress=False).events
def placed(size):
    return EventArray(np.asarray(ev.x) + 500, np.asarray(ev.y) + 300, ev.t, ev.p, size)
cases = {"sim 120x160": ev, "sim on 1280x720": placed((720, 1280)),
         "sim on 4096x4096": placed((4096, 4096))}
if data != "-":
    from evmotion.io import read_events
    rec = read_events(data)
    wins = rec.windows_by_count(30_000)
    cases["evt3 1280x720 30k"] = rec.window(wins[len(wins) // 2])
def verdicts(r):
    d = r.diagnostics
    return {"valid": bool(r.valid), "collapsed": bool(r.collapsed),
            "poor_fit": bool(r.poor_fit),
            "explained_share": float(d["fit"].get("explained_share", float("nan"))),
            "contrast_gain": float(d["contrast_gain"]), "chance_gain": float(d["chance_gain"])}
out = {}
estimate_egomotion(ev, "translation")  # numba's caches, once
for name, e in cases.items():
    tot, diag = [], []
    for _ in range(repeat + 1):  # the first run warms the memory up, untimed
        t0 = time.perf_counter()
        r = estimate_egomotion(e, "translation")
        tot.append(time.perf_counter() - t0)
        diag.append(r.timings["diagnose"])
    out["egomotion " + name] = {"events": len(e), "sensor": "x".join(map(str, e.sensor_size[::-1])),
                                "s": statistics.median(tot[1:]),
                                "diagnose_s": statistics.median(diag[1:]), **verdicts(r)}
if flow_reps:
    e = cases["sim on 4096x4096"]
    tot = []
    for _ in range(flow_reps):
        t0 = time.perf_counter()
        f = estimate_flow(e)
        tot.append(time.perf_counter() - t0)
    m = f.meta
    out["multicm sim on 4096x4096"] = {
        "events": len(e), "sensor": "4096x4096", "s": statistics.median(tot),
        "valid_px": int(f.valid.sum()), "no_focus": bool(m.get("no_focus")),
        "chance_gain": float(m.get("chance_gain", float("nan"))),
        "halves": float(m.get("halves_correlation", float("nan"))),
        "flow_sum": float(np.nansum(np.abs(f.flow), dtype=np.float64))}
print(json.dumps(out))
"""


def _child(src: Path, repeat: int, flow_reps: int) -> dict:
    env = dict(os.environ, PYTHONPATH=str(src), OPENBLAS_NUM_THREADS="1",
               NUMBA_NUM_THREADS="1", OMP_NUM_THREADS="1")
    data = DATA / "formats" / "evt3.raw"
    out = subprocess.run([sys.executable, "-c", _CHILD, str(repeat),
                          str(data) if data.exists() else "-", str(flow_reps)],
                         env=env, check=True, capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(quick: bool = False, before: str = BEFORE) -> list[dict]:
    cpu = harness.pin_idlest_core()  # (the children inherit the core)
    rounds, repeat = (1, 1) if quick else (3, 3)
    runs: dict[str, list[dict]] = {"before": [], "after": []}
    with tempfile.TemporaryDirectory() as tmp:
        tree = Path(tmp) / "before"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(tree),
                        before], check=True, capture_output=True)
        try:
            for _ in range(rounds):
                for label, src in (("before", tree / "src"), ("after", ROOT / "src")):
                    runs[label].append(_child(src, repeat, flow_reps=1))
                    print(label, runs[label][-1], flush=True)
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force",
                            str(tree)], check=False, capture_output=True)
    after_sha = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"],
                               capture_output=True, text=True).stdout.strip()
    rows = []
    for case in runs["after"][0]:
        b = [r[case] for r in runs["before"]]
        a = [r[case] for r in runs["after"]]
        row = {"case": case, "events": a[0]["events"], "sensor": a[0]["sensor"],
               "before s": statistics.median(r["s"] for r in b),
               "after s": statistics.median(r["s"] for r in a)}
        if "diagnose_s" in a[0]:
            row["before checks s"] = statistics.median(r["diagnose_s"] for r in b)
            row["after checks s"] = statistics.median(r["diagnose_s"] for r in a)
        row["speedup"] = row["before s"] / row["after s"]
        if "before checks s" in row:
            row["checks speedup"] = row["before checks s"] / row["after checks s"]
        skip = {"s", "diagnose_s", "events", "sensor"}
        vb = {k: v for k, v in b[0].items() if k not in skip}
        va = {k: v for k, v in a[0].items() if k not in skip}
        row["verdicts before"] = json.dumps(vb)
        row["verdicts equal"] = all(
            v == va[k] or (isinstance(v, float) and abs(v - va[k]) <= 1e-9 * max(1.0, abs(v)))
            for k, v in vb.items())
        rows.append(row)
    harness.record("large_sensor", rows, notes=(
        f"before = {before}, after = {after_sha} plus the working tree; fresh processes "
        f"taking turns, {rounds} round(s) of {repeat} timed run(s) each (multicm: 1), "
        f"medians; one pinned core ({cpu}) on a shared 2-core machine. Egomotion: "
        "estimate_egomotion(ev, 'translation'), defaults; 'checks' = timings['diagnose'] "
        "(collapse, fit, chance, contrast gain). Verdicts compared within 1e-9 relative."))
    return rows


if __name__ == "__main__":
    argv = sys.argv[1:]
    kw = {"before": argv[argv.index("--before") + 1]} if "--before" in argv else {}
    main(quick="--quick" in argv, **kw)
