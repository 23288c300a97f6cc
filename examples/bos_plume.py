"""Background-oriented schlieren with events and frames (thesis ch. 6).

Simulates a hot-air plume rising in front of a random-dot background, seen by an event
camera that also records frames (120 fps). ``estimate_bos`` recovers the apparent flow of
the background (px/s) over one frame interval and its Poisson potential q (flow = grad q),
which are drawn next to the simulator's exact ones.

Run: ``python examples/bos_plume.py [OUT_DIR]``.
"""

import os
import sys
from pathlib import Path

import numpy as np

from evmotion.eval.metrics import event_mask, flow_metrics
from evmotion.methods.bos import estimate_bos
from evmotion.sim.schlieren import simulate_schlieren
from evmotion.viz import event_histogram, iwe_to_rgb, save_flow_png, save_panel
from evmotion.viz.bos import save_q_png

PNGS = ("bos_input.png", "bos_flow.png", "bos_gt_flow.png", "bos_q.png")

out = Path(sys.argv[1] if len(sys.argv) > 1 else os.environ.get("EVMOTION_EXAMPLES_OUT",
                                                                 "examples_out"))
out.mkdir(parents=True, exist_ok=True)

sim = simulate_schlieren("plume", sensor_size=(180, 160), duration_s=2 / 120, seed=0)
frames, t = sim.frames.images, sim.frames.t
k = 1                                                    # the second frame interval
t0, t1 = int(t[k]), int(t[k + 1])
res = estimate_bos(sim.events, frames[k], t0_us=t0, t1_us=t1, frame_next=frames[k + 1],
                   iterations=100, seed=0)
gt = sim.gt.flow[k]
win = sim.events.slice_time(t0, t1)
mask = event_mask(win)
dt = (t1 - t0) * 1e-6
m = flow_metrics(res.flow * dt, gt * dt, mask=mask, out_px=1.0)
print(f"BOS over {len(win)} events: AEE {m.aee:.3f} px, AE {np.radians(m.ae_deg):.3f} rad, "
      f"contrast threshold C = {res.contrast_threshold:.3f} (from the frames)")

vmax = float(np.percentile(np.hypot(gt[..., 0], gt[..., 1])[mask], 99))
save_panel(out / PNGS[0], [frames[k], iwe_to_rgb(event_histogram(win, signed=True),
                                                 polarity=True)],
           ["frame (random-dot background)", "events of the frame interval"])
save_flow_png(out / PNGS[1], res.flow, max_speed=vmax, unit="px/s", title="estimated flow")
save_flow_png(out / PNGS[2], gt, max_speed=vmax, unit="px/s", title="exact flow")
save_q_png(out / PNGS[3], res.q, title="Poisson field q (estimated)")
print(f"wrote {', '.join(str(out / p) for p in PNGS)}")
