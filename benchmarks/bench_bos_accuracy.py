"""Accuracy of event-based BOS (thesis ch. 6) against the simulator's exact flow.

Every case simulates a schlieren scene (:func:`evmotion.sim.simulate_schlieren`, 120 fps,
three frames) and scores the frame interval ``[t_1, t_2)`` on the pixels with at least one
event in it (thesis §6.6.1): AEE (px over the interval), %Out (endpoint error > 1 px) and
AE (angle of (u, v, 1), radians, as the authors' code).

1. ``table64`` (Table 6.4 analog), per scene (plume, jet, breath, ice): Ours (Poisson) and
   Ours (Flow) with the scale-aware data term, MultiCM on the interval's events (MCM row),
   Farneback on the two frames (the thesis' "ground truth"), and the magnitude ratio
   ``median |v̂| / |v|`` (pixels with ``|v| Δt >= 0.05`` px) of Ours (Poisson) with the
   scale-aware term, the thesis' normalized term as is (the authors' code), and the
   normalized term rescaled by the estimated contrast threshold. PNGs in results/bos/.
2. ``table65`` (Table 6.5 analog) on two scenes: base, without regularizers, p = 0, and the
   λ1 / λ2 sweeps.
3. ``lowlight`` (Fig. 6.12 analog): the plume with shot-noise frames down to a few photons
   per pixel and events with the matching shot noise (``event_photons_for``) under both
   photoreceptor models of the simulator (``event_bandwidth``: "fixed", the worst case,
   and "intensity", the standard DVS model); Ours vs Farneback on the same frames, AEE
   ratio, and Ours on noise-free events (the thesis' ablation, which dims only the
   frames) beside it.
4. ``diagnosis``: why Ours trails Farneback on the frames (see :func:`diagnosis`): the same
   solver fed the frames' log difference or the exact LEGM increment instead of the
   events, the solver's suspects one at a time, and the sensor's contrast threshold swept.

Sizes and iterations are recorded in each row; by default the solver's own schedule runs
(150/150/150/300, within 0.3 % of the thesis' 600 per scale in objective), ``--iterations
600`` the thesis'. Table 6.4 also has rows on frames with shot noise (``NOISY_PHOTONS``
photons per white pixel), as real frames have: the noise-free 8-bit frames flatter
Farneback.

Run: ``python benchmarks/bench_bos_accuracy.py --parts table64 --size 720 640 --iterations 150``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import harness
from bench_bos import interval

RESULTS = Path(__file__).resolve().parent / "results"
PNG_DIR = RESULTS / "bos"
SCENES = ("plume", "jet", "breath", "ice")
MIN_DISP_PX = 0.05
NOISY_PHOTONS = 1000.0
EVENT_TAU_US = 1000


def _simulate(scene: str, size, seed: int = 0, photons: float | None = None,
              noise_rate: float = 0.0, event_photons: float | None = None,
              contrast_threshold: float = 0.2, event_bandwidth: str = "fixed", **camera):
    """A three-frame simulation; ``camera``: the frame camera's keywords of
    :func:`simulate_schlieren` (gain, read_noise_e, bit_depth, normalize)."""
    from evmotion.sim.schlieren import simulate_schlieren

    return simulate_schlieren(scene, sensor_size=tuple(size), duration_s=2 / 120, seed=seed,
                              photons=photons, noise_rate=noise_rate,
                              event_photons=event_photons, event_tau_us=EVENT_TAU_US,
                              contrast_threshold=contrast_threshold,
                              event_bandwidth=event_bandwidth, **camera)


def exact_flow(sim, k: int) -> tuple[np.ndarray, np.ndarray, dict]:
    """The simulator's exact optical flow (px/s) and q of frame interval ``k``, with
    Farneback's correlation with it on the noise-free frames as a check of the convention
    (the image moves by ``gt.flow``: a negative correlation would be a simulator bug)."""
    from evmotion.methods.farneback import farneback_flow

    dt = (int(sim.frames.t[k + 1]) - int(sim.frames.t[k])) * 1e-6
    fb = farneback_flow(sim.frames.images[k], sim.frames.images[k + 1], dt)
    gt = sim.gt.flow[k]
    sel = np.hypot(gt[..., 0], gt[..., 1]) * dt > 0.1
    corr = float(np.corrcoef(fb[sel].ravel(), gt[sel].ravel())[0, 1])
    if corr < 0.3:
        raise RuntimeError(f"Farneback on noise-free frames correlates {corr:.2f} with "
                           "gt.flow: the simulator's flow is not the image motion")
    return gt, sim.gt.q[k], {"corr_farneback_gt": corr}


def _score(flow, gt_flow, mask, dt) -> dict:
    from evmotion.eval.metrics import flow_metrics

    m = flow_metrics(flow * dt, gt_flow * dt, mask=mask, out_px=1.0)
    return {"AEE": m.aee, "%Out": m.pct_out, "AE_rad": float(np.radians(m.ae_deg))}


def _ratio(flow, gt_flow, mask, dt) -> float:
    g = np.hypot(gt_flow[..., 0], gt_flow[..., 1])
    e = np.hypot(flow[..., 0], flow[..., 1])
    sel = mask & (g * dt >= MIN_DISP_PX)
    return float(np.median(e[sel] / g[sel])) if sel.any() else float("nan")


def _its(res) -> str:
    """Adam iterations run at each scale (after the convergence stop)."""
    return "/".join(str(i) for i in res.iterations)


def _ours(sim, k, iterations, frames=None, **kw):
    """Ours on interval ``k`` of ``sim``'s events, with ``sim``'s frames or ``frames``
    (another camera's frames of the same scene)."""
    from evmotion.methods.bos import estimate_bos

    fr = sim.frames if frames is None else frames
    f, t = fr.images, fr.t
    start = time.perf_counter()
    res = estimate_bos(sim.events, f[k], t0_us=int(t[k]), t1_us=int(t[k + 1]),
                       frame_next=f[k + 1], iterations=iterations, **kw)
    return res, time.perf_counter() - start


def _ours_refusable(sim, k, iterations, **kw):
    """:func:`_ours`, or ``(None, nan, reason)`` when the estimator refuses the input (a
    black frame has no texture; the events may not give C): recorded, not scored."""
    from evmotion.errors import EventDataError, ParameterError

    try:
        res, sec = _ours(sim, k, iterations, **kw)
    except EventDataError as e:
        return None, float("nan"), str(e)
    except ParameterError as e:
        if "textureless" not in str(e):  # only the black frame's refusal is an outcome
            raise
        return None, float("nan"), str(e)
    return res, sec, ""


def _panel(path, scene, gt, flows: dict, mask, gt_q, q):
    from evmotion.viz import flow_to_rgb, save_panel
    from evmotion.viz.bos import symmetric_limit

    vmax = float(np.percentile(np.hypot(gt[..., 0], gt[..., 1])[mask], 99)) if mask.any() \
        else None
    images = [flow_to_rgb(gt, vmax)] + [flow_to_rgb(np.nan_to_num(f), vmax)
                                        for f in flows.values()]
    titles = ["exact flow"] + list(flows)
    import matplotlib

    cmap = matplotlib.colormaps["RdBu_r"]
    for name, field in (("exact q", gt_q), ("Ours (Poisson) q", q)):
        c = symmetric_limit(field)
        images.append((cmap(0.5 + 0.5 * np.clip(field / c, -1, 1))[..., :3] * 255)
                      .astype(np.uint8))
        titles.append(name)
    save_panel(path, images, titles, ncols=4,
               suptitle=f"{scene}: flow colour wheel rim = {vmax:.3g} px/s (99th pct of "
                        "|v| on event pixels); q in diverging colours")


def table64(size, iterations) -> list[dict]:
    from evmotion.methods.baselines import multicm_interval
    from evmotion.methods.farneback import farneback_flow

    rows = []
    PNG_DIR.mkdir(parents=True, exist_ok=True)
    for scene in SCENES:
        sim = _simulate(scene, size)
        k = 1
        t0, t1, win, mask = interval(sim, k)
        dt = (t1 - t0) * 1e-6
        gt, gt_q, check = exact_flow(sim, k)
        base = {"scene": scene, "size": f"{size[1]}x{size[0]}", "events": len(win),
                "max_disp_px": float(np.hypot(gt[..., 0], gt[..., 1]).max() * dt), **check}
        flows = {}
        res_p, s_p = _ours(sim, k, iterations, param="poisson", data_term="scale")
        res_f, s_f = _ours(sim, k, iterations, param="flow", data_term="scale")
        res_n, s_n = _ours(sim, k, iterations, param="poisson", data_term="normalized")
        for name, res, sec in (("Ours (Poisson)", res_p, s_p), ("Ours (Flow)", res_f, s_f)):
            flows[name] = res.flow
            rows.append({**base, "method": name, **_score(res.flow, gt, mask, dt),
                         "ratio_median": _ratio(res.flow, gt, mask, dt),
                         "C_est": res.contrast_threshold, "iterations": _its(res),
                         "seconds": sec})
        raw = res_n.flow / np.float32(res_n.scale)
        for name, fl in (("Ours (Poisson), normalized term as is", raw),
                         ("Ours (Poisson), normalized term rescaled by C", res_n.flow)):
            rows.append({**base, "method": name, **_score(fl, gt, mask, dt),
                         "ratio_median": _ratio(fl, gt, mask, dt),
                         "C_est": res_n.contrast_threshold, "iterations": _its(res_n),
                         "seconds": s_n})
        start = time.perf_counter()
        mcm = multicm_interval(sim.events, t0, t1)
        flows["MultiCM (events)"] = mcm.flow
        rows.append({**base, "method": "MultiCM (events)", **_score(mcm.flow, gt, mask, dt),
                     "ratio_median": _ratio(mcm.flow, gt, mask, dt),
                     "seconds": time.perf_counter() - start})
        start = time.perf_counter()
        fb = farneback_flow(sim.frames.images[k], sim.frames.images[k + 1], dt)
        flows["Farneback (frames)"] = fb
        rows.append({**base, "method": "Farneback (frames)", **_score(fb, gt, mask, dt),
                     "ratio_median": _ratio(fb, gt, mask, dt),
                     "seconds": time.perf_counter() - start})
        # real frames carry shot noise: the same air and events, frames with
        # NOISY_PHOTONS photons per white pixel (SNR ~32 at white, ~22 at mid grey)
        noisy = _simulate(scene, size, photons=NOISY_PHOTONS)
        fr_n = noisy.frames.images
        res_pn, s_pn = _ours(noisy, k, iterations, param="poisson", data_term="scale")
        rows.append({**base, "method": f"Ours (Poisson), frames {NOISY_PHOTONS:g} photons",
                     **_score(res_pn.flow, gt, mask, dt),
                     "ratio_median": _ratio(res_pn.flow, gt, mask, dt),
                     "C_est": res_pn.contrast_threshold, "iterations": _its(res_pn),
                     "seconds": s_pn})
        start = time.perf_counter()
        fbn = farneback_flow(fr_n[k], fr_n[k + 1], dt)
        rows.append({**base, "method": f"Farneback (frames {NOISY_PHOTONS:g} photons)",
                     **_score(fbn, gt, mask, dt), "ratio_median": _ratio(fbn, gt, mask, dt),
                     "seconds": time.perf_counter() - start})
        _panel(PNG_DIR / f"table64_{scene}.png", scene, gt, flows, mask, gt_q, res_p.q)
        print(f"{scene}: done", flush=True)
    return rows


ABLATIONS = (
    ("Ours (lambda1=0.5, lambda2=0.1)", {}),
    ("w/o regularizers (lambda1=lambda2=0)", {"lambda_tv": 0.0, "lambda_p": 0.0}),
    ("w/o translation model (p=0)", {"use_p": False}),
    ("lambda1=0.05, lambda2=0.1", {"lambda_tv": 0.05}),
    ("lambda1=1.0, lambda2=0.1", {"lambda_tv": 1.0}),
    ("lambda1=0.5, lambda2=0.01", {"lambda_p": 0.01}),
    ("lambda1=0.5, lambda2=1.0", {"lambda_p": 1.0}),
)


def table65(size, iterations, scenes=("plume", "ice"), noise_rate: float = 0.0) -> list[dict]:
    rows = []
    for scene in scenes:
        sim = _simulate(scene, size, noise_rate=noise_rate)
        k = 1
        t0, t1, _, mask = interval(sim, k)
        dt = (t1 - t0) * 1e-6
        gt = exact_flow(sim, k)[0]
        for name, kw in ABLATIONS:
            res, sec = _ours(sim, k, iterations, param="poisson", data_term="scale", **kw)
            rows.append({"scene": scene, "size": f"{size[1]}x{size[0]}",
                         "noise_ev_per_px_s": noise_rate, "variant": name,
                         **_score(res.flow, gt, mask, dt),
                         "ratio_median": _ratio(res.flow, gt, mask, dt),
                         "iterations": _its(res), "seconds": sec})
        print(f"{scene}: done", flush=True)
    return rows


SWEEP_C = (0.1, 0.05, 0.025)
DIFF_VARIANT = "increment = G*(L1 - L0) (frames' log difference)"


def diagnosis(size, iterations, scenes=SCENES) -> list[dict]:
    """Why Ours (Poisson) trails Farneback on the frames: the same solver and interval with
    the measured increment swapped for finer ones, the solver's suspects varied one at a
    time, and the sensor's contrast threshold swept (the simulator's default C = 0.2).

    * ``increment = G*(L1 - L0)``: the two frames' log difference instead of C times the
      events' polarity sums (what Farneback sees, in the LEGM's form);
    * ``increment = -grad L0 . v dt``: the exact LEGM increment of the true flow, smoothed
      like the events (so the only model error is the frame smoothed before the product);
    * ``frame gradient at mid-window``: the model frame is the geometric mean of the two
      frames (gradient at the window's middle instead of its start), C the events' run's;
    * ``thesis schedule``: 600 Adam iterations per scale on full-resolution pixels, no
      convergence stop (is the default converged?);
    * ``w = 1``: alpha = 0, no event-weighted TV;
    * ``C = ...``: the scene re-simulated with that contrast threshold (same air, frames
      and background); Farneback on its frames is scored on the new event mask."""
    from evmotion.methods.bos import estimate_bos, log_frame
    from evmotion.methods.farneback import farneback_flow

    rows = []
    k = 1
    for scene in scenes:
        for c_sensor in (0.2,) + SWEEP_C:
            sim = _simulate(scene, size, contrast_threshold=c_sensor)
            t0, t1, win, mask = interval(sim, k)
            dt = (t1 - t0) * 1e-6
            gt = sim.gt.flow[k]
            f0, f1 = sim.frames.images[k], sim.frames.images[k + 1]
            base = {"scene": scene, "size": f"{size[1]}x{size[0]}", "C_sensor": c_sensor,
                    "events": len(win), "event_pixels": int(mask.sum())}
            start = time.perf_counter()
            fb = farneback_flow(f0, f1, dt)
            rows.append({**base, "variant": "Farneback (frames)", **_score(fb, gt, mask, dt),
                         "ratio_median": _ratio(fb, gt, mask, dt),
                         "seconds": time.perf_counter() - start})
            variants = [("Ours (Poisson), events", {})]
            if c_sensor == 0.2:
                l0, l1 = log_frame(f0), log_frame(f1)
                g0y, g0x = np.gradient(l0)
                legm = -(g0x * gt[..., 0] + g0y * gt[..., 1]) * dt
                mid = np.sqrt(f0.astype(np.float64) * f1.astype(np.float64)) / 255.0
                variants += [
                    (DIFF_VARIANT, {"increment": l1 - l0}),
                    ("increment = -grad L0 . v dt (exact LEGM, true flow)", {"increment": legm}),
                    # C as the events' run: estimated against the mid frame it would halve
                    ("frame gradient at mid-window", {"frame": mid, "contrast_threshold": None}),
                    ("thesis schedule (600/scale, full res, no stop)",
                     {"iterations": 600, "pool": None, "tol": 0.0}),
                    ("w = 1 (alpha = 0)", {"alpha": 0.0}),
                ]
            c_events = None
            for name, kw in variants:
                frame = kw.pop("frame", f0)
                its = kw.pop("iterations", iterations)
                if "contrast_threshold" in kw:
                    kw["contrast_threshold"] = c_events
                start = time.perf_counter()
                res = estimate_bos(sim.events, frame, t0_us=t0, t1_us=t1, frame_next=f1,
                                   iterations=its, param="poisson", data_term="scale", **kw)
                rows.append({**base, "variant": name, **_score(res.flow, gt, mask, dt),
                             "ratio_median": _ratio(res.flow, gt, mask, dt),
                             "C_est": res.contrast_threshold, "iterations": _its(res),
                             "objective": res.objective,
                             "seconds": time.perf_counter() - start})
                c_events = c_events or res.contrast_threshold
        print(f"{scene}: done", flush=True)
    return rows


def diagnosis_lines(rows: list[dict]) -> list[str]:
    """bos_goals' summary of the diagnosis: AE (rad) per scene and variant."""
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    keys = list(dict.fromkeys((r["C_sensor"], r["variant"]) for r in rows))
    ae = {(r["scene"], r["C_sensor"], r["variant"]): r["AE_rad"] for r in rows}
    lines = ["Diagnosis (bos_diagnosis.json): AE (rad) of Ours (Poisson, scale-aware term) "
             "with the measured increment or one suspect changed, and with the sensor's "
             "contrast threshold C swept, against Farneback on the same frames and event "
             "pixels.", "",
             "| C | variant | " + " | ".join(scenes) + " |", "|" + "---|" * (2 + len(scenes))]
    for c, v in keys:
        cells = " | ".join(f"{ae[(s, c, v)]:.3f}" if (s, c, v) in ae else "-" for s in scenes)
        lines.append(f"| {c:g} | {v} | {cells} |")
    return lines + [""]


PHOTONS = (None, 10000.0, 1000.0, 100.0, 30.0, 10.0, 3.0, 1.0)

# The thesis' frame camera (§6.5.1): Basler acA1300-200um, onsemi PYTHON 1300 sensor,
# 4.8 um pixels, Mono8 at 120 fps. Basler's EMVA 1288 figures for it, as quoted in a public
# camera-model preset (basler_ace_aca1300_200um: temporal dark noise 6.83 e-, saturation
# capacity 10.2 ke-, peak QE ~52 %); the onsemi NOIP1SN1300A data sheet: 4.8 um global
# shutter pixels with in-pixel CDS, 10-bit on-chip ADC.
CAMERA_READ_NOISE_E = 6.83
CAMERA_BITS = 8
CAMERA = ("thesis' camera: gain fixed at the brightest level, read noise "
          f"{CAMERA_READ_NOISE_E:g} e-, {CAMERA_BITS} bits, each frame normalized to 0-255")
IDEAL = "ideal camera: gain 255/photons (full scale at any light), shot noise only"
CAMERA_RAW = ("thesis' camera, Ours on the original (not normalized) frames, Farneback on "
              "the normalized ones, as the thesis' Fig. 6.12 (read noise "
              f"{CAMERA_READ_NOISE_E:g} e-, {CAMERA_BITS} bits, gain fixed)")
# column suffix -> (short name, frame camera, suffix of the Farneback run that the ratio
# divides)
CAMERAS = {"": ("ideal camera", IDEAL, ""),
           "_cam": ("thesis' camera, Ours on the normalized frames", CAMERA, "_cam"),
           "_camraw": ("thesis' camera, Ours on the original frames", CAMERA_RAW, "_cam")}

# Rough photoelectrons of a white background pixel per lux on the background (an ESTIMATE,
# uncertain by 2x or more): Lambertian white paper (reflectance, assumed), image-plane
# illuminance E * R * T * split / (4 N^2) (magnification 25 mm / 3.3 m ~ 0), photons of
# white LED light per lux s um^2 (~300 lm/W of radiation, mean photon ~ 560 nm; 4.1e3 for
# monochromatic 555 nm), the pixel's area and QE. Thesis §6.5.1: f/10, 50/50 splitter.
LUX_MODEL = dict(reflectance=0.8, lens_transmission=0.9, splitter=0.5, f_number=10.0,
                 photons_per_lux_s_um2=9.3e3, pixel_um=4.8, qe=0.5)


def electrons_per_lux(exposure_s: float, m: dict = LUX_MODEL) -> float:
    """Photoelectrons a white background pixel of the frame camera collects per lux of
    illuminance on the background in ``exposure_s`` (:data:`LUX_MODEL`; an estimate)."""
    image_lux = m["reflectance"] * m["lens_transmission"] * m["splitter"] / (
        4 * m["f_number"] ** 2)
    return (image_lux * m["photons_per_lux_s_um2"] * m["pixel_um"] ** 2 * exposure_s
            * m["qe"])


def camera_keywords(brightest_photons: float) -> dict:
    """The thesis' frame camera as :func:`simulate_schlieren` keywords: the exposure and
    the gain fixed (white at full scale at ``brightest_photons``), read noise, 8 bits, each
    frame normalized to the full range after quantization (thesis §6.6.6)."""
    return dict(gain=(2 ** CAMERA_BITS - 1) / brightest_photons,
                read_noise_e=CAMERA_READ_NOISE_E, bit_depth=CAMERA_BITS, normalize=True)


def event_photons_for(photons: float, exposure_s: float,
                      event_tau_us: int = EVENT_TAU_US) -> float:
    """Photons a white event pixel collects per ``event_tau_us`` when a white frame pixel
    collects ``photons`` in ``exposure_s``: the same photon flux per pixel on both sensors
    (same optics and pixel, light split evenly), integrated over the photoreceptor's time
    constant instead of the exposure."""
    return photons * event_tau_us * 1e-6 / exposure_s


def lowlight(size, iterations, scene="plume", photon_levels=PHOTONS) -> list[dict]:
    """Fig. 6.12 analog. At each illumination the frames carry shot noise and the events
    are simulated three times from the same frames' scene: from the noise-free radiance
    (the "clean" columns, as the thesis' ablation, which dims only the frames) and with the
    matching event shot noise (``event_photons_for``), the physically consistent case,
    under the simulator's two photoreceptor models: a noise bandwidth fixed at every light
    level ("noisy" columns, the worst case) and a photoreceptor whose bandwidth falls with
    the light ("dvs" columns, ``event_bandwidth="intensity"``, the standard DVS model).
    Two frame cameras see the same photons (same shot-noise draws): the ideal one (gain
    following the light; columns without suffix) and the thesis' (:func:`camera_keywords`:
    fixed gain, read noise, 8 bits, normalized; columns ``*_cam``); Farneback and Ours run
    on each camera's frames with the same events. Every score is taken on the pixels with
    >= 1 noise-free event (the schlieren's support): noise events reach every pixel and
    would otherwise change the mask."""
    from scipy.ndimage import gaussian_filter

    from evmotion.methods.farneback import farneback_flow
    from evmotion.viz import flow_to_rgb, iwe_to_rgb, save_panel

    brightest = max(p for p in photon_levels if p is not None)
    camera = camera_keywords(brightest)
    rows, images, titles = [], [], []
    k = 1
    for photons in photon_levels:
        sim = _simulate(scene, size, photons=photons)
        t0, t1, win, mask = interval(sim, k)
        dt = (t1 - t0) * 1e-6
        if photons is None:  # first: the air (and its flow) is the same at every level
            gt = exact_flow(sim, k)[0]
            gt_mag = np.hypot(gt[..., 0], gt[..., 1]).ravel()
            vmax = float(np.percentile(gt_mag.reshape(gt.shape[:2])[mask], 99))
            # the trivial estimate: a method worse than it has learnt nothing
            zero = _score(np.zeros_like(gt), gt, mask, dt)["AEE"]
        runs, panel = [("clean", sim, None)], {}
        cameras = {"": sim.frames}
        if photons is not None:
            ep = event_photons_for(photons, sim.gt.meta["exposure_s"])
            # the noisy events' simulations carry the thesis' camera: the same scene, shot
            # noise draws and events as with the ideal camera, other frames
            noisy = _simulate(scene, size, photons=photons, event_photons=ep, **camera)
            dvs = _simulate(scene, size, photons=photons, event_photons=ep,
                            event_bandwidth="intensity", **camera)
            if not np.array_equal(noisy.frames.images, dvs.frames.images):
                raise RuntimeError("the two photoreceptor runs gave different frames")
            runs += [("noisy", noisy, ep), ("dvs", dvs, ep)]
            cameras["_cam"] = noisy.frames
            # the same camera's frames before the normalization (thesis: Ours used these)
            cameras["_camraw"] = _simulate(scene, size, photons=photons,
                                           **(camera | {"normalize": False})).frames
        label = "noise-free" if photons is None else f"{photons:g}"
        row = {"scene": scene, "size": f"{size[1]}x{size[0]}", "photons": label,
               "event_photons": "noise-free" if photons is None else runs[1][2],
               "frame_mean_grey": float(sim.frames.images[k].mean()),
               "frame_levels": int(np.unique(sim.frames.images[k]).size),
               "AEE_zero_flow": zero}
        if photons is not None:
            row.update({"lux_estimate": photons / electrons_per_lux(
                            sim.gt.meta["exposure_s"]),
                        "frame_white_grey_cam": camera["gain"] * photons,
                        "frame_levels_cam": int(np.unique(cameras["_cam"].images[k]).size),
                        "gain_cam": camera["gain"]})
        fbs = {}
        for cs, fr in cameras.items():
            fbs[cs] = farneback_flow(fr.images[k], fr.images[k + 1], dt)
            farn = _score(fbs[cs], gt, mask, dt)
            row.update({f"AEE_farneback{cs}": farn["AEE"],
                        f"AE_farneback_rad{cs}": farn["AE_rad"]})
        for kind, s, _ in runs:
            ev = s.events.slice_time(t0, t1)
            # how well the events alone show the schlieren: correlation of the event count
            # image (sigma 2 px) with the exact |flow|
            counts = np.zeros(gt.shape[:2])
            np.add.at(counts, (ev.y, ev.x), 1.0)
            corr = float(np.corrcoef(gaussian_filter(counts, 2.0).ravel(), gt_mag)[0, 1])
            row.update({f"events_{kind}": len(ev), f"event_map_vs_|v|_corr_{kind}": corr})
            for cs, fr in cameras.items():
                if photons is None:
                    res, sec = _ours(s, k, iterations, frames=fr, param="poisson",
                                     data_term="scale")
                    c_bright, res_c, c_err, b_err = res.contrast_threshold, res, "", ""
                else:
                    res_c, sec, b_err = _ours_refusable(s, k, iterations, frames=fr,
                                                        param="poisson", data_term="scale",
                                                        contrast_threshold=c_bright)
                    res, _, c_err = _ours_refusable(s, k, iterations, frames=fr,
                                                    param="poisson", data_term="scale")
                farn_aee = row[f"AEE_farneback{CAMERAS[cs][2]}"]
                ours_c, ours = (_score(r.flow, gt, mask, dt) if r is not None
                                else dict.fromkeys(("AEE", "AE_rad"), float("nan"))
                                for r in (res_c, res))
                sfx = f"{kind}{cs}"
                row.update({
                    f"AEE_ours_C_bright_{sfx}": ours_c["AEE"],
                    f"AE_ours_C_bright_rad_{sfx}": ours_c["AE_rad"],
                    f"AEE_ratio_farneback_over_ours_C_bright_{sfx}": farn_aee / ours_c["AEE"],
                    f"ratio_median_ours_C_bright_{sfx}": float("nan") if res_c is None
                    else _ratio(res_c.flow, gt, mask, dt),
                    f"AEE_ours_C_est_{sfx}": ours["AEE"],
                    f"AE_ours_C_est_rad_{sfx}": ours["AE_rad"],
                    f"AEE_ratio_farneback_over_ours_C_est_{sfx}": farn_aee / ours["AEE"],
                    f"ratio_median_ours_C_est_{sfx}": float("nan") if res is None
                    else _ratio(res.flow, gt, mask, dt),
                    f"C_est_{sfx}": float("nan") if res is None else res.contrast_threshold,
                    f"C_est_error_{sfx}": c_err, f"C_bright_error_{sfx}": b_err,
                    f"seconds_{sfx}": sec})
                panel[sfx] = (counts, None if res_c is None else res_c.flow, ours_c)
                if res_c is not None:  # the iterations of the last scored run
                    its = _its(res_c)
        row.update({"C_bright": c_bright, "iterations": its})
        rows.append(row)
        if photons in (None, 1000.0, 100.0, 10.0):
            cs = "_cam" if photons is not None else ""
            images += [sim.frames.images[k], flow_to_rgb(np.nan_to_num(fbs[""]), vmax),
                       cameras[cs].images[k], flow_to_rgb(np.nan_to_num(fbs[cs]), vmax)]
            titles += ["frame (noise-free)" if photons is None else f"ideal frame ({label} ph)",
                       f"Farneback AEE {row['AEE_farneback']:.3f}",
                       "frame (noise-free)" if photons is None else "thesis' camera frame",
                       f"Farneback AEE {row['AEE_farneback' + cs]:.3f}"]
            for kind in ("noisy", "dvs"):
                counts, flow, ours_c = panel.get(kind + cs, panel["clean"])
                name = {"noisy": "fixed tau", "dvs": "DVS tau(I)"}[kind]
                images += [iwe_to_rgb(counts),
                           flow_to_rgb(np.zeros_like(gt) if flow is None else flow, vmax)]
                titles += ["events" if photons is None else f"events ({name})",
                           f"Ours AEE {ours_c['AEE']:.3f}" if photons is None
                           else f"Ours ({name}, cam) AEE {ours_c['AEE']:.3f}"]
        print(f"photons {label}: done", flush=True)
    PNG_DIR.mkdir(parents=True, exist_ok=True)
    save_panel(PNG_DIR / "lowlight.png", images, titles, ncols=8,
               suptitle="Fig. 6.12 analog: frames of the ideal camera and of the thesis' "
                        "(fixed gain, read noise, 8 bits, normalized) with shot noise (white "
                        "pixel = N photons per exposure); events with a fixed photoreceptor "
                        "bandwidth and with the DVS's tau(I); Ours on the thesis' camera")
    return rows


def photoreceptor_lag(size, iterations, scene="plume", photons=10000.0,
                      taus_us=(1000, 250)) -> list[dict]:
    """What the DVS photoreceptor's low-pass alone costs Ours: the events of the noise-free
    frames' scene through ``event_bandwidth="intensity"`` with so many photons (1e8 per time
    constant) that its noise is negligible and its time constant is the bright-light
    ``event_tau_us`` everywhere, against ``"fixed"`` (no low-pass) at the same photons.
    Ours with the contrast threshold of the noise-free events (``C_bright`` of
    :func:`lowlight`); frames with ``photons`` shot noise, as in that row."""
    clean = _simulate(scene, size, photons=photons)
    k = 1
    t0, t1, _, mask = interval(clean, k)
    gt = exact_flow(clean, k)[0]
    dt = (t1 - t0) * 1e-6
    c_bright = _ours(_simulate(scene, size), k, iterations, param="poisson",
                     data_term="scale")[0].contrast_threshold
    rows = []
    for bandwidth, tau in [("fixed", taus_us[0])] + [("intensity", t) for t in taus_us]:
        from evmotion.sim.schlieren import simulate_schlieren

        sim = simulate_schlieren(scene, sensor_size=tuple(size), duration_s=2 / 120, seed=0,
                                 photons=photons, event_photons=1e8, event_tau_us=tau,
                                 event_bandwidth=bandwidth)
        res, sec = _ours(sim, k, iterations, param="poisson", data_term="scale",
                         contrast_threshold=c_bright)
        sc = _score(res.flow, gt, mask, dt)
        rows.append({"scene": scene, "size": f"{size[1]}x{size[0]}", "photons": photons,
                     "event_photons": 1e8, "event_bandwidth": bandwidth,
                     "bright_tau_us": tau if bandwidth == "intensity" else "none (no low-pass)",
                     "events": len(sim.events.slice_time(t0, t1)), "AEE_ours": sc["AEE"],
                     "AE_ours_rad": sc["AE_rad"], "ratio_median": _ratio(res.flow, gt, mask, dt),
                     "C_bright": c_bright, "seconds": sec})
    return rows


SHOWS_SCHLIEREN = 0.5


MODELS = {"noisy": "fixed photoreceptor bandwidth (worst case)",
          "dvs": "intensity-dependent photoreceptor bandwidth (standard DVS model)"}


def low_light_goal(rows: list[dict]) -> list[str]:
    """Goal 4's lines: Farneback AEE / Ours AEE per level, with clean events and with the
    noisy events of each photoreceptor model (:data:`MODELS`), one table per frame camera
    (the ideal one and, when recorded, the thesis' :data:`CAMERA`), and per model and
    camera the verdict at the lowest level where its events still show the schlieren
    (their count image correlates with |v| at least ``SHOWS_SCHLIEREN`` times as well as
    the noise-free events' does)."""
    ref_row = rows[0]
    ref = ref_row["event_map_vs_|v|_corr_clean"]
    kinds = [k for k in MODELS if any(f"events_{k}" in x for x in rows)]
    cams = [(cs, short, cam) for cs, (short, cam, _) in CAMERAS.items()
            if any(f"AEE_farneback{cs}" in x for x in rows)]
    lines = ["Low light (Fig. 6.12 analog): Farneback AEE / Ours AEE on the same noisy "
             "frames, Ours on events with the matching shot noise under each photoreceptor "
             "model of the simulator (" + "; ".join(f"{k}: {MODELS[k]}" for k in kinds)
             + ") and, as the thesis' ablation, on noise-free events (clean). Goal: >= 2 at "
             "the lowest illumination where the events show the schlieren, taken as: the "
             f"events' count image correlates with |v| >= {SHOWS_SCHLIEREN:g} x as well as "
             f"the noise-free events' ({ref:.3f}). Ratio: Farneback AEE / Ours AEE with "
             "C_bright (the sensor's threshold calibrated in good light) | with C_est "
             "(estimated in the interval). One table per frame camera, the same photons, "
             "shot-noise draws and events.", ""]
    shown = dict.fromkeys(kinds)
    for x in rows:
        for k in kinds:
            corr = ref if x["event_photons"] == "noise-free" \
                else x[f"event_map_vs_|v|_corr_{k}"]
            if corr >= SHOWS_SCHLIEREN * ref:
                shown[k] = x
    verdicts = []
    for cs, short, cam in cams:
        has = [x for x in rows if f"AEE_farneback{cs}" in x]
        lines += [f"Frame camera: {cam}.", ""]
        head = "| photons | ~lux (estimate) | event photons |"
        if cs:
            head += " white grey before normalizing | grey levels |"
        fb = CAMERAS[cs][2]
        head += " Farneback AEE |" if fb == cs else " Farneback AEE (normalized frames) |"
        for k in kinds:
            head += (f" events ({k}) | event map corr ({k}) | Ours AEE ({k}, C_bright) | "
                     f"ratio | Ours AEE ({k}, C_est) | ratio |")
        head += " Ours AEE clean (C_bright) | ratio |"
        lines += [head, "|" + "---|" * (head.count("|") - 1)]
        for x in has:
            noise_free = x["event_photons"] == "noise-free"
            ep = "noise-free" if noise_free else f"{x['event_photons']:.3g}"
            lux = f"{x['lux_estimate']:.3g}" if "lux_estimate" in x else "-"
            cells = f"| {x['photons']} | {lux} | {ep} |"
            if cs:
                cells += f" {x['frame_white_grey_cam']:.3g} | {x['frame_levels_cam']} |"
            cells += f" {x[f'AEE_farneback{fb}']:.3f} |"
            for k in kinds:
                if noise_free:
                    cells += f" {x['events_clean']} | {ref:.3f} | - | - | - | - |"
                else:
                    sfx = k + cs
                    cells += (f" {x[f'events_{k}']} | {x[f'event_map_vs_|v|_corr_{k}']:.3f} | "
                              f"{x[f'AEE_ours_C_bright_{sfx}']:.3f} | "
                              f"{x[f'AEE_ratio_farneback_over_ours_C_bright_{sfx}']:.2f} | "
                              f"{x[f'AEE_ours_C_est_{sfx}']:.3f} | "
                              f"{x[f'AEE_ratio_farneback_over_ours_C_est_{sfx}']:.2f} |")
            lines.append(cells + f" {x[f'AEE_ours_C_bright_clean{cs}']:.3f} | "
                         f"{x[f'AEE_ratio_farneback_over_ours_C_bright_clean{cs}']:.2f} |")
        lines.append("")
        for k in kinds:
            x = shown[k]
            what = f"({MODELS[k]}; {short})"
            if x is None or x["event_photons"] == "noise-free":
                verdicts += [f"Lowest level where the events show the schlieren {what}: "
                             "none with shot noise (goal >= 2: NOT met).", ""]
                continue
            sfx = k + cs
            # a refused (NaN) estimate is no ratio
            best = max((v for v in (x[f"AEE_ratio_farneback_over_ours_C_bright_{sfx}"],
                                    x[f"AEE_ratio_farneback_over_ours_C_est_{sfx}"])
                        if v == v), default=float("nan"))
            verdicts += [f"Lowest level where the events show the schlieren {what}: "
                         f"{x['photons']} photons; Farneback / Ours = {best:.2f} "
                         f"(Farneback AEE {x[f'AEE_farneback{fb}']:.3f}, Ours "
                         f"{x[f'AEE_ours_C_bright_{sfx}']:.3f} | "
                         f"{x[f'AEE_ours_C_est_{sfx}']:.3f}; goal >= 2: "
                         f"{'met' if best >= 2 else 'NOT met'}).", ""]
    if "AEE_zero_flow" in ref_row:
        lines += [f"The zero flow scores AEE {ref_row['AEE_zero_flow']:.3f} px on these "
                  "pixels: an estimate above it carries no information.", ""]
    if len(cams) > 1:
        exp_s = 0.5 / 120
        lines += [f"~lux: an ESTIMATE of the illuminance on the background giving that many "
                  f"photoelectrons per white pixel ({electrons_per_lux(exp_s):.2f} e-/lx in "
                  f"{exp_s * 1e3:.2f} ms): {_lux_text()}. The thesis' levels: 4000 lx "
                  f"~ {4000 * electrons_per_lux(exp_s):.0f} e-, 1000 lx ~ "
                  f"{1000 * electrons_per_lux(exp_s):.0f} e-, 225 lx ~ "
                  f"{225 * electrons_per_lux(exp_s):.0f} e-, 110 lx ~ "
                  f"{110 * electrons_per_lux(exp_s):.0f} e- (times 2 if its fixed exposure "
                  "was the whole 8.3 ms frame period).", ""]
    return lines + verdicts


def _lux_text() -> str:
    m = LUX_MODEL
    return (f"white paper reflectance {m['reflectance']:g} (assumed), lens transmission "
            f"{m['lens_transmission']:g} (assumed), beam splitter {m['splitter']:g}, "
            f"f/{m['f_number']:g}, image-plane lux = scene lux x R T split / (4 N^2), "
            f"{m['photons_per_lux_s_um2']:.2g} photons per lux s um^2 (white LED light; "
            f"4.1e3 at 555 nm), pixel {m['pixel_um']:g} um, QE {m['qe']:g} (PYTHON 1300, "
            "~52 % peak)")


def append_low_light_goal(suffix: str = "") -> None:
    """Append goal 4's table and verdicts (both photoreceptor models side by side) to the
    recorded ``results/bos_lowlight<suffix>.md``."""
    path = RESULTS / f"bos_lowlight{suffix}.md"
    path.write_text(path.read_text() + "\n" + "\n".join(
        low_light_goal(_load_rows("bos_lowlight" + suffix))))


def _load_rows(name: str) -> list[dict] | None:
    import json

    path = RESULTS / f"{name}.json"
    return json.loads(path.read_text())["rows"] if path.exists() else None


def verdict_lines(suffix: str = "") -> list[str]:
    """One line per issue goal: holds or not, with the figures (from the recorded rows)."""
    out = ["## Verdict", ""]
    acc = _load_rows("bos_accuracy" + suffix)
    if acc:
        by = {}
        for x in acc:
            by.setdefault(x["scene"], {})[x["method"]] = x
        n = len(by)
        p_ae = {s: r["Ours (Poisson)"]["AE_rad"] for s, r in by.items()}
        fb_ae = {s: r["Farneback (frames)"]["AE_rad"] for s, r in by.items()}
        ev_best = sum(all(r["Ours (Poisson)"]["AE_rad"] <= r[m]["AE_rad"]
                          for m in ("Ours (Flow)", "MultiCM (events)")) for r in by.values())
        all_best = sum(p_ae[s] <= min(x["AE_rad"] for k, x in r.items()
                                      if "normalized" not in k) for s, r in by.items())
        pf = sum(r["Ours (Poisson)"]["AEE"] < r["Ours (Flow)"]["AEE"] for r in by.values())
        cap = sum(v <= 0.42 for v in p_ae.values())
        ratios = [r["Ours (Poisson)"]["ratio_median"] for r in by.values()]
        fb = ", ".join(f"{s} {fb_ae[s]:.3f} vs {p_ae[s]:.3f}" for s in by)
        out += [
            f"1. Table 6.4 analog: Ours (Poisson) lowest AE of all methods on {all_best}/{n} "
            f"scenes: {'HOLDS' if all_best == n else 'DOES NOT HOLD'} (Farneback on the "
            f"noise-free frames vs Ours, rad: {fb}); lowest AE of the event methods (the "
            f"thesis' Table 6.4 rows: Ours (Flow), MultiCM) on {ev_best}/{n}; Poisson AEE < "
            f"Flow AEE on {pf}/{n}; AE <= 0.42 rad on {cap}/{n}."]
        goal2 = [
            f"2. Magnitude: median |v|/|v_gt| of the scale-aware term "
            f"{min(ratios):.3f}-{max(ratios):.3f}: "
            f"{'HOLDS' if all(0.9 <= r <= 1.1 for r in ratios) else 'DOES NOT HOLD'}."]
    diag = _load_rows("bos_diagnosis" + suffix)
    if diag:
        ae = {(x["scene"], x["C_sensor"], x["variant"]): x["AE_rad"] for x in diag}
        scenes = list(dict.fromkeys(x["scene"] for x in diag))

        def rng(c, v):
            vals = [ae[(s, c, v)] for s in scenes if (s, c, v) in ae]
            return f"{min(vals):.3f}-{max(vals):.3f}"
        c_min = min(x["C_sensor"] for x in diag)
        wins = sum(ae[(s, c_min, "Ours (Poisson), events")]
                   < ae[(s, c_min, "Farneback (frames)")] for s in scenes)
        suspects = [v for c, v in dict.fromkeys((x["C_sensor"], x["variant"]) for x in diag)
                    if c == 0.2 and not v.startswith(("increment", "Farneback", "Ours"))]
        moved = max(abs(ae[(s, 0.2, v)] - ae[(s, 0.2, "Ours (Poisson), events")])
                    for s in scenes for v in suspects if (s, 0.2, v) in ae)
        out.append(
            "   Why goal 1 fails against Farneback (bos_diagnosis): the same solver fed the "
            "frames' log difference instead of the events reaches AE "
            f"{rng(0.2, DIFF_VARIANT)} rad, "
            f"Farneback {rng(0.2, 'Farneback (frames)')}, Ours on the events "
            f"{rng(0.2, 'Ours (Poisson), events')}: the events (C = 0.2, sub-pixel flow) "
            "measure the increment far more coarsely than 8-bit frames. With the sensor's C "
            f"lowered to {c_min:g} Ours is lower than Farneback on {wins}/{len(scenes)} "
            f"scenes. The solver's suspects ({'; '.join(suspects)}) move the AE by at most "
            f"{moved:.4f} rad.")
    if acc:
        out += goal2
    abl = _load_rows("bos_ablation")
    if abl:
        sc = sorted({x["scene"] for x in abl})
        out.append(f"3. Table 6.5 analog on {len(sc)} scenes ({', '.join(sc)}): "
                   f"{'HOLDS' if len(sc) >= 2 else 'DOES NOT HOLD'} (bos_ablation.md).")
    low = _load_rows("bos_lowlight" + suffix)
    if low:
        goal = [ln for ln in low_light_goal(low) if ln.startswith("Lowest level")]
        cam = any("AEE_farneback_cam" in x for x in low)
        out.append("4. Low light" + (" (the verdict: the thesis' camera lines, Ours on the "
                                     "normalized frames as Farneback, and on the original "
                                     "frames as the thesis' Fig. 6.12; the ideal camera's "
                                     "for comparison)" if cam else "") + ": "
                   + " ".join(goal))
        bright = low[1] if len(low) > 1 else low[0]
        lag = _load_rows("bos_lowlight_lag" + suffix)
        if lag:
            aee = {str(x["bright_tau_us"]): x["AEE_ours"] for x in lag}
            lag_text = (" The standard model's low-pass itself costs Ours accuracy: with "
                        "negligible noise, AEE " + ", ".join(
                            f"{v:.3f} ({'no low-pass' if k.startswith('none') else f'tau {k} us'})"
                            for k, v in aee.items()) + " (bos_lowlight_lag.md).")
        else:
            lag_text = ""
        out.append(f"   At {bright['photons']} photons Ours on noise-free events already has AEE "
                   f"{bright['AEE_ours_C_bright_clean']:.3f} against Farneback's "
                   f"{bright['AEE_farneback']:.3f} (goal 1's cause: the events' coarse "
                   "increment at C = 0.2). With a fixed photoreceptor bandwidth the events' "
                   "shot noise (event_photons = 0.24 x photons per 1 ms) swamps the events "
                   "below that level; with the "
                   "DVS's intensity-dependent bandwidth the noise stays near 1/sqrt(162) "
                   "down to 162/13.75 photons per ms and the response slows instead "
                   "(sim/photoreceptor.py)." + lag_text)
        if cam:
            levels = [x for x in low[1:] if "AEE_farneback_cam" in x]
            ref = low[0]["event_map_vs_|v|_corr_clean"]
            kinds = [k for k in MODELS if any(f"events_{k}" in x for x in low)]
            out.append(
                f"   Frames against events per level: Farneback AEE with the ideal camera | "
                f"the thesis' camera ({CAMERA}; its grey levels), and the events' map "
                f"correlation ({' / '.join(kinds)}; they show the schlieren from "
                f"{SHOWS_SCHLIEREN * ref:.3f}): " + ", ".join(
                    f"{x['photons']} photons (~{x['lux_estimate']:.3g} lx, an estimate) "
                    f"{x['AEE_farneback']:.3f} | {x['AEE_farneback_cam']:.3f} "
                    f"({x['frame_levels_cam']} levels), corr "
                    + " / ".join(f"{x[f'event_map_vs_|v|_corr_{k}']:.3f}" for k in kinds)
                    for x in levels) + ".")
        zero = low[0].get("AEE_zero_flow")
        for cs, (short, _, fb) in CAMERAS.items():
            if not any(f"AEE_farneback{cs}" in x for x in low):
                continue
            for kind in [k for k in MODELS if any(f"events_{k}" in x for x in low)]:
                sfx = kind + cs
                noisy = [x for x in low[1:]  # scored levels (NaN: Ours refused the input)
                         if isinstance(x.get(f"AEE_ours_C_bright_{sfx}"), float)
                         and x[f"AEE_ours_C_bright_{sfx}"] == x[f"AEE_ours_C_bright_{sfx}"]]
                best = max(noisy,
                           key=lambda x: x[f"AEE_ratio_farneback_over_ours_C_bright_{sfx}"])
                out.append(
                    f"   Highest Farneback / Ours (C_bright) at any level, {MODELS[kind]}, "
                    f"{short}: "
                    f"{best[f'AEE_ratio_farneback_over_ours_C_bright_{sfx}']:.2f} at "
                    f"{best['photons']} photons (event map corr "
                    f"{best[f'event_map_vs_|v|_corr_{kind}']:.3f}; Ours AEE "
                    f"{best[f'AEE_ours_C_bright_{sfx}']:.3f}, Farneback "
                    f"{best[f'AEE_farneback{fb}']:.3f}, zero flow {zero:.3f}"
                    + _no_information(best[f"AEE_farneback{fb}"],
                                      best[f"AEE_ours_C_bright_{sfx}"], zero) + ").")
    kym = _load_rows("bos_kymogram")
    if kym:
        ok = [x for x in kym if x["source"] == "events" and x["rate_hz"] >= 1200
              and x["method"] == "correlation" and isinstance(x["ratio"], float)]
        if ok:
            worst = max(abs(x["ratio"] - 1) for x in ok)
            out.append(f"5. Kymogram >= 1200 Hz: worst |fitted/true - 1| {worst:.3f} over "
                       f"{len(ok)} event kymograms (correlation fit): "
                       f"{'HOLDS' if worst <= 0.1 else 'DOES NOT HOLD'} (bos_kymogram.md).")
    foreign = _load_rows("bos_foreign")
    if foreign:
        out.append("   On scenes rendered independently of the simulator (bos_foreign.md), "
                   "the default CLI's fitted / rendered speed: "
                   + ", ".join(f"{x['kymo_ratio']:.3f}" for x in foreign) + ".")
    return out + [""]


def _no_information(farneback: float, ours: float, zero: float) -> str:
    """The clause saying which estimate is no better than the zero flow (within 5 %)."""
    names = [n for n, v in (("Farneback", farneback), ("Ours", ours)) if v >= 0.95 * zero]
    if not names:
        return ""
    return (f"; {' and '.join(names)} no better than the zero flow (within 5 %): "
            f"{'neither carries' if len(names) == 2 else 'it carries no'} information")


def summarize(suffix: str = "") -> str:
    """Check the issue's accuracy goals against the recorded results; write
    ``results/bos_goals<suffix>.md`` and return its text."""
    import json

    lines = ["# bos_goals" + suffix, "",
             "Issue #12 accuracy goals checked against the recorded benchmark rows "
             f"(bos_accuracy{suffix}.json, bos_lowlight{suffix}.json).", ""]
    lines += verdict_lines(suffix)
    acc = RESULTS / f"bos_accuracy{suffix}.json"
    if acc.exists():
        data = json.loads(acc.read_text())
        rows = data["rows"]
        lines += [f"Setting: {data['meta']['notes'][:160]}...", "",
                  "| scene | Poisson AE (rad) | lowest AE of all? | lowest AE of the event "
                  "methods (thesis' Table 6.4 rows)? | Poisson AEE < Flow AEE? "
                  "| AE <= 0.42? | median ratio scale-aware | in [0.9, 1.1]? "
                  "| ratio normalized as is | ratio normalized rescaled |", "|" + "---|" * 10]
        for scene in SCENES:
            r = {x["method"]: x for x in rows if x["scene"] == scene}
            if not r:
                continue
            p, f = r["Ours (Poisson)"], r["Ours (Flow)"]
            best = min((x for k, x in r.items() if "normalized" not in k),
                       key=lambda x: x["AE_rad"])
            # the thesis ranks Ours against the event-only methods: Farneback is its GT
            best_ev = min((x for k, x in r.items() if "normalized" not in k
                           and "Farneback" not in k and "photons" not in k),
                          key=lambda x: x["AE_rad"])
            ratio = p["ratio_median"]
            lowest = "yes" if best is p else f"no: {best['method']} {best['AE_rad']:.3f}"
            lowest_ev = "yes" if best_ev is p else \
                f"no: {best_ev['method']} {best_ev['AE_rad']:.3f}"
            lines.append(
                f"| {scene} | {p['AE_rad']:.3f} | {lowest} | {lowest_ev}"
                f" | {'yes' if p['AEE'] < f['AEE'] else 'no'} ({p['AEE']:.3f} vs "
                f"{f['AEE']:.3f}) | {'yes' if p['AE_rad'] <= 0.42 else 'no'} | {ratio:.3f} | "
                f"{'yes' if 0.9 <= ratio <= 1.1 else 'no'} | "
                f"{r['Ours (Poisson), normalized term as is']['ratio_median']:.3f} | "
                f"{r['Ours (Poisson), normalized term rescaled by C']['ratio_median']:.3f} |")
        lines.append("")
    diag = RESULTS / f"bos_diagnosis{suffix}.json"
    if diag.exists():
        lines += diagnosis_lines(json.loads(diag.read_text())["rows"])
    low = RESULTS / f"bos_lowlight{suffix}.json"
    if low.exists():
        rows = json.loads(low.read_text())["rows"]
        lines += low_light_goal(rows)
    text = "\n".join(lines)
    (RESULTS / f"bos_goals{suffix}.md").write_text(text)
    print(text)
    return text


def solver_version() -> str:
    """The commit the solver ran at, and whether its files had uncommitted edits."""
    import subprocess

    root = Path(__file__).resolve().parents[1]
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root,
                              capture_output=True, text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--", "src/evmotion/methods",
                                "src/evmotion/sim"], cwd=root, capture_output=True,
                               text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head + (" with uncommitted edits in methods/ or sim/" if dirty else "")


def main(quick: bool = False, parts=("table64", "table65", "diagnosis", "lowlight"), size=None,
         iterations=None, noise_rate: float = 0.0, photons=PHOTONS) -> list[dict]:
    harness.single_core()
    size = tuple(size or ((180, 160) if quick else (720, 640)))
    iterations = iterations or (30 if quick else None)
    its = ("the solver's default (scale term 150/150/150/300, normalized term 600)"
           if iterations is None else iterations)
    out = []
    note = (f"{size[1]}x{size[0]} px (W x H), {its} Adam iterations per scale "
            "(thesis: 600; the default 150/150/150/300 of the scale term, with pooled "
            "coarse scales and the tol stop, is within 0.3 % of its objective), scales 64-32-16-8, interval [t1, t2) of a 120 fps simulation, "
            "pixels with >= 1 event; AEE px over the interval, %Out: EE > 1 px, AE radians "
            "of (u, v, 1); ratio_median: median |v_est|/|v| where |v| dt >= 0.05 px. "
            f"Seed 0, one shared 2-core machine, code at {solver_version()}. Exact flow: "
            "sim.gt.flow; corr_farneback_gt is Farneback on the noise-free frames "
            "against it.")
    suffix = "_quick" if quick else ""
    if "table64" in parts:
        rows = table64(size, iterations)
        harness.record("bos_accuracy" + suffix, rows, "Table 6.4 analog. " + note)
        out += rows
    if "table65" in parts:
        rows = table65(size, iterations, noise_rate=noise_rate)
        noisy = "_noise" if noise_rate > 0 else ""
        harness.record("bos_ablation" + noisy + suffix, rows, "Table 6.5 analog (Ours "
                       f"(Poisson), scale-aware term), event noise {noise_rate:g} events per "
                       "pixel per second (background activity). " + note)
        out += rows
    if "diagnosis" in parts:
        rows = diagnosis(size, iterations)
        harness.record("bos_diagnosis" + suffix, rows, "Why Ours trails Farneback: Ours "
                       "(Poisson), scale-aware term, with the measured increment swapped "
                       "(frames' log difference; exact LEGM increment of the true flow), the "
                       "frame gradient at mid-window, the thesis' schedule, w = 1, and the "
                       "sensor's contrast threshold swept (C_sensor; the scenes' default "
                       "0.2, nominal, 3 % mismatch). " + note)
        out += rows
    if "lowlight" in parts:
        load = os.getloadavg()[0]
        rows = lowlight(size, iterations, photon_levels=photons)
        harness.record("bos_lowlight" + suffix, rows,
                       "Fig. 6.12 analog: photons = expected photons (photoelectrons) of a "
                       "white pixel per frame (exposure 0.5/fps = 4.17 ms, fixed). Two frame "
                       f"cameras see them: columns without _cam, the {IDEAL}; columns *_cam, "
                       f"the {CAMERA} (gain 255/{max(p for p in photons if p):g} grey per "
                       "e-: the brightest level, about the sensor's 10.2 ke- saturation "
                       "capacity, at full scale), same shot-noise draws and events; columns "
                       "*_camraw: that camera's frames before the normalization, on which "
                       "the thesis ran Ours (Fig. 6.12 caption), ratios against Farneback on "
                       "the normalized frames. Camera: "
                       "Basler acA1300-200um (onsemi PYTHON 1300, 4.8 um pixels, 10-bit "
                       "on-chip ADC: onsemi NOIP1SN1300A data sheet), temporal dark noise "
                       f"{CAMERA_READ_NOISE_E:g} e-, saturation 10.2 ke-, peak QE ~52 % "
                       "(Basler EMVA 1288 figures as quoted in a public camera-model preset, "
                       "basler_ace_aca1300_200um; Basler's own sheet was not retrieved). "
                       "lux_estimate: a rough estimate of the background illuminance (" +
                       _lux_text() + f"). Load average (1 min) {load:.2f} at the start, "
                       f"{os.getloadavg()[0]:.2f} at the end (a 2-core machine shared with "
                       "other runs). "
                       "event_photons = the photons of a white event pixel per "
                       f"event_tau_us = {EVENT_TAU_US} us, set to "
                       "photons * event_tau_us / exposure (same photon flux per pixel on "
                       "both sensors): 0.24 x photons. Columns *_noisy: the simulator's "
                       "event_bandwidth='fixed' (worst case): the log intensity carries "
                       "Gaussian shot noise of std 1/sqrt(event_photons * I) redrawn every "
                       "event_tau_us at every light level; columns *_dvs: "
                       "event_bandwidth='intensity' (the standard DVS model, Lichtsteiner et "
                       "al. 2008, v2e): a first-order low-pass of the log photocurrent with "
                       "tau = event_tau_us * clip(162 / (event_photons * I), 1, 13.75), noise "
                       "std 1/sqrt(event_photons * I * tau / event_tau_us) (literature "
                       "values: sim/photoreceptor.py). Noise events included in events_noisy "
                       "and events_dvs; *_clean: events "
                       "from the noise-free radiance, as the thesis' ablation (frames dimmed, "
                       "events not), kept to show the effect of event noise. Farneback on "
                       "the same noisy frames. Ours with C_bright: the contrast threshold "
                       "estimated on the noise-free frames and clean events (a sensor "
                       "constant, calibrated once in good light), Ours with C_est: estimated "
                       "from the noisy frames and the events of the interval. All scores on "
                       "the pixels with >= 1 noise-free event (the noisy events reach every "
                       "pixel). " + note)
        append_low_light_goal(suffix)
        out += rows
    if "lag" in parts:
        rows = photoreceptor_lag(size, iterations)
        harness.record("bos_lowlight_lag" + suffix, rows,
                       "The DVS photoreceptor's low-pass alone: Ours (Poisson, scale-aware "
                       "term, C_bright) on events through event_bandwidth='intensity' at "
                       "1e8 photons per time constant (noise negligible, time constant = "
                       "the bright-light event_tau_us everywhere) against 'fixed' (no "
                       "low-pass); frames with 10000 photons. The low-pass delays the "
                       "events' increment against the frames' interval. " + note)
        out += rows
    summarize(suffix)
    return out


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--parts", nargs="+", default=["table64", "table65", "diagnosis", "lowlight"])
    ap.add_argument("--size", nargs=2, type=int, default=None, metavar=("H", "W"))
    ap.add_argument("--iterations", type=int, default=None)
    ap.add_argument("--noise-rate", type=float, default=0.0,
                    help="background-activity events per pixel per second (table65)")
    ap.add_argument("--photons", nargs="+", type=float, default=None,
                    help="lowlight photon levels (white frame pixel per exposure); the "
                         "noise-free level always runs first")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--summarize", action="store_true",
                    help="only check the goals against the recorded results")
    a = ap.parse_args()
    if a.summarize:
        summarize("_quick" if a.quick else "")
        sys.exit(0)
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    main(a.quick, a.parts, a.size, a.iterations, a.noise_rate,
         PHOTONS if a.photons is None else (None, *a.photons))
