"""multicm on windows with few events per pixel of motion, rendered without evmotion's
simulator: the coarse scales' sub-pixel jitter (``multicm.JITTER_TO_LEVEL``) against
none.

A sensor fires many events per pixel of motion; a window subsampled to a fixed count
(the thesis optimizes MVSEC's GT intervals on 30k events), a high threshold or a
saturated readout leaves a few. On whole-pixel coordinates the zero flow's IWE is then
sharper than any flow of a pixel or two, and the coarse scales, which start from zero,
stayed there. The scene: smoothed noise (2 px) moving with a constant affine motion
(translation, or rotation about the image centre), drawn with OpenCV's bicubic
``warpAffine`` at 10 kHz; a pixel fires each time its log intensity moves ``C`` from its
reference (``tests/rendered_schlieren.crossing_events``). Windows centred in the
recording span ``disp`` px of motion (at the image corner for the rotation) and are
evenly subsampled to 30k events. AEE (px over the window) against the exact flow at the
window's midpoint, on the pixels with events and on those the result marks valid; the
zero flow's AEE; the chance gain (:func:`evmotion.methods.measured.flow_alignment_gain`).

``python benchmarks/run.py multicm_sparse``
"""

from __future__ import annotations

import sys
import time
import warnings
from pathlib import Path

import cv2
import numpy as np
from scipy.ndimage import gaussian_filter

import harness

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from rendered_schlieren import crossing_events

SIZE = (180, 240)
C = 0.2
RATE_HZ = 10_000
DURATION_S = 0.06
N_EVENTS = 30_000
SCENES = {"translation": {"velocity": (1200.0, 700.0), "omega": 0.0},
          "rotation": {"velocity": (0.0, 0.0), "omega": 12.0}}
DISPLACEMENTS = (5.0, 10.0, 20.0, 30.0)
NOTES = (f"Scenes rendered here (not by evmotion's simulator): {SIZE[1]}x{SIZE[0]} px, "
         f"smoothed noise (2 px), C = {C}, {RATE_HZ} Hz steps, {DURATION_S} s, seed 2; "
         f"{SCENES}. Windows centred in the recording spanning disp px of motion (rotation: "
         f"at the corner), evenly subsampled to {N_EVENTS} events. jitter: multicm's "
         "default (coarse scales up to 4x4 tiles on jittered coordinates); none: "
         "JITTER_TO_LEVEL = 0. AEE px over the window (events: pixels with events; valid: "
         "pixels the result marks valid, empty when none).")


def _transform(scene: dict, t: float) -> np.ndarray:
    h, w = SIZE
    m = cv2.getRotationMatrix2D((w * 1.5, h * 1.5), np.degrees(scene["omega"] * t), 1.0)
    m[:, 2] += (scene["velocity"][0] * t, scene["velocity"][1] * t)
    return m


def render(scene: dict, seed: int = 2) -> np.ndarray:
    """Events ``(N, 4)``: t (s), x, y, p, sorted by time."""
    h, w = SIZE
    rng = np.random.default_rng(seed)
    big = gaussian_filter(rng.random((h * 3, w * 3)), 2.0)
    big = ((big - big.min()) / (big.max() - big.min()) * 0.8 + 0.1).astype(np.float32)

    def log_frame(t):
        img = cv2.warpAffine(big, _transform(scene, t), (w * 3, h * 3),
                             flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
        return np.log(img[h:2 * h, w:2 * w] + 1e-2)

    first = log_frame(0.0)
    ref = first + rng.uniform(-0.5, 0.5, first.shape) * C
    ev = crossing_events(log_frame, first, ref, np.full(first.shape, C),
                         int(DURATION_S * RATE_HZ), RATE_HZ)
    return ev[np.argsort(ev[:, 0], kind="stable")]


def rendered_events(scene: dict):
    """:func:`render`'s events as an EventArray on ``SIZE``."""
    from evmotion.events import EventArray

    ev = render(scene)
    return EventArray(x=ev[:, 1].astype(np.uint16), y=ev[:, 2].astype(np.uint16),
                      t=np.round(ev[:, 0] * 1e6).astype(np.int64),
                      p=ev[:, 3].astype(np.uint8), sensor_size=SIZE)


def exact_flow(scene: dict) -> np.ndarray:
    """(H, W, 2) px/s: the motion is stationary, the same at every time."""
    h, w = SIZE
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    cx, cy = w * 1.5 - w, h * 1.5 - h
    om = scene["omega"]
    # cv2's positive angle turns the image counter-clockwise on screen (y down)
    u = scene["velocity"][0] + om * (yy - cy)
    v = scene["velocity"][1] - om * (xx - cx)
    return np.stack([u, v], -1)


def main(quick: bool = False) -> list[dict]:
    from evmotion.methods import multicm

    rows = []
    for name, scene in SCENES.items():
        events = rendered_events(scene)
        gt = exact_flow(scene)
        speed = float(np.linalg.norm(gt, axis=-1).max())
        mid = int(np.median(events.t))
        for disp in DISPLACEMENTS[:2] if quick else DISPLACEMENTS:
            half = int(0.5e6 * disp / speed)
            full = events.slice_time(mid - half, mid + half)
            win = full[np.linspace(0, len(full) - 1, N_EVENTS).round().astype(np.int64)]
            dt = (int(win.t[-1]) - int(win.t[0])) * 1e-6
            hit = np.zeros(SIZE, bool)
            hit[win.y.astype(int), win.x.astype(int)] = True
            for variant, level in (("jitter", multicm.JITTER_TO_LEVEL), ("none", 0)):
                saved = multicm.JITTER_TO_LEVEL
                multicm.JITTER_TO_LEVEL = level
                try:
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        start = time.perf_counter()
                        res = multicm.estimate_flow(win)
                        seconds = time.perf_counter() - start
                finally:
                    multicm.JITTER_TO_LEVEL = saved
                err = np.linalg.norm((res.flow - gt) * dt, axis=-1)
                rows.append({"scene": name, "disp_px": disp, "variant": variant,
                             "AEE_events_px": float(err[hit].mean()),
                             "AEE_valid_px": float(err[res.valid].mean())
                             if res.valid.any() else "",
                             "zero_AEE_px": float((np.linalg.norm(gt, axis=-1) * dt)[hit].mean()),
                             "valid_share": float(res.valid[hit].mean()),
                             "chance_gain": res.meta["chance_gain"], "seconds": seconds,
                             "window_events_before_subsampling": len(full)})
                print(rows[-1], flush=True)
    harness.record("multicm_sparse", rows, NOTES)
    return rows


if __name__ == "__main__":
    main()
