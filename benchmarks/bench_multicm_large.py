"""Memory and time of multicm at 1280x720 (issue #14: a near-static EVT3 recording took
155 s and 1.3 GB, with flow of up to 19,000 px/s where no event was).

Each case runs in a fresh process (its peak resident memory is its own ``ru_maxrss``) on the
real Prophesee recording ``../shared/data/formats/evt3.raw`` (1280x720, 1.2 M events,
10.8 s):

* ``window``: ``estimate_flow`` of the middle 30k-event window, plain and time-aware
  (Burgers, 40 bins, the default at 1280 px), with the flow's speed where events support it
  and where they do not (``valid``; before this change: pixels without events);
* ``cli``: ``evmotion flow --method multicm`` over the first ``--seconds`` (default 2.5 s)
  of the recording, written to HDF5: memory that grows with the number of windows shows
  here.

``--src DIR`` runs the cases against another checkout's ``src`` (e.g. the code before the
change) and labels the rows with ``--label``.

The whole recording (41 windows of 30k events, ``evmotion flow evt3.raw --method multicm
--out flow.h5``, measured once with ``/usr/bin/time -v`` on the loaded 2-core machine): before
604 s and 1.17 GB peak (every window's flow and four IWEs kept until the end), after 285 s
and 346 MB.

    python benchmarks/bench_multicm_large.py [--quick] [--src DIR --label before]
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import harness

DATA = Path(os.environ.get("EVMOTION_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared"
                           / "data")) / "formats" / "evt3.raw"
SRC = Path(__file__).resolve().parents[1] / "src"

_WINDOW = r"""
import json, resource, sys, time
import numpy as np
from evmotion.io import read_events
from evmotion.methods.multicm import estimate_flow
ev = read_events(sys.argv[1])
wins = ev.windows_by_count(30_000)
sub = ev.window(wins[len(wins) // 2])
rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
t = time.perf_counter()
res = estimate_flow(sub, time_aware=None if sys.argv[2] == "none" else sys.argv[2])
sec = time.perf_counter() - t
speed = np.linalg.norm(res.flow, axis=-1)
valid = getattr(res, "valid", None)
if valid is None:
    valid = res.iwes["identity"] > 0
print(json.dumps({"seconds": sec, "rss_before_MB": rss0,
                  "peak_rss_MB": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "n_events": len(sub), "window_ms": (int(sub.t[-1]) - int(sub.t[0])) / 1e3,
                  "valid_fraction": float(valid.mean()),
                  "median_speed_valid": float(np.median(speed[valid])),
                  "median_speed_unsupported": float(np.median(speed[~valid])),
                  "max_speed_unsupported": float(speed[~valid].max())}))
"""

_CUT = r"""
import sys
from evmotion.io import read_events, write_events
ev = read_events(sys.argv[1])
write_events(sys.argv[2], ev.slice_time(int(ev.t[0]), int(ev.t[0] + float(sys.argv[3]) * 1e6)))
"""

_CLI = r"""
import json, resource, sys, time
from evmotion.cli import main
t = time.perf_counter()
rc = main(["flow", sys.argv[1], "--method", "multicm", "--out", sys.argv[2]])
print(json.dumps({"rc": rc, "seconds": time.perf_counter() - t,
                  "peak_rss_MB": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def _run(code: str, args: list[str], src: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=str(src), OPENBLAS_NUM_THREADS="1",
               NUMBA_NUM_THREADS="1", OMP_NUM_THREADS="1")
    out = subprocess.run([sys.executable, "-c", code, *args], env=env, check=True,
                         capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(quick: bool = False, src: Path = SRC, label: str = "after",
         seconds: float = 2.5) -> list[dict]:
    if not DATA.exists():
        print(f"skipped: {DATA} not found")
        return []
    rows = []
    # compile once, so that the timed runs do not pay numba's cache misses
    _run(_WINDOW, [str(DATA), "none"], src)
    for ta in (("none",) if quick else ("none", "burgers")):
        r = _run(_WINDOW, [str(DATA), ta], src)
        rows.append({"code": label, "case": f"window time_aware={ta}", **r})
        print(rows[-1], flush=True)
    with tempfile.TemporaryDirectory() as d:
        cut = Path(d) / "cut.h5"
        _run(_CUT + "\nprint('{}')", [str(DATA), str(cut), str(seconds)], src)
        r = _run(_CLI, [str(cut), str(Path(d) / "flow.h5")], src)
        rows.append({"code": label, "case": f"cli flow multicm, first {seconds:g} s", **r})
        print(rows[-1], flush=True)
    # keep the rows of the other code version (before/after) from the previous record
    prev = harness.RESULTS / "multicm_large.json"
    keep = []
    if prev.exists():
        keep = [r for r in json.loads(prev.read_text())["rows"] if r.get("code") != label]
    harness.record("multicm_large", keep + rows, notes="evt3.raw (Prophesee 1280x720, "
                   "near-static), each case in a fresh process; 'before' = the code before "
                   "issue #14's fix (--src of that checkout), 'after' = this one; speeds in "
                   "px/s; 'unsupported' = pixels outside the validity mask (before: without "
                   "events)")
    return rows


if __name__ == "__main__":
    argv = sys.argv[1:]
    kw = {}
    if "--src" in argv:
        kw["src"] = Path(argv[argv.index("--src") + 1]).resolve()
    if "--label" in argv:
        kw["label"] = argv[argv.index("--label") + 1]
    main(quick="--quick" in argv, **kw)
