"""I/O speed and streaming memory: evmotion HDF5, DSEC layout, ECD text.

Each reader is compared with a reference run in the same process on the same file: a raw
h5py read of the same datasets (HDF5 formats) and ``np.loadtxt`` on a subset (ECD text).
Streaming memory is measured in a fresh subprocess (peak RSS, /proc VmHWM, above the
post-import baseline, plus the tracemalloc peak) while iterating over a
10 M-event file window by window.

Targets: HDF5 / DSEC reading >= 20 M events/s, ECD text >= 3 M events/s, streaming a
10 M-event file with peak memory <= 200 MB.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from evmotion.events import EventArray
from evmotion.io import dsec, ecd, h5
from harness import record, single_core, timeit

STREAM_SCRIPT = r"""
import json, resource, sys, tracemalloc
import evmotion.io as eio
import numpy as np


def hwm_mb():
    # VmHWM belongs to this process image; ru_maxrss would include the parent's peak
    # inherited across fork.
    try:
        for line in open("/proc/self/status"):
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


path, fmt, window_us = sys.argv[1], sys.argv[2], int(sys.argv[3])
eio.detect_format(path)  # imports the format modules before the baseline
base = hwm_mb()
tracemalloc.start()
n = nw = 0
if window_us > 0:
    it = eio.iter_events(path, 1_000_000, window_us=window_us, format=fmt)
else:
    it = [eio.read_events(path, format=fmt)]
for w in it:
    n += len(w)
    nw += 1
peak_py = tracemalloc.get_traced_memory()[1]
peak = hwm_mb()
print(json.dumps({"events": n, "windows": nw, "rss_baseline_mb": base, "rss_peak_mb": peak,
                  "rss_growth_mb": peak - base, "tracemalloc_peak_mb": peak_py / 2**20}))
"""


def _synthetic(n: int, seed: int = 0) -> EventArray:
    rng = np.random.default_rng(seed)
    t = 1_000_000_000 + np.cumsum(rng.integers(0, 2, n))  # ~2 M events/s
    return EventArray(x=rng.integers(0, 640, n).astype(np.uint16),
                      y=rng.integers(0, 480, n).astype(np.uint16), t=t,
                      p=rng.integers(0, 2, n).astype(np.uint8), sensor_size=(480, 640),
                      validate=False)


def _raw_h5(path: Path, names) -> int:
    import h5py

    from evmotion.io.h5filters import register_filters

    register_filters()
    with h5py.File(path, "r") as f:
        return sum(f[k][()].nbytes for k in names)


def _stream(path: Path, fmt: str, window_us: int) -> dict:
    out = subprocess.run([sys.executable, "-c", STREAM_SCRIPT, str(path), fmt, str(window_us)],
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(quick: bool = False) -> list[dict]:
    single_core()
    n = 2_000_000 if quick else 10_000_000
    n_txt = 300_000 if quick else 2_000_000
    repeat = 3 if quick else 7
    rows: list[dict] = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        ev = _synthetic(n)

        t0 = time.perf_counter()
        h5.write(tmp / "ev.h5", ev)
        rows.append({"case": "evmotion h5 write", "events": n,
                     "Mev_per_s": n / (time.perf_counter() - t0) / 1e6})
        r = timeit(lambda: h5.read(tmp / "ev.h5"), repeat=repeat, warmup=1)
        ref = timeit(lambda: _raw_h5(tmp / "ev.h5", [f"events/{k}" for k in "xytp"]),
                     repeat=repeat, warmup=1)
        rows.append({"case": "evmotion h5 read", "events": n, "median_s": r["median_s"],
                     "Mev_per_s": n / r["median_s"] / 1e6, "target_Mev_per_s": 20,
                     "reference": "raw h5py read", "ref_median_s": ref["median_s"],
                     "ratio_vs_ref": r["median_s"] / ref["median_s"]})
        sub = (int(ev.t[n // 3]), int(ev.t[n // 3 + 100_000]))
        r = timeit(lambda: h5.read(tmp / "ev.h5", t0=sub[0], t1=sub[1]), repeat=repeat)
        rows.append({"case": "evmotion h5 read 100k-event time slice (ms index)",
                     "events": 100_000, "median_s": r["median_s"],
                     "Mev_per_s": 1e5 / r["median_s"] / 1e6})

        dsec.write(tmp / "events.h5", ev)
        r = timeit(lambda: dsec.read(tmp / "events.h5"), repeat=repeat, warmup=1)
        ref = timeit(lambda: _raw_h5(tmp / "events.h5", [f"events/{k}" for k in "xytp"]),
                     repeat=repeat, warmup=1)
        rows.append({"case": "DSEC layout read (Blosc/zstd, t_offset)", "events": n,
                     "median_s": r["median_s"], "Mev_per_s": n / r["median_s"] / 1e6,
                     "target_Mev_per_s": 20, "reference": "raw h5py read",
                     "ref_median_s": ref["median_s"],
                     "ratio_vs_ref": r["median_s"] / ref["median_s"]})

        evt = ev[:n_txt]
        ecd.write(tmp / "events.txt", evt)
        r = timeit(lambda: ecd.read(tmp / "events.txt", sensor_size=(480, 640)),
                   repeat=repeat, warmup=1)
        sub_n = 100_000
        lines = (tmp / "events.txt").read_bytes().split(b"\n", sub_n)[:sub_n]
        (tmp / "sub.txt").write_bytes(b"\n".join(lines) + b"\n")
        ref = timeit(lambda: np.loadtxt(tmp / "sub.txt"), repeat=3, warmup=0)
        ref_rate = sub_n / ref["median_s"]
        rate = n_txt / r["median_s"]
        rows.append({"case": "ECD text read (numba parser)", "events": n_txt,
                     "median_s": r["median_s"], "Mev_per_s": rate / 1e6,
                     "target_Mev_per_s": 3, "reference": f"np.loadtxt on {sub_n:,} lines",
                     "ref_median_s": ref["median_s"], "ref_Mev_per_s": ref_rate / 1e6,
                     "speedup_vs_ref": rate / ref_rate})

        r = timeit(lambda: ecd.write(tmp / "w.txt", evt), repeat=repeat, warmup=1)
        arr = np.column_stack([evt.t[:sub_n] * 1e-6, evt.x[:sub_n], evt.y[:sub_n],
                               evt.p[:sub_n]])
        ref = timeit(lambda: np.savetxt(tmp / "ref.txt", arr, fmt="%.6f %d %d %d"),
                     repeat=3, warmup=0)
        rate, ref_rate = n_txt / r["median_s"], sub_n / ref["median_s"]
        rows.append({"case": "ECD text write (numba formatter)", "events": n_txt,
                     "median_s": r["median_s"], "Mev_per_s": rate / 1e6,
                     "reference": f"np.savetxt on {sub_n:,} events",
                     "ref_median_s": ref["median_s"], "ref_Mev_per_s": ref_rate / 1e6,
                     "speedup_vs_ref": rate / ref_rate})

        for fmt, path in (("h5", tmp / "ev.h5"), ("dsec", tmp / "events.h5")):
            s = _stream(path, fmt, 10_000)
            rows.append({"case": f"stream {fmt} in 10 ms windows (subprocess)",
                         "events": s["events"], "windows": s["windows"],
                         "rss_growth_mb": s["rss_growth_mb"], "rss_peak_mb": s["rss_peak_mb"],
                         "tracemalloc_peak_mb": s["tracemalloc_peak_mb"],
                         "target_peak_mb": 200})
        s = _stream(tmp / "ev.h5", "h5", 0)
        rows.append({"case": "reference: read whole h5 file (subprocess)",
                     "events": s["events"], "rss_growth_mb": s["rss_growth_mb"],
                     "rss_peak_mb": s["rss_peak_mb"],
                     "tracemalloc_peak_mb": s["tracemalloc_peak_mb"]})
    record("io", rows, notes=f"single core; synthetic {n:,} events (480x640, ~2 M ev/s); "
           "medians over repeats; references measured in the same run")
    return rows


if __name__ == "__main__":
    main(quick="--quick" in sys.argv)
