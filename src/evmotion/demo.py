"""``python -m evmotion.demo --out DIR``: the tour behind ``make demo``.

Simulates recordings with ground truth (no download), runs every method on them and writes
pictures plus an HTML report that gathers them:

1. camera rotation: events, ego-motion by contrast maximization (rotation warp), IWE before
   and after, estimated vs true angular velocity;
2. forward motion (zoom): event collapse without a regularizer, cured by RCAD;
3. dense optical flow (multi-reference CMax) of a translating scene with an independently
   moving object, against ground truth, with and without time-aware transport;
4. event-by-event triplet-matching flow of the same scene;
5. background-oriented schlieren: a simulated hot-air plume seen through events and frames,
   its flow and Poisson field q against the simulator's exact ones.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from evmotion.eval.metrics import event_mask, flow_metrics, fwl, rms_error
from evmotion.events import Window
from evmotion.io import write_events
from evmotion.jitcache import compile_seconds
from evmotion.methods.egomotion import estimate_egomotion
from evmotion.methods.multicm import estimate_flow
from evmotion.methods.triplet import TripletMatcher, estimate_flow_triplet
from evmotion.sim import sim_calibration, simulate, write_ground_truth
from evmotion.viz import (
    HtmlReport,
    event_histogram,
    flow_picture,
    full_scale,
    iwe_to_rgb,
    picture_row,
    save_flow_png,
    save_flow_summary,
    save_panel,
    save_png,
    sequence_max_speed,
)


def _log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def _rotation(out: Path, rep: HtmlReport, seed: int) -> dict:
    _log("[1/5] camera rotation: simulate, estimate angular velocity")
    sim = simulate("rotation", duration_s=0.1, seed=seed, show_progress=False)
    write_events(out / "rotation.h5", sim.events,
                 calibration=sim_calibration(sim.gt.K, sim.events.sensor_size))
    write_ground_truth(out / "rotation_gt.h5", sim.gt)
    win = sim.events[:30000]
    res = estimate_egomotion(win, warp="rotation", K=sim.gt.K)
    # (the truth at the time the estimate refers to: the start, with a regularizer)
    t_ref = res.t_ref_us
    true_omega = np.asarray(sim.gt.params(t_ref)["omega"], dtype=float)
    err = rms_error(res.params, true_omega)
    # one scale for both, stated (the pictures had no legend, probe BX)
    vmax = full_scale(res.iwe_after)
    save_panel(out / "rotation_iwe.png",
               [iwe_to_rgb(res.iwe_before, vmax=vmax), iwe_to_rgb(res.iwe_after, vmax=vmax)],
               [f"identity warp (white 0, black >= {vmax:.3g} events/px)",
                "rotation warp (same scale): omega = (" + ", ".join(
                   f"{v:.2f}" for v in res.params) + ") rad/s, true (" + ", ".join(
                   f"{v:.2f}" for v in true_omega) + ")"])
    gt_flow = sim.gt.flow(t_ref)
    save_flow_png(out / "rotation_gt_flow.png", gt_flow, unit="px/s",
                  title="ground-truth flow (px/s)")
    rep.add_heading("1. Camera rotation (contrast maximization, 3-DOF)")
    rep.add_table([{"": "true", "wx": true_omega[0], "wy": true_omega[1], "wz": true_omega[2]},
                   {"": "estimated", "wx": res.params[0], "wy": res.params[1],
                    "wz": res.params[2]}],
                  caption=f"Angular velocity (rad/s) of a 30k-event window; RMS error "
                          f"{err.overall:.4f} rad/s, {1e3 * res.timings['estimate']:.0f} ms "
                          f"(+ {1e3 * res.timings['compile']:.0f} ms compiling kernels)")
    rep.add_figure(out / "rotation_iwe.png", "IWE before and after motion compensation")
    rep.add_figure(out / "rotation_gt_flow.png",
                   "Ground-truth flow at the warp's reference time (the window's start)")
    return {"omega_true": true_omega.tolist(), "omega_est": res.params.tolist(),
            "omega_rms_error": err.overall, "ms": 1e3 * res.timings["estimate"],
            "compile_ms": 1e3 * res.timings["compile"]}


def _zoom(out: Path, rep: HtmlReport, seed: int) -> dict:
    _log("[2/5] forward motion: event collapse and its cure (the collapse warning below is "
         "this step's point: no regularizer)")
    # a fine 1/f texture, as in benchmarks/bench_collapse.py: its sharp IWE is weak against
    # the collapsed one, as in real driving data
    sim = simulate("zoom", duration_s=0.05, sensor_size=(180, 240), seed=seed, texture="noise",
                   show_progress=False)
    win = sim.events
    t_ref = win.t_start
    span_s = win.duration_us * 1e-6
    disp_gt = sim.gt.flow(t_ref) * span_s
    mask = event_mask(win)
    # rates up to the collapse 1/T, where events flip sides (|h_z| < 1 in normalized time)
    bounds = (np.array([-0.999 / span_s]), np.array([0.999 / span_s]))
    rows, images, titles = [], [], []
    for reg in (None, "divergence", "deformation", "rcad"):
        res = estimate_egomotion(win, warp="zoom", regularizer=reg, optimizer="tpe", seed=seed,
                                 t_ref=t_ref, bounds=bounds, dataset=reg and "dsec",
                                 maps=False)
        flow = _warp_flow(res, win)
        m = flow_metrics(flow * span_s, disp_gt, mask=mask)
        rows.append({"regularizer": reg or "none", "h_z (1/s)": res.params[0], "AEE px": m.aee,
                     "20PE %": m.npe[20], "FWL": fwl(win, flow, t_ref)})
        vmax = full_scale(res.iwe_after)
        images.append(iwe_to_rgb(res.iwe_after, vmax=vmax))
        titles.append(f"{reg or 'no regularizer'}: AEE {m.aee:.2f} px\n"
                      f"white 0, black >= {vmax:.3g} events/px")
    save_panel(out / "zoom_collapse.png", images, titles)
    rep.add_heading("2. Forward motion: event collapse (1-DOF zoom warp)")
    rep.add_table(rows, caption="Variance objective, 600-sample TPE, thesis (DSEC) weights. "
                                "Without a regularizer the optimum collapses the events towards "
                                "the centre; divergence, deformation and RCAD prevent it")
    rep.add_figure(out / "zoom_collapse.png", "IWE at each optimum")
    return {"zoom": rows}


def _warp_flow(res, events) -> np.ndarray:
    """Dense flow (H, W, 2) px/s of an ego-motion estimate at its reference time."""
    from evmotion.core.warps import make_warp

    w = make_warp(res.warp, events.sensor_size)
    h, wd = events.sensor_size
    yy, xx = np.mgrid[0:h, 0:wd].astype(np.float64)
    fx, fy = w.optical_flow(xx.ravel(), yy.ravel(), res.params)
    return np.stack([fx.reshape(h, wd), fy.reshape(h, wd)], axis=-1).astype(np.float32)


def _dense_flow(out: Path, rep: HtmlReport, seed: int) -> tuple[dict, object]:
    _log("[3/5] dense optical flow (multi-reference CMax) with an occluding object (the "
         "thesis' 30k-event window: its background moves under 2.5 px, which the small-motion "
         "warning below says)")
    sim = simulate("object", duration_s=0.1, seed=seed, show_progress=False)
    win = sim.events[:30000]
    disp_gt = sim.gt.displacement(win.t_start, win.t_end)
    mask = event_mask(win)
    rows = []
    # one colour scale for the truth and every estimate, so their colours compare
    scale = sequence_max_speed([disp_gt], [mask])
    pictures = [flow_picture(disp_gt, valid=mask, max_speed=scale, unit="px").rgb]
    titles = ["ground truth (grey: no events)"]
    for ta in (None, "burgers"):
        res = estimate_flow(win, time_aware=ta)
        m = flow_metrics(res.displacement(), disp_gt, mask=mask)
        rows.append({"time-aware": ta or "none", "AEE px": m.aee, "%Out": m.pct_out,
                     "FWL": fwl(win, res.flow, res.t_ref_us),
                     "seconds": res.timings["estimate_s"],
                     "compile s": res.timings["compile_s"]})
        pictures.append(flow_picture(res.displacement(), valid=mask, max_speed=scale,
                                     unit="px").rgb)
        titles.append(f"multicm{' + ' + ta if ta else ''}: AEE {m.aee:.2f} px")
        if ta is None:
            save_flow_summary(out / "object_iwe.png", win, res.flow, t_ref_us=res.t_ref_us,
                              valid=mask, title="multicm: the estimated flow sharpens the events")
    save_png(out / "object_flow.png", picture_row(pictures, titles))
    rep.add_heading("3. Dense optical flow (multi-reference contrast maximization)")
    rep.add_table(rows, caption="30k events; displacement over the window, pixels with events")
    rep.add_figure(out / "object_flow.png",
                   "Displacement over the window (colour wheel, one scale) against ground truth")
    rep.add_figure(out / "object_iwe.png", "Events, IWE warped by the estimated flow, the flow "
                   "(px/s, where the picture above gives the displacement over the window, px)")
    return {"multicm": rows}, (sim, win, disp_gt, mask)


def _triplet(out: Path, rep: HtmlReport, scene) -> dict:
    _log("[4/5] event-by-event triplet matching")
    sim, win, disp_gt, mask = scene
    matcher = TripletMatcher(sim.events.sensor_size)
    c0, t0 = compile_seconds(), time.perf_counter()
    matcher.process(sim.events)
    # the rate of the matching itself: a first run also compiles its kernels
    compile_s = compile_seconds() - c0
    rate = len(sim.events) / max(time.perf_counter() - t0 - compile_s, 1e-9)
    window = Window(0, win.t_start, win.t_end + 1, 0, len(win))
    scale = sequence_max_speed([disp_gt], [mask])
    rows, titles = [], ["ground truth"]
    panels = [flow_picture(disp_gt, valid=mask, max_speed=scale, unit="px").rgb]
    for dense, label in (("mean", "thesis: voxel mean, 3x3 non-zero average"),
                         ("lsq", "extension: normal-flow least squares, 11x11")):
        res = estimate_flow_triplet(sim.events, [window], dense=dense)
        disp = res.displacement(0)
        valid = mask & res.valid[0]
        m = flow_metrics(disp, disp_gt, mask=valid)
        rows.append({"dense output": label, "AEE px": m.aee, "%Out": m.pct_out,
                     "pixels evaluated": m.n_pixels})
        panels.append(flow_picture(disp, valid=valid, max_speed=scale, unit="px").rgb)
        titles.append(f"triplet {dense}: AEE {m.aee:.2f} px")
    # the input first, as the other sections' pictures (probe DA)
    save_png(out / "triplet_flow.png",
             picture_row([iwe_to_rgb(event_histogram(win)), *panels], ["events", *titles]))
    rep.add_heading("4. Event-by-event flow (triplet matching)")
    rep.add_table(rows, caption=f"Per-event flow at {rate / 1e6:.2f} M events/s (one core; "
                                f"+ {compile_s:.1f} s compiling kernels), made dense over the "
                                "window")
    rep.add_figure(out / "triplet_flow.png",
                   "Triplet flow against ground truth (one colour scale; grey: no events or "
                   "no estimate)")
    return {"triplet": {"events_per_s": rate, "compile_s": compile_s, "aee": rows[0]["AEE px"],
                        "pct_out": rows[0]["%Out"], "aee_lsq": rows[1]["AEE px"],
                        "pct_out_lsq": rows[1]["%Out"]}}


def _schlieren(out: Path, rep: HtmlReport, seed: int) -> dict:
    _log("[5/5] background-oriented schlieren (events + frames; on a scene this small the "
         "air's structures are near the solver's patches, the flow comes out small, and the "
         "estimate says so below)")
    from evmotion.methods.bos import estimate_bos
    from evmotion.sim.schlieren import simulate_schlieren
    from evmotion.viz.bos import save_bos_flow_png, save_q_png

    sim = simulate_schlieren("plume", sensor_size=(180, 160), duration_s=2 / 120, seed=seed)
    f, t = sim.frames.images, sim.frames.t
    k = 1
    t0, t1 = int(t[k]), int(t[k + 1])
    dt = (t1 - t0) * 1e-6
    win = sim.events.slice_time(t0, t1)
    mask = event_mask(win)
    gt, gt_q = sim.gt.flow[k], sim.gt.q[k]
    rows = []
    for data_term in ("scale", "normalized"):
        c0, start = compile_seconds(), time.perf_counter()
        res = estimate_bos(sim.events, f[k], t0_us=t0, t1_us=t1, frame_next=f[k + 1],
                           data_term=data_term, iterations=100, seed=seed)
        compile_s = compile_seconds() - c0
        seconds = time.perf_counter() - start - compile_s
        m = flow_metrics(res.flow * dt, gt * dt, mask=mask, out_px=1.0)
        speed = np.hypot(res.flow[..., 0], res.flow[..., 1])[mask]
        true = np.hypot(gt[..., 0], gt[..., 1])[mask]
        rows.append({"data term": data_term, "AEE px": m.aee, "%Out (> 1 px)": m.pct_out,
                     "AE rad": float(np.radians(m.ae_deg)),
                     "median |v|/|v_true|": float(np.median(speed) / np.median(true)),
                     "C estimated": res.contrast_threshold, "seconds": seconds,
                     "compile s": compile_s})
        if data_term == "scale":
            best = res
    vmax = float(np.percentile(np.hypot(gt[..., 0], gt[..., 1])[mask], 99))
    # framed on pixel axes at q's magnification (bos_flow.png had been 1x, unframed, beside
    # a 3.8x q; probe DA)
    save_bos_flow_png(out / "bos_flow.png", best.flow, max_speed=vmax, unit="px/s",
                      title="BOS flow (Poisson, scale-aware)")
    save_bos_flow_png(out / "bos_gt_flow.png", gt, max_speed=vmax, unit="px/s",
                      title="exact flow")
    # one colour scale for both q (the exact q's)
    limit = save_q_png(out / "bos_gt_q.png", gt_q, title="Poisson field q (exact)")
    save_q_png(out / "bos_q.png", best.q, limit=limit,
               title="Poisson field q (estimated)")
    hist = event_histogram(win, signed=True)
    vmax = full_scale(hist)
    save_panel(out / "bos_input.png", [f[k], iwe_to_rgb(hist, polarity=True, vmax=vmax)],
               ["frame (random-dot background), 8-bit grey",
                f"events of the frame interval: polarity sum, red +, blue -, full at "
                f"+-{vmax:.3g} / px"])
    rep.add_heading("5. Background-oriented schlieren (events + one frame)")
    rep.add_table(rows, caption=f"Simulated plume, 160x180 px, one 120 fps frame interval "
                                f"({len(win)} events), 100 Adam iterations per scale; "
                                "scored on pixels with events. The thesis' normalized data term "
                                "has no scale of its own (rescaled here by C); the scale-aware "
                                "one fits C times the events. On a scene this small the air's "
                                "structures are near the solver's 8-px patches, and both come "
                                "out small (640x720 scenes: 0.93-0.99, bos_accuracy.md)")
    rep.add_figure(out / "bos_input.png", "Input: the frame and the events (signed)")
    rep.add_figure(out / "bos_flow.png", "Estimated flow")
    rep.add_figure(out / "bos_gt_flow.png", "Exact flow of the simulator")
    rep.add_figure(out / "bos_q.png", "Estimated Poisson field q (flow = Sobel(q))")
    rep.add_figure(out / "bos_gt_q.png", "Exact q")
    return {"bos": rows}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m evmotion.demo",
                                 description=__doc__.replace("``", ""),
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="demo_out", help="output folder (default demo_out)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    from evmotion.cli import show_warning

    shown = warnings.showwarning
    # the demo shows a collapse on purpose: its warning is a line, as the CLI prints it,
    # not a source dump
    warnings.showwarning = show_warning
    try:
        return _run(args)
    finally:
        warnings.showwarning = shown


def _run(args) -> int:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rep = HtmlReport("evmotion demo: simulated recordings with ground truth")
    summary: dict = {}
    summary["rotation"] = _rotation(out, rep, args.seed)
    summary.update(_zoom(out, rep, args.seed))
    dense, scene = _dense_flow(out, rep, args.seed)
    summary.update(dense)
    summary.update(_triplet(out, rep, scene))
    summary.update(_schlieren(out, rep, args.seed))
    page = rep.write(out / "report.html")
    (out / "summary.json").write_text(json.dumps(summary, indent=2, default=float))
    pngs = sorted(Path(p).name for p in rep.figure_paths)
    print(f"evmotion demo: wrote {len(pngs)} pictures to {out.resolve()}/ ({', '.join(pngs)}), "
          "rotation.h5 and its ground truth rotation_gt.h5, summary.json")
    rot = summary["rotation"]
    print(f"evmotion demo: angular velocity error {rot['omega_rms_error']:.3f} rad/s (RMS), "
          f"dense flow AEE {summary['multicm'][0]['AEE px']:.2f} px, BOS AEE "
          f"{summary['bos'][0]['AEE px']:.3f} px")
    print(f"evmotion demo: open {Path(page).resolve()} to see them together")
    return 0


if __name__ == "__main__":
    sys.exit(main())
