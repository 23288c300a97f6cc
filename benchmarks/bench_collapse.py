"""Accuracy tables of ch. 3 (like thesis Tables 3.1/3.2): event collapse reproduced and cured.

Simulated forward motion (``evmotion.sim.simulate("zoom")``, ground-truth flow) is fitted
with the 1-DOF zoom warp (3.7) and the 4-DOF in-plane warp (A.22; the thesis' 4-DOF warp,
which collapses at ``h_z = 1/T`` like the zoom) by TPE sampling (300 / 600 samples,
as in the thesis, so the optimizer can reach the collapsed optimum), with the variance and
gradient-magnitude objectives, without a regularizer, with each of divergence, deformation,
their sum (the thesis' "Div. + Def.") and RCAD, and with whitening. Rows give AEE (px over the window), 3/10/20PE (%), FWL and the
AEE improvement over the unregularized run; an identity-warp row is the reference. FWL
is computed from the estimate's flow field (as in the thesis); ``G/G0`` is the optimized
focus with the warp itself (for the variance objective the same ratio), which shows the
collapse also where the flow-field FWL of a large 4-DOF warp does not.

The weights are the thesis' (Sec. 3.6.1, ``DEFAULT_WEIGHTS``), no hand tuning: each
regularizer is run with the MVSEC and with the DSEC set, and with the weight derived from the
window (``weights = window``, :mod:`evmotion.methods.weights`; the default when no data set is
named). Column ``collapsed`` is the estimate's own collapse flag
(:mod:`evmotion.methods.diagnostics`). ``G`` is normalized by its value
at the identity warp (see :mod:`evmotion.methods.egomotion`). The window (0.05 s) keeps
the true zoom within the thesis' margins (per-window divergence -2 h T = -0.15 > -0.2);
a second table shows what the margins do to a window in which it is not (0.1 s).

A third table checks that the well-posed rotation warp is not harmed (simulated camera
rotation, BFGS): angular-velocity RMS error with each regularizer vs without. A fourth lists
the real ECD rotation windows: omega error vs the IMU and FWL of estimate vs IMU.

    python benchmarks/bench_collapse.py [--quick]
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import harness
from evmotion.core.warps import make_warp
from evmotion.eval.metrics import event_mask, flow_metrics, fwl
from evmotion.methods.egomotion import estimate_egomotion
from evmotion.sim import simulate

#: (regularizer, thesis weight set) per row group; None / whitening take no weight
RUNS = ((None, None), ("divergence", "mvsec"), ("divergence", "dsec"),
        ("divergence", "window"), ("deformation", "mvsec"), ("deformation", "dsec"),
        ("deformation", "window"), ("divergence+deformation", "mvsec"),
        ("divergence+deformation", "dsec"), ("divergence+deformation", "window"),
        ("rcad", "mvsec"), ("rcad", "dsec"), ("rcad", "window"), ("whitening", None))
SHAPE = (180, 240)


def _lambda(weight) -> str:
    """lambda as printed: one weight, or div/def for the summed penalties."""
    return "/".join(f"{v:g}" for v in weight.values()) if isinstance(weight, dict) else f"{weight:g}"


def _dataset(weights):
    """``dataset=`` of estimate_egomotion for a row's weight set (None: the window's)."""
    return None if weights in (None, "window") else weights


def _flow(warp, theta):
    ys, xs = np.mgrid[0:warp.sensor_size[0], 0:warp.sensor_size[1]]
    u, v = warp.optical_flow(xs.ravel().astype(float), ys.ravel().astype(float), theta)
    return np.stack([u, v], axis=-1).reshape(*warp.sensor_size, 2)


def collapse_rows(quick: bool, duration_s: float = 0.05, warps=("zoom", "inplane"),
                  objectives=("variance", "gradient_magnitude"), runs=RUNS) -> list[dict]:
    # a fine random texture: its sharp IWE is weak against the collapsed one, as in real data
    sim = simulate("zoom", duration_s=duration_s, sensor_size=SHAPE, seed=0, texture="noise",
                   show_progress=False)
    ev = sim.events
    t_ref = int(ev.t[0])
    span_s = (int(ev.t[-1]) - t_ref) * 1e-6
    gt = sim.gt.flow(t_ref)
    mask = event_mask(ev, SHAPE)
    gt_disp = gt * span_s
    rows = []
    ident = np.zeros(SHAPE + (2,))
    m = flow_metrics(ident, gt_disp, mask).as_dict()
    rows.append({"warp": "-", "objective": "-", "regularizer": "identity warp",
                 "AEE": m["AEE"], "3PE": m["3PE"], "10PE": m["10PE"], "20PE": m["20PE"],
                 "FWL": fwl(ev, ident, t_ref), "params": "0"})
    hz = sim.gt.params(t_ref)["hz"]
    rows.append({"warp": "-", "objective": "-", "regularizer": "ground truth",
                 "AEE": 0.0, "3PE": 0.0, "10PE": 0.0, "20PE": 0.0,
                 "FWL": fwl(ev, gt, t_ref), "params": f"hz={hz:.3g} (hz T={hz * span_s:.3f})"})
    if quick:
        warps, objectives = warps[:1], objectives[:1]
    for wname in warps:
        for obj in objectives:
            base_aee = None
            for reg, dataset in runs:
                t0 = time.perf_counter()
                w = make_warp(wname, SHAPE)
                # rates up to the collapse 1/T, where events flip sides (the thesis' |h_z| < 1
                # in normalized time): TPE can reach the collapse, RCAD's barrier applies.
                # The in-plane rotation rate of forward driving is small: +-1 rad/s (with
                # +-8 rad/s, 600 samples miss the narrow 4-DOF collapse basin)
                half = np.array([0.999 / span_s if u in ("1/s", "1") else
                                 (1.0 if u in ("rad/s", "rad") else 1500.0)
                                 for u in w.param_units])
                res = estimate_egomotion(ev, wname, obj, reg, optimizer="tpe", seed=0,
                                         t_ref=t_ref, maps=False, bounds=(-half, half),
                                         dataset=_dataset(dataset),
                                         n_samples=100 if quick else None)
                flow = _flow(w, res.params)
                m = flow_metrics(flow * span_s, gt_disp, mask).as_dict()
                base_aee = m["AEE"] if reg is None else base_aee
                rows.append({"warp": wname, "objective": obj, "regularizer": reg or "none",
                             "weights": dataset or "-", "lambda": _lambda(res.weight),
                             "AEE": m["AEE"], "3PE": m["3PE"], "10PE": m["10PE"],
                             "20PE": m["20PE"], "FWL": fwl(ev, flow, t_ref),
                             "G/G0": res.focus, "penalty": res.penalty,
                             "collapsed": res.collapsed,
                             "AEE_improvement_%": 100 * (1 - m["AEE"] / base_aee),
                             "params": " ".join(f"{v:.3g}" for v in res.params),
                             "seconds": time.perf_counter() - t0})
                print(rows[-1], flush=True)
    return rows


def rotation_rows(quick: bool) -> list[dict]:
    sim = simulate("rotation", duration_s=0.05, sensor_size=SHAPE, seed=1, show_progress=False)
    ev = sim.events
    omega = sim.gt.angular_velocity()
    rows = []
    base = None
    for reg in (None, "divergence", "deformation", "divergence+deformation", "rcad"):
        if quick and reg in ("divergence", "deformation", "divergence+deformation"):
            continue
        res = estimate_egomotion(ev, "rotation", regularizer=reg, K=sim.gt.K, t_ref="mid",
                                 dataset="ecd" if reg else None, maps=False)
        rms = float(np.sqrt(np.mean((res.params - omega) ** 2)))
        base = rms if reg is None else base
        rows.append({"warp": "rotation (sim)", "regularizer": reg or "none",
                     "rms_rad_s": rms, "ratio_vs_none": rms / base,
                     "params": " ".join(f"{v:.3f}" for v in res.params),
                     "gt": " ".join(f"{v:.3f}" for v in omega)})
        print(rows[-1], flush=True)
    return rows


def ecd_rows() -> list[dict]:
    from evmotion.events import EventArray
    from evmotion.io.calibration import read_ecd

    base = Path(os.environ.get("EVMOTION_SHARED_DATA", Path(__file__).resolve().parents[2]
                               / "shared" / "data")) / "ecd_rotation_windows"
    rows = []
    for scene in ("boxes_rotation", "poster_rotation"):
        folder = base / scene
        if not folder.is_dir():
            continue
        d = np.loadtxt(folder / "events.txt")
        cam = read_ecd(folder / "calib.txt")
        ev = cam.undistort_events(EventArray(
            d[:, 1].astype(np.int64), d[:, 2].astype(np.int64),
            np.round(d[:, 0] * 1e6).astype(np.int64), d[:, 3].astype(np.int64), (180, 240)))
        imu = np.loadtxt(folder / "motion.txt")
        w = make_warp("rotation", (180, 240), K=cam.K)
        for reg, weights in ((None, None), ("divergence", "ecd"), ("deformation", "ecd"),
                             ("rcad", "ecd"), ("divergence", "window"),
                             ("deformation", "window"), ("rcad", "window")):
            res = estimate_egomotion(ev, "rotation", regularizer=reg, K=cam.K, t_ref="mid",
                                     dataset=_dataset(weights) if reg else None, maps=False)
            err = res.params - imu
            rows.append({"scene": scene, "regularizer": reg or "none",
                         "weights": weights or "-", "lambda": _lambda(res.weight),
                         "collapsed": res.collapsed,
                         "explained_share": res.diagnostics["fit"].get("explained_share"),
                         "omega": " ".join(f"{v:.3f}" for v in res.params),
                         "omega_imu": " ".join(f"{v:.3f}" for v in imu),
                         "abs_err_xyz": " ".join(f"{abs(v):.3f}" for v in err),
                         "rms_rad_s": float(np.sqrt(np.mean(err**2))),
                         "FWL_est": fwl(ev, _flow(w, res.params), res.t_ref_us),
                         "FWL_imu": fwl(ev, _flow(w, imu), res.t_ref_us)})
            print(rows[-1], flush=True)
    return rows


def main(quick: bool = False) -> list[dict]:
    rows = collapse_rows(quick)
    harness.record("collapse", rows, notes="simulated zoom scene (0.05 s, 240x180), TPE "
                   "300/600 samples, box +-0.999/T for 1/s, +-1 rad/s, +-1500 px/s, "
                   "t_ref = start; AEE etc. over the window on pixels with events; thesis "
                   "weights (Sec. 3.6.1) of the data set in column 'weights'; G normalized "
                   "by G(identity)")
    margin = collapse_rows(quick, 0.1, ("zoom",), runs=((None, None), ("divergence", "dsec"),
                                                        ("deformation", "dsec"),
                                                        ("rcad", "dsec"), ("rcad", "window")))
    harness.record("collapse_margin", margin, notes="as 'collapse' but a 0.1 s window: the "
                   "true zoom (hz T = 0.147, per-window divergence -0.29, IWA at the window "
                   "end 0.73) lies beyond the thesis margins (-0.2, 0.8), so divergence and "
                   "deformation hold the estimate at the margin: the bias these margins imply")
    rot = rotation_rows(quick)
    harness.record("collapse_rotation", rot, notes="simulated rotation (0.05 s), BFGS, "
                   "thesis ECD weights")
    ecd = ecd_rows()
    harness.record("collapse_ecd", ecd, notes="real ECD windows, undistorted, BFGS, t_ref=mid, "
                   "thesis ECD weights and the window's; rms over the 3 axes; "
                   "explained_share: the fit check of evmotion.methods.diagnostics")
    return rows + margin + rot + ecd


if __name__ == "__main__":
    main(quick="--quick" in sys.argv)
