"""Cost of the checks on every ego-motion result (:mod:`evmotion.methods.diagnostics`), one
core: the collapse test (warp geometry on a 9x9 grid at both window ends, IWE concentration)
and the fit test (per-tile sharpness under the estimate against each tile's best local
translation), on simulated windows of 30k events at 240x180 and 346x260, with the estimate
itself (``diagnose=False``) as the reference in the same run.

    python benchmarks/bench_diagnostics.py [--quick]
"""

from __future__ import annotations

import harness
from evmotion.core.warps import make_warp
from evmotion.methods.diagnostics import collapse_diagnostics, fit_diagnostics
from evmotion.methods.egomotion import estimate_egomotion
from evmotion.sim import simulate


def _row(shape, repeat: int) -> dict:
    sim = simulate("rotation", duration_s=0.1, sensor_size=shape, seed=1, show_progress=False)
    ev = sim.events
    mid = len(ev) // 2
    ev = ev[mid - 15_000: mid + 15_000]
    K = sim.gt.K
    res = estimate_egomotion(ev, "rotation", K=K, maps=False)
    w = make_warp("rotation", shape, K=K)
    dt = (ev.t - res.t_ref_us) * 1e-6
    xw, yw = w.warp(ev.x, ev.y, dt, res.params)
    span = (float(dt.min()), float(dt.max()))
    est = harness.timeit(lambda: estimate_egomotion(ev, "rotation", K=K, maps=False,
                                                    diagnose=False), repeat=repeat, warmup=1)
    coll = harness.timeit(lambda: collapse_diagnostics(w, res.params, span, res.iwe_before,
                                                       res.iwe_after), repeat=repeat, warmup=1)
    fit = harness.timeit(lambda: fit_diagnostics(ev.x, ev.y, dt, xw, yw, shape),
                         repeat=repeat, warmup=1)
    d = fit_diagnostics(ev.x, ev.y, dt, xw, yw, shape)
    return {"window": f"rotation sim {shape[1]}x{shape[0]}", "events": len(ev),
            "estimate_ms": est["median_s"] * 1e3, "collapse_check_ms": coll["median_s"] * 1e3,
            "fit_check_ms": fit["median_s"] * 1e3,
            "checks_over_estimate": (coll["median_s"] + fit["median_s"]) / est["median_s"],
            "tiles": d["n_tiles"], "explained_share": d["explained_share"]}


def main(quick: bool = False) -> list[dict]:
    harness.pin_idlest_core()
    rows = []
    for shape in ((180, 240), (260, 346)):
        rows.append(_row(shape, 3 if quick else 7))
        print(rows[-1], flush=True)
    harness.record("diagnostics", rows, notes="one core; estimate = estimate_egomotion "
                   "(rotation, BFGS, integer coordinates) with diagnose=False; the checks run "
                   "once per result")
    return rows


if __name__ == "__main__":
    import sys

    main(quick="--quick" in sys.argv)
