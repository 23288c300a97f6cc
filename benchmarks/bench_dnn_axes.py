"""Does EV-FlowNet learn both flow components? Short training runs with and without batch
norm, supervised and unsupervised (issue #13).

The network trained without normalization predicted u only (``dnn_diagnosis.md``: gain of
v -0.10 to 0.07). This suite separates the loss from the network: the same 32 simulated
windows (176x240, seeds 1000-1031, ``sim_window``; 8 held-out ones, seeds 5000-5007), the
same network (width 0.125, torch seed 0, Adam lr 1e-3, batch 8 cycling through the
windows), trained

* ``supervised``: L1 between each decoder scale's flow and the ground-truth displacement,
  on pixels with events (no unsupervised loss at all),
* ``supervised_v``: the same on v alone (can the network learn v at all?),
* ``unsupervised``: the shipped loss (multicm's objective at the 4 decoder scales),

each with ``norm = none`` (the network before 2026-11-28) and ``norm = batch``, and
unsupervised with the symmetric network (``symmetric``: v is the u of the input mirrored
about the diagonal; the shipped network since 2026-11-28), with and without batch norm.
Scores
(eval mode): least-squares gain of each component, ``v_c ~ a_c g_c`` (1 = right
magnitude, 0 = not predicted) and AEE / mean |GT| (1 = zero flow) on 8 training and the
8 held-out windows. No timings. Run: ``python benchmarks/run.py dnn_axes``.
"""

from __future__ import annotations

import numpy as np

import harness

CROP = (176, 240)
TRAIN_SEEDS = range(1000, 1032)
HELD_SEEDS = range(5000, 5008)
BATCH = 8


def _windows(seeds):
    from evmotion.methods.dnn.data import sim_window

    n = round(40_000 * CROP[0] * CROP[1] / (260 * 346))
    return [sim_window(s, sensor_size=CROP, window_events=n) for s in seeds]


def _targets(wins):
    import torch

    mask = np.zeros((len(wins), 1, *CROP), np.float32)
    gt = np.zeros((len(wins), 2, *CROP), np.float32)
    for i, w in enumerate(wins):
        mask[i, 0, w.events.y.astype(int), w.events.x.astype(int)] = 1
        gt[i] = w.gt.transpose(2, 0, 1)
    return torch.from_numpy(mask), torch.from_numpy(gt)


def _score(net, wins) -> dict:
    import torch

    from evmotion.methods.dnn.train import batch_input

    net.eval()
    with torch.no_grad():
        flow = net(batch_input(wins, CROP))[-1].numpy()
    net.train()
    mask, gt = (a.numpy() for a in _targets(wins))
    m = mask[:, 0] > 0
    g = [gt[:, c][m] for c in (0, 1)]
    f = [flow[:, c][m] for c in (0, 1)]
    aee = np.hypot(f[0] - g[0], f[1] - g[1]).mean() / np.hypot(g[0], g[1]).mean()
    return {"gain_u": float((f[0] * g[0]).sum() / (g[0] ** 2).sum()),
            "gain_v": float((f[1] * g[1]).sum() / (g[1] ** 2).sum()), "AEE_over_zero": float(aee)}


def _run(mode: str, norm: str, symmetric: bool, steps: int, train, held,
         checkpoints) -> list[dict]:
    import torch

    from evmotion.methods.dnn.loss import WindowLoss, multiscale_loss, window_problem
    from evmotion.methods.dnn.network import EVFlowNet, upsample_flows
    from evmotion.methods.dnn.train import batch_input

    torch.manual_seed(0)
    net = EVFlowNet(width=0.125, norm=norm, symmetric=symmetric)
    opt = torch.optim.Adam(net.parameters(), lr=1e-3)
    probs = [WindowLoss(window_problem(w.events), w.events.sensor_size) for w in train]
    rows = []
    for step in range(1, steps + 1):
        idx = [((step - 1) * BATCH + i) % len(train) for i in range(BATCH)]
        batch = [train[i] for i in idx]
        opt.zero_grad()
        flows = upsample_flows(net(batch_input(batch, CROP)), CROP)
        if mode == "unsupervised":
            loss = multiscale_loss(flows, [probs[i] for i in idx])
        else:
            mask, gt = _targets(batch)
            comp = slice(1, 2) if mode == "supervised_v" else slice(0, 2)
            loss = sum(((f[:, comp] - gt[:, comp]).abs().sum(1, keepdim=True) * mask).sum()
                       / mask.sum() for f in flows)
        loss.backward()
        opt.step()
        if step in checkpoints:
            row = {"training": mode, "norm": norm, "symmetric": symmetric, "step": step}
            row.update({f"train_{k}": v for k, v in _score(net, train[:8]).items()})
            row.update({f"held_{k}": v for k, v in _score(net, held).items()})
            rows.append(row)
            print(row, flush=True)
    return rows


def main(quick: bool = False) -> list[dict]:
    import torch

    harness.pin_idlest_core()
    torch.set_num_threads(1)
    steps = 40 if quick else 200
    train, held = _windows(TRAIN_SEEDS), _windows(HELD_SEEDS)
    rows = []
    runs = [(mode, norm, False) for mode in ("supervised", "supervised_v", "unsupervised")
            for norm in ("none", "batch")]
    runs += [("unsupervised", "none", True), ("unsupervised", "batch", True)]
    for mode, norm, symmetric in runs:
        rows += _run(mode, norm, symmetric, steps, train, held, {steps // 2, steps})
    harness.record("dnn_axes", rows, notes=(
        "Short training runs (module docstring): gains of u and v (1 = right, 0 = not "
        "predicted) and AEE / zero-flow AEE, eval mode, on 8 training and 8 held-out "
        "simulated windows at 176x240; width 0.125, Adam 1e-3, batch 8, torch seed 0, 1 "
        "thread. Without batch norm the two-channel network learns u (the larger component "
        "in these windows) and not v even when supervised with the ground truth on both, "
        "though it learns v when supervised on v alone: the network, not the loss, is at "
        "fault. Batch norm lets it fit v on the training windows, but on held-out ones v "
        "stays weak; the symmetric network (one set of weights for both axes) learns both "
        "on held-out windows, with or without batch norm (the shipped network has both). "
        "No timings (shared machine: the training of the shipped checkpoint ran on the "
        "other core)."))
    return rows
