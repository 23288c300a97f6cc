"""Dense optical flow by multi-reference contrast maximization (thesis ch. 4).

Pipeline for one window of events (times ``t_1 .. t_N``, ``t_mid = (t_1 + t_N) / 2``):

* the flow at ``t_mid`` is a tile flow (:mod:`evmotion.core.tileflow`), estimated coarse to
  fine over ``n_scales`` grids of ``2^(l-1) x 2^(l-1)`` tiles, each scale initialized by
  bilinear upsampling of the previous one (and the coarsest from ``init``, e.g. the previous
  window: warm start of §4.2.4);
* events are warped to ``t_ref`` along the flow, ``x' = x + (t_ref - t_k) v(x_k)`` (4.4)
  or, time-aware, ``x' = x + (t_ref - t_k) v(x_k, t_k)`` (4.8), with the flow transported
  over ``n_bins`` time bins by :mod:`evmotion.methods.transport`. (The thesis writes
  ``t_k - t_ref``; with the flow pointing where the scene moves, as everywhere in
  evmotion, transporting an event back to ``t_ref`` needs ``t_ref - t_k``.) The flow is
  looked up at the event's sub-pixel position;
* the multi-reference focus ``f = (G(t_1) + 2 G(t_mid) + G(t_N)) / (4 G(0))`` (4.6) with
  ``G`` the mean squared IWE gradient (or the variance) is maximized through the composite
  objective ``1/f + lam * TV`` (4.9).

Optimizer: L-BFGS-B (scipy) with the analytic gradient, at most ``max_iter`` iterations
per scale (default 20), each tile's displacement over the window kept within the sensor's
longer side by a wall around the objective (:func:`_boxed`). From the 4 x 4-tile scale on,
a scale that starts from a flow (the coarser scale's, or ``init``) also stops when an
iteration lowers the objective by less than ``tol`` (see :func:`_scale_tol`).
``optimizer="newton-cg"`` runs scipy's Newton-CG with Hessian-vector products by central
differences of the analytic gradient, for comparison (see
``benchmarks/bench_multicm_accuracy.py``).

Flow where no event was seen is not a measurement. The result carries a validity mask
``valid``: the pixels with event support (:func:`evmotion.methods.flowresult.event_support`:
at least ``SUPPORT_MIN_EVENTS`` events within ``SUPPORT_RADIUS`` px; an isolated noise event
supports nothing), which the CLI writes next to the flow. The optimization is the
thesis' objective alone, so the tiles next to an empty region are free to fit the events
near them; the flow it extrapolates into empty regions (a near-static 1280x720 recording
gave up to 19,000 px/s there) is not returned: a pixel without support whose tile
neighbourhood (3 x 3 finest tiles) has support on less than ``EMPTY_TILE_SUPPORT`` of its
pixels is brought to rest in proportion (fully at rest where the neighbourhood has none).
An earlier version pulled such tiles to zero flow inside the objective instead, which also
dragged the supported tiles beside them (simulated translation: AEE 0.077 -> 0.099 px).

Internal units: flow in px per window, time as the fraction of the window; results are
converted to px/s.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit

from evmotion.catalog import MAX_TIME_BINS
from evmotion.core import tileflow as tf
from evmotion.core.objectives import events_value_grad, objective_value_grad
from evmotion.core.tilegrid import auto_finest_level, charbonnier_tv
from evmotion.errors import EmptyWindowError, ParameterError
from evmotion.events import EventArray, Window, as_window, require_events
from evmotion.jitcache import compile_seconds
from evmotion.methods import transport as tr
from evmotion.methods.flowresult import (
    SUPPORT_MIN_EVENTS,
    SUPPORT_RADIUS,
    FlowResult,
    aligned_support,
    estimate_or_skip,
    event_support,
)
from evmotion.methods.measured import (
    flow_alignment_chance,
    halves_consistency,
    other_motion,
    warn_by_chance,
    warn_by_refit,
    warn_flicker,
    warn_gap,
    warn_inconsistent_halves,
    warn_no_gain,
    warn_small_flow,
    warn_too_few_for_flow,
)
from evmotion.methods.options import merge_options
from evmotion.utils import check_switches, resolve_options, whole_number

__all__ = ["FlowResult", "MultiCMOptions", "MultiCMProblem", "auto_finest_level",
           "estimate_flow", "estimate_flow_sequence", "rest_where_empty"]

TV_EPS = 1e-2  # 1/s; Charbonnier smoothing of |grad v| so TV is differentiable at 0
RESTART_PX = 1.0  # px per window; see the restart in estimate_flow
#: Scales multicm still runs from the network's flow (``init="dnn"``): from the 4 x 4 tiles
#: on. With only the finest two, the network's errors (AEE 0.7-1.6 px on bench_dnn's
#: simulated windows) stayed in the result (translation 1.34x multicm's AEE); from 4 x 4
#: tiles the result matched multicm's within 5 % on all four scenes.
DNN_INIT_SCALES = 3
#: Coarsest level at which a scale may stop on a stalled objective (``tol``): 3 = 4 x 4 tiles.
TOL_FROM_LEVEL = 3
#: Finest level whose problem sees the events' coordinates with a seeded uniform sub-pixel
#: jitter (3 = 4 x 4 tiles; the finer scales, and always the finest, see them as
#: measured). Sensor coordinates are whole pixels (or, undistorted, one fixed point per
#: pixel), so under the zero flow the events of a pixel all vote in one place: that IWE
#: is sharper than under any flow of a pixel or two, a local optimum the coarse scales,
#: which start from zero, could not leave (single tile, 20 px of translation over a 30k
#: window of a fine texture: 0.07 px found). Jittered, the zero flow has no such edge;
#: the finer scales, started near the optimum, refine on the measured coordinates.
JITTER_TO_LEVEL = 3
#: The level (3 = 4 x 4 tiles) after which each tile's events are searched for a
#: translation of their own that sharpens them far more than the flow
#: (:func:`evmotion.core.tilesearch.tile_restarts`, within
#: :data:`evmotion.core.translation.TILE_REACH` of the sensor's longer side); the scale is
#: optimized again from there, and both starts go on to the finest scale, which keeps the
#: better objective. A region whose motion the coarse scales did not follow (an object's background
#: under the object's flow, probe BZ) is found there, not at the finer scales.
TILE_SEARCH_LEVEL = 3
#: Below this many events per finest tile, the result's focus is compared with what the
#: solver reaches on the same events with their times shuffled (:func:`_shuffled_focus`,
#: on its finest ``REFIT_SCALES`` scales, ``REFIT_MAX_ITER`` iterations each).
REFIT_EVENTS_PER_TILE = 64
REFIT_SCALES = 3
REFIT_MAX_ITER = 10
TIMESTAMP_OBJECTIVES = ("avg_timestamp", "avg_timestamp_norm")
OBJECTIVE_NAMES = ("gradient_magnitude", "variance", *TIMESTAMP_OBJECTIVES)
#: A pixel without event support whose tile neighbourhood (3 x 3 finest tiles) has support
#: on less than this fraction of its pixels is brought to rest in proportion: its flow is
#: scaled by ``fraction / EMPTY_TILE_SUPPORT`` (see :func:`rest_where_empty`).
EMPTY_TILE_SUPPORT = 0.02
REFERENCES = {
    "multi": ((0.0, 1.0), (0.5, 2.0), (1.0, 1.0)),
    "single": ((0.0, 1.0),),
}


# The fields of MultiCMOptions that MultiCMProblem reads (its keywords).
#: Cell size (px) of the grid the time-aware PDE runs on where none is given: the tile
#: flow is smooth at a tile's scale (>= 16 px), so 4 px cells resolve it at ~1/64 the cost.
TRANSPORT_CELL = 4

PROBLEM_OPTIONS = ("objective", "lam", "references", "time_aware", "n_bins", "transport_cell")


class MultiCMProblem:
    """The composite objective (4.9) of one window at one scale, with its gradient.

    Parameters
    ----------
    x, y : ndarray (N,) float64
        Event positions in px (sub-pixel allowed).
    s : ndarray (N,) float64
        Event times as the fraction of the window, ``(t - t_1) / (t_N - t_1)`` in [0, 1].
    shape : (H, W)
    grid : TileGrid
        The scale's tiles; the unknowns are tile flows ``(ny, nx, 2)`` in px per window.
    p : ndarray (N,), optional
        Polarities (0/1), needed by the average-timestamp objectives.
    g0 : float, optional
        ``G(0)`` of the identity warp (computed if not given; it does not depend on the
        scale, so :func:`estimate_flow` passes it on).
    duration_s : float
        Window duration ``t_N - t_1`` in seconds (default 1): the TV term is measured on
        the flow in px/s, so that its weight does not grow with the window's displacement.
    options : MultiCMOptions, optional
        The objective's tuning as one object (only the fields of ``PROBLEM_OPTIONS``
        apply; ``n_bins`` None means 5); then no keyword below may be given.
    **keywords
        ``objective``, ``lam``, ``references``, ``time_aware``, ``n_bins`` (default 5),
        ``transport_cell``: as in :func:`estimate_flow`.

    Examples
    --------
    >>> import numpy as np
    >>> x = np.array([10.0, 11.0, 12.0]); y = np.full(3, 5.0); s = np.array([0, .5, 1])
    >>> prob = MultiCMProblem(x, y, s, (10, 20), tf.TileGrid(1, 1, (10, 20)))
    >>> v0, _ = prob.value_grad(np.zeros(2)); v1, _ = prob.value_grad(np.array([2.0, 0]))
    >>> bool(v1 < v0)   # 2 px per window to the right aligns the three events
    True
    """

    def __init__(self, x, y, s, shape, grid, *, g0=None, p=None, duration_s=1.0,
                 options: MultiCMOptions | None = None, **keywords):
        unknown = sorted(set(keywords) - set(PROBLEM_OPTIONS))
        if unknown:
            raise ParameterError(f"MultiCMProblem() got unknown keyword(s) "
                                 f"{', '.join(unknown)}; its options are "
                                 f"{', '.join(PROBLEM_OPTIONS)}")
        o = resolve_options(MultiCMOptions, options, keywords, "MultiCMProblem")
        objective, time_aware = o.objective, o.time_aware
        n_bins = 5 if o.n_bins is None else o.n_bins
        self.x, self.y, self.s, self.shape, self.grid = x, y, s, shape, grid
        self.duration_s = float(duration_s)
        self.objective, self.lam = objective, o.lam
        self.refs = REFERENCES[o.references]
        self.wsum = sum(w for _, w in self.refs)
        self.time_aware = time_aware
        self.idx, self.w = tf.event_weights(x, y, grid)
        self.p = p
        self.dtn = [np.ascontiguousarray(tr_ - s) for tr_, _ in self.refs]
        if g0 is not None:
            self.g0 = g0
        elif objective in TIMESTAMP_OBJECTIVES:
            if p is None:
                raise ParameterError(f"objective {objective!r} needs the polarities p")
            self.g0 = self._ts_loss(np.zeros((x.size, 2)))[0]
        else:
            self.g0 = objective_value_grad(objective, tf.iwe_forward(
                x, y, np.zeros((x.size, 2)), np.zeros(x.size), shape))[0]
        if self.g0 <= 0:
            # (a 2 x 1000 px sensor was said to have too few events; probe CK)
            why = (f"an image of {shape[0]} x {shape[1]} px (H x W) has no gradient: 3 px "
                   "or more a side" if min(shape) < 3 else "too few events")
            raise EmptyWindowError(f"the identity-warp IWE has no contrast ({why})")
        if time_aware:
            self.n_bins = n_bins
            b = np.minimum((s * n_bins).astype(np.int64), n_bins - 1)
            self.bin_times = (np.arange(n_bins) + 0.5) / n_bins - 0.5
            # the PDE runs on a grid of ~transport_cell px cells, in cells per window
            h, w = shape
            cell = TRANSPORT_CELL if o.transport_cell is None else o.transport_cell
            self.tgrid = tf.TileGrid(max(1, round(h / cell)), max(1, round(w / cell)), shape)
            self.cell = np.array(self.tgrid.spacing)[::-1]  # (sx, sy)
            self.ay = tf.axis_matrix(self.tgrid.centers_y(), grid.ny, h)
            self.ax = tf.axis_matrix(self.tgrid.centers_x(), grid.nx, w)
            idx, wts = tf.event_weights(x, y, self.tgrid)
            self.tidx, self.tw, self.tbin = idx, wts, b

    # ----------------------------------------------------------------- event flow
    def event_flow(self, params):
        """Per-event flow (N, 2) in px/window, and the state needed by the adjoint."""
        if not self.time_aware:
            return tf.interpolate(params, self.idx, self.w), None
        dense = np.stack([self.ay @ params[..., c] @ self.ax.T / self.cell[c]
                          for c in range(2)])
        plan = tr.transport_to_times(dense, self.bin_times, self.time_aware)
        flow = np.empty((self.x.size, 2))
        _interp_bins(np.stack(plan.flows), self.tbin, self.tidx, self.tw, self.cell, flow)
        return flow, plan

    def _flow_adjoint(self, gflow, plan):
        if not self.time_aware:
            return tf.interpolate_adjoint(gflow, self.idx, self.w, self.grid)
        g = np.zeros((self.n_bins, 2, self.tgrid.ny, self.tgrid.nx))
        _interp_bins_adj(gflow, self.tbin, self.tidx, self.tw, self.cell, g)
        gd = tr.transport_adjoint(plan, list(g))
        return np.stack([self.ay.T @ gd[c] @ self.ax / self.cell[c] for c in range(2)], axis=-1)

    # ---------------------------------------------------------------- objective
    def _ts_loss(self, flow, with_grad=True):
        # average-timestamp losses L = -G of core.objectives, timestamps measured from
        # each reference time (|t_k - t_ref| / window), multi-reference weighted
        loss = 0.0
        gflow = np.zeros_like(flow)
        for (r, wt), dtn in zip(self.refs, self.dtn, strict=True):
            xw = self.x + dtn * flow[:, 0]
            yw = self.y + dtn * flow[:, 1]
            g, gx, gy = events_value_grad(self.objective, xw, yw, self.shape,
                                          polarity=self.p, tn=np.abs(self.s - r))
            loss -= wt / self.wsum * g
            gflow[:, 0] -= wt / self.wsum * dtn * gx
            gflow[:, 1] -= wt / self.wsum * dtn * gy
        return loss, gflow

    def focus_grad(self, params):
        """Multi-reference focus ``f`` (4.6), its gradient and the IWEs.

        For the average-timestamp objectives ``f = L(0) / L(theta)`` with ``L`` the
        multi-reference loss, so that ``1/f`` in (4.9) is the loss normalized by the zero
        flow's (and ``f > 1`` still means better than zero flow).
        """
        flow, plan = self.event_flow(params)
        if self.objective in TIMESTAMP_OBJECTIVES:
            loss, gl = self._ts_loss(flow)
            loss = max(loss, 1e-300)
            f = self.g0 / loss
            iwes = [tf.iwe_forward(self.x, self.y, flow, dtn, self.shape) for dtn in self.dtn]
            return f, self._flow_adjoint(gl * (-self.g0 / loss ** 2), plan), iwes
        f = 0.0
        gflow = np.zeros_like(flow)
        iwes = []
        for (_, wt), dtn in zip(self.refs, self.dtn, strict=True):
            iwe = tf.iwe_forward(self.x, self.y, flow, dtn, self.shape)
            val, giwe = objective_value_grad(self.objective, iwe)
            c = wt / (self.wsum * self.g0)
            f += c * val
            tf.iwe_bwd(self.x, self.y, flow, dtn, giwe * c, gflow)
            iwes.append(iwe)
        return f, self._flow_adjoint(gflow, plan), iwes

    def tv_grad(self, params):
        """Charbonnier TV of the tile flow and its gradient.

        ``TV = mean over tiles of sum over components of sqrt(gx^2 + gy^2 + eps^2)`` with
        ``gx``, ``gy`` the forward differences to the right/lower neighbouring tile of the
        flow in px/s divided by the tile spacing in px: the mean ``|grad v|`` over the
        image in 1/s. It does not depend on the sensor resolution, the number of tiles or
        the window duration (a flow field with a given spatial variation costs the same
        however long the window; measuring it on the displacement over the window instead
        made the regularizer outweigh the focus term on long windows, e.g. rotation at
        MVSEC-like dt = 4 was flattened towards a constant flow).
        """
        return charbonnier_tv(params, self.grid.spacing, self.duration_s, TV_EPS)

    def value_grad(self, theta):
        """Composite objective ``1/f + lam * TV`` (4.9) and its gradient (flat)."""
        params = theta.reshape(self.grid.ny, self.grid.nx, 2)
        f, gf, _ = self.focus_grad(params)
        f = max(f, 1e-12)
        tv, gtv = self.tv_grad(params)
        val = 1.0 / f + self.lam * tv
        grad = -gf / (f * f) + self.lam * gtv
        return val, grad.ravel()


def rest_where_empty(flow: np.ndarray, valid: np.ndarray, grid) -> np.ndarray:
    """Dense flow with the pixels of empty regions brought to rest.

    A pixel without event support (``~valid``) keeps its flow scaled by
    ``min(1, fraction / EMPTY_TILE_SUPPORT)``, ``fraction`` the share of supported pixels in
    its tile's 3 x 3 tile neighbourhood: a gap between events keeps the flow the
    optimization carried into it, a region far from any event is at rest instead of an
    extrapolation. Supported pixels are returned unchanged.

    Parameters
    ----------
    flow : ndarray (H, W, 2)
        Dense flow, px/s.
    valid : ndarray (H, W) bool
        Pixels with event support (:func:`evmotion.methods.flowresult.event_support`).
    grid : TileGrid
        The finest scale's tiles.

    Returns
    -------
    ndarray (H, W, 2)
        A new array of ``flow``'s dtype.

    Examples
    --------
    >>> flow = np.full((4, 40, 2), 10.0, np.float32)
    >>> valid = np.zeros((4, 40), bool); valid[:, :2] = True
    >>> out = rest_where_empty(flow, valid, tf.TileGrid(1, 10, (4, 40)))
    >>> out[0, [0, 5, 39], 0].tolist()  # supported, a neighbour of support, far from it
    [10.0, 10.0, 0.0]
    """
    out = flow.copy()
    if valid.all():
        return out
    frac = _box3(tf.tile_means(valid.astype(np.float64), grid))
    keep = np.clip(frac / EMPTY_TILE_SUPPORT, 0.0, 1.0)[tf.pixel_tiles(valid.shape, grid)]
    out[~valid] *= keep[~valid, None].astype(flow.dtype)
    return out


def _box3(a: np.ndarray) -> np.ndarray:
    """Mean over each cell's 3 x 3 neighbourhood (within the array)."""
    p = np.pad(a, 1)
    n = np.pad(np.ones_like(a), 1)
    s = sum(p[i:i + a.shape[0], j:j + a.shape[1]] for i in range(3) for j in range(3))
    c = sum(n[i:i + a.shape[0], j:j + a.shape[1]] for i in range(3) for j in range(3))
    return s / c


@njit(cache=True)
def _interp_bins(flows, tbin, idx, w, cell, out):
    # flows (n_bins, 2, hc, wc) in cells/window -> per-event px/window, bin by event time
    nx = flows.shape[3]
    for k in range(idx.shape[0]):
        b = tbin[k]
        u = 0.0
        v = 0.0
        for c in range(4):
            j = idx[k, c]
            u += w[k, c] * flows[b, 0, j // nx, j % nx]
            v += w[k, c] * flows[b, 1, j // nx, j % nx]
        out[k, 0] = u * cell[0]
        out[k, 1] = v * cell[1]


@njit(cache=True)
def _interp_bins_adj(g, tbin, idx, w, cell, out):
    nx = out.shape[3]
    for k in range(idx.shape[0]):
        b = tbin[k]
        gu = g[k, 0] * cell[0]
        gv = g[k, 1] * cell[1]
        for c in range(4):
            j = idx[k, c]
            out[b, 0, j // nx, j % nx] += w[k, c] * gu
            out[b, 1, j // nx, j % nx] += w[k, c] * gv


def _as_xy(events: EventArray):
    return (np.ascontiguousarray(events.x, dtype=np.float64),
            np.ascontiguousarray(events.y, dtype=np.float64))


def _init_params(init, grid, duration_s, shape):
    if init is None:
        return np.zeros((grid.ny, grid.nx, 2))
    if isinstance(init, FlowResult):
        if init.flow.shape[:2] != tuple(shape):
            # a result's flow is dense: of another sensor it is no start (it had been
            # read as tile params of its own size: probe)
            raise ParameterError(f"init is the result of a {init.flow.shape[1]}x"
                                 f"{init.flow.shape[0]} px (W x H) sensor; these events' "
                                 f"is {shape[1]}x{shape[0]}")
        init = init.flow
    init = np.asarray(init, dtype=np.float64)
    if init.ndim != 3 or init.shape[2] != 2:
        raise ParameterError(f"init must be a FlowResult, a dense flow (H, W, 2) or tile "
                             f"params (ny, nx, 2) in px/s; got shape {init.shape}")
    bad = ~np.isfinite(init)
    if bad.any():
        raise ParameterError(f"init has {int(bad.any(axis=-1).sum())} pixels or tiles with a "
                             "NaN or infinite flow: a warm start must be finite everywhere "
                             "(np.nan_to_num, or the previous result's flow)")
    h, w = shape
    if init.shape[0] > h or init.shape[1] > w:
        hint = (" (H and W swapped? a dense flow is (H, W, 2))"
                if init.shape[:2] == (w, h) else "")
        raise ParameterError(f"init of shape {init.shape} is neither the sensor's dense flow "
                             f"({h}, {w}, 2) nor tile params (at most the sensor){hint}")
    if init.shape[:2] == tuple(shape):
        p = tf.tile_means(init, grid)  # tile averages of the dense flow
    else:
        p = tf.resample(init, grid)
    return p * duration_s


@dataclass(frozen=True)
class MultiCMOptions:
    """Tuning of :func:`estimate_flow` (method ``"multicm"``), as one object (every field is
    also a keyword of the function, with the same default).

    Attributes
    ----------
    time_aware : {None, "upwind", "burgers"}
        Warp with the flow transported over time bins (4.8) instead of (4.4).
    n_scales : int
        Coarse-to-fine scales ending at ``finest_level``; scale ``l`` has
        ``2^(l-1) x 2^(l-1)`` tiles (5: 1x1 ... 16x16; 1: the finest only); at most the
        finest level chosen when ``finest_level`` is None.
    objective : {"gradient_magnitude", "variance", "avg_timestamp", "avg_timestamp_norm"}
        Focus of the IWEs (4.5 or 4.3), or the average-timestamp losses (Table 4.5).
    lam : float
        TV weight in (4.9), dimensionless (the flow enters as px per window).
    n_bins : int, optional
        Time bins of the time-aware flow (None: 5, or 40 for sensors >= 640 px wide).
    seed : int
        Seed of the sub-pixel jitter of the event coordinates on the coarse scales (up
        to ``JITTER_TO_LEVEL``); the same seed gives the same flow.
    max_iter : int
        Optimizer iterations per scale.
    tol : float
        A scale from ``TOL_FROM_LEVEL`` on that starts from a flow stops once an iteration
        lowers the objective by less than ``tol * max(|f|, 1)`` (L-BFGS-B's ``ftol``; 0:
        every scale runs ``max_iter`` iterations).
    references : {"multi", "single"}
        Multi-reference loss (t_1, t_mid, t_N) or single reference at t_1 (ablation).
    optimizer : {"lbfgs", "newton-cg"}
    time_aware_scales : int, optional
        Use the time-aware warp only on the finest this-many scales (None: all).
    finest_level : int, optional
        Level of the finest scale (5: 16 x 16 tiles). None: the finest level, at most
        ``AUTO_FINEST_LEVEL`` (5), whose tiles hold ``AUTO_EVENTS_PER_TILE`` (100) events
        on average (5 from 25,600 events on).
    transport_cell : int, optional
        Cell size of the grid the time-aware PDE runs on, px (1 = every pixel; None:
        ``TRANSPORT_CELL``, 4). Only with ``time_aware``.
    restart : bool
        At the first multi-tile scale, also optimize from the warm start (or zero flow) when
        the optimum moved more than ``RESTART_PX`` px from the single-tile flow, and keep the
        better optimum.

    Examples
    --------
    >>> opts = MultiCMOptions(time_aware="upwind", n_scales=3)
    >>> opts.lam
    0.0025
    """

    time_aware: str | None = None
    n_scales: int = 5
    objective: str = "gradient_magnitude"
    lam: float = 0.0025
    n_bins: int | None = None
    seed: int = 0
    max_iter: int = 20
    tol: float = 3e-5
    references: str = "multi"
    optimizer: str = "lbfgs"
    time_aware_scales: int | None = None
    finest_level: int | None = None
    transport_cell: int | None = None
    restart: bool = True

    def __post_init__(self):
        # what needs no window checked here: MultiCMOptions(lam="x") had constructed, to
        # fail at estimate_flow (probe CB); the rest in _checked, against the window
        for name in ("lam", "tol"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float, np.number)) and not isinstance(v, bool)):
                raise ParameterError(f"{name} must be a number, got {v!r}")
        # (lam = inf passed 'lam >= 0' and ended in numpy's invalid-value warnings: probe)
        for ok, need, got in ((0 <= self.lam < float("inf"), "0 <= lam < inf",
                               f"lam={self.lam}"),
                              (0 <= self.tol < 1, "0 <= tol < 1", f"tol={self.tol}")):
            if not ok:
                raise ParameterError(f"need {need}, got {got}")
        if self.time_aware not in (None, "none", "upwind", "burgers"):
            raise ParameterError(f"time_aware must be None, 'upwind' or 'burgers', "
                                 f"got {self.time_aware!r}")
        if self.objective not in OBJECTIVE_NAMES:
            raise ParameterError(f"objective must be one of {OBJECTIVE_NAMES}, got "
                                 f"{self.objective!r}")
        if self.references not in REFERENCES:
            raise ParameterError(f"references must be 'multi' or 'single', got "
                                 f"{self.references!r}")
        if self.optimizer not in ("lbfgs", "newton-cg"):
            raise ParameterError(f"optimizer must be 'lbfgs' or 'newton-cg', got "
                                 f"{self.optimizer!r}")


# what a caller who set nothing gets (method="dnn" refuses anything else)
MULTICM_DEFAULTS = MultiCMOptions()


def estimate_flow(events: EventArray, method: str = "multicm", *,
                  time_aware: str | None = None, n_scales: int = 5,
                  objective: str = "gradient_magnitude", lam: float = 0.0025,
                  n_bins: int | None = None, init=None, seed: int = 0, max_iter: int = 20,
                  tol: float = 3e-5, references: str = "multi", optimizer: str = "lbfgs",
                  time_aware_scales: int | None = None, finest_level: int | None = None,
                  transport_cell: int | None = None, restart: bool = True,
                  checkpoint=None, device: str = "cpu", threads: int | None = 1,
                  options: MultiCMOptions | None = None) -> FlowResult:
    """Dense optical flow of one event window by multi-reference contrast maximization.

    Parameters
    ----------
    events : EventArray
        One window; undistort first if needed. Under
        :func:`~evmotion.methods.measured.min_flow_events` events (1,000, fewer on a sensor
        under 20,000 px) it is no measurement (``valid`` all False, a PoorFitWarning).
    method : {"multicm", "dnn"}
        ``"dnn"``: the unsupervised EV-FlowNet (:mod:`evmotion.methods.dnn`; numpy runs
        the shipped network where torch is not imported, torch a ``model.pt`` or
        ``device="cuda"``: :func:`~evmotion.methods.dnn.infer.resolve_backend`) from
        ``checkpoint`` on ``device`` and ``threads``; the multicm options below must
        then be left at their defaults (:func:`evmotion.methods.dnn.estimate_flow_dnn` has
        the network's own: input scales, the plane, the refinement...).
    time_aware : {None, "upwind", "burgers"}
        Warp with the flow transported over time bins (4.8) instead of (4.4).
    n_scales : int
        Coarse-to-fine scales ending at ``finest_level``; scale ``l`` has
        ``2^(l-1) x 2^(l-1)`` tiles (default 5: 1x1 ... 16x16; 1: the finest only); at
        most the finest level when that is chosen from the window (``finest_level`` None).
    objective : {"gradient_magnitude", "variance", "avg_timestamp", "avg_timestamp_norm"}
        Focus of the IWEs (4.5 or 4.3), or the average-timestamp losses of Zhu et al. and
        Hagenaars et al. (Table 4.5 ablation; bilinear votes from :mod:`evmotion.core`).
    lam : float
        TV weight in (4.9) (default 0.0025).
    n_bins : int, optional
        Time bins of the time-aware flow (default 5, or 40 for sensors >= 640 px wide).
    init : FlowResult, ndarray or "dnn", optional
        Warm start: previous result, dense flow (H, W, 2) or tile flow (ny, nx, 2), px/s.
        ``"dnn"``: start from the network's flow (``checkpoint``; its plain pass at each
        input scale, the sharpest kept) and run only the finest
        ``min(n_scales, DNN_INIT_SCALES)`` scales (from 4 x 4 tiles by default): the
        coarse scales, which find the large displacements, are what the network
        replaces. Each tile of the first of them starts from the network's flow averaged
        over the tile's events.
    seed : int
        Seed of the sub-pixel jitter of the event coordinates on the coarse scales (see
        ``JITTER_TO_LEVEL``); the same seed gives the same flow.
    max_iter : int
        Optimizer iterations per scale (default 20).
    tol : float
        Stop a scale early once an iteration lowers the objective by less than
        ``tol * max(|f|, 1)`` (default 3e-5; 0: always ``max_iter`` iterations). It applies
        from the 4 x 4-tile scale on, to scales that start from a flow: from the zero flow
        the objective is nearly flat, and an early stop there misses the basin. The
        coarse scales have already placed the finer ones near their optimum: over 32
        simulated and ECD windows the stop cut multicm's CPU time to 0.67x (geometric
        mean) at 0.96x the AEE (worst 1.009x) and the same FWL (within 0.6 %); 1e-4
        stopped a large rotation short (AEE 1.17x) (``benchmarks/results/multicm_tol.md``).
    references : {"multi", "single"}
        Multi-reference loss (t_1, t_mid, t_N) or single reference at t_1 (ablation).
    optimizer : {"lbfgs", "newton-cg"}
    time_aware_scales : int, optional
        Use the time-aware warp only on the finest this-many scales (default: all).
    finest_level : int, optional
        Level of the finest scale (5: 16 x 16 tiles). Default: chosen from the window, the
        finest level up to 5 whose tiles hold at least ``AUTO_EVENTS_PER_TILE`` (100)
        events on average: 16 x 16 tiles from 25,600 events on, 8 x 8 from 6,400, 4 x 4
        from 1,600. A tile's flow fitted to a few dozen events follows their noise: on
        the ECD rotation windows thinned to 4k events the AEE fell from 1.47 / 1.92 px
        (16 x 16) to 0.88 / 1.17 px (``benchmarks/results/multicm_finest.md``). An
        independently moving object smaller than the coarser tiles loses detail: give
        ``finest_level=5`` for it.
    transport_cell : int, optional
        Cell size in px of the grid the time-aware PDE runs on (default None:
        ``TRANSPORT_CELL``, 4; 1 = every pixel); only with ``time_aware``. The tile flow is smooth at the scale of a tile (>= 16 px), so 4 px cells
        resolve it while cutting the cost ~64x (16x fewer cells, 4x fewer CFL sub-steps).
    restart : bool
        At the first scale with more than one tile, if its optimum moved away from the
        upsampled single-tile flow, also optimize from ``init`` (or zero flow) and keep
        the better optimum (default True; needed for large displacements of flows that
        are not translations, e.g. zoom over 20 px).
    checkpoint : path, optional
        Network weights for ``method="dnn"`` or ``init="dnn"`` (default: shipped).
    device, threads : str, int or None
        The network's torch device and threads for ``method="dnn"`` or ``init="dnn"``
        (default ``"cpu"``, one thread: :func:`~evmotion.methods.dnn.estimate_flow_dnn`);
        anything else without the network is an error.
    options : MultiCMOptions, optional
        The multicm options above (all but ``init`` and the network's) as one object; the
        keywords must then be left at their defaults.

    Returns
    -------
    FlowResult
        With ``valid``, the pixels whose flow events support. A flow that sharpens the
        events by less than 5 % (``focus`` under
        :data:`~evmotion.methods.diagnostics.MIN_CONTRAST_GAIN`: too few events, no motion)
        is no measurement: PoorFitWarning, ``valid`` all False, ``meta["no_focus"]`` True.

    Examples
    --------
    >>> import numpy as np
    >>> from evmotion.events import EventArray
    >>> rng = np.random.default_rng(0)
    >>> n = 4000
    >>> t = np.sort(rng.integers(0, 10_000, n))
    >>> x0 = rng.choice([20.0, 40.0], n); y0 = rng.uniform(5, 55, n)
    >>> ev = EventArray(x=np.round(x0 + 1000 * t * 1e-6), y=np.round(y0), t=t, p=np.ones(n),
    ...                 sensor_size=(64, 64))
    >>> res = estimate_flow(ev, n_scales=2, finest_level=2)
    >>> bool(abs(np.median(res.flow[..., 0]) - 1000) < 150)
    True
    """
    events = require_events(events, "estimate_flow", on_sensor=True)
    o = merge_options(MultiCMOptions, options, time_aware=time_aware, n_scales=n_scales,
                      objective=objective, lam=lam, n_bins=n_bins, seed=seed,
                      max_iter=max_iter, tol=tol, references=references, optimizer=optimizer,
                      time_aware_scales=time_aware_scales, finest_level=finest_level,
                      transport_cell=transport_cell, restart=restart)
    if method == "dnn":
        from evmotion.methods.dnn import estimate_flow_dnn

        given = [f.name for f in dataclasses.fields(o)
                 if getattr(o, f.name) != getattr(MULTICM_DEFAULTS, f.name)]
        if init is not None:
            given.append("init")
        if given:
            raise ParameterError(f"estimate_flow(method='dnn'): {', '.join(given)} "
                                 f"appl{'ies' if len(given) == 1 else 'y'} to method "
                                 "'multicm' only (the network takes "
                                 "checkpoint, device and threads; estimate_flow_dnn has "
                                 "its own options)")
        return estimate_flow_dnn(events, checkpoint, device=device, threads=threads)
    if method == "triplet":
        raise ParameterError("estimate_flow: the triplet method is event by event: "
                             "evmotion.methods.triplet.estimate_flow_triplet(events) for "
                             "dense windows, or evmotion.TripletMatcher for a stream")
    if method != "multicm":
        raise ParameterError(f"estimate_flow: unknown method {method!r} "
                             "(available: 'multicm', 'dnn'; 'triplet' has its own functions)")
    if not (isinstance(init, str) and init == "dnn") and (
            device != "cpu" or threads != 1 or checkpoint is not None):
        # only what was given (threads=0 was said with a device='cpu' nobody passed, and
        # read as no range error; probe BQ); a checkpoint went unopened, unsaid (probe CK)
        given = [f"{k}={v!r}" for k, v, default in (("checkpoint", checkpoint, None),
                                                    ("device", device, "cpu"),
                                                    ("threads", threads, 1)) if v != default]
        raise ParameterError(f"estimate_flow: {' and '.join(given)} "
                             f"{'are' if len(given) > 1 else 'is'} the network's option"
                             f"{'s' if len(given) > 1 else ''}: "
                             f"{'they apply' if len(given) > 1 else 'it applies'} with "
                             "method='dnn' or init='dnn' (multicm runs "
                             "on one thread; workers= of estimate_flow_sequence runs windows "
                             "in parallel)")
    net = None
    if isinstance(init, str):
        if init != "dnn":
            raise ParameterError(f"init must be a FlowResult, an array or 'dnn', got {init!r}")
        from evmotion.methods.dnn import estimate_flow_dnn

        o = dataclasses.replace(o, n_scales=min(o.n_scales, DNN_INIT_SCALES))
        # the network's plain forward pass at each input scale, the sharpest kept: the
        # refinement makes up for what time reversal, tile fusion and the gain search
        # add (0.16 s at 346x260), at the same AEE after the three scales
        # (without the network's own verdicts, "no focus" and the like: multicm's checks
        # judge the flow it refines; probe AP saw "not a measurement" said of a valid
        # result, and they cost 10-12 ms a 40k window)
        net = estimate_flow_dnn(events, checkpoint, device=device, threads=threads,
                                with_iwes=False, time_reversal=False, fuse=False,
                                rescale=False, planar=False, refine=False, check=False)
    for name, what in (("n_bins", "the time bins"), ("transport_cell", "the PDE's cells")):
        if getattr(o, name) is not None and o.time_aware in (None, "none"):
            # (it was ignored: estimate_flow(ev, n_bins=7) ran the plain model, probe BE;
            # transport_cell likewise, probe EVAL)
            raise ParameterError(f"{name}={getattr(o, name)!r} sets {what} of the "
                                 "time-aware flow, but time_aware is None: give "
                                 f"time_aware='upwind' or 'burgers' too (or leave {name} out)")
    o = _checked(o, events)
    if net is not None:
        # The network answers at every pixel, but only where events are is its flow fitted
        # to anything (elsewhere it is the decoder's extrapolation, often far off): each
        # first-scale tile starts from the network's flow averaged over the tile's events
        # (the plain tile mean was up to 16 % worse in AEE after the two scales, zoom)
        init = tf.event_tile_means(net.flow, events.x, events.y, tf.scale_grid(
            o.finest_level - o.n_scales + 1, events.sensor_size))
    c_start = compile_seconds()
    t_start = time.perf_counter()
    t0, t1 = int(events.t[0]), int(events.t[-1])
    duration_s = (t1 - t0) * 1e-6
    x, y = _as_xy(events)
    s = (events.t - t0).astype(np.float64) / (t1 - t0)
    shape = events.sensor_size
    valid = event_support(x, y, shape, SUPPORT_RADIUS, SUPPORT_MIN_EVENTS)
    params, prob, all_params, history, timings = _coarse_to_fine(
        x, y, s, events.p, shape, init, duration_s, o)
    focus, iwe_dict = _final_iwes(prob, params, x, y, s, shape)
    fitted = tf.dense_flow(params, shape)  # px over the window
    flow = rest_where_empty((fitted / duration_s).astype(np.float32), valid, prob.grid)
    # (the mask only: where noise alone fires, the flow carried in stays as it was)
    valid &= aligned_support(events, fitted / duration_s, t0 + (t1 - t0) // 2)
    chance = chance_z = float("nan")
    # flicker lights every pixel at once: a flow that gathers those bursts sharpens them,
    # whatever moves (said first: it names the cause the focus tests below cannot)
    no_focus = (warn_too_few_for_flow(events) is not None
                or warn_gap(events.t, "dense flow") is not None
                or warn_flicker(events, "dense flow") is not None
                or warn_no_gain(focus, "dense flow") is not None)
    if not no_focus:
        # the focus above is what the optimizer raised: on half a pixel of motion, or a
        # window whose warped image is blurrier than the unwarped one, it fits the
        # window's own event clusters (1.2 and 19); shuffled times keep that and lose motion
        # (z: on a small sensor chance itself scatters that ratio widely, 3,000 noise
        # events on 8x8 to 1.31, so it must also lie beyond chance's spread; probe DB)
        chance, chance_z = flow_alignment_chance(events, flow, (t0 + t1) // 2)
        no_focus = warn_by_chance(chance, "dense flow", z=chance_z) is not None
    halves = float("nan")
    if not no_focus:
        # a flow far from the motion can still beat shuffled times a little (an 8 s window
        # of a pan the scene crossed twice: 2.6 px/s for 67, chance 1.44): it does not carry
        # the window's first half onto its second
        halves = halves_consistency(events, flow, (t0 + t1) // 2)
        no_focus = warn_inconsistent_halves(halves, "dense flow") is not None
    refit = float("nan")
    if not no_focus and len(events) < REFIT_EVENTS_PER_TILE * prob.grid.nx * prob.grid.ny:
        # Few events a tile: the flow's unknowns can sharpen noise by 10-20 % with
        # nothing moving, and shuffled times keep part of that fit (chance 1.06-1.13 on
        # noise). What the same solver makes of the events with their times shuffled is
        # what no motion gives; the flow must sharpen the events clearly more than that.
        refit = focus / _shuffled_focus(x, y, s, events.p, shape, duration_s, o)
        no_focus = warn_by_refit(refit, "dense flow") is not None
    other = 0
    if no_focus:
        valid = np.zeros_like(valid)
    else:
        # a region the coarse scales did not follow, its tiles' events far sharper moved
        # by a translation of their own (probe BZ: a patch's flow over the background,
        # AEE above the zero flow's, valid)
        from evmotion.core.tilesearch import jit_scores

        # (the fitted flow, as the objective saw it: the one at rest where events are
        # few would leave the events at the edge of its support unmoved)
        valid, other = other_motion(x, y, s - 0.5, fitted, valid, "dense flow",
                                    scores=jit_scores)
        if valid.any():
            warn_small_flow(float(np.median(np.hypot(fitted[..., 0], fitted[..., 1])[valid])),
                            "dense flow")
    timings["total_s"] = time.perf_counter() - t_start
    # numba's first-use compilation is not the estimate's time: reported apart
    timings["compile_s"] = compile_seconds() - c_start
    timings["estimate_s"] = timings["total_s"] - timings["compile_s"]
    return FlowResult(flow=flow, t0_us=t0, t1_us=t1, t_ref_us=(t0 + t1) // 2,
                      params=tuple(all_params), iwes=iwe_dict, focus=float(focus),
                      history=history, timings=timings, time_aware=o.time_aware,
                      n_bins=o.n_bins if o.time_aware else 0, n_events=len(events),
                      meta={"init": ("dnn" if net is not None else
                                     None if init is None else "given"),
                            "objective": o.objective, "lam": o.lam,
                            "references": o.references, "optimizer": o.optimizer,
                            "max_iter": o.max_iter, "tol": o.tol,
                            "n_scales": o.n_scales, "seed": o.seed,
                            "finest_level": o.finest_level,
                            "transport_cell": o.transport_cell, "restart": o.restart,
                            "no_focus": no_focus, "chance_gain": chance,
                            "chance_z": chance_z,
                            "halves_correlation": halves,
                            "refit_gain": refit, "other_motion_tiles": other},
                      valid=valid)


def _checked(o: MultiCMOptions, events: EventArray) -> MultiCMOptions:
    """``o`` validated against ``events``, with ``time_aware="none"`` read as None,
    ``n_bins`` resolved for the sensor and ``finest_level`` for the window."""
    # as ints: n_scales=2.0 passed the check and failed in range() (probe BE)
    # (n_scales=-1 was "a whole number >= 0", and 0 then "need 1 <= n_scales", probe BQ)
    if o.transport_cell is None:
        o = dataclasses.replace(o, transport_cell=TRANSPORT_CELL)
    o = dataclasses.replace(o, **{name: whole_number(name, getattr(o, name), lo=lo)
                                  for name, lo in (("n_scales", 1), ("max_iter", 1),
                                                   ("transport_cell", 1), ("seed", 0))})
    if o.n_bins is not None:
        o = dataclasses.replace(o, n_bins=whole_number("n_bins", o.n_bins, lo=1))
    if o.time_aware_scales is not None:
        o = dataclasses.replace(o, time_aware_scales=whole_number(
            "time_aware_scales", o.time_aware_scales, lo=1, hi=max(1, o.n_scales)))
    if o.finest_level is None:
        level = auto_finest_level(len(events), events.sensor_size)
        o = dataclasses.replace(o, finest_level=level, n_scales=min(o.n_scales, level))
    o = dataclasses.replace(o, finest_level=whole_number("finest_level", o.finest_level, lo=0))
    # (compared in logs: 2 ** (10**30 - 1) never ended, probe API)
    if o.finest_level - 1 > np.log2(max(events.sensor_size)):
        raise ParameterError(f"finest_level={o.finest_level} makes 2^{o.finest_level - 1} "
                             f"tiles per side, more than the {max(events.sensor_size)} px "
                             "of the sensor: tiles under a pixel fit nothing (at most "
                             f"{int(np.log2(max(events.sensor_size))) + 1} here)")
    # the first bound broken is named alone (one message listing all five read as a
    # puzzle); lam's and tol's are MultiCMOptions' own
    for ok, need, got in (
            (1 <= o.n_scales <= o.finest_level, "1 <= n_scales <= finest_level",
             f"n_scales={o.n_scales}, finest_level={o.finest_level}"),
            (o.max_iter >= 1, "max_iter >= 1", f"max_iter={o.max_iter}"),
            (o.transport_cell >= 1, "transport_cell >= 1", f"transport_cell={o.transport_cell}")):
        if not ok:
            raise ParameterError(f"need {need}, got {got}")
    if len(events) < 10 or events.t[-1] <= events.t[0]:
        raise EmptyWindowError(f"window has {len(events)} event"
                               f"{'' if len(events) == 1 else 's'} spanning "
                               f"{int(events.t[-1] - events.t[0]) if len(events) else 0} us; "
                               "need at least 10 events and a positive duration")
    n_bins = o.n_bins
    if n_bins is None:
        n_bins = 40 if events.sensor_size[1] >= 640 else 5
    if not 1 <= n_bins <= MAX_TIME_BINS:
        raise ParameterError(f"n_bins must be in [1, {MAX_TIME_BINS}], got {n_bins}")
    return dataclasses.replace(o, n_bins=n_bins,
                               time_aware=None if o.time_aware == "none" else o.time_aware)


def _coarse_to_fine(x, y, s, p, shape, init, duration_s, o: MultiCMOptions):
    """Optimize the tile flow scale by scale (4.9), each scale started from the previous
    one's upsampled flow. Returns the finest params (px per window), the finest scale's
    problem, every scale's params (px/s), the (level, cost) history and per-scale seconds."""
    levels = list(range(o.finest_level - o.n_scales + 1, o.finest_level + 1))
    # (a single tile is a constant flow, which the transport leaves unchanged: level 1 uses
    # the plain warp whatever time_aware says, at identical result and lower cost)
    ta_from = 1 if o.time_aware_scales is None else o.finest_level - o.time_aware_scales + 1
    g0 = {}
    jittered = _jittered(x, y, o.seed)

    # (the recursion goes through ``again``, not the closure's own name: a closure that
    # refers to itself is a cycle, which kept the window's events, its problem and its warm
    # start (the previous window's result, and so back) until a full garbage collection; a
    # 1280 x 720 flow run grew by some 15 MB a window)
    def run(first: int, params, all_params, history, timings, again):
        prob = None
        for i in range(first, len(levels)):
            level = levels[i]
            ts = time.perf_counter()
            grid = tf.scale_grid(level, shape)
            if params is None:
                params = _init_params(init, grid, duration_s, shape)
            else:
                params = tf.resample(params, grid)
            coarse = level <= JITTER_TO_LEVEL and level < o.finest_level
            xl, yl = jittered if coarse else (x, y)
            prob = MultiCMProblem(xl, yl, s, shape, grid, objective=o.objective, lam=o.lam,
                                  references=o.references,
                                  time_aware=o.time_aware if level >= max(ta_from, 2) else None,
                                  n_bins=o.n_bins, transport_cell=o.transport_cell,
                                  g0=g0.get(coarse), p=p, duration_s=duration_s)
            # the identity warp's focus normalizes the objective: one per set of coordinates
            g0[coarse] = prob.g0
            theta, val = _optimize(prob, params.ravel(), o.optimizer, o.max_iter,
                                   _scale_tol(o.tol, level, params))
            if (o.restart and len(all_params) == 1 and all_params[0].size == 2 and grid.nx > 1
                    and np.abs(theta - params.ravel()).max() > RESTART_PX):
                # The single tile fits one translation to the whole image; where the flow
                # is not a translation (zoom, rotation about the image centre, a moving
                # object) it locks onto the region with the most contrast, a start the
                # finer scales cannot leave once the displacement over the window exceeds
                # the focus basin (a few px). So when the first multi-tile scale moves away
                # from that translation (by more than RESTART_PX somewhere), it also starts
                # from the warm start (or zero flow) and keeps the better optimum.
                th2, val2 = _optimize(prob, _init_params(init, grid, duration_s, shape).ravel(),
                                      o.optimizer, o.max_iter, 0.0)
                if val2 < val:
                    theta, val = th2, val2
            params = theta.reshape(grid.ny, grid.nx, 2)
            all_params = [*all_params, params / duration_s]
            history = [*history, (level, float(val))]
            timings = {**timings, f"scale{level}_s": time.perf_counter() - ts}
            if o.restart and level == TILE_SEARCH_LEVEL and level < o.finest_level:
                from evmotion.core.tilesearch import tile_restarts
                from evmotion.core.translation import TILE_REACH

                start = tile_restarts(xl, yl, s - 0.5, params, grid, TILE_REACH * max(shape))
                if start is not None:
                    # both go on to the finest scale, which decides: at this one the
                    # restart's blend across the regions' boundary costs about what it
                    # gains (probe BZ's patch: 0.1353 against 0.1348 here, 0.1168
                    # against 0.1173 at the finest; AEE 5.6 px against 8.8)
                    ts = time.perf_counter()
                    th2, val2 = _optimize(prob, start.ravel(), o.optimizer, o.max_iter, 0.0)
                    p2 = th2.reshape(grid.ny, grid.nx, 2)
                    branch = again(i + 1, p2, [*all_params[:-1], p2 / duration_s],
                                   [*history[:-1], (level, float(val2))],
                                   {**timings, "tile_search_s": time.perf_counter() - ts},
                                   again)
                    mine = again(i + 1, params, all_params, history, timings, again)
                    return min(mine, branch, key=lambda r: r[3][-1][1])
        return params, prob, all_params, history, timings

    return run(0, None, [], [], {}, run)


def _shuffled_focus(x, y, s, p, shape, duration_s: float, o: MultiCMOptions) -> float:
    """The focus multicm reaches on the events with their times permuted (seeded by
    ``o.seed``; the finest ``REFIT_SCALES`` scales, at most ``REFIT_MAX_ITER`` iterations
    each): what the flow's unknowns make of these positions without any motion."""
    order = np.random.default_rng(o.seed).permutation(x.size)
    quick = dataclasses.replace(o, n_scales=min(o.n_scales, REFIT_SCALES),
                                max_iter=min(o.max_iter, REFIT_MAX_ITER))
    params, prob, *_ = _coarse_to_fine(x[order], y[order], s, np.asarray(p)[order], shape,
                                       None, duration_s, quick)
    return float(prob.focus_grad(params)[0])


def _jittered(x: np.ndarray, y: np.ndarray, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``x, y`` moved by a uniform offset in [-0.5, 0.5) px each, drawn from ``seed``."""
    rng = np.random.default_rng(seed)
    return x + rng.uniform(-0.5, 0.5, x.size), y + rng.uniform(-0.5, 0.5, y.size)


def _final_iwes(prob: MultiCMProblem, params, x, y, s, shape):
    """Focus at the estimate and the float32 IWEs at t_1, t_mid, t_N and of the identity
    warp (the single-reference loss builds only t_1: the other two are voted here)."""
    focus, _, iwes = prob.focus_grad(params)
    zero = np.zeros((x.size, 2))
    iwe_id = tf.iwe_forward(x, y, zero, np.zeros(x.size), shape)
    if len(iwes) == 3:
        iwe_dict = {"t1": iwes[0], "tmid": iwes[1], "tN": iwes[2]}
    else:
        flow_ev, _ = prob.event_flow(params)
        iwe_dict = {name: tf.iwe_forward(x, y, flow_ev, np.ascontiguousarray(r - s), shape)
                    for name, r in (("t1", 0.0), ("tmid", 0.5), ("tN", 1.0))}
    iwe_dict = {k: v.astype(np.float32) for k, v in iwe_dict.items()}
    iwe_dict["identity"] = iwe_id.astype(np.float32)
    return focus, iwe_dict


def _scale_tol(tol: float, level: int, start: np.ndarray) -> float:
    """The stalled-objective stop of a scale at ``level`` started from ``start``: ``tol``
    from ``TOL_FROM_LEVEL`` on, for a start that is not the zero flow; else 0 (none).

    From the zero flow (or the near-zero flow a single tile finds for a rotation about
    the image centre) the first iterations barely lower the objective, and a 2 x 2 scale
    stopped there after 3 of its 20 iterations (simulated rotation over 89 ms: AEE 8.4 px
    against 1.46), so the coarse scales always run to ``max_iter`` or convergence.

    Examples
    --------
    >>> _scale_tol(1e-4, 5, np.ones((16, 16, 2))), _scale_tol(1e-4, 2, np.ones((2, 2, 2)))
    (0.0001, 0.0)
    >>> _scale_tol(1e-4, 5, np.zeros((16, 16, 2)))
    0.0
    """
    return tol if level >= TOL_FROM_LEVEL and np.any(start) else 0.0


def _optimize(prob: MultiCMProblem, theta0: np.ndarray, optimizer: str, max_iter: int,
              tol: float = 0.0):
    # imported here: scipy.optimize costs ~0.3 s of start-up that the network's path
    # (method="dnn"), which shares this module's result type, never needs
    from scipy.optimize import minimize

    if optimizer == "lbfgs":
        vmax = float(max(prob.shape))
        options = {"maxiter": max_iter, "maxfun": 2 * max_iter + 10}
        if tol > 0:
            options["ftol"] = tol
        res = minimize(_boxed(prob.value_grad, vmax), np.clip(theta0, -vmax, vmax),
                       jac=True, method="L-BFGS-B", options=options)
        theta = np.clip(res.x, -vmax, vmax)
        # res.fun is the objective at res.x (the wall adds nothing inside the box)
        return theta, float(res.fun if np.array_equal(theta, res.x)
                            else prob.value_grad(theta)[0])

    def fun(th):
        return prob.value_grad(th)

    def hessp(th, p):
        eps = 1e-4 / max(float(np.linalg.norm(p)), 1e-12)
        return (prob.value_grad(th + eps * p)[1] - prob.value_grad(th - eps * p)[1]) / (2 * eps)

    res = minimize(fun, theta0, jac=True, hessp=hessp, method="Newton-CG",
                   options={"maxiter": max_iter, "xtol": 1e-6})
    return res.x, float(res.fun)


def _boxed(value_grad, vmax: float):
    """``value_grad`` evaluated only inside the box ``|theta_i| <= vmax``, continued outside
    by a quadratic wall: ``F(clip(theta)) + |theta - clip(theta)|^2``.

    A tile cannot move further over the window than the sensor is long; the wall keeps
    the line search from evaluating such flows (whose time-aware transport needs a CFL
    sub-step per pixel of displacement: minutes and gigabytes at 1280x720). It is not
    given to L-BFGS-B as bounds: with every variable boxed, L-BFGS-B takes its first step
    at the raw gradient's length instead of a unit one, and the small gradients of a
    single-tile start then stall the coarse scales (simulated translation over 89 ms,
    22.7 px: AEE 0.209 px with bounds, 0.046 without). Inside the box it is
    ``value_grad`` itself.

    Examples
    --------
    >>> f = _boxed(lambda th: (float(th @ th), 2 * th), 1.0)
    >>> f(np.array([0.5]))[0], f(np.array([3.0]))[0]   # 0.25 inside; 1 + 2**2 outside
    (0.25, 5.0)
    """
    def fun(theta):
        inside = np.clip(theta, -vmax, vmax)
        val, grad = value_grad(inside)
        out = theta - inside
        if out.any():
            val = val + float(out @ out)
            grad = np.where(out != 0.0, 2.0 * out, grad)
        return val, grad
    return fun


def warms(res: FlowResult, kwargs: dict) -> bool:
    """Whether ``res``, a window's result from :func:`estimate_flow` called with
    ``kwargs``, starts the next window: not when skipped (nothing estimated), nor the
    network's (``method="dnn"`` takes no initial flow: its second window refused it)."""
    return "skipped" not in res.meta and kwargs.get("method", "multicm") != "dnn"


def estimate_flow_sequence(events: EventArray, windows: Sequence[Window], *,
                           warm_start: bool = True, show_progress: bool = False,
                           workers: int = 1, scheduler: Any = None, keep_iwes: bool = True,
                           on_empty: str = "raise", **kwargs) -> list[FlowResult]:
    """:func:`estimate_flow` over consecutive windows, each warm-started from the previous.

    Parameters
    ----------
    events : EventArray
    windows : sequence of Window or of (t0, t1) µs
        E.g. ``events.windows_by_count(30000)``.
    warm_start : bool
        Initialize each window with the previous result (§4.2.4; method ``"multicm"``
        only: the network of ``method="dnn"`` takes no initial flow).
    show_progress : bool
        Progress bar on stderr.
    workers : int
        With more than 1, the windows are split into ``workers`` contiguous chunks run by
        as many processes, warm-started within each chunk only
        (:mod:`evmotion.methods.multicm_windows`).
    scheduler : distributed.Client, optional
        Run those chunks on this Dask cluster instead.
    keep_iwes : bool
        With chunks: keep each result's images of warped events (15 MB a window at
        1280x720).
    on_empty : {"raise", "skip"}
        A window that cannot be estimated (fewer than 10 events, or all at one time)
        raises :class:`EmptyWindowError` (default), or with ``"skip"`` gives a
        :func:`~evmotion.methods.flowresult.skipped_window` (no valid pixel) and an
        :class:`~evmotion.errors.EvmotionWarning` naming it; the next window starts from
        the last estimated one.
    **kwargs
        Passed to :func:`estimate_flow` (``init`` seeds the first window).

    Returns
    -------
    list of FlowResult
    """
    from evmotion.parallel import report_progress
    from evmotion.utils import progress

    if on_empty not in ("raise", "skip"):
        raise ParameterError(f"on_empty must be 'raise' or 'skip', got {on_empty!r}")
    require_events(events, "estimate_flow_sequence")
    check_switches(warm_start=warm_start, show_progress=show_progress, keep_iwes=keep_iwes)
    # (a pair failed on its missing index range: AttributeError 'start')
    windows = [as_window(events, k, w) for k, w in enumerate(windows)]
    if workers != 1 or scheduler is not None:
        from evmotion.methods.multicm_windows import estimate_in_chunks

        if not warm_start:
            raise ParameterError("warm_start=False with workers or a scheduler: chunks are "
                                 "warm-started; run one process")
        return estimate_in_chunks(events, windows, workers=workers, scheduler=scheduler,
                                  keep_iwes=keep_iwes, on_empty=on_empty, **kwargs)

    init = kwargs.pop("init", None)
    # the network's options go with the caller's init only: a window warm-started from the
    # previous one's result was refused them (init='dnn' with a checkpoint failed at the
    # second window, probe CR)
    net_kw = {k: kwargs.pop(k) for k in ("checkpoint", "device", "threads") if k in kwargs}
    out = []
    it = progress(windows, total=len(windows), desc="multicm") if show_progress else windows
    warmed = False
    for w in it:
        res = estimate_or_skip(
            lambda ev, i0=init, own=not warmed: estimate_flow(
                ev, init=i0, **kwargs, **(net_kw if own else {})),
            events, w, on_empty)
        out.append(res)
        report_progress()  # a chunk run by map_windows: one of its windows is done
        if warm_start and warms(res, kwargs):
            init, warmed = res, True
    return out
