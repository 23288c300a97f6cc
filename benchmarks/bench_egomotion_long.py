"""egomotion on long recordings: peak memory and time of the streamed read (a block of
windows at a time, :mod:`evmotion.cli.windowed`) against the whole read, in the same run.

Recordings of 1280 x 720 events are made by tiling ``../shared/data/formats/evt3.raw``
(1.22 M events, 10.8 s) end to end, sped up 10x, into evmotion HDF5 files of growing length.
Each row runs ``evmotion egomotion FILE --warp translation --max-png 0`` (its default
windows: 307k events each on this sensor) in a fresh process, streamed (the command as it
is) and whole (the same command with :data:`evmotion.streamed_windows.BLOCK_EVENTS` set
past the recording's length, as every recording was read before), the two in turns;
peak RSS of the process (``getrusage``), wall time, and whether the two params.csv agree
(all columns but the seconds each window took).

``python benchmarks/run.py egomotion_long [--quick]``
"""

from __future__ import annotations

import csv
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
DATA = Path(os.environ.get("EVMOTION_SHARED_DATA", HERE.parents[1] / "shared" / "data"))
SOURCE = DATA / "formats" / "evt3.raw"

RUN = """
import sys
import evmotion.streamed_windows as s
if sys.argv[1] == "whole":
    s.BLOCK_EVENTS = 10**12
from evmotion.cli import main
raise SystemExit(main(sys.argv[2:]))
"""


def _tile(path: Path, reps: int) -> int:
    from evmotion.events import EventArray
    from evmotion.io import read_events
    from evmotion.io.h5 import EventWriter

    src = read_events(SOURCE)
    t = ((src.t - src.t[0]) // 10).astype(np.int64)
    period = int(t[-1]) + 1
    with EventWriter(path, src.sensor_size) as w:
        for r in range(reps):
            w.append(EventArray(src.x, src.y, t + r * period, src.p, src.sensor_size,
                                validate=False))
    return reps * len(src)


def _run(mode: str, path: Path, out: Path) -> dict:
    env = dict(os.environ, EVMOTION_PROGRESS="0", NUMBA_NUM_THREADS="1")
    argv = ["egomotion", str(path), "--warp", "translation", "--max-png", "0",
            "--out", str(out)]
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-c", RUN, mode, *argv], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    proc.stdout.close()
    if os.waitstatus_to_exitcode(status) != 0:
        raise RuntimeError(f"{mode} run on {path} failed")
    return {"wall_s": wall, "peak_mb": usage.ru_maxrss / 1024}


def _rows(out: Path) -> list[list[str]]:
    rows = list(csv.reader((out / "params.csv").open()))
    drop = rows[0].index("seconds")
    return [r[:drop] + r[drop + 1:] for r in rows]


def main(quick: bool = False) -> list[dict]:
    if not SOURCE.exists():
        print(f"skipped: {SOURCE} missing (EVMOTION_SHARED_DATA)")
        return []
    lengths = (4, 16) if quick else (4, 16, 40)
    repeat = 1 if quick else 2
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for reps in lengths:
            path = tmp / f"long{reps}.h5"
            n = _tile(path, reps)
            runs = {"streamed": [], "whole": []}
            for k in range(repeat):
                for mode in runs:
                    runs[mode].append(_run(mode, path, tmp / f"{mode}{k}"))
            same = all(_rows(tmp / f"streamed{k}") == _rows(tmp / f"whole{k}")
                       for k in range(repeat))
            med = {m: {key: statistics.median(r[key] for r in runs[m])
                       for key in ("wall_s", "peak_mb")} for m in runs}
            rows.append({"events": n, "windows": len(_rows(tmp / "streamed0")) - 1,
                         "streamed_peak_MB": med["streamed"]["peak_mb"],
                         "whole_peak_MB": med["whole"]["peak_mb"],
                         "peak_ratio": med["streamed"]["peak_mb"] / med["whole"]["peak_mb"],
                         "streamed_s": med["streamed"]["wall_s"],
                         "whole_s": med["whole"]["wall_s"],
                         "time_ratio": med["streamed"]["wall_s"] / med["whole"]["wall_s"],
                         "same_params": same})
            path.unlink()
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    harness.record("egomotion_long", rows,
                   notes=f"medians of {repeat} run(s) each, streamed and whole in turns; "
                         "block 2^23 events; this harness process peaked at "
                         f"{peak:.0f} MB (tiling).")
    return rows


if __name__ == "__main__":
    main(quick="--quick" in sys.argv)
