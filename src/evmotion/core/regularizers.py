"""Event-collapse regularizers of ch. 3 (3.6): divergence, deformation, RCAD; whitening.

The augmented objective is ``J(theta) = -G(theta) + lambda R(theta)`` (3.6). Every
regularizer here is a *penalty*: larger means more collapse. The thesis' statistics are
signed so that collapse gives small values (negative divergence, area amplification below
one); the penalties negate them:

* ``"divergence"`` -- per-event divergence of the warp flow (3.9) measured per window
  (``div f`` in 1/s times the window duration ``T = max dt - min dt``: the thesis'
  normalized time, so that its margin and weights apply unchanged), averaged per pixel into
  the DIWE map (3.11) (bilinear votes of the warped events, empty pixels 0); the penalty is
  minus the trimmed mean (3.12) of the DIWE pixels below ``alpha = -0.2`` (0 when none).
* ``"deformation"`` -- per-event area amplification ``|det J|`` (3.14), averaged per pixel
  into the IWA map (3.16) (empty pixels 1); the penalty is the mean of ``1 - IWA`` over the
  pixels with ``IWA < 0.8`` (the trimmed mean (3.17), negated and shifted).
* ``"rcad"`` -- the rate of change of area deformation integrated over the window's time
  span ``[min dt, max dt]`` (see :meth:`evmotion.core.warps.Warp.area_log_ratio`):
  the closed form (3.21) for the zoom, the scaling DOF for the similarity (A.44) and the
  in-plane warp (its ``h_z``, as the thesis prescribes), (A.53) for the affine warp, zero
  for translation and SE(2); for the rotation and the homography the (3.28)/(A.6) map over
  a pixel grid, penalized as the mean of the map values above ``0.2`` (the thesis
  thresholds the sign-flipped map at -0.2). It needs no event accumulation: O(1), or
  O(pixels / stride^2) for the map.

Each returns its value and analytic gradient with respect to theta
(:func:`regularizer_value_grad`) and its maps for plotting (:func:`regularizer_maps`). The
trimmed means are piecewise smooth: the gradient is that of the current piece (the set of
pixels below the margin held fixed).

Cost (what CMax pays per evaluation on top of its data term; ``benchmarks/bench_regularizers``):

* the per-event values come first (closed forms, or for the rotation one vectorized pass
  from the warped pixels); when none is below the margin no pixel mean can be, and the
  penalty is 0 without building any map -- the usual case away from collapse;
* otherwise one pass votes the count image (``count=`` reuses a caller's) and marks the
  tiles of the events below the margin, the image of values is voted only around them
  (the blocks of events that reach those tiles; both images in one pass where most
  values are below: :mod:`evmotion.core.trim`), one pass trims them into their padded
  adjoint images, and the gradient takes one pass over the events with no per-event
  output, so that it vectorizes: :meth:`~evmotion.core.warps.Warp.reduce_pair` chains
  the votes' adjoint through the warp (its Jacobian recomputed, never stored) and the
  values' own derivatives (closed forms; for the rotation from the warped point) with the
  same gathered pixels,
  the values' image gathered only in the flagged blocks (the rotation). CMax
  (:class:`evmotion.methods.egomotion.CMaxCost`) votes the count image as its IWE and folds
  the penalty's adjoint images into its data term's, so that that one pass chains both
  (:func:`_trimmed_parts`). Warps without fused adjoints (or given ``jx, jy``) chain
  per-event derivatives through the stored Jacobians;
* RCAD maps test their threshold on the area ratio, without logarithms, sum the selected
  values as the logarithm of a product and their gradients as three sums contracted once
  (:func:`_k_rcad_grid`); ``span=(min dt, max dt)`` spares the pass over the times when the
  caller knows them.

Whitening (:func:`whiten`) is the baseline the thesis compares with (Nunes & Demiris): it is
not a penalty but a normalization of the warped events to zero mean and identity
covariance (an SVD of the event covariance) before the objective is computed.
"""

from __future__ import annotations

import math
import threading

import numpy as np
from numba import njit

from evmotion.core.iwe import _shape, _vote_bilinear, _vote_pair, _vote_pairs
from evmotion.core.trim import (
    MIN_COUNT,
    flag_blocks,
    n_blocks,
    pairs_size,
    pairs_view,
    tile_grid,
    trim_pairs,
    trim_pass,
    vote_marked,
    vote_values,
)
from evmotion.core.warps import (
    _BLOCK,
    _EMPTY1,
    _EMPTY2,
    _FAST_FINITE,
    Warp,
    _bilinear_sample,
    _cell_diff,
    _k_rot_divdet,
    _max_abs,
    _pad_index,
    _rod_coeffs,
    _rod_coeffs_exact,
    _rod_coeffs_short,
    _rod_mode,
    _rot_matrix,
    _rot_series_mode,
    _rot_warp_norm,
    _rows01,
    _sincos_block,
)
from evmotion.errors import EmptyWindowError, ParameterError
from evmotion.jitcache import kernel_case

__all__ = [
    "DEFAULT_MARGINS",
    "DEFAULT_WEIGHTS",
    "RCAD_STRIDE",
    "REGULARIZERS",
    "window_span",
    "regularizer_maps",
    "regularizer_value_grad",
    "whiten",
]

#: Regularizer weights lambda of (3.6) per data set (Sec. 3.6.1). The thesis gives no
#: rcad weight for ECD (rotation, a well-posed warp); the DSEC value is used there.
DEFAULT_WEIGHTS: dict[str, dict[str, float]] = {
    "mvsec": {"divergence": 2.0, "deformation": 5.0, "rcad": 0.2},
    "dsec": {"divergence": 50.0, "deformation": 100.0, "rcad": 1.0},
    "ecd": {"divergence": 5.0, "deformation": 10.0, "rcad": 1.0},
}

#: Pixel stride of the RCAD map's grid (rotation, homography).
RCAD_STRIDE = 8

#: Margins of the trimmed means (Sec. 3.4): DIWE < -0.2, IWA < 0.8, RCAD map > 0.2.
DEFAULT_MARGINS: dict[str, float] = {"divergence": -0.2, "deformation": 0.8, "rcad": 0.2}

_LOW63 = np.int64(0x7FFFFFFFFFFFFFFF)  # all float64 bits but the sign


def _count_image_for(shape, count=None, count_out=None):
    """Where the vote counts are: the caller's ``count`` (already voted), else
    ``count_out`` (to be voted), else a scratch buffer."""
    if count is not None:
        return count
    return count_out if count_out is not None else _scratch((shape,), "cnt")[0]


def _votes(xw, yw, d, shape, count=None, count_out=None):
    """``(cnt, num)``: the bilinear IWE of ones and of the per-event values ``d``, in one
    pass (:func:`evmotion.core.iwe._vote_pair`); ``cnt`` is ``count`` when the caller has
    it (not voted again), else written into ``count_out`` if given; scratch buffers
    otherwise."""
    cnt = _count_image_for(shape, count, count_out)
    (num,) = _scratch((shape,), "num")
    _vote_pair(xw, yw, d, cnt, num, count is None)
    return cnt, num


def _sparse_votes(xw, yw, d, margin, shape, count=None, count_out=None):
    """``(cnt, num, near, blocks)`` of :mod:`evmotion.core.trim`: the count image as
    :func:`_votes`'s, the image of values exact on the ``near`` tiles (those that can hold
    a pixel mean below ``margin``), the flags of the blocks of events that vote there
    (for at most :data:`_SPARSE_MAX` of the values below ``margin``)."""
    grid = tile_grid(shape)
    marks, near = _scratch((grid, grid), "tiles", np.uint8)
    (num,) = _scratch((shape,), "num")
    nb = n_blocks(xw.shape[0])
    (boxes,) = _scratch(((nb, 4),), "boxes", np.int64)
    (blocks,) = _scratch(((nb,),), "blocks", np.uint8)
    cnt = _count_image_for(shape, count, count_out)
    vote_marked(xw, yw, d, margin, cnt, count is None, marks, boxes)
    flag_blocks(marks, boxes, near, blocks)
    vote_values(xw, yw, d, blocks, num)
    return cnt, num, near, blocks


#: Largest fraction of values below the margin for which the values are voted sparsely.
_SPARSE_MAX = 0.25
_ALL_NEAR = np.zeros((0, 0), np.uint8)  # trim_pass's near: every pixel


@njit(cache=True, error_model="numpy")
def _backward_events(xw, yw, d, pads, h, wd, scale, gx, gy, gd):
    """Per-event derivatives ``gx, gy, gd`` (N,) of ``scale * sum(gS * num + gN * cnt)``
    with respect to ``xw_k, yw_k, d_k`` (0 off the image), ``num``/``cnt`` the bilinear
    IWEs of ``d`` and of ones, for the chain rule through stored Jacobians; ``pads`` holds
    ``gN`` then ``gS``, padded (:func:`evmotion.core.trim.trim_pass`), so no corner needs a
    bounds test."""
    wp = wd + 2
    b = (h + 2) * wp
    for k in range(xw.shape[0]):
        _, _, _, a, fx, fy, i = _pad_index(xw[k], yw[k], 0.0, scale, 1.0, h, wd)
        e = d[k]
        s00 = pads[b + i]
        s01 = pads[b + i + 1]
        s10 = pads[b + i + wp]
        s11 = pads[b + i + wp + 1]
        gx[k], gy[k] = _cell_diff(a, fx, fy, e * s00 + pads[i], e * s01 + pads[i + 1],
                                  e * s10 + pads[i + wp], e * s11 + pads[i + wp + 1])
        gd[k] = a * _bilinear_sample(fx, fy, s00, s01, s10, s11)


@njit(cache=True, error_model="numpy")
def _contract(gx, gy, gd, jx, jy, dd, out):
    """``out = jx^T gx + jy^T gy`` (+ ``dd^T gd`` if ``dd`` has rows): the chain rule
    through stored Jacobians (a compiled loop: BLAS threads pinned to one core spin for
    milliseconds on these small products)."""
    P = out.shape[0]
    use_dd = dd.shape[0] > 0
    acc = np.zeros(P)
    for k in range(gx.shape[0]):
        for j in range(P):
            acc[j] += gx[k] * jx[k, j] + gy[k] * jy[k, j] + (gd[k] * dd[k, j] if use_dd
                                                               else 0.0)
    for j in range(P):
        out[j] = acc[j]


@njit(cache=True, error_model="numpy")
def _all_above(d, margin):
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


@njit(cache=True, error_model="numpy")
def _any_vote(xw, yw, h, wd):
    """Whether any event votes into the image (the bilinear support test of the votes)."""
    for k in range(xw.shape[0]):
        x = xw[k]
        y = yw[k]
        if x > -1.0 and x < wd and y > -1.0 and y < h:
            return True
    return False


# ---------------------------------------------------------------------------------------
# Per-event statistics and their parameter derivatives

def window_span(dt) -> float:
    """The window's duration ``T = max dt - min dt`` in seconds (1 if all times are equal):
    the unit of the thesis' normalized time, in which the divergence is measured."""
    t0, t1 = _time_span(dt)
    return t1 - t0 if t1 > t0 else 1.0


def _event_values(kind: str, warp: Warp, x, y, dt, theta, want_grad: bool = True,
                  T: float | None = None, xw=None, yw=None):
    """(d_k, dd_k/dtheta, fac): divergence per window (1/s times T, the window's span,
    computed from ``dt`` unless given), or |det J| - 1. ``xw, yw``: the events warped
    with ``theta``, if at hand (the rotation's values are cheapest from them).

    ``dd`` is None without ``want_grad``, and always for the rotation: its derivatives are
    contracted later (in :meth:`~evmotion.core.warps.Warp.reduce_pair`, or with stored
    Jacobians by :func:`_rotation_grad`), with ``fac`` (N,) the factor from the raw
    divergence / det J to ``d``."""
    code = _FAST.get(warp.name)
    is_div = kind == "divergence"
    if not is_div:
        T = 1.0
    elif T is None:
        T = window_span(dt)
    n = dt.shape[0]
    if code is not None:
        if want_grad:
            d, g = _scratch(((n,), (n, warp.n_params)), "ev")
        else:
            (d,), g = _scratch(((n,),), "ev0"), None
        _k_fast_values(code, is_div, dt, theta, T, d, _EMPTY2 if g is None else g, want_grad)
        return d, g, None
    if warp.name == "rotation":
        d, fac = _scratch(((n,), (n,)), "ev1")
        if xw is None or yw is None:
            xw, yw = warp.warp(x, y, dt, theta)
        _k_rot_values(xw, yw, dt, theta, warp._kinv, is_div, T, d, fac)
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


def _rotation_grad(warp, kind, x, y, dt, th, gd, fac, out):
    """``out += sum_k gd_k dd_k/d omega`` without an (N, 3) buffer (``fac`` is
    overwritten)."""
    (gw,) = _scratch(((gd.shape[0],),), "gw")
    np.multiply(gd, fac, out=gw)
    _k_rot_divdet(x, y, dt, th, warp._kinv, kind == "divergence", fac, _EMPTY2, gw, out)


@njit(cache=True, error_model="numpy", inline="always")
def _rot_value_event(X, Y, t, a, b, wx, wy, wz, ww, want_div):
    """Divergence (1/s) or det J of the rotation warp for the event whose warped normalized
    point is (X, Y), ``dt = t``, Rodrigues coefficients ``a, b`` of ``|t omega|``.

    With ``R = exp(t omega^)`` and ``q = R v``, ``v = K^-1 (x, y, 1)``: ``v = R^T q`` and
    ``v_z = 1`` give ``1 / q_z = R_02 X + R_12 Y + R_22``, so neither the event nor a
    division is needed: det J = (1 / q_z)^3, and div f = tr(A J) with ``J = dX/dv``
    (rows ``(R_i. - X_i R_2.) / q_z``) and ``A`` the derivative of the rotational flow at
    (X, Y) (the formulas of :func:`evmotion.core.warps._k_rot_divdet`)."""
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = _rot_matrix(a, b, t, wx, wy, wz, ww)
    iz = r02 * X + r12 * Y + r22
    if not want_div:
        return iz * iz * iz
    j00 = (r00 - X * r20) * iz
    j01 = (r01 - X * r21) * iz
    j10 = (r10 - Y * r20) * iz
    j11 = (r11 - Y * r21) * iz
    a00 = 2.0 * wy * X - wx * Y
    a01 = -wz - wx * X
    a10 = wz + wy * Y
    a11 = wy * X - 2.0 * wx * Y
    return a00 * j00 + a01 * j10 + a10 * j01 + a11 * j11


@njit(cache=True, error_model="numpy", inline="always")
def _rot_finish(v, want_div, T, d, fac, k):
    """d_k = divergence times T, or |det J| - 1, and fac_k = d(d_k)/d(v)."""
    if want_div:
        d[k] = v * T
        fac[k] = T
    else:
        d[k] = abs(v) - 1.0
        fac[k] = 1.0 if v >= 0.0 else -1.0


def _rot_values_case(mode, want_div):
    """:func:`_k_rot_values` in series mode ``mode`` for the divergence or det J: one case,
    compiled on first use (:func:`evmotion.jitcache.kernel_case`)."""

    @njit(cache=True, error_model="numpy", fastmath=_FAST_FINITE)
    def rot_values(xw, yw, dt, w, Kinv, T, d, fac):
        wx, wy, wz = w[0], w[1], w[2]
        ww = wx * wx + wy * wy + wz * wz
        i00, i01, i02, i10, i11, i12 = _rows01(Kinv)
        for k in range(xw.shape[0]):
            t = dt[k]
            a, b, _ = _rod_mode(t * t * ww, mode)
            v = _rot_value_event(i00 * xw[k] + i01 * yw[k] + i02, i10 * xw[k] + i11 * yw[k]
                                 + i12, t, a, b, wx, wy, wz, ww, want_div)
            _rot_finish(v, want_div, T, d, fac, k)

    return rot_values


def _k_rot_values(xw, yw, dt, w, Kinv, want_div, T, d, fac):
    """Per-event d_k (divergence times T, or |det J| - 1) and fac_k of the rotation warp
    from the warped pixels ``xw, yw`` (one pass; the loop of each series mode has no
    branch, so it vectorizes like the warp's)."""
    kernel_case(_rot_values_case, _rot_series_mode(dt, w), bool(want_div))(
        xw, yw, dt, w, Kinv, T, d, fac)


def _rot_warp_values_case(mode, want_div):
    """:func:`_k_rot_warp_values` in series mode ``mode`` for the divergence or det J: one
    case, compiled on first use."""

    @njit(cache=True, error_model="numpy", fastmath=_FAST_FINITE)
    def rot_warp_values(x, y, dt, w, Kmat, Kinv, T, xw, yw, d, fac):
        wx, wy, wz = w[0], w[1], w[2]
        ww = wx * wx + wy * wy + wz * wz
        k00, k01, k02, k10, k11, k12 = _rows01(Kmat)
        i00, i01, i02, i10, i11, i12 = _rows01(Kinv)
        for k in range(x.shape[0]):
            t = dt[k]
            a, b, _ = _rod_mode(t * t * ww, mode)
            X, Y = _rot_warp_norm(x[k], y[k], t, a, b, wx, wy, wz, i00, i01, i02, i10, i11,
                                  i12)
            xw[k] = k00 * X + k01 * Y + k02
            yw[k] = k10 * X + k11 * Y + k12
            v = _rot_value_event(X, Y, t, a, b, wx, wy, wz, ww, want_div)
            _rot_finish(v, want_div, T, d, fac, k)

    return rot_warp_values


def _k_rot_warp_values(x, y, dt, w, Kmat, Kinv, want_div, T, xw, yw, d, fac):
    """The rotation warp (``xw, yw``, as :meth:`~evmotion.core.warps.Warp.warp_into`) and
    the per-event ``d``, ``fac`` of :func:`_k_rot_values` in one pass: each event's
    Rodrigues coefficients and warped normalized point serve both (no reload of the warped
    pixels, no second series)."""
    kernel_case(_rot_warp_values_case, _rot_series_mode(dt, w), bool(want_div))(
        x, y, dt, w, Kmat, Kinv, T, xw, yw, d, fac)


def _warp_values(kind, warp, x, y, dt, th, xw, yw, span):
    """Warp the events into ``xw, yw`` and return ``(d, fac)`` of :func:`_event_values`
    from the same pass where the warp has a fused kernel for them (the rotation), else
    ``None`` (only warped). Inputs as :meth:`~evmotion.core.warps.Warp.warp_into`'s, theta
    checked."""
    if warp.name != "rotation" or kind not in ("divergence", "deformation"):
        warp.warp_into(x, y, dt, th, xw, yw)
        return None
    is_div = kind == "divergence"
    T = (window_span(dt) if span is None else _span_T(span)) if is_div else 1.0
    n = dt.shape[0]
    d, fac = _scratch(((n,), (n,)), "ev1")
    _k_rot_warp_values(x, y, dt, th, warp.K, warp._kinv, is_div, T, xw, yw, d, fac)
    return d, fac


def _k_fast_values(code, is_div, dt, th, T, d, g, want_g):
    """Closed forms of the warps whose divergence and det J depend on dt only: zoom (3.7),
    translation, SE(2) (A.13)/(A.14), similarity (A.40)/(A.42), in-plane (A.25)/(A.27).
    Writes d_k (divergence times T, or |det J| - 1) and, if ``want_g``, dd_k/dtheta into
    ``g`` (N, P). One kernel per warp (``code``), compiled on first use."""
    kernel_case(_fast_values_case, code)(is_div, dt, th, T, d, g, want_g)


def _fast_values_case(code):
    """:func:`_k_fast_values` for the warp ``code`` (:data:`_FAST`)."""

    @njit(cache=True, error_model="numpy", fastmath=_FAST_FINITE)
    def fast_values(is_div, dt, th, T, d, g, want_g):
        _fast_values_body(code, is_div, dt, th, T, d, g, want_g)

    return fast_values


@njit(cache=True, error_model="numpy", inline="always")
def _fast_values_body(code, is_div, dt, th, T, d, g, want_g):
    """The loops of :func:`_k_fast_values`."""
    n = dt.shape[0]
    P = th.shape[0]
    if want_g:
        for k in range(n):
            for j in range(P):
                g[k, j] = 0.0
    if code == 0 and not want_g:  # zoom values alone: branch-free loops that vectorize
        h = th[0]
        if is_div:
            for k in range(n):
                d[k] = -2.0 * h * T
        else:
            for k in range(n):
                s = 1.0 - dt[k] * h
                d[k] = s * s - 1.0
    elif code == 0:  # zoom
        h = th[0]
        for k in range(n):
            if is_div:
                d[k] = -2.0 * h * T
                if want_g:
                    g[k, 0] = -2.0 * T
            else:
                s = 1.0 - dt[k] * h
                d[k] = s * s - 1.0
                if want_g:
                    g[k, 0] = -2.0 * dt[k] * s
    elif code == 1:  # translation
        for k in range(n):
            d[k] = 0.0
    elif code == 2:  # SE(2) (P = 3, s = 0) and similarity
        w = th[2]
        s = th[3] if P == 4 else 0.0
        amax = _max_abs(dt) * abs(w)
        small = amax < 1.0
        if not is_div and not want_g:
            for k in range(n):
                ib = 1.0 / (1.0 + dt[k] * s)
                d[k] = ib * ib - 1.0
            return
        if is_div and not want_g and amax * amax < 0.05:
            # the usual case: angles below 0.22 rad, the short series of sin and cos inline
            # in one branch-free loop (it vectorizes)
            for k in range(n):
                t = dt[k]
                a = -t * w
                z = a * a
                sa, cb, _ = _rod_coeffs_short(z)
                ib = 1.0 / (1.0 + t * s)
                d[k] = T * (-2.0 * s * ib * ib * (1.0 - z * cb) + 2.0 * w * ib * (a * sa))
            return
        sbuf = np.empty(_BLOCK)
        cbuf = np.empty(_BLOCK)
        for k0 in range(0, n, _BLOCK):
            k1 = min(k0 + _BLOCK, n)
            if not is_div:
                for k in range(k0, k1):
                    t = dt[k]
                    ib = 1.0 / (1.0 + t * s)
                    d[k] = ib * ib - 1.0
                    if want_g and P == 4:
                        g[k, 3] = -2.0 * t * ib * ib * ib
                continue
            if small:
                _sincos_block(dt, k0, k1, w, sbuf, cbuf)  # of -dt w
            else:
                for k in range(k0, k1):
                    sbuf[k - k0] = math.sin(-dt[k] * w)
                    cbuf[k - k0] = math.cos(-dt[k] * w)
            for k in range(k0, k1):
                t = dt[k]
                ib = 1.0 / (1.0 + t * s)
                sn = -sbuf[k - k0]
                c = cbuf[k - k0]
                ib2 = ib * ib
                d[k] = T * (-2.0 * s * ib2 * c - 2.0 * w * ib * sn)
                if not want_g:
                    continue
                g[k, 2] = T * (2.0 * s * ib2 * t * sn - 2.0 * ib * sn - 2.0 * w * ib * t * c)
                if P == 4:
                    g[k, 3] = T * (-2.0 * c * ib2 + 4.0 * s * t * c * ib2 * ib
                                   + 2.0 * w * t * sn * ib2)
    else:  # in-plane
        phi = th[2]
        kk = th[3] + 1.0
        c = math.cos(phi)
        sn = math.sin(phi)
        if not is_div and not want_g:
            for k in range(n):
                t = dt[k]
                a = 1.0 + t
                d[k] = abs(a * a - 2.0 * a * t * kk * c + t * t * kk * kk) - 1.0
            return
        for k in range(n):
            t = dt[k]
            if is_div:
                d[k] = T * (2.0 - 2.0 * kk * c)
                if want_g:
                    g[k, 2] = T * 2.0 * kk * sn
                    g[k, 3] = -T * 2.0 * c
            else:
                a = 1.0 + t
                det = a * a - 2.0 * a * t * kk * c + t * t * kk * kk
                sgn = 1.0 if det >= 0 else -1.0
                d[k] = abs(det) - 1.0
                if not want_g:
                    continue
                g[k, 2] = 2.0 * a * t * kk * sn * sgn
                g[k, 3] = (-2.0 * a * t * c + 2.0 * t * t * kk) * sgn


_FAST = {"zoom": 0, "translation": 1, "se2": 2, "similarity": 2, "inplane": 3}
#: Warps whose divergence does not depend on the event, (3.10), (A.25).
_CONST_DIV = ("zoom", "translation", "inplane")

_TLS = threading.local()


def _scratch(shapes, tag, dtype=np.float64):
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


# ---------------------------------------------------------------------------------------
# DIWE / IWA trimmed means

def _checked_theta(warp: Warp, theta) -> np.ndarray:
    """``warp._theta(theta)`` without its copies when theta already is a finite float64
    (P,) array (the per-evaluation call of an optimizer)."""
    if (isinstance(theta, np.ndarray) and theta.dtype == np.float64
            and theta.shape == (warp.n_params,) and all(map(math.isfinite, theta.tolist()))):
        return theta
    return warp._theta(theta)


def _span_T(span) -> float:
    """The window's duration from its (min dt, max dt), as :func:`window_span`."""
    return span[1] - span[0] if span[1] > span[0] else 1.0


def _count_image(count, shape) -> np.ndarray:
    """A caller's vote-count image, checked: (H, W) float64 C-contiguous, read only."""
    if not (isinstance(count, np.ndarray) and count.dtype == np.float64
            and count.shape == tuple(shape) and count.flags.c_contiguous):
        raise ParameterError(f"count must be the (H, W) = {tuple(shape)} C-contiguous "
                             f"float64 bilinear IWE of the warped events, got "
                             f"{getattr(count, 'shape', type(count))}")
    return count


def _prepare(warp, x, y, dt, theta, xw, yw):
    """Checked events and theta, and the warped events (computed unless given)."""
    x, y, dt = Warp._events(x, y, dt)
    if x.shape[0] == 0:
        raise EmptyWindowError("the regularizer needs at least one event, got none")
    th = _checked_theta(warp, theta)
    if xw is None or yw is None:
        xw, yw = warp.warp(x, y, dt, th)
    xw = np.ascontiguousarray(xw, dtype=np.float64)
    yw = np.ascontiguousarray(yw, dtype=np.float64)
    return x, y, dt, th, xw, yw


def _pixel_average(kind, warp, x, y, dt, th, shape, xw, yw):
    """(d, fac, cnt, num) of the DIWE/IWA: per-event values and their vote images."""
    d, _, fac = _event_values(kind, warp, x, y, dt, th, want_grad=False, xw=xw, yw=yw)
    cnt, num = _votes(xw, yw, d, shape)
    return d, fac, cnt, num


def _trimmed_value_grad(kind, warp, x, y, dt, theta, shape, xw, yw, jx, jy, margin, kernel,
                        grad=True, span=None, count=None):
    x, y, dt, th, xw, yw = _prepare(warp, x, y, dt, theta, xw, yw)
    if count is not None:
        count = _count_image(count, shape)
    h, wd = shape
    (buf,) = _scratch(((pairs_size(shape),),), "adj")
    value, g, d, fac, scale, blocks = _trimmed_parts(kind, warp, x, y, dt, th, shape, xw, yw,
                                                     margin, buf, span, count, grad)
    if d is None or not grad:
        return value, g
    pads = buf[:2 * (h + 2) * (wd + 2)]
    T = window_span(dt) if span is None else _span_T(span)
    if (jx is None or jy is None) and chains_pair(warp):
        warp.reduce_pair(x, y, dt, xw, yw, th, pads, d, h, wd, g, scale, kind, T, blocks)
        return value, g
    n = x.shape[0]
    dd = None
    if fac is None:
        # the value derivatives (the values themselves are unchanged)
        d, dd, _ = _event_values(kind, warp, x, y, dt, th, T=T)
    if jx is None or jy is None:
        # only now: the Jacobians matter only when some pixel is trimmed
        _, _, jx, jy = warp.warp(x, y, dt, th, jacobian=True)
    gx, gy, gd = _scratch(((n,),) * 3, "gjac")
    _backward_events(xw, yw, d, pads, h, wd, scale, gx, gy, gd)
    _contract(gx, gy, gd, np.ascontiguousarray(jx), np.ascontiguousarray(jy),
              _EMPTY2 if dd is None else np.ascontiguousarray(dd), g)
    if fac is not None:
        _rotation_grad(warp, kind, x, y, dt, th, gd, fac, g)
    return value, g


def chains_pair(warp: Warp) -> bool:
    """Whether the trimmed penalties of ``warp`` chain their gradient, the values' own
    derivatives included, through :meth:`~evmotion.core.warps.Warp.reduce_pair` (no stored
    Jacobians): the warps with fused adjoints whose per-event values have compiled
    derivatives (closed forms, rotation)."""
    return hasattr(warp, "reduce_pair") and (warp.name in _FAST or warp.name == "rotation")


def _trimmed_parts(kind, warp, x, y, dt, th, shape, xw, yw, margin, pads, span=None,
                   count=None, grad=True, count_out=None, values=None):
    """The divergence or deformation penalty up to the chain rule through the warp, for
    callers that fuse that step with their own (CMax's data term): ``(value, g, d, fac,
    scale, blocks)`` for checked events and theta (:func:`_prepare`).

    ``d`` None: ``value`` and ``g`` (P,) are complete (no pixel trimmed, or the constant
    divergence; ``g`` None without ``grad``). Otherwise ``g`` (P,) is uninitialized and
    ``pads`` (:func:`evmotion.core.trim.pairs_size`: the votes are made in it too) holds in
    its first 2 (H + 2) (W + 2) values the adjoint images ``gN``, ``gS`` of the penalty
    divided by ``scale`` (with respect to the vote counts and the votes of the per-event
    values ``d``; padded by a ring of zeros): the gradient is that of ``scale * sum(gN *
    cnt + gS * num)`` through the votes and the values
    (:meth:`~evmotion.core.warps.Warp.reduce_pair` with ``derivs=kind``; ``fac``: the
    rotation's factor from its raw divergence / det J to ``d``, for the chain rule through
    stored Jacobians; ``blocks``: the flags of the blocks of events that reach a nonzero
    ``gS``, for ``reduce_pair``'s ``blocks``: :mod:`evmotion.core.trim`).
    ``count_out`` (H, W), if given (and ``count`` not), receives the bilinear IWE of
    ``xw, yw`` in every case, voted with the values' IWE where the maps are built (the data
    term's IWE of a caller that votes once). ``values``: ``(d, fac)`` of
    :func:`_event_values` for ``xw, yw``, if at hand (:func:`_warp_values`)."""
    zero = (0.0, np.zeros(warp.n_params) if grad else None, None, None, 0.0, None)

    def unvoted(result):
        # returned before the maps: the caller's count image is still to be voted
        if count_out is not None and count is None:
            _vote_bilinear(xw, yw, _EMPTY1, count_out)
        return result

    T = None
    if kind == "divergence":
        T = window_span(dt) if span is None else _span_T(span)
    # deformation's map is 1 + mean: its margin on `mean` is margin - 1
    m = margin - 1.0 if kind == "deformation" else margin
    if kind == "divergence" and warp.name in _CONST_DIV:
        # the divergence is the same for every event: so is the DIWE on its support, and
        # the trimmed mean is that constant (no vote moves it); one event gives it
        d, dd, _ = _event_values(kind, warp, x[:1], y[:1], dt[:1], th, T=T)
        if not (d[0] < m and _any_vote(xw, yw, shape[0], shape[1])):
            return unvoted(zero)
        return unvoted((-float(d[0]), (-dd[0].copy() if grad else None), None, None, 0.0,
                        None))
    if values is None:
        d, _, fac = _event_values(kind, warp, x, y, dt, th, want_grad=False, T=T, xw=xw,
                                  yw=yw)
    else:
        d, fac = values
    above, m_round, n_below = _all_above(d, m)
    if above:
        # no collapse anywhere (the usual case away from collapse): no maps to build
        return unvoted(zero)
    # R = -(1/n) sum_sel S/N with S = sum d_k b_k, N = sum b_k (b_k: bilinear votes)
    size = (shape[0] + 2) * (shape[1] + 2)
    gN, gS = pads[:size], pads[size:2 * size]
    blocks = None
    if n_below > _SPARSE_MAX * d.shape[0]:
        # most values below (the zoom's, similarity's and in-plane warp's depend on dt
        # only: below everywhere at once): both images in full, interleaved in one pass
        # unless the counts are given
        if count is None:
            # in the second adjoint image's memory: trim_pairs writes it over read rows
            pairs = pairs_view(pads, shape)
            _vote_pairs(xw, yw, d, pairs)
            total, n_sel = trim_pairs(pairs, m, gN, gS, _count_image_for(shape, None, count_out))
        else:
            cnt, num = _votes(xw, yw, d, shape, count)
            total, n_sel = trim_pass(cnt, num, m, gN, gS, _ALL_NEAR)
    else:
        # the values voted only around the events below the margin (core.trim)
        cnt, num, near, blocks = _sparse_votes(xw, yw, d, m_round, shape, count, count_out)
        total, n_sel = trim_pass(cnt, num, m, gN, gS, near)
    if n_sel == 0:
        return zero
    scale = -1.0 / n_sel
    if not grad:
        return total * scale, None, None, None, 0.0, None
    return total * scale, np.empty(warp.n_params), d, fac, scale, blocks


# ---------------------------------------------------------------------------------------
# RCAD

def _time_span(dt):
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


def _rcad_scalar(warp: Warp, th, t0, t1):
    """Closed-form RCAD penalties (constant over the image) and their gradient, or None."""
    g = np.zeros(warp.n_params)
    name = warp.name
    if name in ("translation", "se2"):
        return 0.0, g
    if name in ("zoom", "inplane"):
        h = th[0] if name == "zoom" else th[3]
        a0, a1 = 1.0 - t0 * h, 1.0 - t1 * h
        j = 0 if name == "zoom" else 3
        g[j] = 2.0 * (t1 / a1 - t0 / a0)
        return 2.0 * math.log(abs(a0 / a1)), g
    if name == "similarity":
        s = th[3]
        b0, b1 = 1.0 + t0 * s, 1.0 + t1 * s
        g[3] = 2.0 * (t1 / b1 - t0 / b0)
        return 2.0 * math.log(abs(b1 / b0)), g
    if name == "affine":
        G = np.array([[th[2], th[3]], [th[4], th[5]]])
        A0, A1 = np.eye(2) + t0 * G, np.eye(2) + t1 * G
        val = math.log(abs(np.linalg.det(A1) / np.linalg.det(A0)))
        dG = t1 * np.linalg.inv(A1).T - t0 * np.linalg.inv(A0).T
        g[2:] = dG.ravel()
        return val, g
    return None


def _area_coeffs(warp: Warp, th, t):
    """The log area ratio from t_ref to ``t`` of the rotation and homography trajectories
    is ``c - 3 log|a . (x, y, 1)|`` in pixels: returns ``a`` (3,), ``da/dtheta`` (3, P),
    ``c`` and ``dc/dtheta`` (P,)."""
    if warp.name == "rotation":
        a = np.empty(3)
        da = np.empty((3, 3))
        _rot_area_coeffs(th, t, warp._kinv, a, da)
        return a, da, 0.0, _ZERO3
    # homography: H = Id + t G (centred); a = e3^T H T^-1, c = log|det H|
    G = np.array([[th[0], th[1], th[2]], [th[3], th[4], th[5]], [th[6], th[7], 0.0]])
    H = np.eye(3) + t * G
    Ti = np.array([[1.0, 0, -warp.center[0]], [0, 1.0, -warp.center[1]], [0, 0, 1.0]])
    da = np.zeros((3, 8))
    da[:, 6] = t * Ti[0]
    da[:, 7] = t * Ti[1]
    dc = (t * np.linalg.inv(H).T).ravel()[:8]
    return H[2] @ Ti, da, math.log(abs(np.linalg.det(H))), dc


_ZERO3 = np.zeros(3)


@njit(cache=True, error_model="numpy")
def _rot_area_coeffs(om, t, kinv, a, da):
    """``a = e3^T R(-t omega) K^-1`` and ``da/d omega`` (3, 3): with ``v = K^-1 x``,
    d(e3^T R v)/d omega_j = t (R_0 . v) Jl_1j - t (R_1 . v) Jl_0j, ``Jl = J_l(-t omega)``."""
    p0, p1, p2 = -t * om[0], -t * om[1], -t * om[2]
    z = p0 * p0 + p1 * p1 + p2 * p2
    ca, cb, cc = _rod_coeffs(z) if z < 1.0 else _rod_coeffs_exact(z)
    P = np.array([[0.0, -p2, p1], [p2, 0.0, -p0], [-p1, p0, 0.0]])
    P2 = P @ P
    R = np.eye(3) + ca * P + cb * P2
    Jl = np.eye(3) + cb * P + cc * P2
    for j in range(3):
        a[j] = R[2, 0] * kinv[0, j] + R[2, 1] * kinv[1, j] + R[2, 2] * kinv[2, j]
    for i in range(3):
        for j in range(3):
            # (K^-T D)_ij with D = t (R_0^T Jl_1 - R_1^T Jl_0)
            acc = 0.0
            for m in range(3):
                acc += kinv[m, i] * t * (R[0, m] * Jl[1, j] - R[1, m] * Jl[0, j])
            da[i, j] = acc


@njit(cache=True, error_model="numpy")
def _k_rcad_grid(h, w, stride, a0, da0, c0, a1, da1, c1, margin, out):
    """Mean over the grid points (stride px) where the log area ratio
    ``c1 - c0 - 3 log q``, ``q = |(a1 . x) / (a0 . x)|``, exceeds ``margin``, and its
    gradient into ``out`` (P,). Returns (mean, count).

    No logarithm per point: the threshold is ``q < r = exp((c1 - c0 - margin) / 3)`` (the
    same up to the rounding of ``exp``; where ``r`` over- or underflows, the logarithm is
    taken per point), and the sum of the selected values is ``n (c1 - c0) - 3 log`` of the
    product of their ``q``, taken whenever that product leaves [1e-150, 1e150] (so it
    neither under- nor overflows). The gradient of a selected point, ``-3 da1^T x / (a1 .
    x) + 3 da0^T x / (a0 . x)``, is linear in ``x / (a . x)``: those are summed, and
    contracted with the (3, P) derivatives once at the end."""
    P = out.shape[0]
    r = math.exp((c1 - c0 - margin) / 3.0)
    by_ratio = 0.0 < r < math.inf
    n_sel = 0
    prod = 1.0
    logs = 0.0
    # sums of (x, y, 1) / (a1 . x) and / (a0 . x) over the selected points
    u0 = u1 = u2 = v0 = v1 = v2 = 0.0
    for iy in range(stride // 2, h, stride):
        b0 = a0[1] * iy + a0[2]
        b1 = a1[1] * iy + a1[2]
        for ix in range(stride // 2, w, stride):
            s0 = a0[0] * ix + b0
            s1 = a1[0] * ix + b1
            i0 = 1.0 / s0
            q = abs(s1 * i0)
            if not (q < r if by_ratio else c1 - c0 - 3.0 * math.log(q) > margin):
                continue
            n_sel += 1
            prod *= q
            if not 1e-150 < prod < 1e150:
                logs += math.log(prod)
                prod = 1.0
            i1 = 1.0 / s1
            u0 += ix * i1
            u1 += iy * i1
            u2 += i1
            v0 += ix * i0
            v1 += iy * i0
            v2 += i0
    if n_sel == 0:
        for j in range(P):
            out[j] = 0.0
        return 0.0, 0
    for j in range(P):
        out[j] = (3.0 * (da0[0, j] * v0 + da0[1, j] * v1 + da0[2, j] * v2)
                  - 3.0 * (da1[0, j] * u0 + da1[1, j] * u1 + da1[2, j] * u2)) / n_sel
    return c1 - c0 - 3.0 * (logs + math.log(prod)) / n_sel, n_sel


@njit(cache=True, error_model="numpy")
def _k_rcad_rotation(h, w, stride, om, t0, t1, kinv, margin, out):
    """:func:`_k_rcad_grid` of the rotation between ``t0`` and ``t1`` s, its coefficients
    (:func:`_rot_area_coeffs`) computed in the same call."""
    a0 = np.empty(3)
    da0 = np.empty((3, 3))
    a1 = np.empty(3)
    da1 = np.empty((3, 3))
    _rot_area_coeffs(om, t0, kinv, a0, da0)
    _rot_area_coeffs(om, t1, kinv, a1, da1)
    return _k_rcad_grid(h, w, stride, a0, da0, 0.0, a1, da1, 0.0, margin, out)


def _rcad_value_grad(warp, x, y, dt, theta, shape, margin, stride, grad=True, span=None):
    x, y, dt = Warp._events(x, y, dt)
    if x.shape[0] == 0:
        raise EmptyWindowError("the regularizer needs at least one event, got none")
    th = _checked_theta(warp, theta)
    t0, t1 = _time_span(dt) if span is None else (float(span[0]), float(span[1]))
    return _rcad_checked(warp, th, t0, t1, shape, margin, stride, grad)


def _rcad_checked(warp, th, t0, t1, shape, margin, stride, grad=True):
    """The RCAD penalty and its gradient for checked arguments: ``th`` a finite float64
    (P,) array, the window's time span ``[t0, t1]`` (s), ``shape`` (H, W), ``margin`` and
    ``stride`` (the map's; rotation and homography) -- what a caller that evaluates one
    window many times (CMax) has checked once."""
    g = np.empty(warp.n_params)
    if warp.name == "rotation":
        # coefficients and grid in one compiled call (c = 0 for a rotation); g is 0 when
        # no point is selected
        value, _ = _k_rcad_rotation(shape[0], shape[1], stride, th, t0, t1, warp._kinv,
                                    margin, g)
        return float(value), (g if grad else None)
    closed = _rcad_scalar(warp, th, t0, t1)
    if closed is not None:
        return closed
    a0, da0, c0, dc0 = _area_coeffs(warp, th, t0)
    a1, da1, c1, dc1 = _area_coeffs(warp, th, t1)
    value, n_sel = _k_rcad_grid(shape[0], shape[1], stride, a0, np.ascontiguousarray(da0), c0,
                                a1, np.ascontiguousarray(da1), c1, margin, g)
    if n_sel == 0:
        return 0.0, np.zeros(warp.n_params)
    g += dc1 - dc0
    return float(value), (g if grad else None)


# ---------------------------------------------------------------------------------------
# Public API

def _check_kernel(kernel):
    if kernel != "bilinear":
        raise ParameterError(f"the DIWE/IWA maps use bilinear votes (kernel='bilinear'), "
                             f"got kernel={kernel!r}")


def _divergence(warp, x, y, dt, theta, shape, xw=None, yw=None, jx=None, jy=None,
                margin=None, kernel="bilinear", grad=True, span=None, count=None):
    m = DEFAULT_MARGINS["divergence"] if margin is None else float(margin)
    return _trimmed_value_grad("divergence", warp, x, y, dt, theta, shape, xw, yw, jx, jy, m,
                               kernel, grad, span, count)


def _deformation(warp, x, y, dt, theta, shape, xw=None, yw=None, jx=None, jy=None,
                 margin=None, kernel="bilinear", grad=True, span=None, count=None):
    m = DEFAULT_MARGINS["deformation"] if margin is None else float(margin)
    return _trimmed_value_grad("deformation", warp, x, y, dt, theta, shape, xw, yw, jx, jy, m,
                               kernel, grad, span, count)


def _rcad(warp, x, y, dt, theta, shape, xw=None, yw=None, jx=None, jy=None, margin=None,
          kernel="bilinear", grad=True, stride=RCAD_STRIDE, span=None, count=None):
    m = DEFAULT_MARGINS["rcad"] if margin is None else float(margin)
    return _rcad_value_grad(warp, x, y, dt, theta, shape, m, int(stride), grad, span)


#: Name -> function(warp, x, y, dt, theta, shape, **kw) -> (value, grad (P,)).
REGULARIZERS = {"divergence": _divergence, "deformation": _deformation, "rcad": _rcad}


def regularizer_value_grad(name: str, warp: Warp, x, y, dt, theta, shape,
                           xw=None, yw=None, *, jx=None, jy=None, margin: float | None = None,
                           kernel: str = "bilinear", stride: int = RCAD_STRIDE,
                           grad: bool = True,
                           span: tuple[float, float] | None = None,
                           count: np.ndarray | None = None,
                           ) -> tuple[float, np.ndarray | None]:
    """Value of a collapse penalty and its gradient with respect to ``theta``.

    Parameters
    ----------
    name : {"divergence", "deformation", "rcad"}
    warp : Warp
        From :func:`evmotion.core.warps.make_warp`.
    x, y : array (N,)
        Event pixels.
    dt : array (N,)
        ``t_k - t_ref`` in seconds.
    theta : array (P,)
        Warp parameters.
    shape : (int, int)
        ``(H, W)`` of the DIWE/IWA maps, pixels.
    xw, yw : array (N,), optional
        The events warped with ``theta`` (saves a warp; the rotation's per-event values are
        read from them), in the order of ``x, y, dt``; ``jx, jy`` (N, P) their parameter
        Jacobians. Without Jacobians, warps with a ``vjp`` contract the adjoint themselves
        (no (N, P) buffers); others compute the Jacobians when a pixel is trimmed.
    margin : float, optional
        Trimming margin; defaults :data:`DEFAULT_MARGINS`.
    kernel : {"bilinear"}
        Vote kernel of the DIWE/IWA maps (the bilinear votes of core.iwe, fused here into
        one forward and one adjoint pass).
    stride : int
        Pixel stride of the RCAD map grid (rotation, homography).
    grad : bool
        Compute the gradient (else ``None`` is returned in its place).
    span : (float, float), optional
        ``(min dt, max dt)`` in seconds, when the caller knows it (e.g. once per window for
        many evaluations): saves a pass over ``dt`` per call. It must be that of ``dt``.
    count : array (H, W) float64, optional
        The bilinear IWE of ``xw, yw`` without weights, when the caller has it (CMax's data
        term): the DIWE/IWA vote-count map is then not accumulated again (divergence,
        deformation; ignored by rcad). It must be that of ``xw, yw``; it is not modified.

    Returns
    -------
    value : float
        The penalty (dimensionless; >= 0 for the trimmed ones; larger = more collapse).
    grad : array (P,)
        ``d value / d theta``.

    Examples
    --------
    >>> from evmotion.core.warps import make_warp
    >>> w = make_warp("zoom", (260, 346))
    >>> x = np.array([10.0, 200.0]); y = np.array([10.0, 100.0]); dt = np.array([0.0, 0.05])
    >>> v, g = regularizer_value_grad("rcad", w, x, y, dt, np.array([4.0]), (260, 346))
    >>> round(v, 4), round(float(g[0]), 4)  # (3.21): -2 log|1 - 4 * 0.05|
    (0.4463, 0.125)
    """
    if name not in REGULARIZERS:
        raise ParameterError(f"unknown regularizer '{name}'; choose one of "
                             f"{sorted(REGULARIZERS)}")
    _check_kernel(kernel)
    shape = _shape(shape)
    return REGULARIZERS[name](warp, x, y, dt, theta, shape, xw=xw, yw=yw, jx=jx, jy=jy,
                              margin=margin, kernel=kernel, grad=grad, span=span,
                              count=count, **({"stride": stride} if name == "rcad" else {}))


def regularizer_maps(name: str, warp: Warp, x, y, dt, theta, shape, *,
                     kernel: str = "bilinear", margin: float | None = None,
                     ) -> dict[str, np.ndarray]:
    """Maps for plotting (H, W) float64.

    * divergence: ``"diwe"`` (3.11, per window as in the thesis, empty pixels 0),
      ``"count"`` (the IWE of vote mass), ``"trimmed"`` (bool, the pixels below the
      margin);
    * deformation: ``"iwa"`` (3.16, empty pixels 1), ``"count"``, ``"trimmed"``;
    * rcad: ``"rcad"`` -- the integrated rate (area log-ratio) at every pixel's trajectory,
      dense (also where no event warps), and ``"trimmed"``.

    Examples
    --------
    >>> from evmotion.core.warps import make_warp
    >>> w = make_warp("zoom", (4, 5))
    >>> m = regularizer_maps("divergence", w, np.array([2.0]), np.array([1.0]),
    ...                      np.array([0.01]), np.array([1.0]), (4, 5))
    >>> float(m["diwe"][1, 2])  # -2 h_z per window; one event: T = 1
    -2.0
    """
    if name not in REGULARIZERS:
        raise ParameterError(f"unknown regularizer '{name}'; choose one of "
                             f"{sorted(REGULARIZERS)}")
    _check_kernel(kernel)
    shape = _shape(shape)
    x, y, dt = Warp._events(x, y, dt)
    th = warp._theta(theta)
    m = DEFAULT_MARGINS[name] if margin is None else float(margin)
    if name == "rcad":
        t0, t1 = _time_span(dt) if x.shape[0] else (0.0, 0.0)
        closed = _rcad_scalar(warp, th, t0, t1)
        if closed is not None:
            vals = np.full(shape, closed[0])
            return {"rcad": vals, "trimmed": np.ones(shape, dtype=bool)}
        ys, xs = np.mgrid[0:shape[0], 0:shape[1]]
        vals = warp.area_log_ratio(xs.ravel().astype(float), ys.ravel().astype(float), t0, t1,
                                   th).reshape(shape)
        return {"rcad": vals, "trimmed": vals > m}
    xw, yw = warp.warp(x, y, dt, th)
    _, _, cnt, num = _pixel_average(name, warp, x, y, dt, th, shape, xw, yw)
    support = cnt > MIN_COUNT
    mean = np.zeros(shape)
    np.divide(num, cnt, out=mean, where=support)
    cnt = cnt.copy()
    if name == "divergence":
        return {"diwe": mean, "count": cnt, "trimmed": support & (mean < m)}
    iwa = 1.0 + mean
    return {"iwa": iwa, "count": cnt, "trimmed": support & (iwa < m)}


def whiten(xw: np.ndarray, yw: np.ndarray, jx: np.ndarray | None = None,
           jy: np.ndarray | None = None, *, center: tuple[float, float] = (0.0, 0.0),
           scale: float = 1.0):
    """Whiten warped events (the baseline of Nunes & Demiris compared in Sec. 3.6).

    ``z_k = center + scale * C^(-1/2) (p_k - mu)`` with ``mu`` the mean and ``C`` the
    covariance of the warped positions ``p_k = (xw_k, yw_k)`` (eigen-decomposition of the
    2x2 covariance, i.e. an SVD of the centred events). ``center`` and ``scale`` (pixels)
    put the whitened cloud back on an image grid for an IWE objective (e.g. the image
    centre and the spread of the unwarped events, which do not depend on theta).

    Parameters
    ----------
    xw, yw : array (N,)
        Warped events (pixels).
    jx, jy : array (N, P), optional
        Their parameter Jacobians; if given, those of the whitened events are returned.

    Returns
    -------
    zx, zy : array (N,), and ``zjx, zjy`` (N, P) if Jacobians were given.

    Examples
    --------
    >>> zx, zy = whiten(np.array([0.0, 2.0, 0.0, 2.0]), np.array([0.0, 0.0, 4.0, 4.0]))
    >>> zx.tolist(), zy.tolist()
    ([-1.0, 1.0, -1.0, 1.0], [-1.0, -1.0, 1.0, 1.0])
    """
    xw = np.ascontiguousarray(xw, dtype=np.float64)
    yw = np.ascontiguousarray(yw, dtype=np.float64)
    n = xw.shape[0]
    if n < 3:
        raise EmptyWindowError(f"whitening needs at least 3 events, got {n}")
    jac = jx is not None and jy is not None
    if jac:
        jx = np.ascontiguousarray(jx, dtype=np.float64)
        jy = np.ascontiguousarray(jy, dtype=np.float64)
        if jx.shape != jy.shape or jx.ndim != 2 or jx.shape[0] != n:
            raise ParameterError(f"jx, jy must be ({n}, P) like the events, got {jx.shape} "
                                 f"and {jy.shape}")
    else:
        jx = jy = _EMPTY2
    P = jx.shape[1]
    mu = np.empty(2)
    C = np.empty((2, 2))
    mj = np.empty((2, P))
    _k_whiten_stats(xw, yw, jx, jy, mu, C, mj)
    lam, V = np.linalg.eigh(C)
    if lam[0] <= 1e-12 * max(lam[1], 1e-300):
        raise EmptyWindowError("whitening: the warped events are collinear (singular "
                               "covariance); cannot whiten")
    f = lam ** -0.5
    # C^(-1/2) = V diag(f) V^T, written out (2 x 2: no BLAS call)
    Cm = np.array([[V[0, 0] * f[0] * V[0, 0] + V[0, 1] * f[1] * V[0, 1],
                    V[0, 0] * f[0] * V[1, 0] + V[0, 1] * f[1] * V[1, 1]],
                   [V[1, 0] * f[0] * V[0, 0] + V[1, 1] * f[1] * V[0, 1],
                    V[1, 0] * f[0] * V[1, 0] + V[1, 1] * f[1] * V[1, 1]]])
    # Daleckii-Krein: d f(C) = V (F o (V^T dC V)) V^T, F_ij divided differences of f(l)=l^-1/2
    if abs(lam[1] - lam[0]) > 1e-12 * lam[1]:
        off = (f[1] - f[0]) / (lam[1] - lam[0])
    else:
        off = -0.5 * lam[0] ** -1.5
    F = np.array([[-0.5 * lam[0] ** -1.5, off], [off, -0.5 * lam[1] ** -1.5]])
    zx = np.empty(n)
    zy = np.empty(n)
    zjx = np.empty((n, P))
    zjy = np.empty((n, P))
    _k_whiten_apply(xw, yw, jx, jy, mu, mj, np.ascontiguousarray(V), F, Cm, float(center[0]),
                    float(center[1]), float(scale), zx, zy, zjx, zjy)
    if not jac:
        return zx, zy
    return zx, zy, zjx, zjy


@njit(cache=True, error_model="numpy")
def _k_whiten_stats(xw, yw, jx, jy, mu, C, mj):
    """Means of the warped events ``mu`` (2,) and of their Jacobians ``mj`` (2, P), and
    their covariance ``C`` (2, 2) (centred, divided by N)."""
    n = xw.shape[0]
    P = jx.shape[1]
    sx = 0.0
    sy = 0.0
    for k in range(n):
        sx += xw[k]
        sy += yw[k]
    mx = sx / n
    my = sy / n
    cxx = 0.0
    cxy = 0.0
    cyy = 0.0
    for k in range(n):
        a = xw[k] - mx
        b = yw[k] - my
        cxx += a * a
        cxy += a * b
        cyy += b * b
    mu[0] = mx
    mu[1] = my
    C[0, 0] = cxx / n
    C[0, 1] = cxy / n
    C[1, 0] = cxy / n
    C[1, 1] = cyy / n
    for j in range(P):
        mj[0, j] = 0.0
        mj[1, j] = 0.0
    for k in range(jx.shape[0]):
        for j in range(P):
            mj[0, j] += jx[k, j]
            mj[1, j] += jy[k, j]
    for j in range(P):
        mj[0, j] /= n
        mj[1, j] /= n


@njit(cache=True, error_model="numpy")
def _k_whiten_apply(xw, yw, jx, jy, mu, mj, V, F, Cm, c0, c1, scale, zx, zy, zjx, zjy):
    """Whitened events and, if ``jx`` has rows, their parameter Jacobians (see
    :func:`whiten`): one pass for the covariance derivatives ``dC_j``, one for the
    outputs."""
    n = xw.shape[0]
    P = jx.shape[1]
    mx = mu[0]
    my = mu[1]
    for k in range(n):
        a = xw[k] - mx
        b = yw[k] - my
        zx[k] = c0 + scale * (Cm[0, 0] * a + Cm[0, 1] * b)
        zy[k] = c1 + scale * (Cm[1, 0] * a + Cm[1, 1] * b)
    if jx.shape[0] == 0:
        return
    # S_j = sum_k c_k dc_kj^T; dC_j = (S_j + S_j^T) / n
    S = np.zeros((P, 2, 2))
    for k in range(n):
        a = xw[k] - mx
        b = yw[k] - my
        for j in range(P):
            u = jx[k, j] - mj[0, j]
            v = jy[k, j] - mj[1, j]
            S[j, 0, 0] += a * u
            S[j, 0, 1] += a * v
            S[j, 1, 0] += b * u
            S[j, 1, 1] += b * v
    D = np.empty((P, 2, 2))
    for j in range(P):
        d00 = 2.0 * S[j, 0, 0] / n
        d01 = (S[j, 0, 1] + S[j, 1, 0]) / n
        d11 = 2.0 * S[j, 1, 1] / n
        # M = F o (V^T dC V), then dCm = V M V^T
        m = np.empty((2, 2))
        for p in range(2):
            for q in range(2):
                t = (V[0, p] * (d00 * V[0, q] + d01 * V[1, q])
                     + V[1, p] * (d01 * V[0, q] + d11 * V[1, q]))
                m[p, q] = F[p, q] * t
        for p in range(2):
            for q in range(2):
                D[j, p, q] = (V[p, 0] * (m[0, 0] * V[q, 0] + m[0, 1] * V[q, 1])
                              + V[p, 1] * (m[1, 0] * V[q, 0] + m[1, 1] * V[q, 1]))
    for k in range(n):
        a = xw[k] - mx
        b = yw[k] - my
        for j in range(P):
            u = jx[k, j] - mj[0, j]
            v = jy[k, j] - mj[1, j]
            zjx[k, j] = scale * (D[j, 0, 0] * a + D[j, 0, 1] * b + Cm[0, 0] * u + Cm[0, 1] * v)
            zjy[k, j] = scale * (D[j, 1, 0] * a + D[j, 1, 1] * b + Cm[1, 0] * u + Cm[1, 1] * v)
