"""Per-event collapse values: the divergence of the warp flow times the window's duration,
or ``|det J| - 1``, with their parameter derivatives, and the window's time span.

The values come from the warp: closed forms where they depend on dt only
(``warp.event_values``: zoom, translation, SE(2), similarity, in-plane), the rotation's from
its warped points (``warp.values_from_warped``, or fused with the warp,
``warp.warp_values_into``), the generic complex-step derivatives of
:meth:`~evmotion.core.warps.Warp.divergence` / ``jacobian_det`` otherwise.
"""

from __future__ import annotations

import math
import threading
from typing import NamedTuple

import numpy as np
from numba import njit

from evmotion.core.warps import Warp
from evmotion.core.warps.common import EMPTY2

__all__ = ["PenaltyEvents", "all_above", "checked_theta", "event_values", "rotation_grad",
           "scratch", "span_duration", "time_span", "warp_values", "window_span"]

_LOW63 = np.int64(0x7FFFFFFFFFFFFFFF)  # all float64 bits but the sign

_TLS = threading.local()


class PenaltyEvents(NamedTuple):
    """A window's events as the collapse penalties take them, with what the caller already
    has of them (each optional: computed where needed).

    Attributes
    ----------
    x, y, dt : array (N,)
        The events: pixels and ``t_k - t_ref`` in seconds.
    xw, yw : array (N,), optional
        The events warped with the parameters evaluated.
    jx, jy : array (N, P), optional
        Their parameter Jacobians.
    span : (float, float), optional
        ``(min dt, max dt)`` in seconds.
    count : array (H, W) float64, optional
        The bilinear IWE of ``xw, yw`` without weights (the vote counts; read only).
    """

    x: np.ndarray
    y: np.ndarray
    dt: np.ndarray
    xw: np.ndarray | None = None
    yw: np.ndarray | None = None
    jx: np.ndarray | None = None
    jy: np.ndarray | None = None
    span: tuple[float, float] | None = None
    count: np.ndarray | None = None

    def duration(self) -> float:
        """The window's duration ``T`` in seconds (:func:`window_span`), from ``span`` when
        given."""
        return window_span(self.dt) if self.span is None else span_duration(self.span)

def scratch(shapes, tag, dtype=np.float64):
    """Reusable buffers per thread (float64 unless ``dtype``): fresh large arrays cost page
    faults on every call (several times the arithmetic here); callers must not return
    them."""
    cache = getattr(_TLS, "bufs", None)
    if cache is None:
        cache = _TLS.bufs = {}
    key = (tag, tuple(shapes))
    bufs = cache.get(key)
    if bufs is None:
        if len(cache) > 32:
            cache.clear()
        bufs = cache[key] = tuple(np.empty(sh, dtype) for sh in shapes)
    return bufs


def checked_theta(warp: Warp, theta) -> np.ndarray:
    """``warp.check_theta(theta)`` without its copies when theta already is a finite float64
    (P,) array (the per-evaluation call of an optimizer)."""
    if (isinstance(theta, np.ndarray) and theta.dtype == np.float64
            and theta.shape == (warp.n_params,) and all(map(math.isfinite, theta.tolist()))):
        return theta
    return warp.check_theta(theta)


def window_span(dt) -> float:
    """The window's duration ``T = max dt - min dt`` in seconds (1 if all times are equal):
    the unit of the thesis' normalized time, in which the divergence is measured."""
    t0, t1 = time_span(dt)
    return t1 - t0 if t1 > t0 else 1.0


def span_duration(span) -> float:
    """The window's duration from its (min dt, max dt), as :func:`window_span`."""
    return span[1] - span[0] if span[1] > span[0] else 1.0


def time_span(dt):
    """(min dt, max dt) in seconds, (0, 0) for no events."""
    dt = np.ascontiguousarray(dt, dtype=np.float64)
    if dt.shape[0] == 0:
        return 0.0, 0.0
    t0, t1 = _k_span(dt)
    return float(t0), float(t1)


@njit(cache=True, error_model="numpy")
def _k_span(a):
    """min and max of a non-empty contiguous float64 array in one pass: on the float bits
    mapped to integers of the same order (negatives: magnitude bits flipped), whose min/max
    vectorize where float ones (NaN semantics) do not; several times faster than
    np.min + np.max. A NaN maps beyond +-inf, so it still shows."""
    bits = a.view(np.int64)
    lo = _LOW63
    hi = -_LOW63 - 1
    for k in range(bits.shape[0]):
        b = bits[k]
        key = b ^ ((b >> 63) & _LOW63)
        lo = min(lo, key)
        hi = max(hi, key)
    out = np.empty(2, np.int64)
    out[0] = lo ^ ((lo >> 63) & _LOW63)
    out[1] = hi ^ ((hi >> 63) & _LOW63)
    f = out.view(np.float64)
    return f[0], f[1]


@njit(cache=True, error_model="numpy")
def all_above(d, margin):
    """Whether every value exceeds ``margin`` by more than the rounding of a vote-weighted
    pixel average could take away: then no DIWE/IWA pixel is below the margin (a weighted
    mean is at least the smallest value), and the trimmed mean selects nothing. (Min and
    max magnitude on order-preserving integer keys of the float bits, as :func:`_k_span`,
    so that the pass vectorizes; a NaN counts as below.) Also returns the margin raised by
    that rounding (no pixel whose events' values all reach it can be below ``margin``)
    and the number of values below ``margin``."""
    bits = d.view(np.int64)
    lo = _LOW63
    big = np.int64(0)
    n_below = 0
    for k in range(bits.shape[0]):
        b = bits[k]
        lo = min(lo, b ^ ((b >> 63) & _LOW63))
        big = max(big, b & _LOW63)
        n_below += 1 if d[k] < margin else 0
    out = np.empty(2, np.int64)
    out[0] = lo ^ ((lo >> 63) & _LOW63)
    out[1] = big
    f = out.view(np.float64)
    vmin, vbig = f[0], max(f[1], abs(margin))
    # a pixel's sums carry at most ~N roundings of size eps * big
    tol = vbig * max(1e-12, 4.0 * d.shape[0] * 2.3e-16)
    return vmin > margin + tol, margin + tol, n_below


def event_values(kind: str, warp: Warp, x, y, dt, theta, want_grad: bool = True,
                  T: float | None = None, xw=None, yw=None):
    """(d_k, dd_k/dtheta, fac): divergence per window (1/s times T, the window's span,
    computed from ``dt`` unless given), or |det J| - 1. ``xw, yw``: the events warped
    with ``theta``, if at hand (the rotation's values are cheapest from them).

    ``dd`` is None without ``want_grad``, and always for the rotation: its derivatives are
    contracted later (in :meth:`~evmotion.core.warps.Warp.reduce_pair`, or with stored
    Jacobians by :func:`rotation_grad`), with ``fac`` (N,) the factor from the raw
    divergence / det J to ``d``."""
    closed = getattr(warp, "event_values", None)
    is_div = kind == "divergence"
    if not is_div:
        T = 1.0
    elif T is None:
        T = window_span(dt)
    n = dt.shape[0]
    if closed is not None:
        if want_grad:
            d, g = scratch(((n,), (n, warp.n_params)), "ev")
        else:
            (d,), g = scratch(((n,),), "ev0"), None
        closed(is_div, dt, theta, T, d, EMPTY2 if g is None else g, want_grad)
        return d, g, None
    if hasattr(warp, "values_from_warped"):
        d, fac = scratch(((n,), (n,)), "ev1")
        if xw is None or yw is None:
            xw, yw = warp.warp(x, y, dt, theta)
        warp.values_from_warped(xw, yw, dt, theta, is_div, T, d, fac)
        return d, None, fac
    if is_div:
        if not want_grad:
            return warp.divergence(x, y, dt, theta) * T, None, None
        d, g = warp.divergence(x, y, dt, theta, grad=True)
        return d * T, g * T, None
    if not want_grad:
        return np.abs(warp.jacobian_det(x, y, dt, theta)) - 1.0, None, None
    det, g = warp.jacobian_det(x, y, dt, theta, grad=True)
    sgn = np.sign(det)
    return np.abs(det) - 1.0, g * sgn[:, None], None


def rotation_grad(warp, kind, x, y, dt, th, gd, fac, out):
    """``out += sum_k gd_k dd_k/d omega`` without an (N, 3) buffer (``fac`` is
    overwritten)."""
    (gw,) = scratch(((gd.shape[0],),), "gw")
    np.multiply(gd, fac, out=gw)
    warp.values_vjp(x, y, dt, th, kind == "divergence", gw, out, fac)


def warp_values(kind, warp, x, y, dt, th, xw, yw, span):
    """Warp the events into ``xw, yw`` and return ``(d, fac)`` of :func:`event_values`
    from the same pass where the warp has a fused kernel for them (the rotation), else
    ``None`` (only warped). Inputs as :meth:`~evmotion.core.warps.Warp.warp_into`'s, theta
    checked."""
    if not hasattr(warp, "warp_values_into") or kind not in ("divergence", "deformation"):
        warp.warp_into(x, y, dt, th, xw, yw)
        return None
    is_div = kind == "divergence"
    T = (window_span(dt) if span is None else span_duration(span)) if is_div else 1.0
    n = dt.shape[0]
    d, fac = scratch(((n,), (n,)), "ev1")
    warp.warp_values_into(x, y, dt, th, is_div, T, xw, yw, d, fac)
    return d, fac
