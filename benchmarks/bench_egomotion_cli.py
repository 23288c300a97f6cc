"""``evmotion egomotion`` end to end with its default PNG panels: where the panels are drawn.

The recording of ``bench_cluster`` (simulated translation, 1 s at 240x180, 35 windows of
20k events), ``--warp affine --reg divergence``, with ``--max-png 20`` (the default) and
``--max-png 0``, on 1 and 2 local worker processes. Each command runs in a fresh process
(start-up included), the variants interleaved, medians of ``repeat`` runs. With
``--before DIR`` the same commands also run from another checkout's ``src`` (the code
before a change) in the same rounds.

``python benchmarks/bench_egomotion_cli.py [--quick] [--before DIR]``
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import harness
from bench_cluster import _recording

SRC = Path(__file__).resolve().parents[1] / "src"


def _run(src: Path, rec: Path, out: Path, max_png: int, workers: int) -> float:
    env = {**os.environ, "PYTHONPATH": str(src), "OPENBLAS_NUM_THREADS": "1",
           "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    cmd = [sys.executable, "-m", "evmotion", "egomotion", str(rec), "--warp", "affine",
           "--reg", "divergence", "--window-events", "20000", "--max-png", str(max_png),
           "--workers", str(workers), "--out", str(out)]
    t0 = time.perf_counter()
    subprocess.run(cmd, env=env, check=True, capture_output=True)
    return time.perf_counter() - t0


def main(quick: bool = False, before: str | None = None) -> list[dict]:
    repeat = 1 if quick else 3
    codes = {"after": SRC, **({"before": Path(before) / "src"} if before else {})}
    cases = [(code, png, w) for code in codes for png in (20, 0) for w in (1, 2)]
    times: dict[tuple, list[float]] = {c: [] for c in cases}
    with tempfile.TemporaryDirectory(prefix="bench_ego_cli_") as d:
        rec = _recording(Path(d))
        for code in codes:  # warm numba's cache and the file cache
            _run(codes[code], rec, Path(d) / "warm", 1, 1)
        for _ in range(repeat):
            for c in cases:
                times[c].append(_run(codes[c[0]], rec, Path(d) / "o", c[1], c[2]))
    rows = []
    for code in codes:
        for png in (20, 0):
            one, two = (statistics.median(times[(code, png, w)]) for w in (1, 2))
            rows.append({"code": code, "max_png": png, "workers_1_s": one, "workers_2_s": two,
                         "speedup_2_workers": one / two,
                         "png_cost_1_worker_s": None if png == 0 else
                         one - statistics.median(times[(code, 0, 1)])})
    harness.record("egomotion_cli", rows,
                   notes="evmotion egomotion REC --warp affine --reg divergence "
                         "--window-events 20000 --max-png N --workers W, REC = "
                         "bench_cluster's recording (35 windows, 240x180); fresh processes, "
                         f"interleaved, medians of {repeat}; load average "
                         f"{os.getloadavg()[0]:.2f} at the end. after: this tree (each "
                         "panel drawn in the window's job, a worker); before: --before's "
                         "checkout (panels drawn by the client after all windows). "
                         "png_cost_1_worker_s: the time --max-png 20 adds on one worker.")
    return rows


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--before", help="another checkout whose src/ runs as 'before'")
    a = ap.parse_args()
    main(a.quick, a.before)
