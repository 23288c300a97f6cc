"""Speed of multi-reference CMax dense flow (thesis ch. 4), one core.

Targets: one 30k-event window at 346x260 with 5 scales <= 0.5 s median; time-aware
(Burgers, 10 bins) <= 1.5x the plain run; 500k events at 640x480 <= 5 s per window. The
windows come from the simulator (translation scene, seeded). Also reported: the cost of one
objective+gradient evaluation, and the fused B-spline IWE kernel against the composition
``core.iwe.accumulate(kernel="gaussian")`` + ``accumulate_backward`` (the thesis' Gaussian
Dirac approximation), measured in the same run.
"""

from __future__ import annotations

import functools
import statistics
import time

import numpy as np

import harness


def _window(shape, n, scene="translation", duration_s=0.2):
    from evmotion.sim import simulate

    sim = simulate(scene, duration_s=duration_s, sensor_size=shape, seed=0,
                   show_progress=False)
    ev = sim.events
    if len(ev) < n:
        raise RuntimeError(f"simulated only {len(ev)} events, need {n}")
    mid = len(ev) // 2
    return ev[mid - n // 2: mid + n // 2]


def _interleaved(fns: dict, repeat: int) -> dict:
    for fn in fns.values():
        fn()
    runs: dict = {k: [] for k in fns}
    for _ in range(repeat):
        for k, fn in fns.items():
            t0 = time.perf_counter()
            fn()
            runs[k].append(time.perf_counter() - t0)
    return {k: {"median_s": statistics.median(v), "min_s": min(v), "max_s": max(v),
                "repeat": repeat} for k, v in runs.items()}


def main(quick: bool = False) -> list[dict]:
    harness.single_core()
    from evmotion.core import iwe as ciwe
    from evmotion.core import tileflow as tf
    from evmotion.methods.multicm import MultiCMProblem, estimate_flow

    rep = 3 if quick else 9
    rows = []
    ev = _window((260, 346), 30_000)
    # plain and time-aware runs interleaved, so that load from other jobs on this shared
    # machine hits all variants alike and the ratios stay meaningful
    variants = {
        "30k ev, 346x260, 5 scales": {},
        "30k ev, burgers 10 bins": {"time_aware": "burgers", "n_bins": 10},
        "30k ev, upwind 10 bins": {"time_aware": "upwind", "n_bins": 10},
        "30k ev, burgers 5 bins": {"time_aware": "burgers", "n_bins": 5},
    }
    times = _interleaved({k: functools.partial(estimate_flow, ev, **kw)
                          for k, kw in variants.items()}, repeat=rep)
    base = times["30k ev, 346x260, 5 scales"]["median_s"]
    for k, r in times.items():
        row = {"case": k, **r, "ratio_to_plain": r["median_s"] / base}
        row["target_s"] = 0.5 if not variants[k] else 1.5 * base
        rows.append(row)

    # one evaluation of (4.9) and its gradient at the finest scale
    x = ev.x.astype(np.float64)
    y = ev.y.astype(np.float64)
    s = (ev.t - ev.t[0]) / (ev.t[-1] - ev.t[0])
    prob = MultiCMProblem(x, y, s, ev.sensor_size, tf.scale_grid(5, ev.sensor_size))
    theta = np.random.default_rng(0).normal(size=16 * 16 * 2)
    r = harness.timeit(lambda: prob.value_grad(theta), repeat=5 * rep)
    rows.append({"case": "one value+grad (3 refs, 16x16 tiles)", **r})

    # fused B-spline kernel vs Gaussian composition (fwd + bwd of one IWE)
    flow = np.random.default_rng(1).normal(size=(x.size, 2))
    dtn = np.ascontiguousarray(0.5 - s)
    g = np.random.default_rng(2).normal(size=ev.sensor_size)
    rb = harness.timeit(lambda: (tf.iwe_forward(x, y, flow, dtn, ev.sensor_size),
                                 tf.iwe_backward(x, y, flow, dtn, g)), repeat=5 * rep)
    xw = x + dtn * flow[:, 0]
    yw = y + dtn * flow[:, 1]
    rg = harness.timeit(lambda: (ciwe.accumulate(xw, yw, ev.sensor_size, kernel="gaussian"),
                                 ciwe.accumulate_backward(xw, yw, ev.sensor_size, g,
                                                          kernel="gaussian")),
                        repeat=5 * rep)
    rows.append({"case": "IWE fwd+bwd, B-spline (tileflow)", **rb,
                 "ratio_to_plain": rb["median_s"] / rg["median_s"]})
    rows.append({"case": "IWE fwd+bwd, Gaussian sigma 1 (core.iwe)", **rg,
                 "ratio_to_plain": 1.0})

    big = _window((480, 640), 500_000, duration_s=0.25)
    rbig = harness.timeit(lambda: estimate_flow(big), repeat=max(1, rep // 3), warmup=1)
    rows.append({"case": "500k ev, 640x480, 5 scales", **rbig, "target_s": 5.0})
    harness.record("multicm", rows,
                   notes="one core (harness.single_core); medians; ratio_to_plain = median / "
                         "the plain 30k run (time-aware rows) or / the Gaussian kernel (IWE "
                         "rows). The machine is shared by other jobs: absolute times vary.")
    return rows


if __name__ == "__main__":
    import sys

    main(quick="--quick" in sys.argv)
