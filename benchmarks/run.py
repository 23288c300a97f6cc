"""Run benchmark suites: ``python benchmarks/run.py [--quick] [suite ...]``.

A suite is a module ``benchmarks/bench_<suite>.py`` with ``main(quick) -> list[dict]``.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from pathlib import Path

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
