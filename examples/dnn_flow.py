"""Dense flow in one network pass: the unsupervised EV-FlowNet (thesis §4.3.7).

The shipped network was trained with multicm's own loss (no ground truth). It gives the
dense flow of a window in one forward pass (``planar=False, refine=False``: its flow
alone); by default the flow of a plane's motion fitted to it and polished on the events
replaces it where multicm's objective prefers that, and a refinement of the flow kept on
multicm's finest tiles may replace that in turn; ``estimate_flow(..., init=...)`` can start
multicm from it. Needs the ``dnn`` extra (``pip install 'evmotion[dnn]'``, torch).

Run: ``python examples/dnn_flow.py [OUT_DIR]``.
"""

import os
import sys
from pathlib import Path

from evmotion.eval.metrics import event_mask, flow_metrics
from evmotion.methods.dnn import estimate_flow_dnn
from evmotion.methods.multicm import estimate_flow
from evmotion.sim import simulate
from evmotion.viz import flow_picture, picture_row, save_png, sequence_max_speed

PNGS = ("dnn_flow.png",)
NEEDS = "torch"   # the optional package this example needs

out = Path(sys.argv[1] if len(sys.argv) > 1 else os.environ.get("EVMOTION_EXAMPLES_OUT",
                                                                 "examples_out"))
out.mkdir(parents=True, exist_ok=True)

sim = simulate("translation", duration_s=0.1, sensor_size=(180, 240), seed=0,
               show_progress=False)
win = sim.events[:30000]
disp_gt = sim.gt.displacement(win.t_start, win.t_end)
mask = event_mask(win)
scale = sequence_max_speed([disp_gt], [mask])
pictures = [flow_picture(disp_gt, valid=mask, max_speed=scale, unit="px").rgb]
titles = ["ground truth"]
runs = {"network alone": lambda: estimate_flow_dnn(win, planar=False, refine=False),
        "dnn": lambda: estimate_flow(win, method="dnn"),
        "multicm": lambda: estimate_flow(win)}
for method, run in runs.items():
    res = run()
    m = flow_metrics(res.displacement(), disp_gt, mask=mask)
    print(f"{method}: AEE {m.aee:.3f} px")
    pictures.append(flow_picture(res.displacement(), valid=mask, max_speed=scale,
                                 unit="px").rgb)
    titles.append(f"{method}: AEE {m.aee:.2f} px")
save_png(out / PNGS[0], picture_row(pictures, titles))
print(f"wrote {out / PNGS[0]}")
