"""Speed of contrast maximization (thesis Table 3.4): ms per cost+gradient evaluation for
30k events at 346x260 and 500k at 640x480, variance and gradient magnitude, each
regularizer, with the ratio to the unregularized run, at the parameters of WARP_THETA (no
collapse) and of COLLAPSE_THETA (the trimmed means and the RCAD map active); a complete
4-DOF estimate with RCAD (BFGS) on a 30k window and a 600-sample TPE run; the one-off cost of building the cost of a
window (buffers, the tile order of the fused path, the normalization G(0)) per warp.

    python benchmarks/run.py cmax          # or: python benchmarks/bench_cmax.py [--quick]
"""

from __future__ import annotations

import itertools
import sys
from functools import partial
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import harness
from evmotion.core.warps import make_warp
from evmotion.events import EventArray
from evmotion.methods.egomotion import CMaxCost, estimate_egomotion

WARP_THETA = {"zoom": [1.5], "translation": [80.0, -40.0], "rotation": [0.4, -0.6, 0.3],
              "se2": [80.0, -40.0, 0.5], "inplane": [80.0, -40.0, 0.05, 1.0],
              "similarity": [80.0, -40.0, 0.5, 1.0]}
#: Collapsing parameters per warp (strong contraction within the 50 ms window, so that the
#: trimmed means and the RCAD map are active); None where the warp cannot collapse
#: (translation, SE(2): every penalty is 0 by construction).
COLLAPSE_THETA = {"zoom": [15.0], "translation": None, "rotation": [4.0, -6.0, 3.0],
                  "se2": None, "inplane": [80.0, -40.0, 0.05, 15.0],
                  "similarity": [80.0, -40.0, 0.5, 15.0]}
REGS = (None, "divergence", "deformation", "rcad", "whitening")


def _events(n: int, shape, seed: int = 0):
    rng = np.random.default_rng(seed)
    h, w = shape
    dots = rng.uniform([0.1 * w, 0.1 * h], [0.9 * w, 0.9 * h], (max(n // 40, 10), 2))
    k = rng.integers(0, dots.shape[0], n)
    t = np.sort(rng.integers(0, 50_000, n))
    x = np.clip(dots[k, 0] + 200.0 * t * 1e-6, 0, w - 1)
    return x, dots[k, 1].copy(), t * 1e-6, rng.integers(0, 2, n), t


def main(quick: bool = False) -> list[dict]:
    harness.pin_idlest_core()
    rows: list[dict] = []
    sizes = [(30_000, (260, 346))] + ([] if quick else [(500_000, (480, 640))])
    repeat = 5 if quick else 20
    for n, shape in sizes:
        x, y, dt, p, _ = _events(n, shape)
        K = np.array([[shape[1] * 0.8, 0, shape[1] / 2], [0, shape[1] * 0.8, shape[0] / 2],
                      [0, 0, 1.0]])
        for wname, theta in WARP_THETA.items():
            warp = make_warp(wname, shape, K=K)
            ev = (x, y, dt, shape)
            r = harness.timeit(lambda w=warp, ev=ev, p=p: CMaxCost(w, *ev, polarity=p),
                               repeat=max(3, repeat // 4))
            rows.append({"case": "setup", "events": n, "size": f"{shape[1]}x{shape[0]}",
                         "warp": wname, "objective": "variance", "regularizer": "none",
                         "ms_total": r["median_s"] * 1e3})
            for obj, (motion, theta_m) in itertools.product(
                    ("variance", "gradient_magnitude"),
                    (("bench_cmax", theta), ("collapse", COLLAPSE_THETA[wname]))):
                if theta_m is None:
                    continue
                th = np.asarray(theta_m, dtype=float)
                costs = {reg or "none": CMaxCost(warp, x, y, dt, shape, obj, reg, weight=1.0,
                                                 polarity=p) for reg in REGS}
                # whitening (an eigen-decomposition and (N, P) products in numpy) is slow
                reps = {k: max(3, repeat // 4) if k == "whitening" else repeat for k in costs}
                # the regularizers in turn, in rounds (nine at 500k, where a neighbour's
                # memory traffic moves single timings most): same-load ratios
                t = harness.timeit_rounds(
                    {k: partial(c.value_grad, th) for k, c in costs.items()},
                    repeat=reps, rounds=1 if quick else (9 if n > 100_000 else 5), ref="none")
                for k, r in t.items():
                    rows.append({"case": "eval", "events": n, "size": f"{shape[1]}x{shape[0]}",
                                 "warp": wname, "objective": obj, "motion": motion,
                                 "regularizer": k, "ms_per_eval": r["median_s"] * 1e3,
                                 "ratio_vs_none": r["ratio"], "ms_min": r["min_s"] * 1e3,
                                 "ratio_min": r["ratio_min"]})
    # complete estimates on a 30k window
    x, y, dt, p, t = _events(30_000, (260, 346), seed=1)
    ev = EventArray(x.astype(np.float32), y.astype(np.float32), t, p, sensor_size=(260, 346),
                    validate=False)
    for wname, reg, opt in (("similarity", "rcad", "bfgs"), ("similarity", None, "bfgs"),
                            ("similarity", "rcad", "tpe"), ("zoom", "rcad", "tpe")):
        def run(wname=wname, reg=reg, opt=opt):
            # the estimator alone: the result checks (diagnose) are timed in bench_diagnostics
            return estimate_egomotion(ev, wname, regularizer=reg, optimizer=opt, maps=False,
                                      diagnose=False)
        r = harness.timeit(run, repeat=3 if quick else 7, warmup=1)
        res = run()
        rows.append({"case": f"estimate {opt}", "events": 30_000, "size": "346x260",
                     "warp": wname, "objective": "variance", "regularizer": reg or "none",
                     "ms_total": r["median_s"] * 1e3, "n_evals": res.timings["n_evals"]})
    harness.record("cmax", rows, notes="single core (harness.pin_idlest_core); medians; "
                   "ratio_vs_none = ms / ms of the unregularized run of the same row group, "
                   "timed in turn with it in five rounds (nine at 500k events; "
                   "harness.timeit_rounds: the median of the per-round ratios); "
                   "ms_min / ratio_min: the same with the fastest run (less sensitive to other "
                   "processes on a shared machine)")
    _table34(rows)
    return rows


def _table34(rows: list[dict]) -> None:
    """The eval rows pivoted like thesis Table 3.4: one line per (events, warp, objective),
    ms per cost+gradient evaluation for each regularizer and its ratio to the
    unregularized evaluation."""
    ev = [r for r in rows if r["case"] == "eval"]
    group = ("events", "size", "warp", "objective", "motion")
    keys = list(dict.fromkeys(tuple(r[g] for g in group) for r in ev))
    names = [reg or "none" for reg in REGS]
    head = list(group) + [f"{n} ms (x)" for n in names]
    lines = ["# cmax: Table 3.4 layout", "",
             "ms per evaluation of J = -G + lambda R (lambda = 1) and its gradient (one core, "
             "medians), with the ratio to the unregularized evaluation at the same parameters "
             "in brackets, then the same for the fastest run; from cmax.json. motion "
             "'bench_cmax': WARP_THETA (no collapse: the trimmed means select nothing); "
             "'collapse': COLLAPSE_THETA (strong contraction: the DIWE/IWA maps, their "
             "adjoint and the RCAD map are built).", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for k in keys:
        cells = {r["regularizer"]: r for r in ev if tuple(r[g] for g in group) == k}
        vals = [f"{cells[n]['ms_per_eval']:.3g} ({cells[n]['ratio_vs_none']:.2f}); "
                f"min {cells[n]['ms_min']:.3g} ({cells[n]['ratio_min']:.2f})"
                if n in cells else "" for n in names]
        lines.append("| " + " | ".join([str(v) for v in k] + vals) + " |")
    (harness.RESULTS / "cmax_table34.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main(quick="--quick" in sys.argv)
