"""The network's flow refined on multicm's finest tiles, kept where the training loss
prefers it and the events' image at the window's middle is no blurrier.

Where no plane explains a window (:mod:`.planar`: an object moving on its own, a scene
of several depths), the network's dense flow is what remains, and it is a start, not an
optimum of its own loss: on bench_dnn's held-out window with an independently moving
object its loss (4.9) was 0.209 against multicm's 0.189, its AEE 3.75 px against 2.52.
Averaged over the events of each of multicm's finest tiles (16 x 16 from 25.6k events,
:func:`~evmotion.methods.multicm.auto_finest_level`) and polished there by BFGS on
multicm's own objective -- the focus of :mod:`.focus` plus the Charbonnier TV of the
tiles, equal to :class:`~evmotion.methods.multicm.MultiCMProblem`'s value and gradient
(tested) -- it reaches 2.87 px on that window and 2.54-2.98 px on three other seeds' (the
network: 3.72-4.33), in about 25 evaluations. Where those tile means blur what the
network saw, the tiles are instead a correction added to the network's flow, which keeps
its detail finer than a tile (``refine_tiles(..., base=flow)``;
:func:`~evmotion.methods.dnn.infer.estimate_flow_dnn` tries it where the first is not kept).

A few hundred unknowns started from a flow far from the motion can settle where the loss
is low because the flow is smooth, not because it is sharp: on real windows moving 75-87
px, further than the network was trained for, a refinement by scipy's L-BFGS-B (20
iterations, while this was built) brought the loss from 0.20-0.23 to about 0.06 while the
image of the events warped to the middle of the window blurred (DAVIS346: FWL 2.21 ->
1.73, multicm 3.40). So the refinement is kept only where it lowers the loss *and* does
not lower the sharpness (:func:`~evmotion.methods.dnn.infer.sharpness`, the criterion
the network's input scales and gains are chosen by) of the flow it replaces.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from evmotion.core.tilegrid import TileGrid, charbonnier_tv, event_weights, tile_means
from evmotion.events import EventArray
from evmotion.methods.dnn.bfgs import bfgs
from evmotion.methods.dnn.focus import (
    binned_shape,
    identity_focus,
    multi_focus,
    window_times,
)
from evmotion.methods.dnn.planar import LAM, TV_EPS, event_flow

__all__ = ["REFINE_EVALUATIONS", "refine_tiles", "tile_loss_grad"]

#: Evaluations of the loss and its gradient the refinement makes at most (scipy's
#: L-BFGS-B with multicm's 20 iterations took 21-30 on bench_dnn_planar's windows, to
#: the same AEE within 2 % on the moving-object windows). 15, not 25: on bench_dnn's
#: simulated windows the same AEE (the object's 2.82 px against 2.87) and FWL on the
#: twelve ECD windows, and 1.1 s less of a 40k-event 346 x 260 window's one-window
#: command, which two refinements of 25 had taken to 7 s (probe AV).
REFINE_EVALUATIONS = 15
#: Length of the first step (px over the window, the largest tile move): the plane's.
STEP_PX = 0.5


class _Problem(NamedTuple):
    """The arrays of the objective on one grid."""

    x: np.ndarray            # positions (N,), binned
    y: np.ndarray
    s: np.ndarray            # times, fractions of the window
    idx: np.ndarray          # the events' bilinear stencil on the tiles (N, 4)
    w: np.ndarray            # its weights (N, 4), divided by the binning
    shape: tuple[int, int]   # of the (binned) images
    g0: float                # the identity warp's focus
    duration_s: float
    grid: TileGrid
    base: np.ndarray | None = None        # a dense flow at the events (N, 2), binned
    base_tiles: np.ndarray | None = None  # its means over the tiles' pixels (ny, nx, 2)


def _problem(events: EventArray, grid: TileGrid, binning: int,
             base: np.ndarray | None = None, dtype=np.float64) -> _Problem:
    x = np.asarray(events.x, np.float64)
    y = np.asarray(events.y, np.float64)
    idx, w = event_weights(x, y, grid)
    k = int(binning)
    shape = binned_shape(events.sensor_size, k)
    extra = ()
    if base is not None:
        # (the TV's share of base: its mean over each tile's pixels, as a tile without
        # events has a flow too)
        extra = ((event_flow(base, x, y) / k).astype(dtype),
                 tile_means(base, grid).astype(np.float64))
    xb, yb = (x / k).astype(dtype), (y / k).astype(dtype)
    return _Problem(xb, yb, window_times(events).astype(dtype), idx, (w / k).astype(dtype),
                    shape, identity_focus(xb, yb, shape),
                    max(int(events.t[-1] - events.t[0]), 1) * 1e-6, grid, *extra)


def _loss_grad(prob: _Problem, theta: np.ndarray, lam: float) -> tuple[float, np.ndarray]:
    """multicm's objective ``1 / focus + lam * TV`` of the tile flow ``theta`` (flat) and
    its gradient (flat)."""
    g = prob.grid
    p = theta.reshape(g.ny * g.nx, 2)
    flow = (prob.w[..., None] * p[prob.idx].astype(prob.w.dtype)).sum(1)  # px per window
    tiles = p.reshape(g.ny, g.nx, 2)
    if prob.base is not None:
        flow = flow + prob.base
        tiles = tiles + prob.base_tiles
    f, df = multi_focus(prob.x, prob.y, prob.s, flow, prob.shape, prob.g0, grad=True)
    f = max(f, 1e-12)
    tv, gtv = charbonnier_tv(tiles, g.spacing, prob.duration_s, TV_EPS)
    # the focus' gradient from the events to the tiles of their stencils
    dflow = -df / (f * f)
    n = g.ny * g.nx
    grad = np.stack([np.bincount(prob.idx.ravel(), (prob.w * dflow[:, c:c + 1]).ravel(),
                                 minlength=n) for c in range(2)], 1)
    return 1.0 / f + lam * tv, (grad + lam * gtv.reshape(n, 2)).ravel()


def tile_loss_grad(events: EventArray, params: np.ndarray, grid: TileGrid,
                   lam: float = LAM, binning: int = 1) -> tuple[float, np.ndarray]:
    """multicm's objective (4.9) of the tile flow ``params`` (ny, nx, 2, px over the
    window) on ``grid`` and its gradient (flat), in float64: the number
    ``MultiCMProblem(...).value_grad`` gives (multi-reference gradient magnitude, no
    time-aware warp). With ``binning`` k > 1 the focus is measured on the events' images
    binned k x k.

    Examples
    --------
    >>> ev = EventArray(x=[3, 4, 5, 6], y=[2, 2, 2, 2], t=[0, 10, 20, 30], p=[1, 1, 1, 1],
    ...                 sensor_size=(5, 10))
    >>> g = TileGrid(1, 2, (5, 10))
    >>> right = np.zeros((1, 2, 2)); right[..., 0] = 3.0   # 3 px per window
    >>> tile_loss_grad(ev, right, g)[0] < tile_loss_grad(ev, 0 * right, g)[0]
    True
    """
    prob = _problem(events, grid, binning)
    return _loss_grad(prob, np.asarray(params, np.float64).ravel(), lam)


def refine_tiles(events: EventArray, params: np.ndarray, grid: TileGrid,
                 evaluations: int = REFINE_EVALUATIONS, binning: int = 1,
                 base: np.ndarray | None = None) -> np.ndarray:
    """The tile flow (ny, nx, 2, px over the window) that lowers multicm's objective on
    ``grid``, by BFGS from ``params`` (e.g. the network's flow averaged over each tile's
    events, :func:`~evmotion.core.tileflow.event_tile_means`); with ``binning`` k > 1
    the focus of the images binned k x k. In float32 (the loss that decides whether it is
    kept is float64).

    With ``base``, a dense flow (H, W, 2, px over the window), the tiles are a correction
    added to it: the events move by ``base`` (bilinear between pixel centres) plus the
    tiles' field, the TV is that of the tiles plus ``base``'s means over their pixels, and
    the flow found is ``base + dense_flow(result)``. Started from zero, that is ``base``
    itself, detail finer than a tile included.

    Examples
    --------
    >>> t = np.arange(0, 10_000, 4)                 # two edges, 6 px right over the window
    >>> ev = EventArray(x=np.rint(10 + 6e-4 * t) + 15 * (t % 2), y=t % 20, t=t,
    ...                 p=np.ones(t.size, int), sensor_size=(20, 40))
    >>> out = refine_tiles(ev, np.full((1, 2, 2), [4.0, 0.0]), TileGrid(1, 2, (20, 40)))
    >>> out[0, :, 0].round(1).tolist()
    [6.1, 6.1]
    >>> base = np.zeros((20, 40, 2)); base[..., 0] = 4.0   # the same, as a correction
    >>> fix = refine_tiles(ev, np.zeros((1, 2, 2)), TileGrid(1, 2, (20, 40)), base=base)
    >>> (4.0 + fix[0, :, 0]).round(1).tolist()
    [6.1, 6.1]
    """
    start = np.asarray(params, np.float64)
    # in float32: half the traffic of float64, the same fields within 1e-3 px on
    # bench_dnn's windows (the loss that decides, window_loss, is float64)
    prob = _problem(events, grid, binning, base, np.float32)
    if not prob.g0 > 0:  # no contrast to measure
        return start
    out = bfgs(lambda p: _loss_grad(prob, p, LAM), start.ravel(), int(evaluations),
               step_px=STEP_PX)
    return out.reshape(start.shape) if np.isfinite(out).all() else start
