"""Cost of the collapse regularizers and of the gradient-magnitude objective (thesis
Table 3.4's "regularizer overhead"), on one core.

Per warp up to 4 DOF, 30k events at 346x260 and 500k at 640x480 (bench_cmax's events):

* ``data ms``: one unregularized CMax evaluation (variance, value + gradient) -- the
  reference the overheads are measured against, in the same run;
* per regularizer, one evaluation of the CMax cost with it (weight 1), its ratio to ``data
  ms`` (timed in turn with it over five rounds, nine at 500k, the median of the per-round
  ratios: the neighbours' load on a shared machine reaches both alike) and the difference
  (what the penalty costs CMax: divergence and deformation take the data term's IWE as
  their count map and chain their adjoint through the data term's pass over the events),
  and one standalone :func:`regularizer_value_grad` call given what
  CMax has at hand (events by 16 px sensor tile, warped events, its IWE, the window span).
  Two motions: bench_cmax's parameters (no pixel beyond the trimming margins: the usual
  case away from collapse), and a collapsing one (``bench_cmax.COLLAPSE_THETA``:
  contraction strong enough that the trimmed means and the RCAD map are active), where the
  DIWE/IWA maps and their adjoint are built;
* ``gradmag``: the gradient-magnitude objective's value and adjoint image (numba, one
  streaming pass) against a plain-numpy reference (scipy correlate + slice adds).

    python benchmarks/run.py regularizers      # or: python benchmarks/bench_regularizers.py
"""

from __future__ import annotations

import sys
from functools import partial
from pathlib import Path

import numpy as np
from scipy.ndimage import correlate

sys.path.insert(0, str(Path(__file__).resolve().parent))
import harness
from bench_cmax import COLLAPSE_THETA, WARP_THETA, _events
from evmotion.core.objectives import objective_value_grad
from evmotion.core.regularizers import regularizer_value_grad
from evmotion.core.warps import make_warp
from evmotion.methods.egomotion import CMaxCost

REGS = ("divergence", "deformation", "rcad")
_SX = np.array([[-1.0, 0.0, 1.0], [-2.0, 0.0, 2.0], [-1.0, 0.0, 1.0]])


def _gradmag_numpy(img):
    """Plain-numpy gradient magnitude and its adjoint image (the test's reference)."""
    h, w = img.shape
    n = (h - 2) * (w - 2)
    gx = correlate(img, _SX)[1:-1, 1:-1]
    gy = correlate(img, _SX.T)[1:-1, 1:-1]
    grad = np.zeros_like(img)
    for a in range(3):
        for b in range(3):
            grad[a:h - 2 + a, b:w - 2 + b] += 2.0 / n * (_SX[a, b] * gx + _SX.T[a, b] * gy)
    return float(np.mean(gx * gx + gy * gy)), grad


def main(quick: bool = False) -> list[dict]:
    harness.pin_idlest_core()
    rows: list[dict] = []
    sizes = [(30_000, (260, 346))] + ([] if quick else [(500_000, (480, 640))])
    for n, shape in sizes:
        repeat = (10 if quick else 30) if n < 100_000 else (4 if quick else 12)
        x, y, dt, p, _ = _events(n, shape)
        K = np.array([[shape[1] * 0.8, 0, shape[1] / 2], [0, shape[1] * 0.8, shape[0] / 2],
                      [0, 0, 1.0]])
        size = f"{shape[1]}x{shape[0]}"
        for wname, theta in WARP_THETA.items():
            warp = make_warp(wname, shape, K=K)
            for motion, th in (("bench_cmax", theta), ("collapse", COLLAPSE_THETA[wname])):
                if th is None:
                    continue
                th = np.asarray(th, dtype=float)
                cost = CMaxCost(warp, x, y, dt, shape, "variance", None, polarity=p)
                costs = {reg: CMaxCost(warp, x, y, dt, shape, "variance", reg, weight=1.0,
                                       polarity=p) for reg in REGS}
                # the costs in turn, in rounds (nine at 500k, as bench_cmax): same-load ratios
                t = harness.timeit_rounds(
                    {"data": partial(cost.value_grad, th),
                     **{reg: partial(c.value_grad, th) for reg, c in costs.items()}},
                    repeat=repeat, rounds=1 if quick else (9 if n > 100_000 else 5),
                    ref="data")
                data_ms = t["data"]["median_s"] * 1e3
                # what CMax hands a standalone call: its events in tile order, warped with
                # th, its IWE as the count map, the window's span
                cost.value_grad(th)
                ev = (warp, cost._fx, cost._fy, cost._fdt, th, shape, cost.xw.copy(),
                      cost.yw.copy())
                kw = {"span": cost.span, "count": cost.iwe.copy()}
                row = {"case": "regularizer", "events": n, "size": size, "warp": wname,
                       "motion": motion, "data_ms": data_ms}
                for reg in REGS:
                    alone = harness.timeit(partial(regularizer_value_grad, reg, *ev, **kw),
                                           repeat=repeat)
                    ms = t[reg]["median_s"] * 1e3
                    row[f"{reg}_value"] = regularizer_value_grad(reg, *ev, **kw)[0]
                    row[f"{reg}_ms"] = ms - data_ms
                    row[f"{reg}_ratio"] = t[reg]["ratio"]
                    row[f"{reg}_alone_ms"] = alone["median_s"] * 1e3
                rows.append(row)
                print(row, flush=True)
        img = np.random.default_rng(0).poisson(1.0, shape).astype(float)
        out = np.empty(shape)
        fast = harness.timeit(partial(objective_value_grad, "gradient_magnitude", img, out=out),
                              repeat=repeat * 3)
        ref = harness.timeit(partial(_gradmag_numpy, img), repeat=max(3, repeat // 2))
        rows.append({"case": "gradmag image", "events": n, "size": size,
                     "numba_ms": fast["median_s"] * 1e3, "numpy_ms": ref["median_s"] * 1e3,
                     "speedup": ref["median_s"] / fast["median_s"]})
        print(rows[-1], flush=True)
    harness.record("regularizers", rows, notes=(
        "single core (harness.pin_idlest_core); medians; data_ms: one unregularized CMax "
        "evaluation (variance, value + gradient); <reg>_ratio: one evaluation of CMaxCost "
        "with that regularizer (weight 1) over data_ms, timed in turn with it in five "
        "rounds (nine at 500k events; harness.timeit_rounds: the median of the per-round "
        "ratios), and <reg>_ms the difference of the medians (the penalty's cost as CMax "
        "pays it: divergence and deformation share the data term's IWE and its pass over "
        "the events); <reg>_alone_ms: one standalone "
        "regularizer_value_grad call with what CMax has at hand (events in tile order, "
        "warped events, its IWE as count=, span=); motion 'collapse' = strong contraction "
        "(COLLAPSE_THETA: trimmed means active)"))
    return rows


if __name__ == "__main__":
    main(quick="--quick" in sys.argv)
