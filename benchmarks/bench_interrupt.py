"""Ctrl-C at every moment of a short command: where an interrupt still ends in a traceback.

``evmotion --version`` (the installed script) and ``python -m evmotion --version`` are
started ``n`` times each and sent SIGINT after a delay swept from 0 to 1.1x the command's
run time. An outcome is clean when the command exits 130 with the one line "evmotion:
interrupted", or 0 with nothing on stderr (finished first), or dies of the signal before
Python printed anything. Otherwise the row counts where the traceback ended: in
evmotion's own files (a defect: the package takes over Ctrl-C in its first lines, see
``evmotion/__init__.py``) or before any of them ran (the interpreter's start-up: site,
the import system finding the package), which no package can reach.

``python benchmarks/run.py interrupt [--quick]``
"""

from __future__ import annotations

import collections
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import harness

CLEAN = "evmotion: interrupted\n"


def _where(err: str) -> str:
    frames = [line.strip() for line in err.splitlines() if line.strip().startswith('File "')]
    ours = [f for f in frames if "/evmotion/" in f and "/bin/evmotion" not in f]
    return "evmotion code" if ours else "interpreter start-up"


def probe(cmd: list[str], n: int) -> dict:
    runs = []
    for _ in range(3):
        t0 = time.perf_counter()
        subprocess.run(cmd, capture_output=True, check=True)
        runs.append(time.perf_counter() - t0)
    full = sorted(runs)[1]
    kinds: collections.Counter = collections.Counter()
    last_bad_ms = 0.0
    for i in range(n):
        delay = full * 1.1 * i / n
        p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        time.sleep(delay)
        try:
            p.send_signal(signal.SIGINT)
        except ProcessLookupError:
            pass
        _, err = p.communicate(timeout=60)
        clean = (p.returncode == 130 and err == CLEAN) or (p.returncode == 0 and not err) \
            or (p.returncode == -signal.SIGINT and not err)
        if clean:
            kinds["clean"] += 1
        else:
            kinds[_where(err)] += 1
            last_bad_ms = max(last_bad_ms, delay * 1e3)
    return {"command": " ".join(Path(c).name if i == 0 else c for i, c in enumerate(cmd)),
            "run_ms": round(full * 1e3, 1), "interrupts": n, "clean": kinds["clean"],
            "traceback_in_evmotion_code": kinds["evmotion code"],
            "traceback_in_interpreter_startup": kinds["interpreter start-up"],
            "latest_traceback_at_ms": round(last_bad_ms, 1)}


def main(quick: bool = False) -> list[dict]:
    n = 60 if quick else 300
    script = shutil.which("evmotion") or str(Path(sys.executable).parent / "evmotion")
    rows = [probe([script, "--version"], n),
            probe([sys.executable, "-m", "evmotion", "--version"], n)]
    harness.record("interrupt", rows, f"SIGINT after a delay swept over 0-1.1x the run time, "
                   f"{n} runs per command; traceback_in_evmotion_code must be 0.")
    return rows


if __name__ == "__main__":
    main(quick="--quick" in sys.argv)
