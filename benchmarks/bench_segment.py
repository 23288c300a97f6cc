"""Motion segmentation (Sec. 3.6.6, two translation clusters): does it find an object of
10-50 % of the events over a moving background, and say nothing on noise?

Scenes: dots of a 90 px object moving at (-80, 60) px/s over dots of the whole 320 x 240
sensor moving at (50, 0) for 40 ms (``tests/test_segmentation.object_on_background``,
object shares 0.1-0.5, seeds 0-2); the simulator's ``object`` scene (a textured object
turning and moving over a translating background; 20k events mid-recording, seeds 0-2);
uniform noise (15k events on 240 x 180 in 10 ms, seeds 0-3). Per window: each cluster's
velocity, valid flag and event share; ``object_found``: a valid cluster within 10 px/s of
the object's velocity (dot scenes); per-event AEE (px over the window) of the event's
cluster's translation against the exact displacement at its pixel, beside the AEE of one
translation for all events (``segment_motion(n_warps=1)``); CPU seconds (one core).
Run: ``python benchmarks/run.py segment``.
"""

from __future__ import annotations

import sys
import time
import warnings
from pathlib import Path

import numpy as np

import harness

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

OBJECT_V = np.array([-80.0, 60.0])  # px/s, object_on_background's
BACKGROUND_V = np.array([50.0, 0.0])


def _dot_truth(ev) -> np.ndarray:
    """Per-event displacement over the window of object_on_background's scene: the object's
    motion for events whose start position lies in its square, else the background's."""
    dt = (ev.t[-1] - ev.t[0]) * 1e-6
    s = (ev.t - ev.t[0]) * 1e-6
    x0, y0 = ev.x - OBJECT_V[0] * s, ev.y - OBJECT_V[1] * s
    obj = (x0 >= 115) & (x0 <= 205) & (y0 >= 75) & (y0 <= 165)
    return np.where(obj[:, None], OBJECT_V * dt, BACKGROUND_V * dt)


def _windows(quick: bool):
    from evmotion.events import EventArray
    from evmotion.sim import simulate
    from test_segmentation import object_on_background

    out = []
    for share in (0.1, 0.2, 0.3, 0.5):
        for seed in range(1 if quick else 3):
            ev = object_on_background(seed, share)
            out.append((f"dots, object {share:.0%}", seed, ev, _dot_truth(ev)))
    for seed in range(1 if quick else 3):
        sim = simulate("object", duration_s=0.1, sensor_size=(180, 240), seed=seed,
                       show_progress=False)
        mid = len(sim.events) // 2
        ev = sim.events[mid - 10_000: mid + 10_000]
        disp = sim.gt.displacement(int(ev.t[0]), int(ev.t[-1]))
        out.append(("simulator 'object'", seed, ev,
                    disp[ev.y.astype(int), ev.x.astype(int)].astype(np.float64)))
    for seed in range(1 if quick else 4):
        rng = np.random.default_rng(seed)
        n = 15_000
        ev = EventArray(rng.integers(0, 240, n), rng.integers(0, 180, n),
                        np.sort(rng.integers(0, 10_000, n)), rng.integers(0, 2, n), (180, 240))
        out.append(("noise 240x180", seed, ev, None))
    return out


def _aee(seg, ev, truth) -> float:
    dt = (ev.t[-1] - ev.t[0]) * 1e-6
    return float(np.mean(np.linalg.norm(seg.params[seg.labels] * dt - truth, axis=1)))


def main(quick: bool = False) -> list[dict]:
    from evmotion.methods.segmentation import segment_motion

    harness.single_core()
    rows = []
    windows = _windows(quick)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        segment_motion(windows[0][2], n_warps=2, warp="translation", seed=0)  # numba
    for name, seed, ev, truth in windows:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            c0 = time.process_time()
            seg = segment_motion(ev, n_warps=2, warp="translation", seed=0)
            cpu = time.process_time() - c0
            one = segment_motion(ev, n_warps=1, warp="translation", seed=0)
        order = np.argsort(seg.params[:, 0])
        row = {"scene": name, "seed": seed, "events": len(ev), "split": seg.split}
        for k, j in enumerate(order):
            row[f"v{k} [px/s]"] = f"({seg.params[j, 0]:.1f}, {seg.params[j, 1]:.1f})"
            row[f"valid{k}"] = bool(seg.valid[j])
            row[f"share{k}"] = float(np.mean(seg.labels == j))
        if name.startswith("dots"):
            row["object_found"] = bool(any(
                seg.valid[j] and np.linalg.norm(seg.params[j] - OBJECT_V) < 10
                for j in range(2)))
        if truth is not None:
            row["AEE_px"] = _aee(seg, ev, truth)
            row["AEE_one_motion_px"] = _aee(one, ev, truth)
        row["cpu_s"] = cpu
        rows.append(row)
    dots = [r for r in rows if "object_found" in r]
    summary = {"scene": "ALL dots", "object_found": f"{sum(r['object_found'] for r in dots)}"
                                                    f"/{len(dots)}",
               "AEE_px": float(np.median([r["AEE_px"] for r in dots])),
               "AEE_one_motion_px": float(np.median([r["AEE_one_motion_px"] for r in dots]))}
    noise = [r for r in rows if r["scene"].startswith("noise")]
    summary["noise windows with a valid cluster"] = (
        f"{sum(r['valid0'] or r['valid1'] for r in noise)}/{len(noise)}")
    rows.insert(0, summary)
    harness.record("segment", rows,
                   notes="segment_motion(n_warps=2, warp='translation', seed=0) with its "
                         "defaults (split 'best'); AEE px over the window per event, its "
                         "cluster's translation against the exact displacement at its pixel "
                         "(summary: medians over the dot scenes); AEE_one_motion_px: one "
                         "translation for all events; cpu_s: one core.")
    return rows
