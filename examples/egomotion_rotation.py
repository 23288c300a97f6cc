"""Ego-motion by contrast maximization: a rotating camera and a forward-moving one.

Simulates a camera rotating in front of a dotted scene, estimates its angular velocity with
the 3-DOF rotation warp (thesis ch. 3) and shows the image of warped events (IWE) before and
after motion compensation. Then a forward motion (1-DOF zoom warp): without a regularizer
the contrast optimum collapses the events to a point; RCAD keeps it at the true expansion.

Run: ``python examples/egomotion_rotation.py [OUT_DIR]`` (default ``$EVMOTION_EXAMPLES_OUT``
or ``examples_out``).
"""

import os
import sys
import warnings
from pathlib import Path

import numpy as np

from evmotion.errors import CollapseWarning
from evmotion.methods.egomotion import estimate_egomotion
from evmotion.sim import simulate
from evmotion.viz import iwe_to_rgb, save_panel

PNGS = ("egomotion_rotation.png", "egomotion_collapse.png")

out = Path(sys.argv[1] if len(sys.argv) > 1 else os.environ.get("EVMOTION_EXAMPLES_OUT",
                                                                 "examples_out"))
out.mkdir(parents=True, exist_ok=True)

# 1. rotation: angular velocity (rad/s) of a 20k-event window
sim = simulate("rotation", duration_s=0.05, sensor_size=(180, 240), seed=0,
               show_progress=False)
win = sim.events[:20000]
res = estimate_egomotion(win, warp="rotation", K=sim.gt.K, regularizer="rcad")
t_mid = (win.t_start + win.t_end) // 2
true = np.asarray(sim.gt.params(t_mid)["omega"])
print(f"omega estimated {np.round(res.params, 3)} rad/s, true {np.round(true, 3)} rad/s")
save_panel(out / PNGS[0], [iwe_to_rgb(res.iwe_before), iwe_to_rgb(res.iwe_after)],
           ["identity warp", f"rotation warp: omega = {np.round(res.params, 2)} rad/s"])

# 2. forward motion: the zoom warp collapses without a regularizer
sim = simulate("zoom", duration_s=0.03, sensor_size=(120, 160), seed=0, texture="noise",
               show_progress=False)
win = sim.events
span_s = win.duration_us * 1e-6
bounds = (np.array([-0.999 / span_s]), np.array([0.999 / span_s]))  # up to the collapse 1/T
images, titles = [], []
for reg in (None, "rcad"):
    with warnings.catch_warnings():   # the collapse without a regularizer is the point here
        warnings.simplefilter("ignore", CollapseWarning)
        res = estimate_egomotion(win, warp="zoom", regularizer=reg, optimizer="tpe", seed=0,
                                 t_ref=win.t_start, bounds=bounds, maps=False)
    print(f"zoom, regularizer {reg}: h_z = {res.params[0]:.2f} 1/s, "
          f"collapsed: {res.collapsed}")
    images.append(iwe_to_rgb(res.iwe_after))
    titles.append(f"{reg or 'no regularizer'}: h_z = {res.params[0]:.2f} 1/s")
print(f"true h_z = {sim.gt.params(win.t_start)['hz']:.2f} 1/s")
save_panel(out / PNGS[1], images, titles)
print(f"wrote {', '.join(str(out / p) for p in PNGS)}")
