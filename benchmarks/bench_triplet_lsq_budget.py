"""Where the error of the triplet ``dense="lsq"`` output comes from (issue #5: translation
stays 4.5-27x MultiCM's AEE).

On the simulated translation, rotation and zoom scenes (seed 0, default speeds, dt = 1 and
dt = 4 frame windows, as ``bench_triplet_accuracy``), the dense least-squares fit of the
library (``add_normal_voxels`` + ``dense_lsq_from_sums``) is fed four versions of the
per-event normal flows:

* ``estimated``: the matcher's own (what ``estimate_flow_triplet(dense="lsq")`` returns);
* ``exact_speed``: the matcher's normal directions with the ground-truth normal speed
  ``v_gt . n`` -- what a perfect timing of the triplets would give;
* ``exact_speed_ridge0``: the same without the fit's ridge (its pull towards the normal
  flow where one orientation dominates);
* ``estimated_ridge0``: the estimated normal flows without the ridge.

The gap between ``estimated`` and ``exact_speed`` is the part of the AEE due to the
per-event normal speeds (the timing of the matches), the rest the fit's (directions,
aperture, ridge). MultiCM's AEE on the same windows comes from
``results/triplet_accuracy.json`` when it is there.

``python benchmarks/run.py triplet_lsq_budget``
"""

from __future__ import annotations

import json

import numpy as np

import harness
from bench_triplet_accuracy import SIM_CASES, event_gt_flow
from evmotion.eval.metrics import flow_metrics
from evmotion.methods.triplet import (
    TripletFlow,
    TripletMatcher,
    add_normal_voxels,
    dense_defaults,
    dense_lsq_from_sums,
    max_normal_speed,
)
from evmotion.sim import simulate


def _with_normal(flow: TripletFlow, nx: np.ndarray, ny: np.ndarray) -> TripletFlow:
    return TripletFlow(flow.vx, flow.vy, flow.valid, flow.n_triplets,
                       nx.astype(np.float32), ny.astype(np.float32))


def _dense(events, flow, win, vmax, filter_size, ridge):
    h, w = events.sensor_size
    acc = np.zeros((1, h, w, 5))
    cnt = np.zeros((1, h, w), np.int64)
    add_normal_voxels(events[win.start:win.stop], flow[win.start:win.stop], win.t0, win.t1,
                      acc, cnt, vmax)
    return dense_lsq_from_sums(acc, cnt, filter_size=filter_size, ridge=ridge)[0]


def _multicm_aee() -> dict[tuple[str, int], float]:
    """MultiCM's AEE per window from the accuracy suite's results, if recorded."""
    path = harness.RESULTS / "triplet_accuracy.json"
    if not path.exists():
        return {}
    out = {}
    for row in json.loads(path.read_text()).get("rows", []):
        if "multicm_AEE" in row and "window" in row:
            out[(row["case"], row["window"])] = row["multicm_AEE"]
    return out


def main(quick: bool = False) -> list[dict]:
    dx, tau_us, filter_size = dense_defaults("lsq")
    vmax = max_normal_speed(dx, tau_us)
    cm = _multicm_aee()
    rows = []
    for scene, params in SIM_CASES[:3]:
        res = simulate(scene, duration_s=0.3, seed=0, frame_rate=45.0, params=params,
                       show_progress=False)
        ev = res.events
        flow = TripletMatcher(ev.sensor_size, dx, tau_us=tau_us).process(ev)
        nx, ny = flow.nx.astype(np.float64), flow.ny.astype(np.float64)
        speed = np.hypot(nx, ny)
        unit = np.divide(np.stack([nx, ny], 1), speed[:, None],
                         out=np.zeros((len(ev), 2)), where=speed[:, None] > 0)
        g = event_gt_flow(res, ev, step_us=1_000)
        vn = (g * unit).sum(1)
        exact = _with_normal(flow, unit[:, 0] * vn, unit[:, 1] * vn)
        variants = {"estimated": (flow, 1e-2), "exact_speed": (exact, 1e-2),
                    "exact_speed_ridge0": (exact, 0.0), "estimated_ridge0": (flow, 0.0)}
        for dt in (1, 4):
            wins = ev.windows_at(res.gt.frame_times_us, dt=dt, drop_empty=True)
            wins = wins[1:3] if quick else wins[1:]  # the first window lacks history
            aee = {k: [] for k in variants}
            ref = []
            for win in wins:
                sub = ev.window(win)
                gt = res.gt.displacement(win.t0, win.t1)
                for k, (f, ridge) in variants.items():
                    v = _dense(ev, f, win, vmax, filter_size, ridge)
                    aee[k].append(flow_metrics(v * win.duration_s, gt, events=sub).aee)
                ref.append(cm.get((f"sim {scene} dt={dt}", win.index), np.nan))
            row = {"case": f"{scene} dt={dt}", "windows": len(wins)}
            row.update({f"{k}_AEE": float(np.mean(v)) for k, v in aee.items()})
            row["multicm_AEE"] = float(np.mean(ref))
            for k in ("estimated", "exact_speed"):
                row[f"{k}_over_multicm"] = row[f"{k}_AEE"] / row["multicm_AEE"]
            rows.append(row)
            print(row, flush=True)
    harness.record("triplet_lsq_budget", rows, notes=(
        "dense='lsq' defaults (d_x = 2.3, tau = 1 ms, 15 x 15 fit, ridge 1e-2); AEE in px, "
        "mean over the windows; 'exact_speed': the matcher's normal directions with the "
        "ground-truth normal speed (simulator flow at each event, 1 ms slices); "
        "multicm_AEE from results/triplet_accuracy.json (nan when absent)"))
    return rows


if __name__ == "__main__":
    import sys
    main(quick="--quick" in sys.argv)
