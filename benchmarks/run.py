"""Run benchmark suites: ``python benchmarks/run.py [--quick] [suite ...]``.

A suite is a module ``benchmarks/bench_<suite>.py`` with ``main(quick) -> list[dict]``.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from pathlib import Path

# BLAS reads its thread count once, when numpy loads: on the one pinned core of a benchmark,
# extra BLAS threads only spin (milliseconds per matrix product), so set it before any suite
# imports numpy (harness.single_core() pins the process later).
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))


def main() -> int:
    suites = sorted(p.stem.removeprefix("bench_") for p in HERE.glob("bench_*.py"))
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("suites", nargs="*", choices=suites + [[]], default=[])
    ap.add_argument("--quick", action="store_true", help="fewer repeats (smoke run)")
    args = ap.parse_args()
    for name in args.suites or suites:
        print(f"== {name}", flush=True)
        importlib.import_module(f"bench_{name}").main(quick=args.quick)
    return 0


if __name__ == "__main__":
    sys.exit(main())
