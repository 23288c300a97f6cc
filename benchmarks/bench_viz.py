"""Time to draw and write one flow picture at 640x480 (one core): the bare colour wheel, the
picture with its legend (fixed scale: the legend strip is drawn once and reused; per-image
scale: a new strip each frame), the PNG written, the events | warped IWE | flow panel of a
30k-event window, and one video frame (H.264 through imageio-ffmpeg, when installed).
"""

from __future__ import annotations

import itertools
import sys
import tempfile
from pathlib import Path

import numpy as np

import harness

H, W = 480, 640


def main(quick: bool = False) -> list[dict]:
    harness.pin_idlest_core()
    from evmotion.events import EventArray
    from evmotion.viz import flow_panel, flow_picture, flow_to_rgb, save_flow_png

    repeat = 3 if quick else 10
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    flow = np.stack([xx - W / 2, yy - H / 2], axis=-1) * 2.0
    valid = rng.random((H, W)) > 0.5
    n = 30_000
    t = np.sort(rng.integers(0, 20_000, n))
    ev = EventArray(rng.uniform(0, W - 1, n).astype(np.float32),
                    rng.uniform(0, H - 1, n).astype(np.float32), t, rng.integers(0, 2, n),
                    sensor_size=(H, W))
    tmp = Path(tempfile.mkdtemp())
    speeds = itertools.count(500)  # a new rim speed every call: the strip is re-drawn
    fns = {
        "flow_to_rgb (bare)": lambda: flow_to_rgb(flow, 800.0, valid),
        "flow_picture, fixed scale": lambda: flow_picture(flow, max_speed=800.0, valid=valid),
        "flow_picture, per-image scale": lambda: flow_picture(
            flow, max_speed=float(next(speeds)), valid=valid),
        "save_flow_png, fixed scale": lambda: save_flow_png(tmp / "f.png", flow,
                                                            max_speed=800.0, valid=valid),
        "flow_panel, 30k events": lambda: flow_panel(ev, flow, max_speed=800.0, valid=valid),
    }
    res = harness.timeit_rounds(fns, repeat=repeat, rounds=3, ref="flow_to_rgb (bare)")
    rows = [{"step": k, "median_ms": r["median_s"] * 1e3, "min_ms": r["min_s"] * 1e3,
             "ratio_vs_bare": r["ratio"]} for k, r in res.items()]
    try:
        import imageio_ffmpeg  # noqa: F401
    except ImportError:
        print("imageio-ffmpeg absent: no video row", file=sys.stderr)
    else:
        from evmotion.viz import write_video

        frame, _ = flow_panel(ev, flow, max_speed=800.0, valid=valid)
        k = 10 if quick else 40
        r = harness.timeit(lambda: write_video([frame] * k, tmp / "v.mp4", fps=10),
                           repeat=3, warmup=1)
        rows.append({"step": f"write_video, {frame.shape[1]}x{frame.shape[0]} frames",
                     "median_ms": r["median_s"] * 1e3 / k, "min_ms": r["min_s"] * 1e3 / k,
                     "ratio_vs_bare": r["median_s"] / k / res["flow_to_rgb (bare)"]["median_s"]})
    harness.record("viz", rows, notes=f"{W}x{H} flow, one core; per picture / per frame "
                                      "(write_video: H.264 encode of identical panel frames)")
    return rows


if __name__ == "__main__":
    main(quick="--quick" in sys.argv)
