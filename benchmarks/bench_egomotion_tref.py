"""Ego-motion accuracy by the warp's reference time within the window (``t_ref``): the
window's start (the thesis' ch. 3 convention, the default until 2026-11-30) against its
middle (the default since).

Sources: ``evmotion.sim`` at 346x260 (translation, rotation, zoom; 0.2 s, seed 0),
consecutive 30k-event windows, each estimate against the scene's parameters at the
window's reference time; the two ECD rotation windows of ``../shared/data`` against their
IMU angular velocity (``motion.txt``), through the CLI as a user runs it.
``python benchmarks/run.py egomotion_tref``
"""

from __future__ import annotations

import json
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np

import harness

NOTES = ("estimate_egomotion defaults but t_ref (variance objective, BFGS, bilinear votes, "
         "integer sensor pixels for the simulator; the ECD windows undistorted by their "
         "calib.txt). RMS over the windows of each parameter's error in its unit, and "
         "rms_all over all parameters; the ECD rows are one window each (the CLI's "
         "default 30k events).")
SCENES = (("translation", "translation"), ("rotation", "rotation"), ("zoom", "zoom"))


def _sim_rows(quick: bool) -> list[dict]:
    from evmotion.methods.egomotion import estimate_egomotion
    from evmotion.sim import simulate

    rows = []
    for scene, warp in SCENES[:1] if quick else SCENES:
        sim = simulate(scene, duration_s=0.2, sensor_size=(260, 346), seed=0,
                       show_progress=False)
        motion = sim.gt.layers[0].motion
        for t_ref in ("start", "mid"):
            errs = []
            for w in sim.events.windows_by_count(30_000):
                if w.count < 30_000:
                    continue
                win = sim.events.window(w)
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    res = estimate_egomotion(win, warp, K=sim.gt.K, t_ref=t_ref, maps=False)
                errs.append(res.params - motion.params_at(res.t_ref_us * 1e-6))
            e = np.asarray(errs)
            row = {"data": f"sim {scene}", "t_ref": t_ref, "windows": len(errs),
                   **{n: float(np.sqrt(np.mean(e[:, k] ** 2)))
                      for k, n in enumerate(motion.warp.param_names)},
                   "rms_all": float(np.sqrt(np.mean(e ** 2)))}
            rows.append(row)
            print(row, flush=True)
    return rows


def _ecd_rows() -> list[dict]:
    from bench_multicm_accuracy import DATA

    root = DATA / "ecd_rotation_windows"
    if not root.is_dir():
        print(f"skipping the ECD windows: {root} not found")
        return []
    cli = Path(sys.executable).with_name("evmotion")
    rows = []
    for d in sorted(root.iterdir()):
        imu = np.loadtxt(d / "motion.txt")
        for t_ref in ("start", "mid"):
            out = subprocess.run([str(cli), "egomotion", str(d / "events.txt"), "--warp",
                                  "rotation", "--t-ref", t_ref, "--max-png", "0", "--json",
                                  "--out", str(Path(harness.RESULTS) / ".tmp_ego" / d.name)],
                                 capture_output=True, text=True, check=True)
            p = json.loads(out.stdout)["windows"][0]["params"]
            err = np.array([p["wx"], p["wy"], p["wz"]]) - imu
            rows.append({"data": f"ECD {d.name}", "t_ref": t_ref, "windows": 1,
                         "wx": abs(float(err[0])), "wy": abs(float(err[1])),
                         "wz": abs(float(err[2])),
                         "rms_all": float(np.sqrt(np.mean(err ** 2)))})
            print(rows[-1], flush=True)
    return rows


def main(quick: bool = False) -> list[dict]:
    import shutil

    rows = _sim_rows(quick) + ([] if quick else _ecd_rows())
    shutil.rmtree(Path(harness.RESULTS) / ".tmp_ego", ignore_errors=True)
    harness.record("egomotion_tref", rows, NOTES)
    return rows


if __name__ == "__main__":
    main()
