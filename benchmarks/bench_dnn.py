"""The unsupervised EV-FlowNet (thesis §4.3.7): accuracy, speed and DNN-initialized multicm.

1. Held-out simulated 40k-event windows at 346x260 (translation, rotation, zoom, the
   independently moving object; default scene parameters, seeds 900000000+ never drawn in
   training): AEE (px over the window, pixels with events), %Out (> 3 px) and FWL of
   dnn, multicm (defaults) and zero flow -- the Table 4.4 analog -- and multicm started
   from the network's flow (``init="dnn"``: its plain pass at each input scale, then the
   finest ``DNN_INIT_SCALES`` scales), its AEE and time as ratios
   to plain multicm's on the same window in the same run (median CPU seconds of 3 runs),
   and the share of multicm's time in those scales: the least any start that
   skips only the coarse scales can cost.
2. FWL of dnn / multicm / DNN-init multicm on the eight ECD 30k-event windows (never
   trained on).
3. Speed, one torch thread, one pinned core: inference (voxel grid + network) at 346x260
   and 640x480 by ``predict_displacement`` (``InferenceNet`` and ``network_input``) and,
   interleaved in the same run, by the training forward (``EVFlowNet`` on
   ``voxel_grid`` / ``normalize_voxel`` / ``pad_to_multiple``), with the largest
   difference of their flows, and the method's default (``estimate_flow_dnn``: the
   network at input scales 1, 2 and 4, the sharpest warp kept; no IWEs); ``evmotion flow WINDOW --method dnn --window-events 30000
   --out x.flo`` wall and CPU time including start-up, with the numba cache warm and empty
   (a fresh ``NUMBA_CACHE_DIR`` per run), the command not pinned (a user's is not); one
   training step (batch 8, 346x260 input) and the share of the loss in it.

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


def _sim(scene: str, k: int, seed: int | None = None):
    """The middle 40k events of scene ``scene`` at 346x260, seed ``SEED_BASE + k`` (or
    ``seed``), and its exact displacement over them."""
    from evmotion.sim import simulate

    sim = simulate(scene, duration_s=0.2, sensor_size=(260, 346),
                   seed=SEED_BASE + k if seed is None else seed, show_progress=False)
    ev = sim.events
    mid = len(ev) // 2
    win = ev[mid - N_EVENTS // 2: mid + N_EVENTS // 2]
    return win, sim.gt.displacement(int(win.t[0]), int(win.t[-1]))


def _errors(disp, gt, mask):
    e = np.linalg.norm(disp.astype(np.float64) - gt, axis=-1)
    ok = mask & np.isfinite(e)
    return float(e[ok].mean()), float((e[ok] > 3.0).mean() * 100)


def _cpu_wall(fn, repeat: int):
    """``fn()``'s last result and the median / min of its CPU and wall seconds over
    ``repeat`` runs after one warm-up (numba, checkpoint cache)."""
    fn()
    cpu, wall = [], []
    for _ in range(repeat):
        c0, t0 = time.process_time(), time.perf_counter()
        res = fn()
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - t0)
    return res, {"seconds": float(np.median(wall)), "min_s": float(min(wall)),
                 "cpu_s": float(np.median(cpu)), "cpu_min_s": float(min(cpu))}


def accuracy_sim(quick: bool) -> list[dict]:
    from evmotion.methods.dnn import estimate_flow_dnn
    from evmotion.methods.multicm import DNN_INIT_SCALES, estimate_flow

    rows = []
    for k, scene in enumerate(SIM_SCENES[:2] if quick else SIM_SCENES):
        win, gt = _sim(scene, k)
        mask = np.zeros(win.sensor_size, bool)
        mask[win.y.astype(int), win.x.astype(int)] = True
        runs = {"dnn": lambda w=win: estimate_flow(w, method="dnn", checkpoint=_ckpt()),
                "dnn refine=False": lambda w=win: estimate_flow_dnn(w, _ckpt(), refine=False),
                "dnn network only": lambda w=win: estimate_flow_dnn(w, _ckpt(), planar=False,
                                                                   refine=False),
                "multicm": lambda w=win: estimate_flow(w),
                "multicm init=dnn": lambda w=win: estimate_flow(w, init="dnn",
                                                               checkpoint=_ckpt())}
        ref = {}
        for name, fn in runs.items():
            res, t = _cpu_wall(fn, 1 if quick else 3)
            aee, out = _errors(res.displacement(), gt, mask)
            row = {"section": "sim 40k 346x260", "data": scene, "method": name,
                   "AEE_px": aee, "pct_out": out, "FWL": _fwl(res), **t}
            if name == "multicm":
                ref = row
                row["finest_share"] = sum(res.timings[f"scale{5 - i}_s"]
                                          for i in range(DNN_INIT_SCALES)) / res.timings["total_s"]
            elif name == "multicm init=dnn":
                row["AEE_vs_multicm"] = aee / ref["AEE_px"]
                row["cpu_vs_multicm"] = t["cpu_s"] / ref["cpu_s"]
            if name.startswith("dnn"):
                row["planar_kept"] = bool(res.meta["planar"])
                row["refined_kept"] = bool(res.meta["refined"])
            rows.append(row)
        for row in rows[-len(runs):]:
            if row["method"].startswith("dnn"):
                row["AEE_vs_multicm"] = row["AEE_px"] / ref["AEE_px"]
        zaee, zout = _errors(np.zeros_like(gt), gt, mask)
        rows.append({"section": "sim 40k 346x260", "data": scene, "method": "zero flow",
                     "AEE_px": zaee, "pct_out": zout, "FWL": 1.0, "seconds": 0.0})
    return rows


def accuracy_ecd(quick: bool) -> list[dict]:
    from evmotion.io import read_events
    from evmotion.methods.dnn import estimate_flow_dnn
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
                           ("dnn network only", lambda e=ev: estimate_flow_dnn(
                               e, _ckpt(), planar=False, refine=False)),
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


def speed(quick: bool) -> list[dict]:
    import torch

    from evmotion.methods.dnn.infer import (
        GAINS,
        INPUT_SCALES,
        estimate_flow_dnn,
        predict_displacement,
    )
    from evmotion.methods.dnn.loss import WindowLoss, multiscale_loss, window_problem
    from evmotion.methods.dnn.model import load_model
    from evmotion.methods.dnn.network import EVFlowNet, upsample_flows
    from evmotion.methods.dnn.voxel import (
        network_input,
        normalize_voxel,
        pad_to_multiple,
        voxel_grid,
    )

    torch.set_num_threads(1)
    rows = []
    net = load_model(_ckpt())
    params = sum(p.numel() for p in net.parameters())

    def training_forward(e):
        h, w = e.sensor_size
        vox = torch.from_numpy(pad_to_multiple(normalize_voxel(voxel_grid(e, net.n_bins))))
        with torch.inference_mode():
            return net(vox[None])[-1][0, :, :h, :w].permute(1, 2, 0).numpy()

    for shape in ((260, 346), (480, 640)):
        ev = _window(shape, N_EVENTS)
        fns = {"predict_displacement": lambda e=ev: predict_displacement(e, _ckpt(),
                                                                         backend="torch"),
               "predict_displacement numpy": lambda e=ev: predict_displacement(
                   e, _ckpt(), backend="numpy"),
               "training forward": lambda e=ev: training_forward(e),
               "estimate_flow_dnn": lambda e=ev: estimate_flow_dnn(e, _ckpt(),
                                                                   with_iwes=False),
               "estimate_flow_dnn numpy": lambda e=ev: estimate_flow_dnn(
                   e, _ckpt(), with_iwes=False, backend="numpy"),
               "estimate_flow_dnn network only": lambda e=ev: estimate_flow_dnn(
                   e, _ckpt(), with_iwes=False, planar=False, refine=False),
               "network_input": lambda e=ev: network_input(e, net.n_bins),
               "voxel_grid+normalize+pad": lambda e=ev: pad_to_multiple(
                   normalize_voxel(voxel_grid(e)))}
        times = _interleaved(fns, 5 if quick else 30)
        ref = fns["training forward"]()
        for name, voxel in (("predict_displacement", "network_input"),
                            ("predict_displacement numpy", "network_input"),
                            ("training forward", "voxel_grid+normalize+pad")):
            label = {"predict_displacement": "predict_displacement (backend torch)",
                     "predict_displacement numpy": "predict_displacement (backend numpy)"
                     }.get(name, name)
            rows.append({"section": "speed",
                         "data": f"inference {shape[1]}x{shape[0]}, 40k ev",
                         "method": f"{label}, width {net.width} ({params} params)",
                         **times[name], "voxel_s": times[voxel]["seconds"],
                         "voxel_cpu_s": times[voxel]["cpu_s"],
                         "max_diff_px": float(np.abs(fns[name]() - ref).max())})
        rows.append({"section": "speed", "data": f"inference {shape[1]}x{shape[0]}, 40k ev",
                     "method": "estimate_flow_dnn (defaults: input scales "
                               f"{', '.join(map(str, INPUT_SCALES))}, time reversal, gain "
                               f"{GAINS[0]}-{GAINS[-1]}, the plane's polish, on these "
                               "random events the tiles' refinement too; no IWEs; backend "
                               "auto: torch, loaded in this process)",
                     **times["estimate_flow_dnn"]})
        rows.append({"section": "speed", "data": f"inference {shape[1]}x{shape[0]}, 40k ev",
                     "method": "estimate_flow_dnn, the same with backend='numpy' (what a "
                               "process without torch runs: the CLI)",
                     **times["estimate_flow_dnn numpy"]})
        rows.append({"section": "speed", "data": f"inference {shape[1]}x{shape[0]}, 40k ev",
                     "method": "estimate_flow_dnn, planar=False, refine=False (the network's "
                               "flow only)",
                     **times["estimate_flow_dnn network only"]})
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
        for cache in ("warm", "empty"):
            rows.append(_cli_row(win, "ECD window", cache, 2 if quick else 5))
    # the held-out object window (30k of its events): no plane explains it, so the
    # network's flow is refined on multicm's tiles -- the default's longest path
    from evmotion.io import write_events

    with tempfile.TemporaryDirectory() as tmp:
        obj = Path(tmp) / "object30k.h5"
        write_events(obj, _sim("object", 3)[0][5_000:35_000])
        rows.append(_cli_row(obj, "simulated object window (refined)", "empty",
                             2 if quick else 5))
    return rows


def _interleaved(fns: dict, repeat: int) -> dict:
    """Median / min wall and CPU seconds of each function, run in turn (A B C A B C ...)
    after one warm-up each, so that a change in the machine's load hits all alike."""
    for fn in fns.values():
        fn()
    wall = {k: [] for k in fns}
    cpu = {k: [] for k in fns}
    for _ in range(repeat):
        for k, fn in fns.items():
            c0, t0 = time.process_time(), time.perf_counter()
            fn()
            cpu[k].append(time.process_time() - c0)
            wall[k].append(time.perf_counter() - t0)
    return {k: {"seconds": float(np.median(wall[k])), "min_s": float(min(wall[k])),
                "cpu_s": float(np.median(cpu[k])), "cpu_min_s": float(min(cpu[k]))}
            for k in fns}


def _cli_row(win: Path, label: str, cache: str, repeat: int) -> dict:
    """``evmotion flow WIN --method dnn --window-events 30000 --out x.flo`` as a user runs
    it (not pinned: the affinity of this pinned process is undone in the child), numba's
    cache warm (after one run) or empty (a fresh NUMBA_CACHE_DIR each run)."""
    import resource

    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "evmotion", "flow", str(win), "--method", "dnn",
               "--window-events", "30000", "--out", str(Path(tmp) / "x.flo")]
        walls, cpus = [], []
        for i in range(repeat + (cache == "warm")):
            env = dict(os.environ)
            if cache == "empty":
                env["NUMBA_CACHE_DIR"] = str(Path(tmp) / f"numba{i}")
            r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
            t0 = time.perf_counter()
            r = subprocess.run(cmd, capture_output=True, text=True, check=False, env=env,
                               preexec_fn=lambda: os.sched_setaffinity(
                                   0, set(range(os.cpu_count() or 1))))
            wall = time.perf_counter() - t0
            r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
            if r.returncode:
                raise RuntimeError(r.stderr)
            if cache == "warm" and i == 0:
                continue  # fills the cache
            walls.append(wall)
            cpus.append(r1.ru_utime - r0.ru_utime + r1.ru_stime - r0.ru_stime)
    return {"section": "speed", "data": f"evmotion flow {label} --method dnn (30k ev) "
            f"incl. start-up, numba cache {cache}", "method": "CLI, shipped checkpoint",
            "seconds": float(np.median(walls)), "min_s": float(min(walls)),
            "cpu_s": float(np.median(cpus)), "cpu_min_s": float(min(cpus)),
            "load_1min": os.getloadavg()[0]}


def main(quick: bool = False) -> list[dict]:
    from evmotion.methods.multicm import DNN_INIT_SCALES

    cpu = harness.pin_idlest_core()
    load0 = os.getloadavg()
    rows = speed(quick) + accuracy_sim(quick) + accuracy_ecd(quick)
    load1 = os.getloadavg()
    harness.record("dnn", rows, notes=(
        f"one pinned core (cpu {cpu}; the CLI rows unpinned), torch threads 1 (the numpy "
        "network: numpy's BLAS threads, pinned with the process); checkpoint "
        f"{_ckpt() or 'shipped'}. AEE px over the window on pixels with events, %Out > 3 px; "
        "FWL = var(IWE t_mid) / var(IWE zero flow). dnn: estimate_flow(method='dnn') with "
        "its defaults, the plane's polished flow kept where multicm's objective prefers it "
        "(planar_kept), then that flow (the plane's, else the network's) refined on "
        "multicm's finest tiles, kept where that objective is lower and the sharpness "
        "no lower (a plane's correction: 1 % sharper) (refined_kept); dnn refine=False: "
        "the plane only; dnn network only: planar=False, refine=False. multicm: defaults (5 "
        "scales); "
        "init=dnn: the network's plain pass at each input scale (the sharpest kept; tile "
        f"means over the events) then the finest {DNN_INIT_SCALES} scales; AEE_vs_multicm / "
        "cpu_vs_multicm: its AEE and median CPU time over plain multicm's on the same "
        "window in the same run; finest_share: the share of multicm's time in its finest "
        f"{DNN_INIT_SCALES} scales. seconds / min_s wall, cpu_s / cpu_min_s "
        "CPU (median / min). Shared 2-core machine (other jobs running): load average "
        f"(1, 5, 15 min) {load0[0]:.1f}, {load0[1]:.1f}, {load0[2]:.1f} at the start, "
        f"{load1[0]:.1f}, {load1[1]:.1f}, {load1[2]:.1f} at the end; wall times are "
        "inflated by it, CPU times less so."))
    return rows


if __name__ == "__main__":
    main(quick="--quick" in sys.argv)
