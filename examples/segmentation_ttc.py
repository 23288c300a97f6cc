"""Motion segmentation with several warps, and time to contact (thesis §3.6.6-3.6.7).

Segmentation: an object moves across a background that moves the other way; EM with two
translation warps explains every event by one motion (each cluster maximizes the contrast
of its own IWE) and labels the events. Time to contact: the zoom warp's expansion rate
h_z (1/s) of a forward motion, with RCAD against collapse, gives TTC = 1 / h_z.

Run: ``python examples/segmentation_ttc.py [OUT_DIR]``.
"""

import os
import sys
from pathlib import Path

import numpy as np

from evmotion.core.warps import make_warp
from evmotion.events import EventArray
from evmotion.methods.egomotion import estimate_egomotion
from evmotion.methods.segmentation import segment_motion
from evmotion.methods.ttc import time_to_contact
from evmotion.sim import simulate
from evmotion.viz import iwe_to_rgb, save_panel

PNGS = ("segmentation.png",)

out = Path(sys.argv[1] if len(sys.argv) > 1 else os.environ.get("EVMOTION_EXAMPLES_OUT",
                                                                 "examples_out"))
out.mkdir(parents=True, exist_ok=True)

# two groups of dots moving in opposite directions (300 px/s right, 300 px/s left)
rng = np.random.default_rng(0)
n = 8000
dots = np.concatenate([rng.uniform([10, 10], [60, 90], (60, 2)),
                       rng.uniform([90, 10], [150, 90], (60, 2))])
k = rng.integers(0, 120, n)
t = np.sort(rng.integers(0, 40_000, n))
v = np.where(k < 60, 300.0, -300.0)
events = EventArray(dots[k, 0] + v * t * 1e-6, dots[k, 1], t, np.ones(n, int), (100, 160),
                    validate=False)
seg = segment_motion(events, n_warps=2, warp="translation", seed=0)
print(f"cluster velocities (px/s): {np.round(seg.params, 1).tolist()}")
labels = np.zeros((100, 160, 3), np.uint8) + 255
xi = np.clip(np.round(events.x).astype(int), 0, 159)
yi = np.clip(np.round(events.y).astype(int), 0, 99)
labels[yi, xi] = np.where(seg.labels[:, None] == 0, [[200, 40, 40]], [[40, 40, 200]])
save_panel(out / PNGS[0], [labels, iwe_to_rgb(seg.iwes[0]), iwe_to_rgb(seg.iwes[1])],
           ["events by cluster", f"cluster 0 IWE: v = {np.round(seg.params[0], 0)}",
            f"cluster 1 IWE: v = {np.round(seg.params[1], 0)}"])

# time to contact of a forward motion
sim = simulate("zoom", duration_s=0.03, sensor_size=(120, 160), seed=0, texture="noise",
               show_progress=False)
win = sim.events
res = estimate_egomotion(win, warp="zoom", regularizer="rcad", optimizer="tpe", seed=0,
                         t_ref=win.t_start, maps=False)
ttc = time_to_contact(res.params, make_warp("zoom", win.sensor_size), win.duration_us * 1e-6)
true_hz = sim.gt.params(win.t_start)["hz"]
print(f"time to contact {ttc.ttc_s:.3f} s (true {1 / true_hz:.3f} s)")
print(f"wrote {out / PNGS[0]}")
