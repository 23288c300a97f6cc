"""Cost of the collapse regularizers and of the gradient-magnitude objective (thesis
Table 3.4's "regularizer overhead"), on one core.

Per warp up to 4 DOF, 30k events at 346x260 and 500k at 640x480 (bench_cmax's events):

* ``data ms``: one unregularized CMax evaluation (variance, value + gradient) -- the
  reference the overheads are measured against, in the same run;
* per regularizer, one :func:`regularizer_value_grad` call as CMax makes it after its data
  term on its fused path (events by 16 px sensor tile, warped events given, no stored
  Jacobians, the window span given once), and the ratio ``(data + regularizer) / data``. Two motions: bench_cmax's parameters (no pixel
  beyond the trimming margins: the usual case away from collapse), and a collapsing one
  (contraction strong enough that the trimmed means and the RCAD map are active), where the
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
from bench_cmax import WARP_THETA, _events
from evmotion.core.objectives import objective_value_grad
from evmotion.core.regularizers import regularizer_value_grad
from evmotion.core.warps import make_warp
from evmotion.methods.egomotion import CMaxCost

#: Collapsing parameters per warp (strong contraction within the 50 ms window); None where
#: the warp cannot collapse (translation, SE(2): every penalty is 0 by construction).
COLLAPSE_THETA = {"zoom": [15.0], "translation": None, "rotation": [4.0, -6.0, 3.0],
                  "se2": None, "inplane": [80.0, -40.0, 0.05, 15.0],
                  "similarity": [80.0, -40.0, 0.5, 15.0]}
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
    harness.single_core()
    rows: list[dict] = []
    sizes = [(30_000, (260, 346))] + ([] if quick else [(500_000, (480, 640))])
    for n, shape in sizes:
        repeat = (10 if quick else 30) if n < 100_000 else (4 if quick else 12)
        x, y, dt, p, _ = _events(n, shape)
        span = (float(dt.min()), float(dt.max()))
        # the regularizer sees the events in the order of CMax's fused path: by sensor tile
        tile = np.lexsort((np.floor(x) // 16, np.floor(y) // 16))
        xt, yt, dtt = x[tile], y[tile], dt[tile]
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
                data = harness.timeit(partial(cost.value_grad, th), repeat=repeat)
                data_ms = data["median_s"] * 1e3
                xw, yw = warp.warp(xt, yt, dtt, th)
                row = {"case": "regularizer", "events": n, "size": size, "warp": wname,
                       "motion": motion, "data_ms": data_ms}
                for reg in REGS:
                    val = regularizer_value_grad(reg, warp, xt, yt, dtt, th, shape, xw, yw,
                                                 span=span)[0]
                    r = harness.timeit(partial(regularizer_value_grad, reg, warp, xt, yt, dtt,
                                               th, shape, xw, yw, span=span), repeat=repeat)
                    ms = r["median_s"] * 1e3
                    row[f"{reg}_value"] = val
                    row[f"{reg}_ms"] = ms
                    row[f"{reg}_ratio"] = (data_ms + ms) / data_ms
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
        "single core (harness.single_core); medians; data_ms: one unregularized CMax "
        "evaluation (variance, value + gradient) in the same run; <reg>_ms: one "
        "regularizer_value_grad call after it (events by 16 px tile, warped events given, no "
        "Jacobians, span given); <reg>_ratio = (data + reg) / data; motion 'collapse' = strong contraction "
        "(trimmed means active)"))
    return rows


if __name__ == "__main__":
    main(quick="--quick" in sys.argv)
