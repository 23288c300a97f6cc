"""Warps (warp + parameter Jacobian) and collapse regularizers (value + gradient), ch. 3.

Reference measured in the same run: one variance-objective evaluation with its gradient
(warp + Jacobian, bilinear IWE, variance, IWE adjoint, chain rule), as the ego-motion code
does it. Regularizer costs are quoted as a fraction of that reference ("+x %").
Run: ``python benchmarks/run.py warps`` or ``python benchmarks/bench_warps.py [--quick]``.
"""

from __future__ import annotations

import sys

import numpy as np

try:
    from benchmarks import harness
except ImportError:  # run as a script
    import harness

from evmotion.core.iwe import accumulate_backward_reduce, accumulate_into
from evmotion.core.objectives import variance_stats
from evmotion.core.regularizers import regularizer_value_grad
from evmotion.core.warps import WARPS, make_warp

H, W = 260, 346
K = np.array([[226.0, 0, 173.0], [0, 226.0, 130.0], [0, 0, 1]])
THETA = {
    "zoom": [4.0],
    "translation": [50.0, -30.0],
    "rotation": [1.0, -2.0, 3.0],
    "se2": [40.0, 10.0, 2.0],
    "inplane": [40.0, 10.0, 0.3, 8.0],
    "similarity": [40.0, 10.0, 2.0, 3.0],
    "affine": [40.0, 10.0, 1.0, 2.0, -1.0, 3.0],
    "homography": [1.0, 2.0, 30.0, -1.0, 3.0, 20.0, 1e-3, -2e-3],
}


def _events(n, seed=0):
    rng = np.random.default_rng(seed)
    return (rng.uniform(0, W - 1, n), rng.uniform(0, H - 1, n),
            np.sort(rng.uniform(0, 0.05, n)))


def _objective(w, x, y, dt, th, bufs):
    """Variance of the IWE and its gradient as the ego-motion cost evaluates it (warp +
    Jacobian, bilinear IWE, one-pass mean/variance, adjoint reduced through the Jacobian):
    the reference an objective evaluation costs."""
    xw, yw, jx, jy, iwe, out = bufs
    w.warp_into(x, y, dt, th, xw, yw, jx, jy)
    accumulate_into(xw, yw, iwe)
    mu, var = variance_stats(iwe)
    accumulate_backward_reduce(xw, yw, iwe, jx, jy, out, shift=mu, scale=2.0 / iwe.size)
    return var, out


def main(quick: bool = False) -> list[dict]:
    harness.single_core()
    repeat = 5 if quick else 20
    rows: list[dict] = []
    for n in (30_000,) if quick else (30_000, 500_000):
        rows += _bench_size(n, repeat)
    harness.record("warps", rows, notes="single core; synthetic uniform events on 346x260, "
                   "50 ms window; regularizers given the already-warped events and Jacobians; "
                   "medians, and *_min with the fastest run (less sensitive to other processes)")
    return rows


def _bench_size(n: int, repeat: int) -> list[dict]:
    rows = []
    x, y, dt = _events(n)
    for name in WARPS:
        w = make_warp(name, (H, W), K=K)
        th = np.array(THETA[name])
        P = w.n_params
        xw, yw = np.empty(n), np.empty(n)
        jx, jy = np.empty((n, P)), np.empty((n, P))
        t_w = harness.timeit(lambda w=w, th=th, xw=xw, yw=yw: w.warp_into(x, y, dt, th, xw, yw),
                             repeat=repeat)
        t_wj = harness.timeit(lambda w=w, th=th, xw=xw, yw=yw, jx=jx, jy=jy:
                              w.warp_into(x, y, dt, th, xw, yw, jx, jy), repeat=repeat)
        rows.append({"what": f"warp {name}", "events": n, "dof": P,
                     "warp_ms": t_w["median_s"] * 1e3,
                     "warp+jac_ms": t_wj["median_s"] * 1e3,
                     "ns/event": t_wj["median_s"] * 1e9 / n})
    for name in ("zoom", "translation", "rotation", "se2", "inplane", "similarity",
                 "homography"):
        w = make_warp(name, (H, W), K=K)
        th = np.array(THETA[name])
        P = w.n_params
        bufs = (np.empty(n), np.empty(n), np.empty((n, P)), np.empty((n, P)),
                np.empty((H, W)), np.empty(P))
        r = harness.timeit(lambda w=w, th=th, bufs=bufs: _objective(w, x, y, dt, th, bufs),
                           repeat=repeat)
        ref, ref_min = r["median_s"], r["min_s"]
        rows.append({"what": f"objective var+grad ({name}, reference)", "events": n,
                     "dof": P, "ms": ref * 1e3, "vs_objective_%": 100.0,
                     "ms_min": ref_min * 1e3, "vs_objective_min_%": 100.0})
        xw, yw, jx, jy = bufs[:4]
        for reg in ("rcad", "divergence", "deformation"):
            slow = name == "homography" and reg != "rcad"  # complex-step derivatives
            r = harness.timeit(
                lambda w=w, th=th, reg=reg, xw=xw, yw=yw, jx=jx, jy=jy: regularizer_value_grad(
                    reg, w, x, y, dt, th, (H, W), xw, yw, jac=(jx, jy)),
                repeat=min(repeat, 5) if slow else repeat)
            t, t_min = r["median_s"], r["min_s"]
            val = regularizer_value_grad(reg, w, x, y, dt, th, (H, W), xw, yw, jac=(jx, jy))[0]
            rows.append({"what": f"regularizer {reg} ({name}) value+grad", "events": n,
                         "dof": P, "ms": t * 1e3, "vs_objective_%": 100.0 * t / ref,
                         "ms_min": t_min * 1e3, "vs_objective_min_%": 100.0 * t_min / ref_min,
                         "penalty": val})
    return rows


if __name__ == "__main__":
    main(quick="--quick" in sys.argv)
