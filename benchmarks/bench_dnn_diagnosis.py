"""Why the shipped EV-FlowNet misses the ground truth (issue #13): per-component gains, the
training loss at the ground truth vs at the network's flow, inactive ReLU channels, and the
flow read off a transposed input.

On bench_dnn's held-out simulated 40k-event windows at 346x260 (translation, rotation,
zoom, object; seeds 900000000 + k and 900000100 + k, never drawn in training):

* ``gain_u`` / ``gain_v``: least-squares gain ``a_c`` of ``v_c ~ a_c g_c`` per flow
  component (1 = right magnitude, 0 = the component is not predicted); median
  ``|v| / |g|`` and median direction cosine on pixels with events.
* ``loss_*``: the training loss of the finest scale (multicm's ``1/f + lam TV``, 1 at zero
  flow) at zero flow, at the ground truth, at the ground truth with v set to 0, and at the
  network's flow: if the ground truth were not the lowest, the loss could not teach it.
* ``AEE_transposed_px``: u from the window and v as the u the network predicts on the
  window mirrored about the diagonal (x <-> y): what the network knows about both axes
  when it is only asked for its horizontal output. For a symmetric network (the shipped
  one since 2026-11-28) this is how it computes v: equal to ``AEE_px``, a check of its
  equivariance on real windows.
* one ``inactive`` row per layer: channels whose ReLU output is 0 on every pixel of the
  four windows of the first seed set.

Checkpoint: the shipped one, or ``EVMOTION_DNN_CHECKPOINT``. Run:
``python benchmarks/run.py dnn_diagnosis``.
"""

from __future__ import annotations

import os
import sys

import numpy as np

import harness

SIM_SCENES = ("translation", "rotation", "zoom", "object")
N_EVENTS = 40_000
SEED_BASE = 900_000_000
SEED_SETS = (0, 100)


def _sim(scene: str, seed: int):
    from evmotion.sim import simulate

    sim = simulate(scene, duration_s=0.2, sensor_size=(260, 346), seed=seed,
                   show_progress=False)
    ev = sim.events
    mid = len(ev) // 2
    win = ev[mid - N_EVENTS // 2: mid + N_EVENTS // 2]
    return win, sim.gt.displacement(int(win.t[0]), int(win.t[-1]))


def _transposed(ev):
    from evmotion.events import EventArray

    h, w = ev.sensor_size
    return EventArray(x=ev.y, y=ev.x, t=ev.t, p=ev.p, sensor_size=(w, h), validate=False)


def main(quick: bool = False) -> list[dict]:
    import torch

    from evmotion.methods.dnn.infer import predict_displacement
    from evmotion.methods.dnn.loss import window_problem
    from evmotion.methods.dnn.model import load_model
    from evmotion.methods.dnn.voxel import normalize_voxel, pad_to_multiple, voxel_grid

    harness.single_core()
    torch.set_num_threads(1)
    ckpt = os.environ.get("EVMOTION_DNN_CHECKPOINT") or None
    net = load_model(ckpt)
    net.eval()
    active: dict[str, list[np.ndarray]] = {}
    layers = [(f"enc{i}", m) for i, m in enumerate(net.enc)] + \
             [(f"dec{i}", m) for i, m in enumerate(net.dec)]
    rows = []
    for rep in SEED_SETS[:1] if quick else SEED_SETS:
        for k, scene in enumerate(SIM_SCENES):
            win, gt = _sim(scene, SEED_BASE + rep + k)
            mask = np.zeros(win.sensor_size, bool)
            mask[win.y.astype(int), win.x.astype(int)] = True
            disp = predict_displacement(win, ckpt).astype(np.float64)
            disp_t = predict_displacement(_transposed(win), ckpt).astype(np.float64)
            both = np.stack([disp[..., 0], disp_t.transpose(1, 0, 2)[..., 0]], -1)
            g, v = gt[mask].astype(np.float64), disp[mask]
            gm, vm = np.linalg.norm(g, axis=1), np.linalg.norm(v, axis=1)
            ok = gm > 1e-9
            prob = window_problem(win)

            def loss(flow, p=prob):
                return float(p.value_grad(np.ascontiguousarray(flow, np.float64).ravel())[0])

            if rep == SEED_SETS[0]:
                hooks = [m.register_forward_hook(
                    lambda _m, _i, o, n=n: active.setdefault(n, []).append(
                        (o > 0).any(dim=3).any(dim=2)[0].numpy())) for n, m in layers]
                vox = torch.from_numpy(pad_to_multiple(normalize_voxel(voxel_grid(win)))[None])
                with torch.no_grad():
                    net(vox)
                for hk in hooks:
                    hk.remove()
            u_only = gt.astype(np.float64).copy()
            u_only[..., 1] = 0.0
            rows.append({
                "section": "held-out sim 40k 346x260", "data": f"{scene} seed +{rep + k}",
                "AEE_px": float(np.linalg.norm(v - g, axis=1).mean()),
                "AEE_zero_px": float(gm.mean()),
                "AEE_transposed_px": float(np.linalg.norm(both[mask] - g, axis=1).mean()),
                "gain_u": float((v[:, 0] * g[:, 0]).sum() / (g[:, 0] ** 2).sum()),
                "gain_v": float((v[:, 1] * g[:, 1]).sum() / (g[:, 1] ** 2).sum()),
                "median_mag_ratio": float(np.median(vm[ok] / gm[ok])),
                "median_cos": float(np.median((v[ok] * g[ok]).sum(1)
                                              / np.maximum(vm[ok] * gm[ok], 1e-12))),
                "loss_zero": loss(np.zeros_like(gt)), "loss_gt": loss(gt),
                "loss_gt_v0": loss(u_only), "loss_net": loss(disp)})
    for n, a in active.items():
        alive = np.any(np.stack(a), axis=0)
        rows.append({"section": "inactive ReLU channels (4 windows)", "data": n,
                     "channels": int(alive.size), "inactive": int((~alive).sum())})
    harness.record("dnn_diagnosis", rows, notes=(
        f"checkpoint {ckpt or 'shipped'}; torch threads 1. AEE px over the window on pixels "
        "with events; gains: least squares v_c ~ a_c g_c per component; losses: the "
        "finest-scale training loss (1 at zero flow). Load average at the start "
        f"{os.getloadavg()[0]:.1f} (shared 2-core machine; no timings here)."))
    return rows


if __name__ == "__main__":
    main(quick="--quick" in sys.argv)
