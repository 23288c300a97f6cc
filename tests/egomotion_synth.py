"""Exact synthetic events for any warp: dots of a reference image moved along the warp's
own point trajectories (so the true parameters maximize the contrast)."""

from __future__ import annotations

import numpy as np

from evmotion.core.warps import make_warp
from evmotion.events import EventArray

K240 = np.array([[200.0, 0, 119.5], [0, 200.0, 89.5], [0, 0, 1]])


def synth(warp_name: str, theta, n_events: int = 12000, n_dots: int = 400,
          duration_s: float = 0.05, shape=(180, 240), seed: int = 0, margin: float = 40.0):
    """(EventArray, warp): events at ``x = M(dt)^-1 x_ref`` for random dots ``x_ref``."""
    rng = np.random.default_rng(seed)
    w = make_warp(warp_name, shape, K=K240 if warp_name == "rotation" else None)
    h, wd = shape
    dots = np.stack([rng.uniform(margin, wd - margin, n_dots),
                     rng.uniform(margin, h - margin, n_dots), np.ones(n_dots)], axis=1)
    k = rng.integers(0, n_dots, n_events)
    t_us = np.sort(rng.integers(0, int(duration_s * 1e6), n_events))
    M, _ = w.matrices(t_us * 1e-6, np.asarray(theta, dtype=float))
    p = np.linalg.solve(M, dots[k][:, :, None])[:, :, 0]
    x, y = p[:, 0] / p[:, 2], p[:, 1] / p[:, 2]
    keep = (x >= 0) & (x <= wd - 1) & (y >= 0) & (y <= h - 1)
    ev = EventArray(x[keep].astype(np.float32), y[keep].astype(np.float32), t_us[keep],
                    rng.integers(0, 2, int(keep.sum())), sensor_size=shape, validate=False)
    return ev, w
