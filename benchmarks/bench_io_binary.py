"""Decoding speed of the binary camera-format readers (events/s on one core).

Each row times a whole-file ``read`` (and the streaming ``iter_chunks`` path where
noted) on the shared recordings, and gives the ratio to a plain ``np.fromfile`` of the
same file measured in the same run (the I/O floor). EVT3 target: >= 20 M events/s.
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

import numpy as np

import harness

DATA = Path(os.environ.get("EVMOTION_SHARED_DATA",
                           Path(__file__).resolve().parents[2] / "shared" / "data")) / "formats"


def _row(name, path, fn, n_events, repeat, note=""):
    io = harness.timeit(lambda: np.fromfile(path, np.uint8), repeat=repeat)
    res = harness.timeit(fn, repeat=repeat)
    return {"reader": name, "file": path.name, "events": n_events,
            "median_ms": res["median_s"] * 1e3,
            "Mev_per_s": n_events / res["median_s"] / 1e6,
            "best_Mev_per_s": n_events / res["min_s"] / 1e6,
            "file_read_ms": io["median_s"] * 1e3,
            "ratio_vs_file_read": res["median_s"] / io["median_s"], "note": note}


def main(quick: bool = False) -> list[dict]:
    harness.single_core()
    from evmotion.io import aedat2, aedat3, aedat4, dat, evt2, evt3, rosbag
    from evmotion.io.prophesee import parse_raw_header

    repeat = 3 if quick else 15
    rows = []
    if not DATA.is_dir():
        print(f"shared recordings not found at {DATA}; nothing to measure", file=sys.stderr)
        return rows
    raw3 = DATA / "evt3.raw"
    n3 = len(evt3.read(raw3))
    rows.append(_row("evt3.read", raw3, lambda: evt3.read(raw3), n3, repeat))
    rows.append(_row("evt3.read(validate=False)", raw3,
                     lambda: evt3.read(raw3, validate=False), n3, repeat))
    rows.append(_row("evt3.iter_chunks(100k)", raw3,
                     lambda: sum(len(c) for c in evt3.iter_chunks(raw3, 100_000)), n3, repeat,
                     "streaming, 4 MiB blocks"))
    _, off, _, _ = parse_raw_header(raw3, None)
    words = np.fromfile(raw3, np.uint8)[off:].view("<u2").copy()
    rows.append(_row("evt3.decode_words (in memory)", raw3, lambda: evt3.decode_words(words),
                     n3, repeat, "numba kernel, words already in RAM"))
    ev3 = evt3.read(raw3)
    tmp = Path(tempfile.mkdtemp())
    rows.append(_row("evt3.write", raw3, lambda: evt3.write(tmp / "w.raw", ev3), n3, repeat,
                     "encode + atomic write"))
    raw2 = DATA / "evt2.raw"
    n2 = len(evt2.read(raw2))
    rows.append(_row("evt2.read", raw2, lambda: evt2.read(raw2), n2, repeat))
    rows.append(_row("evt2.iter_chunks(100k)", raw2,
                     lambda: sum(len(c) for c in evt2.iter_chunks(raw2, 100_000)), n2, repeat))
    d = DATA / "gen4.dat"
    nd = len(dat.read(d))
    rows.append(_row("dat.read", d, lambda: dat.read(d), nd, repeat))
    a2 = DATA / "davis240_translboxes_aedat2.aedat"
    na2 = len(aedat2.read(a2))
    rows.append(_row("aedat2.read", a2, lambda: aedat2.read(a2), na2, repeat,
                     "includes 1.7 MB text header"))
    a4 = DATA / "davis346.aedat4"
    na4 = len(aedat4.read(a4))
    rows.append(_row("aedat4.read", a4, lambda: aedat4.read(a4), na4, repeat,
                     "LZ4 packets; file mostly frames"))
    # AEDAT 3.1 (no shared sample): evt3.raw's events written by evmotion, in packets of
    # the writer's 8192 events and of 256 (small packets cost per-packet work)
    for events_per_packet in (aedat3.WRITE_PACKET_EVENTS, 256):
        a3 = tmp / f"ev_{events_per_packet}.aedat"
        default = aedat3.WRITE_PACKET_EVENTS
        aedat3.WRITE_PACKET_EVENTS = events_per_packet
        try:
            aedat3.write(a3, ev3)
        finally:
            aedat3.WRITE_PACKET_EVENTS = default
        rows.append(_row("aedat3.read", a3, lambda p=a3: aedat3.read(p), n3, repeat,
                         f"evt3.raw's events, {events_per_packet} per packet"))
    bag = tmp / "evt2.bag"
    rosbag.write(bag, evt2.read(raw2))
    rows.append(_row("rosbag.read", bag, lambda: rosbag.read(bag), n2, repeat,
                     "bag written from evt2.raw, 33 ms messages"))
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    harness.record("io_binary", rows, notes="one core; Mev_per_s from the median, "
                   "best_Mev_per_s from the fastest run; ratio = read time / np.fromfile time "
                   f"of the same file in the same run; 1-min load average at the end {load:.1f}")
    return rows


if __name__ == "__main__":
    main(quick="--quick" in sys.argv)
