"""Dense flow on a scene rendered independently of evmotion's simulator: ``evmotion flow``
with multicm (default), the network (``--method dnn``) and multicm started from it
(``--init dnn``), against the exact flow.

The scene (nothing of evmotion is used to make it): a blob texture (smoothed noise,
thresholded, blurred) turning about the image centre at ``OMEGA`` rad/s while translating
at ``VELOCITY`` px/s, drawn with OpenCV's bicubic ``warpAffine`` at 5 kHz; a pixel fires
each time its log intensity moves ``C`` from its reference (time interpolated inside the
step: ``tests/rendered_schlieren.crossing_events``), written as an ECD text file (240x180,
0.2 s). Each CLI runs on it with 30k-event
windows in a fresh process; AEE (px over the window, the pixels the output marks valid) of
each window against the exact flow at its midpoint, the zero flow's, and the FWL of each
estimate (variance of the events' image at the window's midpoint over the identity's).

``python benchmarks/run.py flow_foreign``
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np
from scipy.ndimage import gaussian_filter

import harness

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from rendered_schlieren import crossing_events

SIZE = (180, 240)
OMEGA = 1.5
VELOCITY = (40.0, -25.0)
C = 0.2
RATE_HZ = 5000
DURATION_S = 0.2
NOTES = (f"Scene: {SIZE[1]}x{SIZE[0]} px, rotation {OMEGA} rad/s about the image centre plus "
         f"{VELOCITY} px/s, C = {C}, {DURATION_S} s at {RATE_HZ} Hz, seed 1 (rendered here, "
         "not by evmotion's simulator); 30k-event windows, default options otherwise; AEE "
         "over the pixels each output marks valid, in the windows not flagged as no "
         "measurement (windows_flagged: none valid); AEE_event_px over the pixels with "
         "events of every window, flagged or not.")


def _transform(t: float) -> np.ndarray:
    h, w = SIZE
    m = cv2.getRotationMatrix2D((w * 1.5, h * 1.5), np.degrees(OMEGA * t), 1.0)
    m[:, 2] += (VELOCITY[0] * t, VELOCITY[1] * t)
    return np.vstack([m, [0.0, 0.0, 1.0]])


def render(path: Path, seed: int = 1) -> None:
    """Write the scene's events as ``t x y p`` lines (s, px, px, 0/1)."""
    h, w = SIZE
    rng = np.random.default_rng(seed)
    big = gaussian_filter(rng.random((h * 3, w * 3)), 3.0)
    big = (big - big.min()) / (big.max() - big.min())
    big = gaussian_filter(np.where(big > 0.5, 0.85, 0.1) + 0.1 * big, 1.0).astype(np.float32)

    def log_frame(t):
        img = cv2.warpAffine(big, _transform(t)[:2], (w * 3, h * 3), flags=cv2.INTER_CUBIC,
                             borderMode=cv2.BORDER_REFLECT)
        return np.log(img[h:2 * h, w:2 * w] + 1e-2)

    first = log_frame(0.0)
    ref = first + rng.uniform(-0.5, 0.5, first.shape) * C
    ev = crossing_events(log_frame, first, ref, np.full(first.shape, C),
                         int(DURATION_S * RATE_HZ), RATE_HZ)
    ev = ev[np.argsort(ev[:, 0], kind="stable")]
    np.savetxt(path, ev, fmt=["%.9f", "%d", "%d", "%d"])


def exact_flow(t_s: float) -> np.ndarray:
    """(H, W, 2) px/s of the content at each pixel at time ``t_s``."""
    h, w = SIZE
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    p = np.stack([xx.ravel() + w, yy.ravel() + h, np.ones(xx.size)])
    d = 1e-5
    q = (_transform(t_s + d) @ np.linalg.inv(_transform(t_s))) @ p
    return ((q[:2] - p[:2]) / d).T.reshape(h, w, 2)


def main(quick: bool = False) -> list[dict]:
    from evmotion.eval.metrics import fwl
    from evmotion.io import read_events
    from evmotion.io.flowread import read_flow

    runs = {"multicm": [], "dnn": ["--method", "dnn"],
            "multicm init=dnn": ["--init", "dnn"]}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        rec = Path(tmp) / "events.txt"
        render(rec)
        events = read_events(rec)
        for name, extra in runs.items():
            out = Path(tmp) / f"{name.replace(' ', '_').replace('=', '')}.h5"
            subprocess.run([sys.executable, "-m", "evmotion", "flow", str(rec),
                            "--window-events", "30000", "--out", str(out), *extra],
                           check=True, capture_output=True, text=True)
            seq = read_flow(out)
            n = 4 if quick else len(seq.t0)
            aee, zero, fwls, all_px = [], [], [], []
            for k in range(n):
                t0, t1 = int(seq.t0[k]), int(seq.t1[k])
                dt = (t1 - t0) * 1e-6
                gt = exact_flow(0.5 * (t0 + t1) * 1e-6) * dt
                err = np.linalg.norm(seq.flow[k] * dt - gt, axis=-1)
                ev_k = events.slice_time(t0, t1)
                hit = np.zeros(err.shape, bool)
                hit[ev_k.y.astype(int), ev_k.x.astype(int)] = True
                all_px.append(float(err[hit].mean()))
                m = seq.valid[k]
                if m.any():  # a window flagged as no measurement has no valid pixel
                    aee.append(float(err[m].mean()))
                    zero.append(float(np.linalg.norm(gt, axis=-1)[m].mean()))
                fwls.append(fwl(ev_k, seq.flow[k], (t0 + t1) // 2))
            rows.append({"method": name, "windows": n, "windows_flagged": n - len(aee),
                         "AEE_px_median": float(np.median(aee)) if aee else "",
                         "AEE_px_max": float(np.max(aee)) if aee else "",
                         "AEE_event_px_median": float(np.median(all_px)),
                         "zero_AEE_px_median": float(np.median(zero)) if zero else "",
                         "FWL_median": float(np.median(fwls))})
            print(rows[-1], flush=True)
    harness.record("flow_foreign", rows, NOTES)
    return rows


if __name__ == "__main__":
    main()
