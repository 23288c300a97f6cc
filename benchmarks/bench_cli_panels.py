"""``evmotion egomotion`` and ``evmotion segment`` end to end with their default PNG
panels, on 1 and 2 local worker processes: where the panels are drawn.

The recording of ``bench_cluster`` (simulated translation, 1 s at 240x180, 35 windows of
20k events). egomotion: ``--warp affine --reg divergence`` with ``--max-png 20`` (the
default) and ``--max-png 0``; segment: ``--warp translation --warps 2`` (a panel every
window). Each command runs in a fresh process (start-up included), the variants
interleaved, medians of ``repeat`` runs. With ``--before DIR`` the same commands also run
from another checkout's ``src`` (the code before a change) in the same rounds.

``python benchmarks/bench_cli_panels.py [--quick] [--before DIR]``
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
from bench_cluster import recording

SRC = Path(__file__).resolve().parents[1] / "src"


COMMANDS = {
    "egomotion --max-png 20": ["egomotion", "{rec}", "--warp", "affine", "--reg",
                               "divergence", "--window-events", "20000", "--max-png", "20"],
    "egomotion --max-png 0": ["egomotion", "{rec}", "--warp", "affine", "--reg", "divergence",
                              "--window-events", "20000", "--max-png", "0"],
    "segment": ["segment", "{rec}", "--warp", "translation", "--warps", "2",
                "--window-events", "20000"],
}


def _run(src: Path, rec: Path, out: Path, case: str, workers: int) -> float:
    env = {**os.environ, "PYTHONPATH": str(src), "OPENBLAS_NUM_THREADS": "1",
           "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    cmd = [sys.executable, "-m", "evmotion", *[a.format(rec=rec) for a in COMMANDS[case]],
           "--workers", str(workers), "--out", str(out)]
    t0 = time.perf_counter()
    subprocess.run(cmd, env=env, check=True, capture_output=True)
    return time.perf_counter() - t0


def main(quick: bool = False, before: str | None = None) -> list[dict]:
    repeat = 1 if quick else 3
    codes = {"after": SRC, **({"before": Path(before) / "src"} if before else {})}
    cases = [(code, case, w) for code in codes for case in COMMANDS for w in (1, 2)]
    times: dict[tuple, list[float]] = {c: [] for c in cases}
    with tempfile.TemporaryDirectory(prefix="bench_ego_cli_") as d:
        rec = recording(Path(d))
        for code in codes:  # warm numba's cache and the file cache
            for case in COMMANDS:
                _run(codes[code], rec, Path(d) / "warm", case, 1)
        for _ in range(repeat):
            for c in cases:
                times[c].append(_run(codes[c[0]], rec, Path(d) / "o", c[1], c[2]))
    rows = []
    for code in codes:
        for case in COMMANDS:
            one, two = (statistics.median(times[(code, case, w)]) for w in (1, 2))
            rows.append({"code": code, "command": case, "workers_1_s": one,
                         "workers_2_s": two, "speedup_2_workers": one / two})
    harness.record("cli_panels", rows,
                   notes="evmotion COMMAND REC ... --workers W (see the module), REC = "
                         "bench_cluster's recording (35 windows, 240x180); fresh processes, "
                         f"interleaved, medians of {repeat}; load average "
                         f"{os.getloadavg()[0]:.2f} at the end. after: this tree (each "
                         "panel drawn in the window's job, a worker); before: --before's "
                         "checkout (panels drawn by the client after all windows).")
    return rows


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--before", help="another checkout whose src/ runs as 'before'")
    a = ap.parse_args()
    main(a.quick, a.before)
