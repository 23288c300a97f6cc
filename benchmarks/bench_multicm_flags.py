"""What multicm's no-measurement tests say on windows of few events: noise, and the
simulator's moving scenes cut to as many events.

Below ``REFIT_EVENTS_PER_TILE`` events per finest tile, multicm also solves the window
with its times shuffled and flags the flow unless its focus beats that fit's by 5 %
(``refit_gain``); every window also gets the chance test (``chance_gain``: the flow's
alignment of the events over the same warp with their times shuffled) and the halves test
(``halves_correlation``: how well the flow carries the window's first half onto its
second), before the refit. Noise: uniform
random events (seeded). Moving: ``evmotion.sim.simulate`` scenes, the 30k events of the
middle of a 0.2 s recording evenly subsampled to N (the motion of a 30k window carried
by few events), AEE against the exact displacement over the window on the pixels with
events. ``valid``: the result marks any pixel valid (not flagged).

``python benchmarks/run.py multicm_flags``
"""

from __future__ import annotations

import itertools
import warnings

import numpy as np

import harness

NOISE = [((128, 128), 2000), ((128, 128), 5000), ((180, 240), 8000), ((260, 346), 12000)]
MOVING = [("translation", 2000), ("translation", 5000), ("rotation", 2000),
          ("rotation", 5000), ("zoom", 2000), ("zoom", 5000), ("object", 5000),
          ("object", 12000)]
NOTES = ("multicm defaults (finest level from the event count, 100 events a tile: "
         "finest_level column) and with 16 x 16 tiles (finest_level 5, the default before); "
         "noise windows 20 ms of uniform events (seeds 0-2, medians and "
         "ranges over the seeds); moving windows from evmotion.sim at 346x260, seed 0, 30k "
         "events subsampled to the count given. "
         "refit_gain is empty where the window has 64 events per finest tile or more, or "
         "an earlier test flagged it (not refitted); chance_gain is empty where the focus "
         "test flagged the window first, halves_correlation (the flow's carrying of the "
         "window's first half onto its second; under 0.15 flagged) where an earlier test "
         "did.")
LEVELS = ("auto", 5)


def _flags(events, level) -> dict:
    from evmotion.methods.multicm import estimate_flow

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = estimate_flow(events, **({} if level == "auto" else {"finest_level": level}))
    return {"chance_gain": res.meta["chance_gain"], "refit_gain": res.meta["refit_gain"],
            "halves": res.meta["halves_correlation"], "valid": bool(res.valid.any()),
            "res": res}


def _num(v):
    return "" if not np.isfinite(v) else float(v)


def main(quick: bool = False) -> list[dict]:
    from evmotion.events import EventArray
    from evmotion.sim import simulate

    rows = []
    for (size, n), level in itertools.product(NOISE[:2] if quick else NOISE, LEVELS):
        out = []
        for seed in range(3):
            rng = np.random.default_rng(seed)
            ev = EventArray(x=rng.integers(0, size[1], n), y=rng.integers(0, size[0], n),
                            t=np.sort(rng.integers(0, 20_000, n)), p=rng.integers(0, 2, n),
                            sensor_size=size)
            f = _flags(ev, level)
            res = f.pop("res")
            f["flow_px"] = float(np.median(np.linalg.norm(res.flow, axis=-1)) * res.duration_s)
            f["finest_level"] = res.meta["finest_level"]
            out.append(f)
        refit = [o["refit_gain"] for o in out if np.isfinite(o["refit_gain"])]
        rows.append({"data": f"noise {size[1]}x{size[0]}", "events": n,
                     "finest_level": out[0]["finest_level"],
                     "chance_gain": _num(np.nanmedian([o["chance_gain"] for o in out])),
                     "halves_correlation": _num(np.nanmedian([o["halves"] for o in out])),
                     "refit_gain": _num(np.median(refit)) if refit else "",
                     "refit_range": f"{min(refit):.3f}-{max(refit):.3f}" if refit else "",
                     "valid_windows": f"{sum(o['valid'] for o in out)} of {len(out)}",
                     "flow_px_median": float(np.median([o["flow_px"] for o in out])),
                     "AEE_px": "", "zero_AEE_px": ""})
        print(rows[-1], flush=True)
    for scene, n in MOVING[:2] if quick else MOVING:
        sim = simulate(scene, duration_s=0.2, sensor_size=(260, 346), seed=0,
                       show_progress=False)
        mid = len(sim.events) // 2
        full = sim.events[mid - 15_000:mid + 15_000]
        win = full[np.linspace(0, len(full) - 1, n).round().astype(np.int64)]
        gt = sim.gt.displacement(int(win.t[0]), int(win.t[-1]))
        hit = np.zeros(win.sensor_size, bool)
        hit[win.y.astype(int), win.x.astype(int)] = True
        for level in LEVELS:
            f = _flags(win, level)
            res = f.pop("res")
            err = np.linalg.norm(res.displacement().astype(np.float64) - gt, axis=-1)
            rows.append({"data": f"sim {scene}", "events": n,
                         "finest_level": res.meta["finest_level"],
                         "chance_gain": _num(f["chance_gain"]),
                         "halves_correlation": _num(f["halves"]),
                         "refit_gain": _num(f["refit_gain"]), "refit_range": "",
                         "valid_windows": "1 of 1" if f["valid"] else "0 of 1",
                         "flow_px_median": float(np.median(np.linalg.norm(
                             res.displacement(), axis=-1)[hit])),
                         "AEE_px": float(np.nanmean(err[hit])),
                         "zero_AEE_px": float(np.nanmean(np.linalg.norm(gt, axis=-1)[hit]))})
            print(rows[-1], flush=True)
    harness.record("multicm_flags", rows, NOTES)
    return rows


if __name__ == "__main__":
    main()
