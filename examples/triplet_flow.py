"""Event-by-event optical flow by triplet matching (thesis ch. 5).

A ``TripletMatcher`` streams the events and gives each one a flow (vx, vy) in px/s as it
arrives, from the event and two earlier ones on a line at equal time steps. The per-event
flow is then made dense over a window, by the thesis' voxel mean (``dense="mean"``) and by
the normal-flow least-squares fit (``dense="lsq"``), and drawn against the exact flow.

Run: ``python examples/triplet_flow.py [OUT_DIR]``.
"""

import os
import sys
from pathlib import Path

from evmotion.eval.metrics import event_mask, flow_metrics
from evmotion.events import Window
from evmotion.methods.triplet import TripletMatcher, estimate_flow_triplet
from evmotion.sim import simulate
from evmotion.viz import flow_picture, picture_row, save_png, sequence_max_speed

PNGS = ("triplet_flow.png",)

out = Path(sys.argv[1] if len(sys.argv) > 1 else os.environ.get("EVMOTION_EXAMPLES_OUT",
                                                                 "examples_out"))
out.mkdir(parents=True, exist_ok=True)

sim = simulate("object", duration_s=0.1, sensor_size=(180, 240), seed=0, show_progress=False)
events = sim.events

# streaming: feed chunks of any size, the matcher keeps its state between them
matcher = TripletMatcher(events.sensor_size)
flows = [matcher.process(chunk) for chunk in (events[:25_000], events[25_000:])]
n_matched = sum(int(f.valid.sum()) for f in flows)
print(f"{n_matched} of {len(events)} events got a flow")

win = events[:20000]
window = Window(0, win.t_start, win.t_end + 1, 0, len(win))
disp_gt = sim.gt.displacement(win.t_start, win.t_end)
mask = event_mask(win)
scale = sequence_max_speed([disp_gt], [mask])
pictures = [flow_picture(disp_gt, valid=mask, max_speed=scale, unit="px").rgb]
titles = ["ground truth"]
for dense in ("mean", "lsq"):
    res = estimate_flow_triplet(events, [window], dense=dense)
    valid = mask & res.valid[0]
    m = flow_metrics(res.displacement(0), disp_gt, mask=valid)
    print(f"triplet dense={dense}: AEE {m.aee:.3f} px over {m.n_pixels} pixels")
    pictures.append(flow_picture(res.displacement(0), valid=valid, max_speed=scale,
                                 unit="px").rgb)
    titles.append(f"triplet {dense}: AEE {m.aee:.2f} px")
save_png(out / PNGS[0], picture_row(pictures, titles))
print(f"wrote {out / PNGS[0]}")
