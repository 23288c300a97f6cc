"""The plane's-motion polish of ``estimate_flow_dnn`` (methods/dnn/planar.py) beyond
bench_dnn's windows: does its rule (keep the polished 8-parameter flow where multicm's
objective (4.9) is lower than the network's flow's) hold on windows it was not built on?

1. Simulated 40k-event windows at 346x260 of seeds bench_dnn does not use (900001011,
   900001022, 900001033; translation, rotation, zoom, the independently moving object):
   AEE (px over the window, pixels with events) of the network's flow (``planar=False``),
   of the default (the polish where kept), and of multicm; the two losses; which was kept.
2. Real windows (30k events): the eight ECD windows (never trained on), the ECD dynamic
   excerpt (the training's validation), and three windows (at 25, 50, 75 % of the events)
   of each recording the network was trained on from other sensors (DAVIS346 AEDAT4,
   DAVIS240 AEDAT2, Prophesee EVT2) and ECD shapes' first 120k events: FWL (var(IWE
   t_mid) / var(IWE zero flow)) of both and of multicm, the ratio to multicm's, which was
   kept, and the default's seconds (with IWEs).

Run: ``python benchmarks/run.py dnn_planar``.
"""

from __future__ import annotations

import time
import warnings

import numpy as np

import bench_dnn
import harness

DATA = bench_dnn.DATA
SEEDS = (900_001_011, 900_001_022, 900_001_033)
SCENES = ("translation", "rotation", "zoom", "object")
ECD = bench_dnn.ECD_WINDOWS
OTHER = (("DAVIS346 AEDAT4 (trained on)", "formats/davis346.aedat4"),
         ("DAVIS240 AEDAT2 (trained on)", "formats/davis240_translboxes_aedat2.aedat"),
         ("Prophesee EVT2 (trained on)", "formats/evt2.raw"),
         ("ECD shapes first 120k (trained on)", "ecd_shapes_rotation_first120k/shapes_rotation.mat"))


def simulated(quick: bool) -> list[dict]:
    from evmotion.methods.dnn import estimate_flow_dnn
    from evmotion.methods.dnn.planar import window_loss
    from evmotion.methods.multicm import estimate_flow

    rows = []
    for seed in SEEDS[:1] if quick else SEEDS:
        for scene in SCENES:
            win, gt = bench_dnn._sim(scene, 0, seed=seed)
            mask = np.zeros(win.sensor_size, bool)
            mask[win.y.astype(int), win.x.astype(int)] = True

            def aee(res, gt=gt, mask=mask):
                return bench_dnn._errors(res.displacement(), gt, mask)[0]

            net = estimate_flow_dnn(win, planar=False, refine=False, with_iwes=False)
            t0 = time.perf_counter()
            res = estimate_flow_dnn(win, with_iwes=False)
            seconds = time.perf_counter() - t0
            mc = estimate_flow(win)
            rows.append({"section": "simulated 40k 346x260", "data": f"{scene} seed {seed}",
                         "AEE_network": aee(net), "AEE_default": aee(res),
                         "AEE_multicm": aee(mc), "default_vs_multicm": aee(res) / aee(mc),
                         "network_vs_multicm": aee(net) / aee(mc),
                         "loss_network": window_loss(win, net.displacement()),
                         "loss_default": window_loss(win, res.displacement()),
                         "planar_kept": bool(res.meta["planar"]),
                         "refined_kept": bool(res.meta["refined"]), "seconds": seconds})
    return rows


def _real_windows(quick: bool):
    from evmotion.io import read_events

    for name in ECD[:2] if quick else ECD:
        path = DATA / "ecd_30k_windows" / name
        if path.is_dir():
            yield f"ECD {name} (held out)", read_events(path)
    path = DATA / "ecd_dynamic_undistorted_excerpt" / "event.mat"
    if path.is_file():
        yield "ECD dynamic excerpt (validation)", read_events(path)
    for label, rel in OTHER[:1] if quick else OTHER:
        path = DATA / rel
        if not path.exists():
            continue
        ev = read_events(path)
        for frac in (0.25, 0.5, 0.75):
            i = max(int(len(ev) * frac) - 15_000, 0)
            yield f"{label} @{int(frac * 100)} %", ev[i:i + 30_000]


def real(quick: bool) -> list[dict]:
    from evmotion.methods.dnn import estimate_flow_dnn
    from evmotion.methods.multicm import estimate_flow

    if not DATA.is_dir():
        print(f"skipping the real windows: {DATA} not found")
        return []
    rows = []
    for label, ev in _real_windows(quick):
        net = estimate_flow_dnn(ev, planar=False, refine=False)
        t0 = time.perf_counter()
        res = estimate_flow_dnn(ev)
        seconds = time.perf_counter() - t0
        mc = estimate_flow(ev)
        fm = bench_dnn._fwl(mc)
        rows.append({"section": "real 30k", "data": label,
                     "size": f"{ev.sensor_size[1]}x{ev.sensor_size[0]}",
                     "FWL_network": bench_dnn._fwl(net), "FWL_default": bench_dnn._fwl(res), "FWL_multicm": fm,
                     "network_vs_multicm": bench_dnn._fwl(net) / fm,
                     "default_vs_multicm": bench_dnn._fwl(res) / fm,
                     "planar_kept": bool(res.meta["planar"]),
                     "refined_kept": bool(res.meta["refined"]), "seconds": seconds})
    return rows


def main(quick: bool = False) -> list[dict]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the verdicts are in the rows, not the log
        rows = simulated(quick) + real(quick)
    harness.record("dnn_planar", rows, notes=(
        "estimate_flow_dnn's default (the plane's polished flow kept where multicm's "
        "objective (4.9), window_loss, is lower than the network's flow's, planar_kept; "
        "then that flow (the plane's, else the network's) refined on multicm's finest "
        "tiles, kept where that loss is lower and the sharpness no lower (a plane's "
        "correction: 1 % sharper), refined_kept) against the "
        "network's flow only (planar=False, refine=False) and multicm (defaults), on "
        "windows the rules were not built on (bench_dnn's four simulated windows were). AEE px over the window on "
        "pixels with events; FWL = var(IWE t_mid) / var(IWE zero flow), the B-spline IWEs "
        "of multicm. seconds: the default's wall time, one torch thread (simulated: no "
        "IWEs; real: with IWEs). Shared 2-core machine."))
    return rows


if __name__ == "__main__":
    import sys

    main(quick="--quick" in sys.argv)
