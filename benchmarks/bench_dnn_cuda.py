"""The network on a CUDA device (``--device cuda``): does it give the CPU's answers, how fast.

Run where a GPU exists (the project never needs one): ``python benchmarks/run.py dnn_cuda``.
Without CUDA it records nothing.

1. Inference: ``estimate_flow_dnn`` (input scales 1, 2, 4, time reversal; no IWEs) and
   ``predict_displacement`` on a simulated 40k-event window at 346x260 and on random
   events at 640x480, CPU (one torch thread) against CUDA: median wall seconds of
   interleaved runs and the largest difference of the flows in px.
2. Training (``evmotion.methods.dnn.train.train``, the CLI's function): 2 epochs of 3
   steps, batch 8, the default crop, simulated windows, on the CPU and on CUDA: seconds
   per step and the share of the multicm loss (numba on the CPU either way); on CUDA the
   run repeated (same weights bit for bit?) and interrupted after epoch 1 then resumed
   (same weights as uninterrupted?), as the CPU's tests check.
3. ``evmotion flow WINDOW --method dnn --device cuda --out x.flo``: exit status and its
   flow against the CPU command's.
Any part that fails records its one-line error instead of numbers.
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

N_EVENTS = 40_000
# the device measured against the CPU (EVMOTION_BENCH_DEVICE=cpu runs every part here)
DEVICE = os.environ.get("EVMOTION_BENCH_DEVICE", "cuda")


def _median_times(fns: dict, repeat: int) -> dict:
    times = {k: [] for k in fns}
    for _ in range(repeat):
        for k, fn in fns.items():
            t0 = time.perf_counter()
            fn()
            times[k].append(time.perf_counter() - t0)
    return {k: float(np.median(v)) for k, v in times.items()}


def _guard(part: str, fn) -> list[dict]:
    try:
        return fn()
    except Exception as exc:  # a device check reports what broke, then goes on
        return [{"part": part, "error": f"{type(exc).__name__}: "
                                        f"{str(exc).splitlines()[0][:300] if str(exc) else ''}"}]


def inference(quick: bool) -> list[dict]:
    import torch

    from evmotion.methods.dnn.data import sim_window
    from evmotion.methods.dnn.infer import estimate_flow_dnn, predict_displacement

    torch.set_num_threads(1)
    rng = np.random.default_rng(0)
    from evmotion.events import EventArray

    wins = {"346x260 simulated": sim_window(900_000_001, sensor_size=(260, 346),
                                             window_events=N_EVENTS).events,
            "640x480 random": EventArray(x=rng.integers(0, 640, N_EVENTS),
                                         y=rng.integers(0, 480, N_EVENTS),
                                         t=np.sort(rng.integers(0, 30_000, N_EVENTS)),
                                         p=rng.integers(0, 2, N_EVENTS),
                                         sensor_size=(480, 640))}
    rows = []
    for name, ev in wins.items():
        for fn_name, fn in (("estimate_flow_dnn",
                             lambda e, d: estimate_flow_dnn(e, device=d,
                                                            with_iwes=False).displacement()),
                            ("predict_displacement",
                             lambda e, d: predict_displacement(e, device=d))):
            devs = {"cpu": "cpu", "device": DEVICE}
            out = {k: fn(ev, d) for k, d in devs.items()}
            t = _median_times({k: (lambda d=d, f=fn, e=ev: f(e, d)) for k, d in devs.items()},
                              3 if quick else 15)
            rows.append({"part": "inference", "data": name, "method": fn_name,
                         "cpu_s": t["cpu"], "device_s": t["device"],
                         "speedup": t["cpu"] / t["device"],
                         "max_diff_px": float(np.nanmax(np.abs(out["cpu"] - out["device"]))),
                         "median_abs_flow_px": float(np.median(np.abs(out["cpu"])))})
    return rows


def _weights(path: Path):
    import torch

    return torch.load(path, map_location="cpu", weights_only=True)["model"]


def _same(a, b) -> bool:
    import torch

    return all(torch.equal(a[k], b[k]) for k in a)


def training(quick: bool) -> list[dict]:
    import torch

    from evmotion.methods.dnn.train import TrainConfig, train

    steps = 2 if quick else 3
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)

        def cfg(device, epochs=2):
            return TrainConfig(sim_windows=8 * steps, batch_size=8, epochs=epochs,
                               val_sim=1, device=device, max_steps_per_epoch=steps)

        for name, device in (("cpu", "cpu"), ("device", DEVICE)):
            t0 = time.perf_counter()
            summary = train(cfg(device), tmp / name)
            wall = time.perf_counter() - t0
            rows.append({"part": "training", "data": f"{2 * steps} steps, batch 8, crop "
                         "176x240, simulated", "method": device,
                         "seconds_per_step_last_epoch": summary["seconds"] / steps,
                         "loss_share_pct": 100 * summary["loss_forward_seconds"]
                         / summary["seconds"], "wall_s": wall,
                         "train_loss": summary["train_loss"]})
        train(cfg(DEVICE), tmp / "again")
        train(cfg(DEVICE, epochs=1), tmp / "resumed")
        train(cfg(DEVICE), tmp / "resumed", resume=True)
        ref = _weights(tmp / "device" / "model.pt")
        cpu = _weights(tmp / "cpu" / "model.pt")
        rows.append({"part": "training", "data": "determinism", "method": DEVICE,
                     "repeat_identical": _same(ref, _weights(tmp / "again" / "model.pt")),
                     "resume_identical": _same(ref, _weights(tmp / "resumed" / "model.pt")),
                     "max_weight_diff_vs_cpu": max(float((ref[k].float() - cpu[k].float())
                                                         .abs().max()) for k in ref
                                                   if ref[k].is_floating_point()),
                     "cublas_workspace": os.environ.get("CUBLAS_WORKSPACE_CONFIG", ""),
                     "torch": torch.__version__})
    return rows


def cli() -> list[dict]:
    from evmotion.io import write_events
    from evmotion.io.flowfiles import read_flo
    from evmotion.methods.dnn.data import sim_window

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        write_events(tmp / "w.h5", sim_window(900_000_002, sensor_size=(260, 346),
                                              window_events=30_000).events)
        flows, walls = {}, {}
        for name, device in (("cpu", "cpu"), ("device", DEVICE)):
            t0 = time.perf_counter()
            proc = subprocess.run([sys.executable, "-m", "evmotion", "flow", str(tmp / "w.h5"),
                                   "--method", "dnn", "--window-events", "30000", "--device",
                                   device, "--out", str(tmp / f"{name}.flo")],
                                  capture_output=True, text=True)
            walls[name] = time.perf_counter() - t0
            if proc.returncode:
                return [{"part": "cli", "method": device, "rc": proc.returncode,
                         "error": proc.stderr.strip()[-300:]}]
            flows[name] = read_flo(tmp / f"{name}.flo")
        ok = np.isfinite(flows["cpu"])
        rows.append({"part": "cli", "data": "346x260 simulated, 30k ev", "method":
                     f"flow --method dnn --device {DEVICE}", "rc": 0,
                     "cpu_wall_s": walls["cpu"], "device_wall_s": walls["device"],
                     "same_unknown_pixels": bool((ok == np.isfinite(flows["device"])).all()),
                     "max_diff_px": float(np.abs(flows["cpu"][ok] - flows["device"][ok]).max())})
    return rows


def main(quick: bool = False) -> list[dict]:
    import torch

    if DEVICE.startswith("cuda") and not torch.cuda.is_available():
        print("no CUDA device: nothing to measure (results left as they are)")
        return []
    rows = (_guard("inference", lambda: inference(quick))
            + _guard("training", lambda: training(quick)) + _guard("cli", cli))
    harness.record("dnn_cuda" if DEVICE.startswith("cuda") else f"dnn_{DEVICE}", rows, notes=(
        f"{torch.cuda.get_device_name(0) if torch.cuda.is_available() else DEVICE}, torch {torch.__version__}, CUDA "
        f"{torch.version.cuda}; CPU side one torch thread on a {os.cpu_count()}-CPU host. "
        "Inference: median wall s of interleaved runs (the CUDA times include the copies "
        "to and from the device); max_diff_px: the largest |CPU flow - CUDA flow|. "
        "Training: evmotion's train() with one validation window, seconds per step of the last epoch "
        "(validation not included), "
        "the loss (multicm's numba objective, on the CPU for both devices) as a share; "
        "repeat/resume_identical: bit-identical weights of two CUDA runs, and of a run "
        "interrupted after epoch 1 and resumed."))
    return rows


if __name__ == "__main__":
    main(quick="--quick" in sys.argv)
