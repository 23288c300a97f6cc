"""The contrast-maximization cost (3.6) of one window, shared by ego-motion
(:mod:`evmotion.methods.egomotion`) and motion segmentation
(:mod:`evmotion.methods.segmentation`): :class:`CMaxCost`, its construction from events
(:func:`make_cost`) and the parameter scales and boxes the optimizers use.

``J(theta) = -G(theta) / G(0) + lambda * R(theta)`` with ``G`` a focus objective of the image
of warped events (:mod:`evmotion.core.objectives`) and ``R`` a collapse penalty
(:mod:`evmotion.core.collapse`) or whitening (:mod:`evmotion.core.whitening`); see
:mod:`evmotion.methods.egomotion` for the choices behind the scaling.

Examples
--------
>>> from evmotion.events import EventArray
>>> ev = EventArray([1, 2, 3], [1, 1, 2], [0, 10, 20], [1, 0, 1], sensor_size=(4, 5))
>>> cost, t_ref = make_cost(ev, warp="translation")
>>> round(cost.value(np.zeros(2)), 6), t_ref
(-1.0, 0)
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping

import numpy as np
from numba import njit

from evmotion.core.collapse import (
    DEFAULT_MARGINS,
    DEFAULT_WEIGHTS,
    RCAD_STRIDE,
    REGULARIZERS,
    PenaltyEvents,
    chains_pair,
    regularizer_value_grad,
)
from evmotion.core.collapse.rcad import rcad_checked
from evmotion.core.collapse.trimmed import trimmed_parts
from evmotion.core.collapse.values import checked_theta, span_duration, warp_values
from evmotion.core.iwe import (
    KERNELS,
    accumulate,
    accumulate_backward_into,
    accumulate_backward_reduce,
    accumulate_into,
    dequantize,
    vote_bilinear,
)
from evmotion.core.objectives import (
    OBJECTIVES,
    events_value_grad,
    objective_value_grad,
    variance_stats,
)
from evmotion.core.trim import pairs_size
from evmotion.core.warps import WARPS, Warp, make_warp
from evmotion.core.whitening import whiten
from evmotion.errors import CalibrationError, EmptyWindowError, EvmotionWarning, ParameterError
from evmotion.events import EventArray, check_reference_time
from evmotion.methods.weights import window_weight

__all__ = [
    "COMBINED_REGULARIZERS",
    "REGULARIZER_CHOICES",
    "CMaxCost",
    "default_bounds",
    "make_cost",
    "param_scales",
    "resolve_t_ref",
]


#: Typical magnitude per parameter unit: the optimizers' scaling and the TPE box half-width.
_UNIT_SCALE = {"1/s": (1.0, 8.0), "rad/s": (1.0, 8.0), "px/s": (100.0, 1500.0),
               "1/(px s)": (1e-3, 1e-2)}


def default_bounds(warp: Warp) -> tuple[np.ndarray, np.ndarray]:
    """Symmetric search box per parameter from its unit (TPE and landscapes).

    ``1/s`` and ``rad/s``: +-8; ``px/s``: +-1500; ``1/(px s)``: +-0.01.

    Examples
    --------
    >>> lo, hi = default_bounds(make_warp("translation", (10, 10)))
    >>> hi.tolist()
    [1500.0, 1500.0]
    """
    half = np.array([_UNIT_SCALE[u][1] for u in warp.param_units])
    return -half, half


@njit(cache=True)
def _chain(gx, gy, jx, jy, out):
    """``out = jx^T gx + jy^T gy`` (P,): the chain rule through stored Jacobians (N, P).

    A loop rather than BLAS: a threaded matrix-vector product stalls for milliseconds on a
    process pinned to one core (BLAS threads spinning), as in the benchmarks."""
    for j in range(out.shape[0]):
        out[j] = 0.0
    for k in range(gx.shape[0]):
        for j in range(out.shape[0]):
            out[j] += gx[k] * jx[k, j] + gy[k] * jy[k, j]
    return out


_NO_WEIGHTS = np.empty(0)


#: Side (px, a power of 2) of the sensor tiles in which the fused path visits the events.
_TILE = 16


@njit(cache=True)
def _tile_cell(v, n):
    """Tile index of coordinate ``v`` px among ``n`` tiles (outside or NaN: clamped)."""
    if not v >= _TILE:  # also NaN
        return 0
    if v >= (n - 1) * _TILE:  # also inf
        return n - 1
    # v / _TILE is exact (a power of 2) and positive: truncation is the floor
    return int(v * (1.0 / _TILE))


@njit(cache=True)
def _tile_order(x: np.ndarray, y: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Stable order of events by their ``_TILE``-pixel tile of the sensor (row-major), in
    time order within a tile.

    Events close in this order warp to pixels close in the image, so the IWE vote and the
    adjoint's gathers stay in cache: about -20 % per evaluation at 500k events on 640x480,
    whose float64 IWE exceeds the L2 cache. Sums over events change order only (rounding).
    A counting sort, once per window (~2 ms for 500k events)."""
    nx = (shape[1] + _TILE - 1) // _TILE
    ny = (shape[0] + _TILE - 1) // _TILE
    n = x.shape[0]
    key = np.empty(n, np.int64)
    start = np.zeros(nx * ny + 1, np.int64)
    for k in range(n):
        key[k] = _tile_cell(y[k], ny) * nx + _tile_cell(x[k], nx)
        start[key[k] + 1] += 1
    for j in range(nx * ny):
        start[j + 1] += start[j]
    order = np.empty(n, np.int64)
    for k in range(n):
        order[start[key[k]]] = k
        start[key[k]] += 1
    return order


@njit(cache=True, error_model="numpy")
def _fold_adjoints(g, shift, c, gN):
    """The adjoint image of the vote counts of ``J`` = data term + penalty for
    ``Warp.reduce_pair``, in place on the padded penalty image: ``gN <- c (g - shift) +
    gN`` (the data term's adjoint ``c (g - shift)`` of the IWE (H, W), relative to the
    penalty's scale, plus the penalty's), the padding ring left 0."""
    h, wd = g.shape
    wp = wd + 2
    for i in range(h):
        r = (i + 1) * wp + 1
        for j in range(wd):
            gN[r + j] += c * (g[i, j] - shift)


def param_scales(warp: Warp) -> np.ndarray:
    """Typical magnitude of each parameter of ``warp`` from its unit (the optimizers'
    scaling): 1 for ``1/s`` and ``rad/s``, 100 for ``px/s``, 1e-3 for ``1/(px s)``.

    Examples
    --------
    >>> param_scales(make_warp("translation", (10, 10))).tolist()
    [100.0, 100.0]
    """
    return np.array([_UNIT_SCALE[u][0] for u in warp.param_units])


#: Regularizer names accepted by :func:`estimate_egomotion` (None = plain CMax).
REGULARIZER_CHOICES = (None, "divergence", "deformation", "rcad", "whitening",
                       "divergence+deformation")


#: Sums of penalties (the thesis' "Div. + Def.", Tables 3.1/3.2): each term keeps its own
#: weight (Sec. 3.6.1: lambda_div and lambda_def of the data set).
COMBINED_REGULARIZERS = {"divergence+deformation": ("divergence", "deformation")}


class CMaxCost:
    """The cost (3.6) of one window and its analytic gradient, with preallocated buffers.

    Parameters
    ----------
    warp : Warp
    x, y : array (N,)
        Event pixels (undistorted for the rotation warp).
    dt : array (N,)
        ``t_k - t_ref`` in seconds.
    shape : (int, int)
        ``(H, W)`` of the IWE.
    objective : str
        One of :data:`evmotion.core.objectives.OBJECTIVES`.
    regularizer : str or None
        One of :data:`REGULARIZER_CHOICES`.
    weight : float or mapping
        ``lambda`` of (3.6) (ignored without a penalty regularizer); for
        ``"divergence+deformation"`` one weight per term (``{"divergence": ...,
        "deformation": ...}``) or one float for both.
    polarity : array (N,), optional
        0/1 polarity; needed by the timestamp objectives, and used as IWE weights +-1 with
        ``use_polarity``.
    tn : array (N,), optional
        Times normalized to [0, 1] over the window (timestamp objectives).
    kernel, sigma
        IWE delta approximation.
    use_polarity : bool
        Accumulate signed polarity (+-1) instead of counts.

    Notes
    -----
    ``value_grad(theta)`` returns ``(J, dJ/dtheta)``; ``value(theta)`` only ``J``;
    ``parts(theta)`` returns the data and penalty terms separately. ``span`` is the
    window's ``(min dt, max dt)`` in seconds.

    Warps up to 4 DOF chain the gradient through fused adjoint kernels that recompute the
    warp Jacobian per event (:meth:`evmotion.core.warps.Warp.warp_into` and
    ``reduce_bilinear``/``vjp``, the penalties through ``vjp`` too), so no (N, P)
    Jacobians are stored (except with whitening). The cost visits the events in an order by sensor
    tile (private copies; ``x``, ``y``, ``dt``, ``weights`` keep the caller's order, the
    buffers ``xw``, ``yw`` do not), which keeps the IWE in cache; sums change order only.
    """

    def __init__(self, warp: Warp, x, y, dt, shape, objective: str = "variance",
                 regularizer: str | None = None, weight: float | Mapping[str, float] = 0.0,
                 polarity=None, tn=None,
                 kernel: str = "bilinear", sigma: float = 1.0, use_polarity: bool = False):
        if objective not in OBJECTIVES:
            raise ParameterError(f"unknown objective '{objective}'; choose one of "
                                 f"{sorted(OBJECTIVES)}")
        if regularizer not in REGULARIZER_CHOICES:
            raise ParameterError(f"unknown regularizer '{regularizer}'; choose one of "
                                 f"{[r for r in REGULARIZER_CHOICES if r]} or None")
        self.warp = warp
        self.x, self.y, self.dt = Warp.check_events(x, y, dt)
        n = self.x.shape[0]
        if n < 3:
            raise EmptyWindowError(f"contrast maximization needs events, got {n}")
        self.shape = (int(shape[0]), int(shape[1]))
        self.objective = objective
        self.regularizer = regularizer
        self._terms = _penalty_terms(regularizer, weight)
        self.weight = (dict(self._terms) if regularizer in COMBINED_REGULARIZERS
                       else float(weight))
        self.kernel, self.sigma = kernel, float(sigma)
        self.needs_time = OBJECTIVES[objective].needs_time
        self.polarity = None if polarity is None else np.asarray(polarity)
        self.tn = None if tn is None else np.ascontiguousarray(tn, dtype=np.float64)
        if self.needs_time and (self.polarity is None or self.tn is None):
            raise ParameterError(f"objective '{objective}' needs polarity and times")
        self._order = None
        self.weights = None
        if use_polarity:
            if self.polarity is None:
                raise ParameterError("use_polarity needs the event polarities")
            self.weights = np.where(self.polarity > 0, 1.0, -1.0)
        p = warp.n_params
        # warps with fused kernels re-derive their Jacobian inside the adjoint passes of the
        # data term and of the penalties (which take jx=None and call the warp's vjp), so
        # no (N, P) Jacobians are stored; whitening transforms the warped events and their
        # Jacobians, so it keeps the composed chain
        self.fused = (hasattr(warp, "vjp") and hasattr(warp, "reduce_bilinear")
                      and regularizer != "whitening")
        store_jac = not self.fused
        self.xw, self.yw = np.empty(n), np.empty(n)
        if store_jac:
            self.jx, self.jy = np.empty((n, p)), np.empty((n, p))
        else:
            self.jx = self.jy = None
        # the cost visits the events tile by tile (see _tile_order): the private copies
        # below, and the warped positions and Jacobians in xw, yw, jx, jy, follow that order
        o = self._order = _tile_order(self.x, self.y, self.shape)
        self._fx, self._fy, self._fdt = self.x[o], self.y[o], self.dt[o]
        self.span = (float(self.dt.min()), float(self.dt.max()))
        self._fp = None if self.polarity is None else self.polarity[o]
        self._ftn = None if self.tn is None else self.tn[o]
        self.weights = self._weights
        self.gx, self.gy = np.empty(n), np.empty(n)
        self.iwe = np.empty(self.shape)
        self.giwe = np.empty(self.shape)
        # the padded image of the fused bilinear adjoint (Warp.reduce_bilinear)
        self._pad = np.empty((self.shape[0] + 2) * (self.shape[1] + 2)) if self.fused else None
        # divergence and deformation chain their votes' adjoint through the data term's
        # pass over the events (Warp.reduce_pair), their counts being the data term's IWE
        self._pair = (self.fused and regularizer in ("divergence", "deformation")
                      and chains_pair(warp) and not self.needs_time and kernel == "bilinear")
        self._pads = np.empty(pairs_size(self.shape)) if self._pair else None
        self.gtheta = np.empty(p)
        # whitening maps the cloud back to the image centre at the spread of the raw events
        self._wcenter = ((self.shape[1] - 1) / 2.0, (self.shape[0] - 1) / 2.0)
        self._wscale = (float(np.sqrt(0.5 * (self.x.var() + self.y.var())))
                        if regularizer == "whitening" else 1.0)
        self.n_evals = 0
        self.normalize_focus()

    def normalize_focus(self) -> float:
        """Set ``g0``, the data term's scale, to ``|G(0)|`` (the focus of the identity warp;
        1 where it is 0) with the current weights, and return it: once per window, and
        again after the weights change (the EM of :mod:`evmotion.methods.segmentation`)."""
        self.g0 = 1.0
        g0 = self._data(self.warp.identity(), grad=False)[0]
        self.g0 = abs(g0) if g0 != 0 else 1.0
        return self.g0

    @property
    def weights(self) -> np.ndarray | None:
        """Per-event IWE weights (N,) in the events' order, or None; assignable (the EM of
        :mod:`evmotion.methods.segmentation` sets its soft labels here)."""
        return self._weights

    @weights.setter
    def weights(self, w) -> None:
        if w is not None:
            w = np.ascontiguousarray(w, dtype=np.float64)
            if w.shape != self.x.shape:
                raise ParameterError(f"weights must have shape {self.x.shape} like the "
                                     f"events, got {w.shape}")
        self._weights = w
        if self._order is not None:
            self._fw = None if w is None else w[self._order]

    # -- pieces --------------------------------------------------------------------------
    def _positions(self, theta, jac: bool):
        if jac:
            self.warp.warp_into(self._fx, self._fy, self._fdt, theta, self.xw, self.yw,
                                self.jx, self.jy)
        else:
            self.warp.warp_into(self._fx, self._fy, self._fdt, theta, self.xw, self.yw)
        xw, yw, jx, jy = self.xw, self.yw, self.jx, self.jy
        if self.regularizer == "whitening":
            if jac:
                xw, yw, jx, jy = whiten(xw, yw, jx, jy, center=self._wcenter, scale=self._wscale)
            else:
                xw, yw = whiten(xw, yw, center=self._wcenter, scale=self._wscale)
        return xw, yw, jx, jy

    def _data(self, theta, grad: bool = True):
        """(G / G0, dG/dtheta / G0): the normalized focus and its gradient."""
        self.n_evals += 1
        if grad and self.fused:
            return self._data_fused(theta)
        xw, yw, jx, jy = self._positions(theta, grad)
        if self.needs_time:
            G, gx, gy = events_value_grad(self.objective, xw, yw, self.shape, self._fp,
                                          self._ftn, kernel=self.kernel, sigma=self.sigma)
            if not grad:
                return G / self.g0, None
            return G / self.g0, _chain(gx, gy, jx, jy, self.gtheta) / self.g0
        self._vote(xw, yw)
        if not grad:
            G = objective_value_grad(self.objective, self.iwe, out=self.giwe)[0]
            return G / self.g0, None
        if self.kernel == "bilinear":
            # fused adjoint and chain rule: no per-event gradient buffers; the variance
            # needs no gradient image either (dG/dIWE = 2 (IWE - mean) / n); whitened
            # events come with their total Jacobians (through the mean and covariance)
            G, g, shift, scale = self._image_grad()
            accumulate_backward_reduce(xw, yw, g, jx, jy, self.gtheta, self._fw,
                                       shift=shift, scale=scale)
            return G / self.g0, self.gtheta / self.g0
        G, gimg = objective_value_grad(self.objective, self.iwe, out=self.giwe)
        gx, gy = accumulate_backward_into(xw, yw, gimg, self.gx, self.gy, self._fw,
                                          self.kernel, self.sigma)
        return G / self.g0, _chain(gx, gy, jx, jy, self.gtheta) / self.g0

    def _vote(self, xw, yw):
        """The IWE of the warped events (in the cost's order) into ``self.iwe``."""
        if self.kernel == "bilinear":
            vote_bilinear(np.ascontiguousarray(xw), np.ascontiguousarray(yw),
                           _NO_WEIGHTS if self._fw is None else self._fw, self.iwe)
        else:
            accumulate_into(xw, yw, self.iwe, self._fw, self.kernel, self.sigma)

    def _image_grad(self):
        """``(G, g, shift, scale)`` of the IWE in ``self.iwe``: ``dG/dIWE = scale (g - shift)``."""
        if self.objective == "variance":
            mu, G = variance_stats(self.iwe)
            return G, self.iwe, mu, 2.0 / self.iwe.size
        G, gimg = objective_value_grad(self.objective, self.iwe, out=self.giwe)
        return G, gimg, 0.0, 1.0

    def _data_fused(self, theta):
        """:meth:`_data` for warps with fused adjoints: warp and vote, then one pass over the
        events with the Jacobian recomputed per event (same values as the composed path)."""
        w = self.warp
        x, y, dt, wts, xw, yw = self._fx, self._fy, self._fdt, self._fw, self.xw, self.yw
        if self.jx is None:
            w.warp_into(x, y, dt, theta, xw, yw)
        else:
            w.warp_into(x, y, dt, theta, xw, yw, self.jx, self.jy)
        if self.needs_time:
            G, gx, gy = events_value_grad(self.objective, xw, yw, self.shape, self._fp,
                                          self._ftn, kernel=self.kernel, sigma=self.sigma)
        else:
            self._vote(xw, yw)
            if self.kernel == "bilinear":
                G, g, shift, scale = self._image_grad()
                w.reduce_bilinear(x, y, dt, xw, yw, theta, g, self.gtheta, wts, shift=shift,
                                  scale=scale, work=self._pad)
                return G / self.g0, self.gtheta / self.g0
            G, gimg = objective_value_grad(self.objective, self.iwe, out=self.giwe)
            gx, gy = accumulate_backward_into(xw, yw, gimg, self.gx, self.gy, wts, self.kernel,
                                              self.sigma)
        w.vjp(x, y, dt, xw, yw, theta, gx, gy, self.gtheta)
        return G / self.g0, self.gtheta / self.g0

    def _penalty(self, theta, grad: bool = True):
        total, gsum = 0.0, np.zeros(self.warp.n_params)
        # the data term has just voted the same warped events into self.iwe (unweighted,
        # bilinear): the penalty's count map, not accumulated twice
        count = (self.iwe if not self.needs_time and self._fw is None
                 and self.kernel == "bilinear" else None)
        for name, lam in self._terms:
            if name == "rcad":
                # events and span checked once per window: the O(1) closed forms cost
                # little more than the call
                r, g = rcad_checked(self.warp, checked_theta(self.warp, theta),
                                    *self.span, self.shape, DEFAULT_MARGINS["rcad"],
                                    RCAD_STRIDE, grad)
                if r < 0.0:
                    # one-sided, like the thresholded RCAD map: the closed forms
                    # (3.21)/(A.44) are negative for expansion, and a signed term would
                    # reward expanding warps
                    continue
            else:
                r, g = regularizer_value_grad(name, self.warp, self._fx, self._fy, self._fdt,
                                              theta, self.shape, self.xw, self.yw,
                                              jac=(self.jx, self.jy), grad=grad,
                                              span=self.span, count=count)
            # the divergence is already measured per window (core.collapse), so the
            # margin and lambda apply as the thesis states them: no further time scaling
            total += lam * r
            if grad:
                gsum += lam * g
        return total, (gsum if grad else None)

    def _value_grad_pair(self, theta):
        """:meth:`value_grad` with a divergence or deformation penalty on the fused path:
        the penalty's vote-count map is the data term's IWE, and its adjoint images are
        folded into the data term's before the one pass over the events that chains both
        through the warp (the same value and gradient as the separate terms, up to
        rounding)."""
        self.n_evals += 1
        w = self.warp
        th = checked_theta(w, theta)
        x, y, dt, xw, yw = self._fx, self._fy, self._fdt, self.xw, self.yw
        reg, pads = self.regularizer, self._pads
        # the rotation's per-event values come from the warp's own pass
        values = warp_values(reg, w, x, y, dt, th, xw, yw, self.span)
        # the IWE is voted there, with the penalty's image of values when it builds its maps
        R, gR, d, _, s, blocks = trimmed_parts(reg, w, PenaltyEvents(x, y, dt, xw, yw,
                                                                     span=self.span),
                                                th, self.shape, DEFAULT_MARGINS[reg], pads,
                                                count_out=self.iwe, values=values)
        G, g, shift, scale = self._image_grad()
        lam = self.weight
        if d is None:
            w.reduce_bilinear(x, y, dt, xw, yw, th, g, self.gtheta, shift=shift, scale=scale,
                              work=self._pad)
            return -G / self.g0 + lam * R, -self.gtheta / self.g0 + lam * gR
        size = self._pad.shape[0]
        # the pass scales both images by the penalty's factor f (nonzero: lam != 0 and a
        # pixel is trimmed), so the data term's adjoint enters divided by it
        f = lam * s
        _fold_adjoints(g, shift, -scale / self.g0 / f, pads[:size])
        h, wd = self.shape
        w.reduce_pair(x, y, dt, xw, yw, th, pads[:2 * size].reshape(2, h + 2, wd + 2), d,
                      self.gtheta, f, reg, span_duration(self.span), blocks)
        return -G / self.g0 + lam * R, self.gtheta.copy()

    # -- public --------------------------------------------------------------------------
    def value_grad(self, theta) -> tuple[float, np.ndarray]:
        """``J(theta)`` and ``dJ/dtheta``."""
        theta = np.asarray(theta, dtype=np.float64)
        if self._pair and self._fw is None and self.weight != 0.0:
            return self._value_grad_pair(theta)
        G, gG = self._data(theta, True)
        R, gR = self._penalty(theta, True)
        return -G + R, -gG + gR

    def value(self, theta) -> float:
        """``J(theta)`` only."""
        theta = np.asarray(theta, dtype=np.float64)
        G, _ = self._data(theta, False)
        R, _ = self._penalty(theta, False)
        return -G + R

    def parts(self, theta) -> dict[str, float]:
        """``{"focus": G/G0, "penalty": lambda R, "cost": J}`` at ``theta``."""
        theta = np.asarray(theta, dtype=np.float64)
        G, _ = self._data(theta, False)
        R, _ = self._penalty(theta, False)
        return {"focus": float(G), "penalty": float(R), "cost": float(-G + R)}

    def iwe_at(self, theta) -> np.ndarray:
        """The IWE (H, W) at ``theta`` (copy; counts, or signed with polarity)."""
        xw, yw, _, _ = self._positions(np.asarray(theta, dtype=np.float64), False)
        return accumulate(xw, yw, self.shape, self._fw, self.kernel, self.sigma)


def resolve_t_ref(t_ref, t: np.ndarray) -> int:
    if isinstance(t_ref, str):
        choices = {"start": int(t[0]), "end": int(t[-1]), "mid": int((int(t[0]) + int(t[-1])) // 2)}
        if t_ref not in choices:
            raise ParameterError(f"t_ref must be 'start', 'mid', 'end' or microseconds, "
                                 f"got '{t_ref}'")
        return choices[t_ref]
    return check_reference_time("t_ref", t_ref, t)


def _default_weight(regularizer, dataset: str) -> float | dict[str, float]:
    if regularizer not in REGULARIZERS and regularizer not in COMBINED_REGULARIZERS:
        return 0.0
    if dataset not in DEFAULT_WEIGHTS:
        raise ParameterError(f"unknown dataset '{dataset}' for default weights; choose one of "
                             f"{sorted(DEFAULT_WEIGHTS)} or pass weight=")
    if regularizer in COMBINED_REGULARIZERS:
        return {t: float(DEFAULT_WEIGHTS[dataset][t]) for t in COMBINED_REGULARIZERS[regularizer]}
    return float(DEFAULT_WEIGHTS[dataset][regularizer])


def _weight_number(value, term: str) -> float:
    """``value`` as a float weight, or ParameterError (a string such as "1" was taken)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.number)):
        raise ParameterError(f"the weight of '{term}' must be a number, got {value!r}")
    return float(value)


def _penalty_terms(regularizer, weight) -> tuple[tuple[str, float], ...]:
    """``(penalty name, lambda)`` of each term of ``regularizer`` with a non-zero weight."""
    if regularizer in COMBINED_REGULARIZERS:
        names = COMBINED_REGULARIZERS[regularizer]
        if isinstance(weight, Mapping):
            unknown = set(weight) - set(names)
            if unknown or set(names) - set(weight):
                raise ParameterError(f"regularizer '{regularizer}' takes one weight per term "
                                     f"{list(names)}, got {sorted(weight)}")
            lams = [_weight_number(weight[t], t) for t in names]
        else:
            lams = [_weight_number(weight, regularizer)] * len(names)
    elif regularizer in REGULARIZERS:
        if isinstance(weight, Mapping):
            raise ParameterError(f"regularizer '{regularizer}' takes one float weight, got "
                                 f"{dict(weight)}")
        names, lams = (regularizer,), [_weight_number(weight, regularizer)]
    else:
        return ()
    for t, lam in zip(names, lams, strict=True):
        if not np.isfinite(lam) or lam < 0.0:
            raise ParameterError(f"regularizer weight for '{t}' must be finite and >= 0, "
                                 f"got {lam}")
    return tuple((t, lam) for t, lam in zip(names, lams, strict=True) if lam != 0.0)


def make_cost(events: EventArray, warp: str | Warp = "rotation", objective: str = "variance",
              regularizer: str | None = None, weight: float | None = None, K=None,
              t_ref: str | int = "start", kernel: str = "bilinear", sigma: float = 1.0,
              use_polarity: bool = False, dataset: str | None = None
              ) -> tuple[CMaxCost, int]:
    """Build the :class:`CMaxCost` of a window; returns ``(cost, t_ref_us)``.

    Parameters are those of :func:`estimate_egomotion`.

    Examples
    --------
    >>> ev = EventArray([1, 2, 3], [1, 1, 2], [0, 10, 20], [1, 0, 1], sensor_size=(4, 5))
    >>> cost, t_ref = make_cost(ev, warp="translation")
    >>> round(cost.value(np.zeros(2)), 6), t_ref
    (-1.0, 0)
    """
    if not isinstance(events, EventArray):
        raise ParameterError(f"events must be an EventArray, got {type(events).__name__}")
    if len(events) < 3:
        raise EmptyWindowError(f"window has {len(events)} events; contrast maximization "
                               f"needs more")
    if int(events.t[-1]) == int(events.t[0]):
        # no time for the motion to act: every warp leaves the image as it is
        raise EmptyWindowError(f"window's {len(events)} events are all at one time "
                               f"({int(events.t[0])} us): no motion to estimate")
    if isinstance(warp, str):
        if warp not in WARPS:
            raise ParameterError(f"unknown warp '{warp}'; choose one of {sorted(WARPS)}")
        if hasattr(K, "K") and hasattr(K, "is_distorted"):
            # a Camera (what read_camera gives) failed in float(): TypeError (probe DB)
            if K.is_distorted and not events.meta.get("undistorted"):
                warnings.warn(EvmotionWarning(
                    f"K is a Camera with lens distortion {list(K.dist)} and the events are "
                    "not undistorted: the warp takes them as a pinhole's (undistort them "
                    "first: camera.undistort_events(events))"), stacklevel=3)
            K = K.K
        if warp == "rotation" and K is None:
            K = events.meta.get("K")
            cal = events.meta.get("calibration")
            if K is None and isinstance(cal, dict):
                # the recording's own calib.txt (an ECD folder's, an evmotion HDF5's), which
                # the reader carries (it was asked for again, probe BQ)
                K = cal.get("K")
                dist = [float(v) for v in cal.get("dist") or []]
                if K is not None and any(dist) and not events.meta.get("undistorted"):
                    warnings.warn(EvmotionWarning(
                        f"the events are not undistorted but their calibration has lens "
                        f"distortion {dist}: the rotation warp takes them as a pinhole's "
                        "(undistort them first: evmotion.io.calibration.read_camera(calib)"
                        ".undistort_events(events))"), stacklevel=3)
            if K is None:
                raise CalibrationError("the rotation warp needs the camera intrinsics: pass "
                                       "K= (3x3, px), or events whose meta holds 'K' or the "
                                       "'calibration' of their recording (the CLI: --calib)")
        warp = make_warp(warp, events.sensor_size, K=K)
    elif not isinstance(warp, Warp):
        raise ParameterError(f"warp must be a name ({', '.join(sorted(WARPS))}) or a Warp, "
                             f"got {warp!r}")
    t = events.t
    t_ref_us = resolve_t_ref(t_ref, t)
    dt = (t - t_ref_us).astype(np.float64) * 1e-6
    span = max(int(t[-1]) - int(t[0]), 1)
    tn = (t - t[0]).astype(np.float64) / span
    if regularizer is None and dataset is not None:
        # (it was ignored, even an unknown name: dataset='kitti', probe BE)
        raise ParameterError(f"dataset={dataset!r} picks a regularizer's weight, but "
                             "regularizer is None: give regularizer= too (or leave dataset "
                             "out)")
    if weight is not None:
        lam = weight
    elif dataset is not None:
        lam = _default_weight(regularizer, dataset)
    elif regularizer in REGULARIZERS or regularizer in COMBINED_REGULARIZERS:
        lam = window_weight(regularizer, events.x, events.y, events.sensor_size)
    else:
        lam = 0.0
    if kernel not in KERNELS:
        raise ParameterError(f"kernel must be one of {KERNELS}, got {kernel!r}")
    # the same events give the same answer whatever their dtype: the bilinear kernel votes
    # events on the integer grid spread over their pixel (a kink at theta = 0 otherwise)
    x, y = dequantize(events.x, events.y) if kernel == "bilinear" else (events.x, events.y)
    cost = CMaxCost(warp, x, y, dt, events.sensor_size, objective, regularizer,
                    lam, polarity=events.p, tn=tn, kernel=kernel, sigma=sigma,
                    use_polarity=use_polarity)
    return cost, t_ref_us
