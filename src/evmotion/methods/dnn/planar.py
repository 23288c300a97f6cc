"""A planar-motion alternative to the network's flow, kept where the training loss prefers it.

The network's flow is dense and noisy (AEE 0.68-1.57 px on bench_dnn's held-out rigid
windows, multicm's 0.08-0.52; ``benchmarks/results/dnn.md``), and that noise gathers events
into pixels: it warps the events sharper than multicm's flow does (translation window: FWL
2.47 against 2.37), so sharpness alone cannot tell it from a better flow. The Charbonnier
smoothness of the training loss can: on windows whose motion is the camera's over a
mostly planar or distant scene (rotation, zoom, pan), an 8-parameter field fitted to the
network's flow and polished on the multi-reference focus has a lower loss (4.9) than the
network's own flow and a far lower error; where an object moves on its own, the network's
flow keeps the lower loss and the plane is not kept (the flow's refinement on multicm's
tiles may be, :mod:`.tiles`; ``benchmarks/results/dnn.md``, ``dnn_planar.md``).

The field is the instantaneous motion of a plane seen by a pinhole camera (the 8-parameter
"pseudo-perspective" flow, exact for any small rotation, zoom and translation in front of
a plane), in centred coordinates ``x = (col - (W - 1) / 2) / (W / 2)``,
``y = (row - (H - 1) / 2) / (W / 2)``::

    u = a0 + a2 x + a3 y + a6 x^2 + a7 x y
    v = a1 + a4 x + a5 y + a6 x y + a7 y^2

in px over the window. Everything here is numpy: neither a numba kernel to compile nor
torch to import in a one-window command. :func:`window_loss` is multicm's
objective (4.9) of a dense flow, the same number as
``evmotion.methods.dnn.problem.window_problem(events).value_grad`` (tested to 1e-9).
"""

from __future__ import annotations

import math

import numpy as np

from evmotion.core.tilegrid import charbonnier_tv
from evmotion.events import EventArray
from evmotion.methods.dnn.bfgs import bfgs
from evmotion.methods.dnn.focus import (
    binned_shape,
    identity_focus,
    multi_focus,
    window_times,
)

__all__ = ["binning", "event_flow", "fit_planar", "planar_flow", "polish_planar",
           "translation_start", "window_loss"]

#: TV weight of the loss that chooses (multicm's and the training loss' default).
LAM = 0.0025
#: Charbonnier epsilon of the TV, 1/s (multicm's ``TV_EPS``).
TV_EPS = 1e-2
#: Evaluations of the focus and its gradient the polish makes at most (on bench_dnn's
#: windows 20 left ECD shapes_rotation's FWL at 3.85, 28 and 36 reached 3.97 / 3.96).
POLISH_EVALUATIONS = 28
#: The first evaluations of the polish, after which a field whose loss is still this many
#: times the network's flow's is given up: on bench_dnn's windows (measured with scipy's
#: BFGS, 4 iterations, about 5 evaluations) the fields kept were at 0.70-0.99, those of
#: the independently moving object at 1.17-1.26 (ending at 1.10-1.24), whose further
#: iterations cost ~1 s.
PROBE_EVALUATIONS = 5
PROBE_RATIO = 1.1
N_PARAMS = 8
#: The most pixels the focus is measured on; a larger sensor's events are binned k x k
#: (k the least integer that brings it under): the image terms cost the polish most of
#: its time, and at 1280x720 took 2 s of a one-window command.
MAX_PIXELS = 120_000
#: The most events the polish and the decision look at (evenly spaced in the window): the
#: network's windows are 30-40k events; a 300k-event 1280x720 window's 28 evaluations
#: took 9.0 s, 1.3 s on 50k of its events (with other work on the machine).
MAX_EVENTS = 50_000


def binning(shape: tuple[int, int]) -> int:
    """The binning ``k`` of the focus images on a sensor of ``shape`` (1 up to
    :data:`MAX_PIXELS` pixels; 346x260 is 1, 640x480 2, 1280x720 3).

    Examples
    --------
    >>> binning((260, 346)), binning((480, 640)), binning((720, 1280))
    (1, 2, 3)
    """
    return max(1, math.ceil(math.sqrt(shape[0] * shape[1] / MAX_PIXELS)))


def _normalized(x, y, shape: tuple[int, int]):
    h, w = shape
    half = w / 2.0
    return (np.asarray(x, np.float64) - (w - 1) / 2.0) / half, \
        (np.asarray(y, np.float64) - (h - 1) / 2.0) / half


def _basis(x, y, shape: tuple[int, int]) -> np.ndarray:
    """(N, 2, 8): the field's (u, v) at the points for each unit parameter."""
    xn, yn = _normalized(x, y, shape)
    one, zero = np.ones_like(xn), np.zeros_like(xn)
    u = np.stack([one, zero, xn, yn, zero, zero, xn * xn, xn * yn], -1)
    v = np.stack([zero, one, zero, zero, xn, yn, xn * yn, yn * yn], -1)
    return np.stack([u, v], 1)


def planar_flow(params, shape: tuple[int, int]) -> np.ndarray:
    """The field of ``params`` (8,) on the pixel grid, (H, W, 2) float32 px.

    Examples
    --------
    >>> planar_flow([1.5, -2, 0, 0, 0, 0, 0, 0], (2, 3))[1, 2].tolist()
    [1.5, -2.0]
    >>> zoom = planar_flow([0, 0, 1, 0, 0, 1, 0, 0], (3, 4))   # outwards from the centre
    >>> bool(zoom[0, 0, 0] < 0 < zoom[0, -1, 0])
    True
    """
    h, w = shape
    a = np.asarray(params, np.float64)
    # on the grid's axes, broadcast (the (H*W, 2, 8) basis took 0.3 s at 1280x720)
    xn, yn = _normalized(np.arange(w), np.arange(h)[:, None], shape)
    out = np.empty((h, w, 2), np.float32)
    out[..., 0] = a[0] + a[2] * xn + a[3] * yn + a[6] * xn * xn + a[7] * xn * yn
    out[..., 1] = a[1] + a[4] * xn + a[5] * yn + a[6] * xn * yn + a[7] * yn * yn
    return out


def _event_pixels(events: EventArray) -> tuple[np.ndarray, np.ndarray]:
    """Each event's nearest pixel ``(column, row)``, clipped to the sensor."""
    h, w = events.sensor_size
    return (np.clip(np.rint(events.x), 0, w - 1).astype(np.intp),
            np.clip(np.rint(events.y), 0, h - 1).astype(np.intp))


def fit_planar(events: EventArray, disp: np.ndarray) -> np.ndarray:
    """Least-squares parameters (8,) of the field closest to ``disp`` (H, W, 2, px over
    the window) at the events' pixels, one equation per event.

    Examples
    --------
    >>> ev = EventArray(x=[0, 5, 9, 2], y=[0, 3, 7, 6], t=[0, 1, 2, 3], p=[1, 1, 0, 0],
    ...                 sensor_size=(8, 10))
    >>> true = [0.5, 1.0, 0.2, 0.0, 0.0, 0.2, 0.0, 0.0]
    >>> np.round(fit_planar(ev, planar_flow(true, (8, 10))), 4).tolist()[:3]
    [0.5, 1.0, 0.2]
    """
    xi, yi = _event_pixels(events)
    a = _basis(xi, yi, events.sensor_size).reshape(-1, N_PARAMS)
    return np.linalg.lstsq(a, disp[yi, xi].astype(np.float64).reshape(-1), rcond=None)[0]


def translation_start(events: EventArray, disp: np.ndarray) -> np.ndarray:
    """The parameters (8,) of the translation by the median of ``disp`` (H, W, 2, px over
    the window) at the events' pixels: a start for :func:`polish_planar` that a noisy
    flow does not bend.

    Examples
    --------
    >>> ev = EventArray(x=[0, 5, 9, 2], y=[0, 3, 7, 6], t=[0, 1, 2, 3], p=[1, 1, 0, 0],
    ...                 sensor_size=(8, 10))
    >>> disp = np.zeros((8, 10, 2)); disp[..., 0] = 3.0; disp[0, 0] = (40.0, -9.0)
    >>> translation_start(ev, disp).tolist()
    [3.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    """
    xi, yi = _event_pixels(events)
    out = np.zeros(N_PARAMS)
    out[:2] = np.median(disp[yi, xi].astype(np.float64), axis=0)
    return out


def event_flow(disp: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The dense flow bilinear between pixel centres at each event (clamped at the edges),
    as multicm's pixel tiles interpolate it."""
    h, w = disp.shape[:2]
    xc = np.clip(x, 0.0, w - 1.0)
    yc = np.clip(y, 0.0, h - 1.0)
    x0 = np.minimum(np.floor(xc).astype(np.intp), max(w - 2, 0))
    y0 = np.minimum(np.floor(yc).astype(np.intp), max(h - 2, 0))
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    fx, fy = (xc - x0)[:, None], (yc - y0)[:, None]
    d = disp.astype(np.float64)
    return ((1 - fy) * ((1 - fx) * d[y0, x0] + fx * d[y0, x1])
            + fy * ((1 - fx) * d[y1, x0] + fx * d[y1, x1]))


def window_loss(events: EventArray, disp: np.ndarray, lam: float = LAM, binning: int = 1
                ) -> float:
    """multicm's objective (4.9), ``1 / focus + lam * TV``, of the dense displacement
    ``disp`` (H, W, 2, px over the window): the network's training loss on one window
    (lower is better); inf where the unwarped events' image has no contrast. With
    ``binning`` k > 1 the focus is measured on the events' images binned k x k (the TV on
    the pixels).

    Examples
    --------
    >>> ev = EventArray(x=[3, 4, 5, 6], y=[2, 2, 2, 2], t=[0, 10, 20, 30], p=[1, 1, 1, 1],
    ...                 sensor_size=(5, 10))
    >>> right = planar_flow([3, 0, 0, 0, 0, 0, 0, 0], (5, 10))   # 3 px per window
    >>> window_loss(ev, right) < window_loss(ev, np.zeros_like(right))
    True
    """
    x = np.asarray(events.x, np.float64)
    y = np.asarray(events.y, np.float64)
    duration_s = max(int(events.t[-1] - events.t[0]), 1) * 1e-6
    flow = event_flow(disp, x, y) / binning
    xb, yb = x / binning, y / binning
    shape = binned_shape(events.sensor_size, binning)
    g0 = identity_focus(xb, yb, shape)
    if not g0 > 0:  # no contrast to measure (a sensor under 3 px a side, one pixel)
        return float("inf")
    f = multi_focus(xb, yb, window_times(events), flow, shape, g0)
    # (multicm's TV on pixel tiles: the mean over pixels)
    tv = charbonnier_tv(disp.astype(np.float64), (1.0, 1.0), duration_s, TV_EPS,
                        grad=False)[0]
    return 1.0 / max(f, 1e-12) + lam * tv


def polish_planar(events: EventArray, params, evaluations: int = POLISH_EVALUATIONS,
                  binning: int = 1) -> np.ndarray:
    """The parameters (8,) that maximize the multi-reference focus (4.6) of the events,
    by BFGS from ``params`` (e.g. :func:`fit_planar` of the network's flow); with
    ``binning`` k > 1, the focus of the events' images binned k x k (the parameters stay
    in px of the sensor).

    Examples
    --------
    >>> rng = np.random.default_rng(1)
    >>> n = 4000
    >>> t = np.sort(rng.integers(0, 10_000, n)); x0 = rng.choice([5, 17, 30], n)  # 3 edges
    >>> ev = EventArray(x=np.rint(x0 + 8e-4 * t), y=rng.integers(0, 30, n), t=t,
    ...                 p=np.ones(n, int), sensor_size=(30, 60))    # 8 px over the window
    >>> round(float(polish_planar(ev, [6, 0, 0, 0, 0, 0, 0, 0])[0]), 1)
    8.0
    """
    h, w = events.sensor_size
    x = np.asarray(events.x, np.float64)
    y = np.asarray(events.y, np.float64)
    k = int(binning)
    # in float32: half the traffic of float64, the same fields within 1e-3 px on
    # bench_dnn's windows; the loss that decides (window_loss) is float64
    basis = (_basis(x, y, (h, w)) / k).astype(np.float32)
    tx, ty = ((a / k).astype(np.float32) for a in (x, y))
    ts = window_times(events).astype(np.float32)
    start = np.asarray(params, np.float64)
    shape = binned_shape((h, w), k)
    g0 = identity_focus(tx, ty, shape)
    if not g0 > 0:
        return start

    def fun_grad(p):
        f, df = multi_focus(tx, ty, ts, basis @ p.astype(np.float32), shape, g0, grad=True)
        return -f, -np.einsum("nci,nc->i", basis, df, dtype=np.float64)

    out = bfgs(fun_grad, start, int(evaluations))
    return out if np.isfinite(out).all() else start
