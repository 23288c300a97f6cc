"""Synthetic BOS inputs straight from the linearized event generation model (6.9), for tests.

A random-dot frame, a curl-free displacement ``d = grad phi`` over the window (a sum of
Gaussian blobs of phi), the LEGM increment ``D = -grad L . d`` and events whose polarity sums
per pixel are ``round(D / C)``. ``frame_next`` is ``exp(L + D)``, consistent with the model.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter

from evmotion.events import EventArray


def random_dots(shape, rng, density=0.08, blur=0.8):
    """Relative intensity in [0.15, 1]: dark dots of 1-3 px on white."""
    h, w = shape
    img = np.ones(shape)
    n = int(density * h * w / 4)
    ys, xs = rng.integers(0, h, n), rng.integers(0, w, n)
    rad = rng.uniform(0.6, 1.6, n)
    yy, xx = np.mgrid[0:h, 0:w]
    for y, x, r in zip(ys, xs, rad, strict=True):
        y0, y1, x0, x1 = max(y - 3, 0), min(y + 4, h), max(x - 3, 0), min(x + 4, w)
        m = (yy[y0:y1, x0:x1] - y) ** 2 + (xx[y0:y1, x0:x1] - x) ** 2 <= r * r
        img[y0:y1, x0:x1][m] = 0.0
    img = gaussian_filter(img, blur)
    return 0.15 + 0.85 * img


def potential(shape, rng, n_blobs=4, amplitude=40.0, sigma=(12.0, 30.0)):
    """phi (px^2): Gaussian blobs; its gradient is the displacement in px."""
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    phi = np.zeros(shape)
    for _ in range(n_blobs):
        cy, cx = rng.uniform(0.2 * h, 0.8 * h), rng.uniform(0.2 * w, 0.8 * w)
        s = rng.uniform(*sigma)
        a = amplitude * rng.choice([-1, 1]) * rng.uniform(0.5, 1.0)
        phi += a * np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / (2 * s * s))
    return phi


def legm_case(shape=(128, 128), seed=0, C=0.1, amplitude=40.0, t0=0, t1=8333, n_blobs=4):
    """(events, frame, frame_next, d_true (H, W, 2) px over the window, C)."""
    rng = np.random.default_rng(seed)
    intensity = random_dots(shape, rng)
    L = np.log(intensity)
    phi = potential(shape, rng, n_blobs=n_blobs, amplitude=amplitude)
    dy, dx = np.gradient(phi)
    gy, gx = np.gradient(L)
    D = -(gx * dx + gy * dy)
    S = np.round(D / C).astype(np.int64)
    ys, xs = np.nonzero(S)
    counts = np.abs(S[ys, xs])
    ex = np.repeat(xs, counts)
    ey = np.repeat(ys, counts)
    ep = np.repeat((S[ys, xs] > 0).astype(np.uint8), counts)
    et = rng.integers(t0, t1, len(ex))
    order = np.argsort(et, kind="stable")
    ev = EventArray(x=ex[order], y=ey[order], t=et[order], p=ep[order], sensor_size=shape)
    frame_next = np.exp(L + D)
    d_true = np.stack([dx, dy], axis=-1)
    return ev, intensity, frame_next, d_true, C


def plume_scene(folder, intervals: int = 2):
    """A tiny simulated plume scene (48 x 40 px, ``intervals`` frame intervals) written to
    ``folder``: the input of the ``evmotion bos`` CLI tests."""
    from evmotion.sim.schlieren import simulate_schlieren, write_schlieren

    sim = simulate_schlieren("plume", sensor_size=(48, 40), duration_s=intervals / 120, seed=0)
    write_schlieren(sim, folder)
    return folder


def run_cli(argv, capsys):
    """``evmotion ARGV`` in this process: (exit code, stdout, stderr); argparse's rejections at
    parse time (SystemExit) give their exit code too."""
    from evmotion.cli import main

    try:
        rc = main([str(a) for a in argv])
    except SystemExit as exc:
        rc = exc.code
    cap = capsys.readouterr()
    return rc, cap.out, cap.err
