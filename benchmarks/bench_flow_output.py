"""Write speed and size of a dense flow sequence in every container of
:func:`evmotion.io.flowout.open_flow_output`: 100 windows of 346 x 260 px (a DAVIS346),
one core, on the local disk (a temporary folder).

The flow is a smooth field (rotation + translation, changing per window) with estimation
noise, in float32 (as estimates are: full mantissas, so lossless codecs gain little), and a
valid mask on ~60 % of the pixels. Each row is the median over ``repeat`` complete writes
(open, 100 appends, close: the rename or assembly included).
"""

from __future__ import annotations

import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

import harness

H, W, N = 260, 346, 100
DT_US = 20_000


def _sequence(seed: int = 0):
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    flows, valids = [], []
    for i in range(N):
        w = 0.5 + 0.01 * i  # rad/s
        u = -w * (yy - H / 2) + 40.0 + rng.normal(0, 2.0, (H, W))
        v = w * (xx - W / 2) - 10.0 + rng.normal(0, 2.0, (H, W))
        flows.append(np.stack([u, v], axis=-1).astype(np.float32))
        valids.append(rng.random((H, W)) < 0.6)
    return flows, valids


def _size(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())


def main(quick: bool = False) -> list[dict]:
    harness.pin_idlest_core()
    from evmotion.io.flowout import open_flow_output

    flows, valids = _sequence()
    repeat = 1 if quick else 3
    cases = {
        ".h5 (Blosc-LZ4, default)": ("f.h5", {}),
        ".h5 (Blosc-zstd)": ("f.h5", {"compression": "zstd"}),
        ".h5 (gzip 1 + shuffle)": ("f.h5", {"compression": "gzip"}),
        ".h5 (lzf)": ("f.h5", {"compression": "lzf"}),
        ".h5 (no compression)": ("f.h5", {"compression": None}),
        ".npz (stored)": ("f.npz", {}),
        ".flo pattern + JSON sidecars": ("f_{:05d}.flo", {}),
        ".png DSEC pattern + JSON sidecars": ("f_{:05d}.png", {}),
    }
    rows = []
    raw_mb = N * H * W * 2 * 4 / 1e6
    for label, (name, kw) in cases.items():
        def write(name=name, kw=kw):
            d = Path(tempfile.mkdtemp(prefix="bench-flowout-"))
            with open_flow_output(d / name, (H, W), {"method": "bench"}, n_windows=N,
                                  **kw) as out:
                for i in range(N):
                    out.append(flows[i], i * DT_US, (i + 1) * DT_US, valid=valids[i])
            return d

        sizes = []

        def timed(write=write, sizes=sizes):
            d = write()
            sizes.append(_size(d))
            shutil.rmtree(d)

        r = harness.timeit(timed, repeat=repeat, warmup=1)
        rows.append({"container": label, "median_s": r["median_s"], "min_s": r["min_s"],
                     "windows_per_s": N / r["median_s"],
                     "raw_flow_MB_per_s": raw_mb / r["median_s"],
                     "output_MB": sizes[-1] / 1e6})
        print(rows[-1], file=sys.stderr)
    harness.record("flow_output", rows,
                   notes=f"{N} windows of {W}x{H} px float32 flow ({raw_mb:.1f} MB raw) + "
                         "valid mask, one core, local disk; median of "
                         f"{repeat} complete writes (open, {N} appends, close)")
    return rows


if __name__ == "__main__":
    main(quick="--quick" in sys.argv)
