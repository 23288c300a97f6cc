"""multicm's problem of one window with one tile per pixel: the training loss' objective
(:mod:`.loss` wraps it for torch) and the IWEs and focus :func:`~.infer.estimate_flow_dnn`
reports, without torch."""

from __future__ import annotations

import numpy as np

from evmotion.core.tileflow import TileGrid
from evmotion.events import EventArray
from evmotion.methods.multicm import MultiCMProblem

__all__ = ["window_problem"]


def window_problem(events: EventArray, *, objective: str = "gradient_magnitude",
                   lam: float = 0.0025, references: str = "multi") -> MultiCMProblem:
    """multicm's problem of one window with one tile per pixel (unknowns: the dense flow
    ``(H, W, 2)`` in px per window).

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> ev = EventArray(x=rng.integers(0, 20, 500), y=rng.integers(0, 10, 500),
    ...                 t=np.arange(500), p=rng.integers(0, 2, 500), sensor_size=(10, 20))
    >>> window_problem(ev).grid.nx
    20
    """
    h, w = events.sensor_size
    t = np.asarray(events.t, dtype=np.int64)
    t0, t1 = int(t[0]), int(t[-1])
    s = (t - t0).astype(np.float64) / max(t1 - t0, 1)
    return MultiCMProblem(np.ascontiguousarray(events.x, dtype=np.float64),
                          np.ascontiguousarray(events.y, dtype=np.float64), s, (h, w),
                          TileGrid(h, w, (h, w)), objective=objective, lam=lam,
                          references=references, p=np.asarray(events.p),
                          duration_s=max(t1 - t0, 1) * 1e-6)
