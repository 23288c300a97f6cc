"""Schlieren scenes rendered independently of ``evmotion.sim``: ECD-style folders with the
exact flow, for checking ``evmotion bos FOLDER`` on data its own simulator did not make.

Nothing here imports evmotion. The background is a field of Gaussian dots drawn on a 4x
supersampled grid and resampled with OpenCV's bicubic ``remap``; the air is a train of
Gaussian blobs of a potential ``phi`` (px^2) that rise (``plume``) or cross the image
(``jet``), and the frame at pixel ``x`` shows the background at ``x - grad phi``. Events
come from the log radiance sampled at ``rate_hz``: a pixel fires each time its log radiance
moves one contrast threshold (its own, Gaussian mismatch) from its reference, with the time
interpolated linearly inside the step, plus uniform background noise events. Frames average
the radiance over their exposure (centred on the frame's time), with Poisson shot noise, quantized to 8 or 16 bits.

The truth is the flow of every frame interval, ``(grad phi(t1) - grad phi(t0)) / (t1 - t0)``
in px/s -- the evmotion simulator's convention, derived here from the same definition.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from scipy.ndimage import gaussian_filter

SUPERSAMPLE = 4
MARGIN = 8  # px of background beyond each border, for displaced samples near the edges


def _background(shape, rng, density, dot_sigma):
    h, w = shape
    s = SUPERSAMPLE
    hi = np.zeros(((h + 2 * MARGIN) * s, (w + 2 * MARGIN) * s), np.float32)
    n = int(density * hi.size / s**2)
    np.add.at(hi, (rng.integers(0, hi.shape[0], n), rng.integers(0, hi.shape[1], n)), 1.0)
    sig = dot_sigma * s
    hi = gaussian_filter(hi, sig) * np.float32(2 * np.pi * sig**2)  # peak 1 per dot
    return np.clip(0.9 - 0.75 * hi, 0.05, 1.0).astype(np.float32)


def _blobs(scene, shape, duration_s, rng, blob_px, speed):
    """(birth s, sigma px, signed weight, phase, speed px/s) of the air's blobs."""
    h, w = shape
    span = (h if scene == "plume" else w) + 6 * blob_px[1]
    births = np.arange(-span / speed, duration_s, 1.5 * blob_px[0] / speed)
    sig = rng.uniform(*blob_px, births.size)
    sign = np.where(rng.random(births.size) < 0.75, 1.0, -0.6)
    return births, sig, sign, rng.uniform(0, 2 * np.pi, births.size), speed


def _displacement(t, scene, shape, blobs, amp):
    """``grad phi`` (H, W, 2) in px at time ``t``."""
    h, w = shape
    births, sig, sign, phase, speed = blobs
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    d = np.zeros((h, w, 2), np.float32)
    if scene == "shift":  # the whole view moves at ``speed`` px/s, 30 degrees below x
        d[..., 0], d[..., 1] = speed * t * np.cos(np.pi / 6), speed * t * np.sin(np.pi / 6)
        return d
    for b, s, a, ph in zip(births, sig, sign, phase, strict=True):
        age = t - b
        if scene == "plume":
            cx, cy = 0.5 * w + 0.05 * w * np.sin(7.0 * t + ph), h + 3 * s - speed * age
        else:
            cx, cy = -3 * s + speed * age, 0.5 * h + 0.05 * h * np.sin(9.0 * t + ph)
        if not (-4 * s < cx < w + 4 * s and -4 * s < cy < h + 4 * s):
            continue
        # phi = A s^2 exp(-r^2 / 2 s^2): its gradient peaks at amp * a px
        g = (amp * a * np.exp(0.5)) * np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * s * s))
        d[..., 0] -= g * (xx - cx) / s
        d[..., 1] -= g * (yy - cy) / s
    return d


def crossing_events(log_at, log_first: np.ndarray, ref: np.ndarray, c: np.ndarray,
                    steps: int, rate_hz: float) -> np.ndarray:
    """Events ``(N, 4)`` of ``t`` (s), ``x``, ``y``, ``p`` (0/1), in step order: the log
    intensity ``log_at(t)`` sampled at ``rate_hz`` from ``log_first`` (its value at 0); a
    pixel fires each time it moves its threshold ``c`` (per pixel) from its reference
    ``ref`` (updated in place), the time interpolated linearly inside the step."""
    chunks = [np.zeros((0, 4))]
    log_prev = log_first
    for i in range(1, steps + 1):
        log_now = log_at(i / rate_hz)
        for sign in (1.0, -1.0):
            while True:
                yi, xi = np.nonzero(sign * (log_now - ref) >= c)
                if yi.size == 0:
                    break
                level = ref[yi, xi] + sign * c[yi, xi]
                frac = (level - log_prev[yi, xi]) / (log_now[yi, xi] - log_prev[yi, xi])
                t = (i - 1 + np.clip(frac, 0.0, 1.0)) / rate_hz
                chunks.append(np.stack([t, xi, yi, np.full(yi.size, sign > 0)], 1))
                ref[yi, xi] = level
        log_prev = log_now
    return np.concatenate(chunks)


def render_scene(folder, *, scene: str = "plume", size=(300, 400), duration_s: float = 0.3,
                 fps: float = 100.0, contrast: float = 0.15, contrast_sigma: float = 0.02,
                 magnitude_px: float = 1.5, rate_hz: float = 4000.0, density: float = 0.08,
                 dot_sigma: float = 0.8, bits: int = 8, noise_hz: float = 0.2,
                 full_well: float = 5000.0, exposure_s: float = 0.004,
                 blob_px: tuple[float, float] = (18.0, 27.0), speed_px_s: float = 360.0,
                 seed: int = 0) -> dict:
    """Write an ECD-style folder (``events.txt`` ``t x y p`` with p in {0, 1}, ``images.txt``
    ``t path`` lines, ``images/*.png``) and return its truth: ``flow`` (N-1, H, W, 2) px/s,
    ``t_s`` (N,) frame times, ``contrast``, ``events`` (their number) and ``velocity_px_s``
    (the blobs' (u, v): the plume rises, the jet crosses to the right). ``shift``: no
    still air, the whole view moves at ``speed_px_s``."""
    if scene not in ("plume", "jet", "shift"):
        raise ValueError(f"scene must be 'plume', 'jet' or 'shift', got {scene!r}")
    folder = Path(folder)
    (folder / "images").mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    h, w = size
    bg = _background(size, rng, density, dot_sigma)
    blobs = _blobs(scene, size, duration_s, rng, blob_px, speed_px_s)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)

    def radiance(t):
        d = _displacement(t, scene, size, blobs, magnitude_px)
        s = SUPERSAMPLE
        mx = (xx - d[..., 0] + MARGIN) * s + (s - 1) / 2
        my = (yy - d[..., 1] + MARGIN) * s + (s - 1) / 2
        # bicubic undershoot at dots finer than a pixel is no radiance (it had made the
        # shot noise's Poisson draw raise)
        return np.maximum(cv2.remap(bg, mx, my, cv2.INTER_CUBIC), 0.0)

    c = np.clip(contrast + contrast_sigma * rng.standard_normal(size), 0.3 * contrast,
                None).astype(np.float32)
    log_first = np.log(radiance(0.0) + 1e-3)
    ref = log_first + rng.uniform(-0.5, 0.5, size).astype(np.float32) * c
    chunks = [crossing_events(lambda t: np.log(radiance(t) + 1e-3), log_first, ref, c,
                              int(round(duration_s * rate_hz)), rate_hz)]
    n_noise = int(noise_hz * h * w * duration_s)
    chunks.append(np.stack([rng.uniform(0, duration_s, n_noise), rng.integers(0, w, n_noise),
                            rng.integers(0, h, n_noise), rng.integers(0, 2, n_noise)], 1))
    ev = np.concatenate(chunks)
    ev = ev[np.argsort(ev[:, 0], kind="stable")]
    with open(folder / "events.txt", "w") as f:
        f.writelines(f"{t:.9f} {int(x)} {int(y)} {int(p)}\n" for t, x, y, p in ev)

    n_frames = int(np.floor(duration_s * fps + 1e-9)) + 1
    t_s = np.arange(n_frames) / fps
    full = 2**bits - 1
    lines = []
    for k, t in enumerate(t_s):
        sub = np.linspace(t - exposure_s / 2, t + exposure_s / 2, 5)  # centred on t
        mean = np.mean([radiance(s) for s in sub], axis=0)
        img = np.clip(np.round(rng.poisson(mean * full_well) / full_well * full), 0, full)
        name = f"images/frame_{k:05d}.png"
        cv2.imwrite(str(folder / name), img.astype(np.uint8 if bits == 8 else np.uint16))
        lines.append(f"{t:.6f} {name}\n")
    (folder / "images.txt").write_text("".join(lines))
    disp = [_displacement(t, scene, size, blobs, magnitude_px) for t in t_s]
    flow = np.stack([(disp[k + 1] - disp[k]) * fps for k in range(n_frames - 1)])
    velocity = {"plume": (0.0, -speed_px_s), "jet": (speed_px_s, 0.0),
                "shift": tuple(speed_px_s * np.array([np.cos(np.pi / 6), np.sin(np.pi / 6)]))
                }[scene]
    return {"flow": flow, "t_s": t_s, "contrast": contrast, "events": len(ev),
            "velocity_px_s": velocity}
