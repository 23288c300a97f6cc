"""multicm's finest level chosen from the window's event count (``finest_level=None``,
:func:`evmotion.methods.multicm.auto_finest_level`) against the fixed 16 x 16 tiles
(level 5) it used before, and levels 4 and 3 for reference.

Each tile of the finest scale has two unknowns; a window of a few thousand events leaves
a few dozen events a tile, whose flow then follows their noise. Three sources, each
subsampled evenly (the same motion carried by fewer events):

1. ``evmotion.sim`` at 346x260 (seed 0), the 40k events of the middle of a 0.2 s
   recording; AEE against the exact displacement over the window.
2. The ECD rotation windows of ``../shared/data`` (real DAVIS240C, undistorted), AEE
   against their IMU flow (``flow.npy``).
3. Scenes rendered without evmotion's simulator (``bench_multicm_sparse.render``: smoothed
   noise under OpenCV's bicubic warp, events from log-intensity crossings), a 20 px
   window (translation; rotation at the corner).

AEE in px over the window on the pixels with events; ``valid``: the result marks any
pixel valid. ``python benchmarks/run.py multicm_finest``
"""

from __future__ import annotations

import time
import warnings

import numpy as np

import harness

COUNTS = (40_000, 30_000, 15_000, 8_000, 4_000, 2_000)
VARIANTS = (("auto (default)", None), ("level 5", 5), ("level 4", 4), ("level 3", 3))
NOTES = ("multicm defaults but finest_level (n_scales = the level: coarse-to-fine from one "
         "tile). auto: the finest level up to 5 whose tiles hold 100 events on average "
         "(AUTO_EVENTS_PER_TILE). Windows evenly subsampled to the count given. AEE px "
         "over the window on pixels with events; zero_AEE_px the zero flow's; valid: any "
         "pixel marked valid (not flagged). seconds: estimate_flow wall time on a shared "
         "2-core machine.")


def _sim_cases():
    from evmotion.sim import simulate

    for scene in ("translation", "rotation", "zoom", "object"):
        sim = simulate(scene, duration_s=0.2, sensor_size=(260, 346), seed=0,
                       show_progress=False)
        mid = len(sim.events) // 2
        win = sim.events[mid - 20_000: mid + 20_000]
        yield f"sim {scene}", win, sim.gt.displacement(int(win.t[0]), int(win.t[-1]))


def _ecd_cases():
    from bench_multicm_accuracy import DATA, read_ecd_txt
    from evmotion.io.calibration import read_ecd

    root = DATA / "ecd_rotation_windows"
    if not root.is_dir():
        print(f"skipping the ECD windows: {root} not found")
        return
    for d in sorted(root.iterdir()):
        ev = read_ecd(d / "calib.txt").undistort_events(read_ecd_txt(d / "events.txt"))
        gt = np.load(d / "flow.npy")[0].transpose(1, 2, 0).astype(np.float64)
        yield f"ECD {d.name}", ev, gt


def _rendered_cases():
    from bench_multicm_sparse import SCENES, exact_flow, rendered_events

    for name, scene in SCENES.items():
        events = rendered_events(scene)
        flow = exact_flow(scene)
        half = int(0.5e6 * 20.0 / float(np.linalg.norm(flow, axis=-1).max()))
        mid = int(np.median(events.t))
        win = events.slice_time(mid - half, mid + half)
        yield f"rendered {name}", win, flow * (int(win.t[-1]) - int(win.t[0])) * 1e-6


def main(quick: bool = False) -> list[dict]:
    from evmotion.methods.multicm import estimate_flow

    rows = []
    sources = [_sim_cases(), _ecd_cases(), _rendered_cases()]
    for cases in sources:
        for name, win, gt in cases:
            hit = np.zeros(win.sensor_size, bool)
            hit[np.round(win.y).astype(int), np.round(win.x).astype(int)] = True
            zero = float(np.linalg.norm(gt, axis=-1)[hit].mean())
            for n in COUNTS[3:] if quick else COUNTS:
                if n > len(win):
                    continue
                sub = win[np.linspace(0, len(win) - 1, n).round().astype(np.int64)]
                for variant, level in VARIANTS:
                    kw = {} if level is None else {"finest_level": level, "n_scales": level}
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        start = time.perf_counter()
                        res = estimate_flow(sub, **kw)
                        seconds = time.perf_counter() - start
                    err = np.linalg.norm(res.displacement().astype(np.float64) - gt, axis=-1)
                    rows.append({"data": name, "events": n, "variant": variant,
                                 "finest_level": res.meta["finest_level"],
                                 "AEE_px": float(err[hit & np.isfinite(err)].mean()),
                                 "zero_AEE_px": zero, "valid": bool(res.valid.any()),
                                 "seconds": seconds})
                    print(rows[-1], flush=True)
    harness.record("multicm_finest", rows, NOTES)
    return rows


if __name__ == "__main__":
    main()
