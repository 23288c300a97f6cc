"""Accuracy of multi-reference CMax dense flow (thesis ch. 4) and its ablations.

1. Simulated 30k-event windows at 346x260 (``evmotion.sim.simulate``): AEE against the
   ground-truth displacement over the window on pixels with events, and FWL, for the
   translation, rotation, zoom and occluding-object scenes, without / with upwind / with
   Burgers time-aware flow.
2. Ablations on the rotation and object scenes: multi vs single reference (Fig. 4.7),
   5 / 3 / 1 scales (Fig. 4.9), gradient magnitude vs variance vs the two average-timestamp
   losses (Table 4.5), lambda (Table 4.6), L-BFGS vs Newton-CG.
   Plus MVSEC-protocol windows on 45 Hz virtual GT frames (``dt = 1`` and ``dt = 4``,
   i.e. 22 and 89 ms, 5-26 px): all events of the GT interval, and 30k of them evenly
   subsampled (the thesis optimizes on 30k events); AEE against the displacement along
   the trajectories (``AEE_px``) and against the GT flow at ``t_mid`` times the window
   (``AEE_tmid_px``, what the warp (4.4) estimates; the two differ by the trajectories'
   curvature, ~1.4 px for the rotation at dt = 4 even for the exact ``t_mid`` flow), and
   ``AEE_streamline_px``: the estimate transported to the interval start along its
   streamlines (``FlowResult.displacement(along_streamlines=True)``) against the
   trajectories.
   And the object scene over a longer window (60k events, ~50 ms, the disc moving
   ~15 px against the background), where the occlusions are large enough for the
   time-aware warp to matter (Table 4.3).
3. Real data: ECD rotation windows (AEE against the IMU flow on the undistorted grid) and
   the eight ECD 30k-event windows (FWL).

FWL here is ``var(IWE(t_mid)) / var(IWE(identity))`` of multicm's own IWEs, so it measures
the time-aware warp too. PNGs (flow, IWE without / with the flow) go to
``results/multicm/``. Run: ``python benchmarks/run.py multicm_accuracy``.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

import harness

RESULTS = Path(__file__).resolve().parent / "results"
DATA = Path(os.environ.get("EVMOTION_SHARED_DATA",
                           Path(__file__).resolve().parents[2] / "shared" / "data"))
N_EVENTS = 30_000


def fwl(res) -> float:
    return float(np.var(res.iwes["tmid"]) / np.var(res.iwes["identity"]))


def event_mask(ev) -> np.ndarray:
    m = np.zeros(ev.sensor_size, bool)
    m[np.round(ev.y).astype(int).clip(0, ev.height - 1),
      np.round(ev.x).astype(int).clip(0, ev.width - 1)] = True
    return m


def aee(res, gt_disp, mask) -> float:
    d = res.displacement().astype(np.float64) - gt_disp
    e = np.sqrt((d ** 2).sum(-1))
    ok = mask & np.isfinite(e)
    return float(e[ok].mean())


def _panel(path, res, title):
    from evmotion.viz import flow_picture, iwe_to_rgb, picture_row, save_png

    mask = res.iwes["identity"] > 0
    vmax = float(np.percentile(res.iwes["identity"][mask], 99)) if mask.any() else None
    save_png(path, picture_row([flow_picture(res.flow, valid=mask).rgb,
                                iwe_to_rgb(res.iwes["identity"], vmax=vmax),
                                iwe_to_rgb(res.iwes["tmid"], vmax=vmax)],
                               ["flow (px/s; grey: no events)", "IWE, zero flow",
                                "IWE, estimated flow"], title=title))


def _sim_window(scene: str):
    from evmotion.sim import simulate

    sim = simulate(scene, duration_s=0.2, sensor_size=(260, 346), seed=0, show_progress=False)
    ev = sim.events
    mid = len(ev) // 2
    win = ev[mid - N_EVENTS // 2: mid + N_EVENTS // 2]
    t0, t1 = int(win.t[0]), int(win.t[-1])
    return win, sim.gt.displacement(t0, t1)


def _row(data, name, res, gt, mask, **extra):
    return {"data": data, "variant": name, "AEE_px": aee(res, gt, mask), "FWL": fwl(res),
            "focus": res.focus, "seconds": res.timings["total_s"],
            "max_gt_disp_px": float(np.nanmax(np.linalg.norm(gt, axis=-1))), **extra}


def mvsec_like(quick: bool) -> list[dict]:
    """dt = 1 / dt = 4 windows on 45 Hz virtual GT frames (MVSEC protocol)."""
    from evmotion.methods.multicm import estimate_flow
    from evmotion.sim import simulate

    rows = []
    for scene in ("translation", "rotation", "zoom"):
        sim = simulate(scene, duration_s=0.3, seed=0, frame_rate=45.0, show_progress=False)
        ev = sim.events
        for dt in (1, 4):
            wins = ev.windows_at(sim.gt.frame_times_us, dt=dt, drop_empty=True)[1:3]
            for w in wins[:1] if quick else wins:
                full = ev.window(w)
                sub = full[np.linspace(0, len(full) - 1, min(N_EVENTS, len(full)))
                           .astype(np.int64)]
                gt = sim.gt.displacement(w.t0, w.t1)
                mask = event_mask(full)
                for name, win in (("all events", full), ("30k events", sub)):
                    res = estimate_flow(win)
                    # the estimate is px/s at t_mid; evaluate over the GT interval
                    d = res.flow.astype(np.float64) * (w.t1 - w.t0) * 1e-6
                    gmid = sim.gt.flow((w.t0 + w.t1) // 2) * (w.t1 - w.t0) * 1e-6
                    e = np.linalg.norm(d - gt, axis=-1)[mask]
                    rows.append({"data": f"sim {scene} dt={dt} (window {w.index})",
                                 "variant": f"none, {name}", "events": len(win),
                                 "AEE_px": float(e.mean()),
                                 "pct_out": float((e > 3.0).mean() * 100),
                                 "AEE_tmid_px": float(np.linalg.norm(d - gmid, axis=-1)[mask]
                                                      .mean()),
                                 "AEE_streamline_px": float(np.linalg.norm(
                                     res.displacement(w.t0, w.t1, along_streamlines=True)
                                     - gt, axis=-1)[mask].mean()),
                                 "FWL": fwl(res), "focus": res.focus,
                                 "seconds": res.timings["total_s"],
                                 "max_gt_disp_px": float(np.linalg.norm(gt, axis=-1).max())})
    return rows


def object_long(quick: bool) -> list[dict]:
    """The occluding-object scene over a 60k-event window: time-aware vs plain warp."""
    from evmotion.methods.multicm import estimate_flow
    from evmotion.sim import simulate

    sim = simulate("object", duration_s=0.3, sensor_size=(260, 346), seed=0,
                   show_progress=False)
    ev = sim.events
    n = 60_000
    mid = len(ev) // 2
    win = ev[mid - n // 2: mid + n // 2]
    t0, t1 = int(win.t[0]), int(win.t[-1])
    gt = sim.gt.displacement(t0, t1)
    mask = event_mask(win)
    fg = (sim.gt.visible_layer(t0) == 1) | (sim.gt.visible_layer(t1) == 1)
    rows = []
    for name, kw in (("none", {}), ("upwind", {"time_aware": "upwind"}),
                     ("burgers", {"time_aware": "burgers"})):
        res = estimate_flow(win, **kw)
        e = np.linalg.norm(res.displacement() - gt, axis=-1)
        rows.append(_row("sim object, 60k events (~50 ms)", name, res, gt, mask,
                         events=len(win), AEE_background_px=float(e[mask & ~fg].mean()),
                         AEE_object_px=float(e[mask & fg].mean())))
        if name in ("none", "burgers"):
            _panel(RESULTS / "multicm" / f"sim_object_long_{name}.png", res,
                   f"sim object, 60k events, {name}")
    return rows


def simulated(quick: bool) -> list[dict]:
    from evmotion.methods.multicm import estimate_flow

    rows = []
    out = RESULTS / "multicm"
    out.mkdir(parents=True, exist_ok=True)
    scenes = ("translation", "rotation", "zoom", "object")
    variants = [("none", {}), ("upwind", {"time_aware": "upwind"}),
                ("burgers", {"time_aware": "burgers"})]
    ablations = [
        ("single reference", {"references": "single"}),
        ("3 scales", {"n_scales": 3}),
        ("1 scale", {"n_scales": 1}),
        ("variance", {"objective": "variance"}),
        ("avg timestamp", {"objective": "avg_timestamp"}),
        ("norm. avg timestamp", {"objective": "avg_timestamp_norm"}),
        ("lambda 0.025", {"lam": 0.025}),
        ("lambda 0.25", {"lam": 0.25}),
        ("lambda 0", {"lam": 0.0}),
    ]
    for scene in scenes:
        win, gt = _sim_window(scene)
        mask = event_mask(win)
        todo = list(variants)
        if scene in ("rotation", "object") or not quick:
            todo += ablations
        if scene == "object":
            # the PDE on 4 px cells (default) vs on every pixel, and more bins
            todo += [("burgers, 1 px cells", {"time_aware": "burgers", "transport_cell": 1}),
                     ("burgers, 10 bins", {"time_aware": "burgers", "n_bins": 10})]
        if scene in ("translation", "rotation") and not quick:
            todo.append(("Newton-CG", {"optimizer": "newton-cg"}))
        for name, kw in todo:
            res = estimate_flow(win, **kw)
            rows.append({"data": f"sim {scene}", "variant": name,
                         "AEE_px": aee(res, gt, mask), "FWL": fwl(res), "focus": res.focus,
                         "seconds": res.timings["total_s"],
                         "max_gt_disp_px": float(np.nanmax(np.linalg.norm(gt, axis=-1)))})
            if name in ("none", "burgers", "single reference", "1 scale"):
                _panel(out / f"sim_{scene}_{name.replace(' ', '_')}.png", res,
                       f"sim {scene}, {name}")
    return rows


def read_ecd_txt(path: Path):
    from evmotion.events import EventArray

    a = np.loadtxt(path, dtype=np.float64)
    t = np.round(a[:, 0] * 1e6).astype(np.int64)
    return EventArray(x=a[:, 1].astype(np.uint16), y=a[:, 2].astype(np.uint16), t=t,
                      p=a[:, 3].astype(np.uint8), sensor_size=(180, 240))


def real(quick: bool) -> list[dict]:
    from evmotion.io.calibration import read_ecd
    from evmotion.methods.multicm import estimate_flow

    rows = []
    if not DATA.is_dir():
        print(f"real data not found at {DATA}: skipped")
        return rows
    out = RESULTS / "multicm"
    out.mkdir(parents=True, exist_ok=True)
    for d in sorted((DATA / "ecd_rotation_windows").iterdir()):
        cam = read_ecd(d / "calib.txt")
        ev = cam.undistort_events(read_ecd_txt(d / "events.txt"))
        gt = np.load(d / "flow.npy")[0].transpose(1, 2, 0).astype(np.float64)
        mask = event_mask(ev)
        for name, kw in (("none", {}), ("burgers", {"time_aware": "burgers"})):
            res = estimate_flow(ev, **kw)
            # flow.npy spans the whole window; our flow at t_mid times the first-to-last
            # event interval is the comparable displacement
            rows.append({"data": f"ECD {d.name}", "variant": name,
                         "AEE_px": aee(res, gt, mask), "FWL": fwl(res), "focus": res.focus,
                         "seconds": res.timings["total_s"],
                         "max_gt_disp_px": float(np.linalg.norm(gt, axis=-1).max())})
            if name == "none":
                _panel(out / f"ecd_{d.name}_gtwindow.png", res, f"ECD {d.name}")
    windows = sorted((DATA / "ecd_30k_windows").iterdir())
    for d in windows[:2] if quick else windows:
        cam = read_ecd(d / "calib.txt")
        ev = cam.undistort_events(read_ecd_txt(d / "events.txt"))
        for name, kw in (("none", {}), ("burgers", {"time_aware": "burgers"})):
            res = estimate_flow(ev, **kw)
            rows.append({"data": f"ECD 30k {d.name}", "variant": name, "AEE_px": "",
                         "FWL": fwl(res), "focus": res.focus,
                         "seconds": res.timings["total_s"]})
            if name == "none":
                _panel(out / f"ecd30k_{d.name}.png", res, f"ECD {d.name} (30k events)")
    return rows


def main(quick: bool = False) -> list[dict]:
    harness.single_core()
    rows = simulated(quick) + mvsec_like(quick) + object_long(quick) + real(quick)
    harness.record("multicm_accuracy", rows,
                   notes="multicm defaults: 5 scales, gradient magnitude, lambda 0.0025, "
                         "L-BFGS <= 20 it/scale, 5 time bins. AEE on pixels with events, "
                         "px over the window (dt rows: over the GT interval, against the "
                         "displacement along the trajectories; AEE_tmid_px against the GT "
                         "flow at t_mid times the interval); FWL = var(IWE t_mid)/var(IWE "
                         "zero flow).")
    return rows


if __name__ == "__main__":
    import sys

    main(quick="--quick" in sys.argv)
