"""The vote kernel's bias on a zoom rate: egomotion's zoom estimate with the bilinear IWE
(the default since a7e5ac1, events spread over their pixel by the R2 sequence) and with
the Gaussian one (sigma 1 px), over seeds of the simulator's forward motion (noise texture,
240x180, 0.05 s, warp referenced at the window's start, BFGS from 0.9x the truth, no
regularizer), against the exact zoom rate at the reference (the simulator moves the scene
by the zoom warp itself: one constant h_z explains every event exactly). The collapse
tables' zoom rows moved with that default (h_z 1.51 -> 1.46 for 1.505).

    python benchmarks/bench_zoom_kernel.py [--quick]
"""

from __future__ import annotations

import time

import numpy as np

import harness
from evmotion.methods.egomotion import estimate_egomotion
from evmotion.sim import simulate


def main(quick: bool = False) -> list[dict]:
    harness.pin_idlest_core()
    seeds = range(2 if quick else 6)
    errs: dict = {}
    secs: dict = {}
    for seed in seeds:
        sim = simulate("zoom", duration_s=0.05, sensor_size=(180, 240), seed=seed,
                       texture="noise", show_progress=False)
        ev = sim.events
        t_ref = int(ev.t[0])
        truth = sim.gt.params(t_ref)["hz"]
        for kernel in ("bilinear", "gaussian"):
            for objective in ("variance", "gradient_magnitude"):
                t0 = time.perf_counter()
                res = estimate_egomotion(ev, "zoom", objective, None, t_ref=t_ref, maps=False,
                                         init=np.array([0.9 * truth]), kernel=kernel,
                                         diagnose=False)
                secs.setdefault((kernel, objective), []).append(time.perf_counter() - t0)
                errs.setdefault((kernel, objective), []).append(
                    100 * (float(res.params[0]) / truth - 1))
    rows = []
    for (kernel, objective), e in errs.items():
        e = np.asarray(e)
        rows.append({"kernel": kernel, "objective": objective, "seeds": len(e),
                     "h_z_error_pct_mean": float(e.mean()), "h_z_error_pct_sd": float(e.std()),
                     "h_z_error_pct_each": " ".join(f"{v:+.2f}" for v in e),
                     "seconds_median": float(np.median(secs[(kernel, objective)]))})
        print(rows[-1], flush=True)
    harness.record("zoom_kernel", rows, notes="simulated zoom (noise texture, 240x180, "
                   "0.05 s, seeds 0-5), t_ref = the first event, BFGS from 0.9 x the true "
                   "h_z, no regularizer; error = estimate / true h_z at t_ref - 1, percent; "
                   "one pinned core, the first call of each kernel includes numba's loading")
    return rows


if __name__ == "__main__":
    import sys

    main(quick="--quick" in sys.argv)
