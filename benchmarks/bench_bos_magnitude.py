"""Accuracy and magnitudes of the event-based BOS solver on the schlieren simulator
(issue #12, "physically right magnitudes"; thesis ch. 6).

For each simulated scene (plume, jet, breath, ice; 360x320 px, 2 px largest displacement,
seed 0) and its frame intervals 1 and 2, ``estimate_bos`` runs with both parameterizations
(poisson, flow) and both ways of getting the flow's scale:

* ``normalized``: the thesis' data term (6.11), whose solution has no scale, rescaled by
  the least-squares factor between its prediction and C times the event sums;
* ``scale``: the scale-aware data term (events times C against the prediction, no
  normalization).

C is estimated from the two frames (``estimate_contrast_threshold``, method "auto": S
regressed on D at the data term's sigma over the pixels that fired, the solver's default);
the reduced-major-axis and one-sided estimates at sigma 1 px ("rma", "events": D on S,
"frames": S on D) are listed beside it and the sensor's nominal C. Metrics against the simulator's exact flow over the pixels with events:
AEE (px over the interval), AE (rad, angle between 2-D flow vectors, as the thesis'
Table 6.4), and the median |v|/|v_gt| over those pixels with |v_gt| > 0.05 px.

``python benchmarks/run.py bos_magnitude``
"""

from __future__ import annotations

import numpy as np

import harness
from bench_bos import accuracy
from evmotion.methods.bos import estimate_bos, estimate_contrast_threshold
from evmotion.sim.schlieren import simulate_schlieren

SIZE = (360, 320)
SCENES = ("plume", "jet", "breath", "ice")


def main(quick: bool = False) -> list[dict]:
    rows = []
    scenes = SCENES[:1] if quick else SCENES
    for scene in scenes:
        sim = simulate_schlieren(scene, sensor_size=SIZE, duration_s=3 / 120,
                                 magnitude_px=2.0, seed=0)
        fr, t = sim.frames.images, sim.frames.t
        for k in (1, 2):
            t0, t1 = int(t[k]), int(t[k + 1])
            dt = (t1 - t0) * 1e-6
            gt_px = sim.gt.flow[k] * dt
            win = sim.events.slice_time(t0, t1)
            mask = np.zeros(SIZE, bool)
            mask[win.y, win.x] = True
            cs = {m: estimate_contrast_threshold(sim.events, fr[k], fr[k + 1], t0_us=t0,
                                                 t1_us=t1, method=m)
                  for m in ("auto", "rma", "events", "frames")}
            for param in ("poisson", "flow"):
                for term in ("normalized", "scale"):
                    res = estimate_bos(sim.events, fr[k], t0_us=t0, t1_us=t1,
                                       frame_next=fr[k + 1], param=param, data_term=term)
                    row = {"scene": scene, "interval": k, "events": len(win),
                           "param": param, "data_term": term,
                           **accuracy(res.flow * dt, gt_px, mask), "scale": res.scale,
                           "C_auto": cs["auto"], "C_rma": cs["rma"], "C_events": cs["events"],
                           "C_frames": cs["frames"], "C_sensor": sim.gt.contrast_threshold,
                           "time_s": sum(res.timings_s)}
                    rows.append(row)
                    print({k2: (round(v, 4) if isinstance(v, float) else v)
                           for k2, v in row.items()}, flush=True)
    summary = []
    for param in ("poisson", "flow"):
        for term in ("normalized", "scale"):
            sel = [r for r in rows if r["param"] == param and r["data_term"] == term]
            summary.append({"scene": "ALL (mean)", "param": param, "data_term": term,
                            **{m: float(np.mean([r[m] for r in sel]))
                               for m in ("AEE_px", "AE_rad", "ratio")},
                            "ratio_min": float(min(r["ratio"] for r in sel)),
                            "ratio_max": float(max(r["ratio"] for r in sel))})
    from bench_bos_accuracy import solver_version

    notes = ("Default options (150/150/150/300 iterations, pool 'auto', tol 1e-3); the "
             "simulator's flow is the image motion (sign fixed in 6e28bc7); code at "
             f"{solver_version()}.")
    harness.record("bos_magnitude", rows + summary, notes)
    return rows


if __name__ == "__main__":
    main()
