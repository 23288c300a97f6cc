"""Table 4.5 analog for the network: the same short fine-tuning with each focus loss.

For each objective (gradient magnitude, variance, average timestamp, normalized average
timestamp) the shipped width-0.125 EV-FlowNet is trained further from the same seed on the
same simulated windows (``STEPS`` steps of batch 8, 176x240 crops, Adam 1e-3) with
``evmotion``'s trainer (40 steps from scratch barely leave zero flow with any loss, so
the comparison starts from a network that already sharpens), then evaluated on held-out simulated 40k-event windows at 346x260: AEE, %Out
(> 3 px), FWL, and the share of events the flow warps off the image at ``t_1`` / ``t_N``
(the collapse of the average-timestamp losses pushes events out, thesis Fig. 4.11).
A short budget on a shared 2-core CPU: a comparison of the losses' direction, not of
converged networks. Run: ``python benchmarks/run.py dnn_losses``.
"""

from __future__ import annotations

import sys
import tempfile
import time

import numpy as np

import harness

OBJECTIVES = ("gradient_magnitude", "variance", "avg_timestamp", "avg_timestamp_norm")
STEPS = 40
SEED_BASE = 910_000_000


def main(quick: bool = False) -> list[dict]:
    import torch

    from evmotion.methods.dnn.data import sim_window
    from evmotion.methods.dnn.infer import predict_displacement
    from evmotion.methods.dnn.model import load_model
    from evmotion.methods.dnn.train import TrainConfig, evaluate_windows, train

    cpu = harness.pin_idlest_core()
    steps = 4 if quick else STEPS
    val = [sim_window(SEED_BASE + i, scene=s, texture="dots", sensor_size=(260, 346),
                      duration_s=0.2)
           for i, s in enumerate(("translation", "rotation", "zoom", "object"))]
    from evmotion.methods.dnn.model import DEFAULT_CHECKPOINT

    rows = []
    base = evaluate_windows(load_model(), val)
    for w, sc in zip(val, base, strict=True):
        rows.append({"objective": "shipped (before fine-tuning)",
                     "window": w.name.split(":")[1], "AEE_px": sc["AEE_px"],
                     "AEE_zero_px": sc["AEE_zero_px"], "FWL": sc["FWL"]})
    for obj in OBJECTIVES:
        with tempfile.TemporaryDirectory() as tmp:
            cfg = TrainConfig(objective=obj, epochs=1, sim_windows=8 * steps, val_sim=0,
                              max_steps_per_epoch=steps, seed=0,
                              init_weights=str(DEFAULT_CHECKPOINT))
            t0 = time.perf_counter()
            train(cfg, tmp)
            sec = time.perf_counter() - t0
            net = load_model(f"{tmp}/model.pt")
            torch.set_num_threads(1)
            scores = evaluate_windows(net, val)
            out_frac = []
            for w in val:
                d = predict_displacement(w.events, f"{tmp}/model.pt").astype(np.float64)
                x = np.asarray(w.events.x, float)
                y = np.asarray(w.events.y, float)
                t = w.events.t
                s = (t - t[0]) / (t[-1] - t[0])
                u, v = d[w.events.y.astype(int), w.events.x.astype(int)].T
                h, wd = w.events.sensor_size
                off = 0.0
                for r in (0.0, 1.0):
                    xw, yw = x + (r - s) * u, y + (r - s) * v
                    off += np.mean((xw < 0) | (xw > wd - 1) | (yw < 0) | (yw > h - 1)) / 2
                out_frac.append(off)
        for w, sc, off in zip(val, scores, out_frac, strict=True):
            rows.append({"objective": obj, "window": w.name.split(":")[1],
                         "AEE_px": sc["AEE_px"], "AEE_zero_px": sc["AEE_zero_px"],
                         "FWL": sc["FWL"], "pct_events_off_image": 100 * off,
                         "train_seconds": sec, "steps": steps})
    harness.record("dnn_losses", rows, notes=(
        f"cpu {cpu}; {steps} steps of batch 8 fine-tuning the shipped network, same seed and "
        "windows per objective; "
        "evaluation on held-out simulated 40k-event windows at 346x260 (seeds 910000000+)."))
    return rows


if __name__ == "__main__":
    main(quick="--quick" in sys.argv)
