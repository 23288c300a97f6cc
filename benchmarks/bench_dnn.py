"""The unsupervised EV-FlowNet (thesis §4.3.7): accuracy, speed and DNN-initialized multicm.

1. Held-out simulated 40k-event windows at 346x260 (translation, rotation, zoom, the
   independently moving object; default scene parameters, seeds 900000000+ never drawn in
   training): AEE (px over the window, pixels with events), %Out (> 3 px) and FWL of
   dnn, multicm (defaults) and zero flow -- the Table 4.4 analog -- and multicm started
   from the network's flow (``init="dnn"``, finest 2 scales) with its time.
2. FWL of dnn / multicm / DNN-init multicm on the eight ECD 30k-event windows (never
   trained on).
3. Speed, one torch thread, one pinned core: inference (voxel grid + network) at 346x260
   and 640x480; ``evmotion flow WINDOW --method dnn --window-events 30000 --out x.flo``
   wall time including start-up; one training step (batch 8, 346x260 input) and the share
   of the loss in it.

Checkpoint: the shipped one, or ``EVMOTION_DNN_CHECKPOINT``. Run:
``python benchmarks/run.py dnn``.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import harness

DATA = Path(os.environ.get("EVMOTION_SHARED_DATA",
                           Path(__file__).resolve().parents[2] / "shared" / "data"))
ECD_WINDOWS = ("boxes_rotation", "boxes_translation", "dynamic_rotation",
               "dynamic_translation", "poster_rotation", "poster_translation",
               "shapes_rotation", "shapes_translation")
SIM_SCENES = ("translation", "rotation", "zoom", "object")
N_EVENTS = 40_000
SEED_BASE = 900_000_000


def _ckpt():
    return os.environ.get("EVMOTION_DNN_CHECKPOINT") or None


def _fwl(res) -> float:
    return float(np.var(res.iwes["tmid"]) / np.var(res.iwes["identity"]))


def _sim(scene: str, k: int):
    from evmotion.sim import simulate

    sim = simulate(scene, duration_s=0.2, sensor_size=(260, 346), seed=SEED_BASE + k,
                   show_progress=False)
    ev = sim.events
    mid = len(ev) // 2
    win = ev[mid - N_EVENTS // 2: mid + N_EVENTS // 2]
    return win, sim.gt.displacement(int(win.t[0]), int(win.t[-1]))


def _errors(disp, gt, mask):
    e = np.linalg.norm(disp.astype(np.float64) - gt, axis=-1)
    ok = mask & np.isfinite(e)
    return float(e[ok].mean()), float((e[ok] > 3.0).mean() * 100)


def accuracy_sim(quick: bool) -> list[dict]:
    from evmotion.methods.multicm import estimate_flow

    rows = []
    for k, scene in enumerate(SIM_SCENES[:2] if quick else SIM_SCENES):
        win, gt = _sim(scene, k)
        mask = np.zeros(win.sensor_size, bool)
        mask[win.y.astype(int), win.x.astype(int)] = True
        runs = {"dnn": lambda w=win: estimate_flow(w, method="dnn", checkpoint=_ckpt()),
                "multicm": lambda w=win: estimate_flow(w),
                "multicm init=dnn": lambda w=win: estimate_flow(w, init="dnn",
                                                               checkpoint=_ckpt())}
        for name, fn in runs.items():
            fn()  # warm (numba, checkpoint cache)
            t0 = time.perf_counter()
            res = fn()
            sec = time.perf_counter() - t0
            aee, out = _errors(res.displacement(), gt, mask)
            rows.append({"section": "sim 40k 346x260", "data": scene, "method": name,
                         "AEE_px": aee, "pct_out": out, "FWL": _fwl(res), "seconds": sec})
        zaee, zout = _errors(np.zeros_like(gt), gt, mask)
        rows.append({"section": "sim 40k 346x260", "data": scene, "method": "zero flow",
                     "AEE_px": zaee, "pct_out": zout, "FWL": 1.0, "seconds": 0.0})
    return rows


def accuracy_ecd(quick: bool) -> list[dict]:
    from evmotion.io import read_events
    from evmotion.methods.multicm import estimate_flow

    root = DATA / "ecd_30k_windows"
    if not root.is_dir():
        print(f"skipping the ECD windows: {root} not found")
        return []
    rows = []
    for name in ECD_WINDOWS[:2] if quick else ECD_WINDOWS:
        ev = read_events(root / name)
        for method, fn in (("dnn", lambda e=ev: estimate_flow(e, method="dnn",
                                                              checkpoint=_ckpt())),
                           ("multicm", lambda e=ev: estimate_flow(e)),
                           ("multicm init=dnn", lambda e=ev: estimate_flow(
                               e, init="dnn", checkpoint=_ckpt()))):
            t0 = time.perf_counter()
            res = fn()
            rows.append({"section": "ECD 30k (held out)", "data": name, "method": method,
                         "FWL": _fwl(res), "seconds": time.perf_counter() - t0})
    return rows


def _window(shape, n, seed=0):
    from evmotion.events import EventArray

    rng = np.random.default_rng(seed)
    h, w = shape
    return EventArray(x=rng.integers(0, w, n), y=rng.integers(0, h, n),
                      t=np.sort(rng.integers(0, 30_000, n)), p=rng.integers(0, 2, n),
                      sensor_size=shape)


def _cpu_median(fn, repeat: int) -> float:
    """Median CPU time (process_time) of ``fn()``: on a shared machine the wall time also
    counts the time this process waited for a core."""
    fn()
    out = []
    for _ in range(repeat):
        c0 = time.process_time()
        fn()
        out.append(time.process_time() - c0)
    return float(np.median(out))


def speed(quick: bool) -> list[dict]:
    import torch

    from evmotion.methods.dnn.infer import predict_displacement
    from evmotion.methods.dnn.loss import WindowLoss, multiscale_loss, window_problem
    from evmotion.methods.dnn.model import load_model
    from evmotion.methods.dnn.network import EVFlowNet, upsample_flows
    from evmotion.methods.dnn.voxel import normalize_voxel, pad_to_multiple, voxel_grid

    torch.set_num_threads(1)
    rows = []
    net = load_model(_ckpt())
    params = sum(p.numel() for p in net.parameters())
    for shape in ((260, 346), (480, 640)):
        ev = _window(shape, N_EVENTS)
        t = harness.timeit(lambda e=ev: predict_displacement(e, _ckpt()),
                           repeat=5 if quick else 20)
        tv = harness.timeit(lambda e=ev: pad_to_multiple(normalize_voxel(voxel_grid(e))),
                            repeat=5 if quick else 20)
        cpu = _cpu_median(lambda e=ev: predict_displacement(e, _ckpt()), 5 if quick else 20)
        rows.append({"section": "speed", "data": f"inference {shape[1]}x{shape[0]}, 40k ev",
                     "method": f"dnn width {net.width} ({params} params)",
                     "seconds": t["median_s"], "min_s": t["min_s"], "cpu_s": cpu,
                     "voxel_s": tv["median_s"]})
    # one training step, batch 8 at 346x260 (padded 352x272), simulated windows
    from evmotion.methods.dnn.data import sim_window

    wins = [sim_window(SEED_BASE + 100 + i, sensor_size=(260, 346), window_events=N_EVENTS)
            for i in range(8)]
    shape = (272, 352)
    torch.manual_seed(0)
    tnet = EVFlowNet(width=net.width)
    opt = torch.optim.Adam(tnet.parameters(), lr=1e-3)
    times = []
    for _ in range(2 if quick else 4):
        t0 = time.perf_counter()
        probs = [WindowLoss(window_problem(w.events), w.events.sensor_size) for w in wins]
        vox = torch.from_numpy(np.stack([pad_to_multiple(normalize_voxel(voxel_grid(w.events)))
                                         for w in wins]))
        t1 = time.perf_counter()
        opt.zero_grad()
        flows = upsample_flows(tnet(vox), shape)
        t2 = time.perf_counter()
        loss = multiscale_loss(flows, probs)
        t3 = time.perf_counter()
        loss.backward()
        t4 = time.perf_counter()
        opt.step()
        t5 = time.perf_counter()
        times.append((t5 - t0, t1 - t0, t3 - t2, t4 - t3))
    tot, prep, lf, bwd = np.median(np.array(times), axis=0)
    rows.append({"section": "speed", "data": "training step, batch 8, 346x260, 40k ev",
                 "method": f"width {net.width}", "seconds": float(tot),
                 "loss_forward_s": float(lf), "backward_s": float(bwd),
                 "prep_s (problems + voxels)": float(prep),
                 "loss_share_pct": float(100 * lf / tot)})
    win = DATA / "ecd_30k_windows" / "boxes_rotation"
    if win.is_dir():
        with tempfile.TemporaryDirectory() as tmp:
            cmd = [sys.executable, "-m", "evmotion", "flow", str(win), "--method", "dnn",
                   "--window-events", "30000", "--out", str(Path(tmp) / "x.flo")]
            walls = []
            for _ in range(2 if quick else 3):
                t0 = time.perf_counter()
                r = subprocess.run(cmd, capture_output=True, text=True, check=False)
                walls.append(time.perf_counter() - t0)
                if r.returncode:
                    raise RuntimeError(r.stderr)
            cpu = os.times()
        rows.append({"section": "speed", "data": "evmotion flow ECD window --method dnn "
                     "(30k ev) incl. start-up", "method": "CLI, shipped checkpoint",
                     "seconds": float(np.median(walls)), "min_s": float(min(walls)),
                     "children_cpu_s": float((cpu.children_user + cpu.children_system)
                                             / len(walls))})
    return rows


def main(quick: bool = False) -> list[dict]:
    cpu = harness.pin_idlest_core()
    rows = speed(quick) + accuracy_sim(quick) + accuracy_ecd(quick)
    harness.record("dnn", rows, notes=(
        f"one pinned core (cpu {cpu}), torch threads 1; checkpoint "
        f"{_ckpt() or 'shipped'}. AEE px over the window on pixels with events, %Out > 3 px; "
        "FWL = var(IWE t_mid) / var(IWE zero flow). multicm: defaults (5 scales); "
        "init=dnn: the network's flow then the finest 2 scales. Wall times on a shared "
        "2-core machine (load from other jobs inflates them)."))
    return rows


if __name__ == "__main__":
    main(quick="--quick" in sys.argv)
