"""multicm on windows that hold two motions, with and without its tile search.

After the 4 x 4 scale each tile's events are searched for a translation of their own
(:mod:`evmotion.core.tilesearch`); tiles it sharpens 1.25x more than the flow restart
from it, and the coarse-to-fine goes on from both starts to the finest scale, which keeps
the better objective. The final flow's 4 x 4 tiles whose own translation sharpens them
1.5x more are flagged (``valid`` False, a PoorFitWarning "another motion"). Scored
against the same estimate with both off (``TILE_SEARCH_LEVEL`` 0, ``OTHER_MOTION_GAIN``
infinite), in the same run:

* a dense square of dots (70 % of the events) moving (200, 80) px/s over sparse
  background dots moving (-60, 30) px/s, 240x180, 30k events, four seeds (the test
  scene of ``test_a_second_motion_is_followed_or_flagged``; probe BZ's own renderer,
  a textured 90-px patch over a textured background, showed the same);
* the simulator's translation, rotation, zoom and moving-object scenes, 346x260, two 30k
  windows each;
* the eight ECD 30k windows (FWL: no ground truth).

AEE in px per window over the events (``all``) and over the events whose pixel is valid;
seconds of one estimate each (numba warm). Run: ``python benchmarks/run.py
multicm_motions``.
"""

from __future__ import annotations

import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

import harness

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
DATA = Path(os.environ.get("EVMOTION_SHARED_DATA",
                           Path(__file__).resolve().parents[2] / "shared" / "data"))


def _estimate(events, search: bool):
    from evmotion.methods import measured, multicm

    saved = multicm.TILE_SEARCH_LEVEL, measured.OTHER_MOTION_GAIN
    if not search:
        multicm.TILE_SEARCH_LEVEL, measured.OTHER_MOTION_GAIN = 0, float("inf")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            t0 = time.perf_counter()
            res = multicm.estimate_flow(events)
            return res, time.perf_counter() - t0
    finally:
        multicm.TILE_SEARCH_LEVEL, measured.OTHER_MOTION_GAIN = saved


def _scores(events, res, truth) -> dict:
    from evmotion.eval.metrics import fwl

    xi, yi = events.x.astype(int), events.y.astype(int)
    ok = res.valid[yi, xi]
    out = {"valid_events": float(ok.mean()),
           "other_tiles": int(res.meta["other_motion_tiles"])}
    if truth is None:
        out["fwl"] = float(fwl(events, res.flow, res.t_ref_us))
        return out
    err = np.linalg.norm(res.flow[yi, xi] - truth, axis=1) * res.duration_s
    out["aee_all"] = float(err.mean())
    out["aee_valid"] = float(err[ok].mean()) if ok.any() else float("nan")
    out["aee_zero"] = float(np.linalg.norm(truth, axis=1).mean() * res.duration_s)
    return out


def _cases():
    from evmotion.io import read_events
    from evmotion.sim import simulate
    from test_multicm import _patch_over_background

    for seed in range(4):
        ev, _, v = _patch_over_background(seed)
        yield f"two motions, seed {seed}", ev, v
    for scene in ("translation", "rotation", "zoom", "object"):
        sim = simulate(scene, duration_s=0.3, sensor_size=(260, 346), seed=3,
                       show_progress=False)
        for k in range(2):
            w = sim.events[k * 30000:(k + 1) * 30000]
            flow = sim.gt.flow((int(w.t[0]) + int(w.t[-1])) // 2)
            yield f"sim {scene} {k}", w, flow[w.y.astype(int), w.x.astype(int)]
    for d in sorted((DATA / "ecd_30k_windows").glob("*")):
        yield f"ECD {d.name}", read_events(d), None


def main(quick: bool = False) -> list[dict]:
    harness.pin_idlest_core()
    rows = []
    cases = list(_cases())
    _estimate(cases[0][1], True)  # numba's kernels compiled and loaded
    for k, (name, events, truth) in enumerate(cases):
        if quick and k % 3:
            continue
        row = {"window": name}
        # alternating which runs first: load drifts reach both alike
        for search in ((True, False) if k % 2 else (False, True)):
            res, seconds = _estimate(events, search)
            tag = "search" if search else "off"
            row.update({f"{key} {tag}": v for key, v in _scores(events, res, truth).items()
                        if not (key in ("other_tiles", "aee_zero") and not search)})
            row[f"s {tag}"] = seconds
        rows.append(row)
    harness.record("multicm_motions", rows,
                   notes="One core; numba warm (a first estimate before). 'search': the "
                         "defaults; 'off': TILE_SEARCH_LEVEL 0 and OTHER_MOTION_GAIN inf.")
    return rows


if __name__ == "__main__":
    main()
