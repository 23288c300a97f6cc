"""Parametric event warps of chapter 3 and Appendix A, with their differential quantities.

Every warp transports an event at pixel ``(x, y)`` and time ``t_ref + dt`` back to the
reference time ``t_ref`` along the point trajectory through it, ``x' = W(x, dt; theta)``.

Conventions (the same for every warp):

* ``x, y`` are plain sensor pixels (column, row; origin top-left), float64 arrays (N,);
  warps that the thesis writes in centred coordinates (zoom, SE(2), in-plane, similarity,
  affine, homography) centre them internally on ``center`` (default: the image centre
  ``((W - 1) / 2, (H - 1) / 2)``), the rotation warp normalizes them with the intrinsics
  ``K``. Inputs and outputs are always sensor pixels.
* ``dt`` is ``t_k - t_ref`` in **seconds** (t_ref may be the window's start, middle or end);
  parameters are rates per second (``param_units`` names them). The thesis writes the zoom
  (3.7) in time normalized to [0, 1]; :func:`zoom_normalized_to_rate` converts.
* Each warp is a 3x3 matrix ``M(dt; theta)`` acting on homogeneous pixel coordinates,
  ``x' ~ M(dt; theta) (x, y, 1)^T``: the inverse of the trajectory homography ``H`` of (A.1).
  The differential quantities below follow from ``M`` and ``dM/dt`` in closed form:

  - :meth:`Warp.flow` -- (3.8) ``f = dW/dt`` at the event, px/s. It is minus the image
    velocity: at ``dt = 0`` the optical flow of the scene is ``-f``
    (:meth:`Warp.optical_flow`).
  - :meth:`Warp.divergence` -- ``div f = tr(df/dx)``, 1/s (3.9); negative = contraction.
  - :meth:`Warp.jacobian_det` -- ``det(dW/dx)`` (3.13), (A.4): ``det M / (e3^T M x)^3``.
  - :meth:`Warp.rcad` -- the rate of change of area deformation at the event,
    ``d|J_{t,t+h}|/dh`` at ``h = 0`` (3.20), (3.27), 1/s. It is the divergence of the
    image velocity along the trajectory, positive where the trajectories spread forward in
    time, i.e. where warping back to ``t_ref`` contracts (collapse-enabling).
  - :meth:`Warp.area_log_ratio` -- the RCAD integrated along the trajectory over a time
    span, (3.21), (3.28), (A.44), (A.53). By Liouville's formula the integral of the
    divergence along a trajectory is the log of the area ratio between its ends, so the
    integral is exact: ``log|det dx(t1)/dx_ref| - log|det dx(t0)/dx_ref|``.

Parameter derivatives: the hot path (:meth:`Warp.warp` / :meth:`Warp.warp_into` with the
Jacobian ``d x'/d theta``) is a hand-derived numba kernel per warp. The warps up to 4 DOF
also chain per-event gradients through their Jacobian without storing it
(``vjp``, ``reduce_bilinear``: the Jacobian recomputed inside the adjoint pass, fused with
the bilinear IWE adjoint), the hot path of gradient-based contrast maximization. The rotation's
divergence and determinant have hand-derived omega-derivatives too (numba); the other
derivatives of the divergence, determinant and area ratio with respect to ``theta`` are
computed exactly by complex-step differentiation of the same closed forms (no step-size
error), and the regularizers use closed forms where the thesis gives them.

Sign conventions of the parameters (camera frame x right, y down, z forward):

* ``translation``: ``theta = (vx, vy)`` is the image velocity in px/s: ``x' = x - dt v``
  (3.5.1 writes ``x + dt theta``; this is the sign used by the rest of the package).
* ``rotation``: ``theta = omega`` is the camera's angular velocity in rad/s:
  ``x'_n ~ exp(dt omega^) x_n`` in normalized coordinates (3.22). Its flow at dt = 0 is minus
  the rotational part of the feature sensitivity matrix (3.29), its divergence is (3.23).
  Right-handed about the camera axes: ``wz > 0`` turns the image content counter-clockwise
  on screen (x right, y down).
* ``se2``, ``similarity``: ``wz`` in rad/s has the rotation's sign (the camera's rate about
  the optical axis; the thesis' A.11/A.36 ``w_z`` is minus it), so that a camera turning
  about z gives the same-sign ``wz`` from ``rotation`` and ``se2``.

Examples
--------
>>> import numpy as np
>>> w = make_warp("zoom", sensor_size=(260, 346))
>>> x = np.array([10.0, 300.0]); y = np.array([20.0, 200.0]); dt = np.array([0.0, 0.05])
>>> xw, yw = w.warp(x, y, dt, np.array([2.0]))
>>> float(w.divergence(x, y, dt, np.array([2.0]))[0])
-4.0
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from evmotion.core.iwe import _shape
from evmotion.errors import CalibrationError, ParameterError
from evmotion.jitcache import kernel_case

__all__ = [
    "WARPS",
    "Warp",
    "make_warp",
    "rodrigues",
    "zoom_normalized_to_rate",
    "zoom_rate_to_normalized",
]

_CSTEP = 1e-30  # complex-step size: exact derivatives to machine precision, any tiny value works


def zoom_normalized_to_rate(b_z: float, window_s: float) -> float:
    """Convert the thesis' zoom parameter of (3.7) (time normalized to [0, 1]) to a rate.

    (3.7) warps ``x' = (1 - t~ b_z) x`` with ``t~ = (t - t_1) / T`` for a window of duration
    ``T`` seconds; with ``dt = t - t_1`` that is ``x' = (1 - dt * rate) x``, so
    ``rate = b_z / T`` in 1/s.

    Examples
    --------
    >>> zoom_normalized_to_rate(0.2, 0.05)
    4.0
    """
    if not window_s > 0:
        raise ParameterError(f"window_s must be > 0 seconds, got {window_s!r}")
    return float(b_z) / float(window_s)


def zoom_rate_to_normalized(rate: float, window_s: float) -> float:
    """Inverse of :func:`zoom_normalized_to_rate`: ``b_z = rate * T`` (dimensionless)."""
    if not window_s > 0:
        raise ParameterError(f"window_s must be > 0 seconds, got {window_s!r}")
    return float(rate) * float(window_s)


# ---------------------------------------------------------------------------------------
# Rodrigues formula, safe for complex arguments (complex-step) and for omega -> 0.

def _sinc_terms(z):
    """``sin(a)/a``, ``(1-cos a)/a^2``, ``(a-sin a)/a^3`` as functions of ``z = a^2``."""
    z = np.asarray(z)
    small = np.abs(z) < 1.0
    zs = np.where(small, z, 0.0)
    a_ = np.zeros_like(zs)
    b_ = np.zeros_like(zs)
    c_ = np.zeros_like(zs)
    term_a = np.ones_like(zs)
    term_b = 0.5 * np.ones_like(zs)
    term_c = np.ones_like(zs) / 6.0
    for k in range(12):  # |z| < 1: 12 terms of the series reach 1e-20
        a_ = a_ + term_a
        b_ = b_ + term_b
        c_ = c_ + term_c
        term_a = -term_a * zs / ((2 * k + 2) * (2 * k + 3))
        term_b = -term_b * zs / ((2 * k + 3) * (2 * k + 4))
        term_c = -term_c * zs / ((2 * k + 4) * (2 * k + 5))
    if np.all(small):
        return a_, b_, c_
    zl = np.where(small, 1.0, z)
    a = np.sqrt(zl)
    with np.errstate(all="ignore"):
        al, bl, cl = np.sin(a) / a, (1 - np.cos(a)) / zl, (a - np.sin(a)) / (zl * a)
    return np.where(small, a_, al), np.where(small, b_, bl), np.where(small, c_, cl)


def _hat(w):
    o = np.zeros_like(w[0])
    return np.array([[o, -w[2], w[1]], [w[2], o, -w[0]], [-w[1], w[0], o]])


def rodrigues(rotvec: np.ndarray) -> np.ndarray:
    """Rotation matrix ``exp(rotvec^)`` (exponential coordinates, radians).

    Parameters
    ----------
    rotvec : array (3,) or (N, 3)
        Rotation vectors in radians (axis times angle).

    Returns
    -------
    R : array (3, 3) or (N, 3, 3)

    Examples
    --------
    >>> np.round(rodrigues(np.array([0.0, 0.0, np.pi / 2])), 6)[0]
    array([ 0., -1.,  0.])
    """
    r = np.asarray(rotvec)
    single = r.ndim == 1
    r = np.atleast_2d(r)
    z = np.sum(r * r, axis=1)
    a, b, _ = _sinc_terms(z)
    W = np.moveaxis(_hat(r.T), -1, 0)
    W2 = W @ W
    R = np.eye(3) + a[:, None, None] * W + b[:, None, None] * W2
    return R[0] if single else R


# ---------------------------------------------------------------------------------------
# numba hot paths: warp + d(x')/d(theta), one pass, into preallocated outputs.
# Angles per event are small in practice (|dt * w| < 1 rad): a Horner polynomial there is
# exact to rounding and several times cheaper than libm's sin/cos.

_ABS_BITS = np.uint64(0x7FFFFFFFFFFFFFFF)


@njit(cache=True, error_model="numpy")
def _max_abs(a):
    """``max |a|`` of a contiguous float64 array (0 if empty; NaN if any is NaN)."""
    # the magnitudes of floats order like their bit patterns without the sign, and an
    # integer max vectorizes where a float max (NaN semantics) does not; a NaN's pattern
    # exceeds inf's, so NaN still wins
    bits = a.view(np.uint64)
    m = np.uint64(0)
    for k in range(bits.shape[0]):
        m = max(m, bits[k] & _ABS_BITS)
    out = np.empty(1, np.uint64)
    out[0] = m
    return out.view(np.float64)[0]


#: 1/n! for n = 0..23, the coefficients of the Rodrigues series below.
_INV_FACT = np.array([1.0 / math.factorial(n) for n in range(24)])


@njit(cache=True, inline="always")
def _series(z, first, nterms):
    """``sum_k (-z)^k / (first + 2k)!`` over ``k < nterms`` (Horner; the constant trip count
    unrolls, and the loops over events calling it stay branch-free)."""
    s = _INV_FACT[first + 2 * (nterms - 1)]
    for k in range(nterms - 2, -1, -1):
        s = _INV_FACT[first + 2 * k] - z * s
    return s


@njit(cache=True, inline="always")
def _rod_coeffs(z):
    """sin(a)/a, (1-cos a)/a^2, (a-sin a)/a^3 for z = a^2 < 1: eleven terms each, the
    truncation below 1/21! < 2e-20."""
    return _series(z, 1, 11), _series(z, 2, 11), _series(z, 3, 11)


@njit(cache=True, inline="always")
def _sincos(a):
    """sin, cos for |a| < 1 from the series of :func:`_rod_coeffs` (sin a = a A(a^2),
    cos a = 1 - a^2 B(a^2)), branch-free so that loops over events vectorize."""
    z = a * a
    sa, cb, _ = _rod_coeffs(z)
    return a * sa, 1.0 - z * cb


@njit(cache=True, inline="always")
def _rod_coeffs_short(z):
    """:func:`_rod_coeffs` for z < 0.05 (|dt omega| < 0.22 rad, the usual case): seven
    terms suffice (truncation below z^7/15! < 1e-21)."""
    return _series(z, 1, 7), _series(z, 2, 7), _series(z, 3, 7)


@njit(cache=True)
def _rod_coeffs_exact(z):
    ang = math.sqrt(z)
    sa = math.sin(ang)
    return sa / ang, (1.0 - math.cos(ang)) / z, (ang - sa) / (z * ang)



# fastmath without the no-NaN/no-inf assumptions: lets LLVM fuse and reorder arithmetic
# (rounding-level differences) while non-finite events still propagate as NaN/inf
_FAST_FINITE = {"contract", "arcp", "nsz", "reassoc"}

_BLOCK = 512  # events per block of the vectorized trigonometric pass


# Each case of a hot kernel (series mode, Jacobian or not, fused image or not, weights,
# pair mode, value kind) is its own kernel, built on first use by
# :func:`evmotion.jitcache.kernel_case` and compiled (or loaded from the cache) then: a call
# compiles the cases it runs, not all of them. One kernel holding every case as a branch
# compiled them all on its first call, whatever it needed: 98 s for the rotation adjoint's
# 20 cases on an empty numba cache, 17 s for the zoom/translation/in-plane ones.



@njit(cache=True, error_model="numpy")
def _sincos_block(dt, k0, k1, w, sbuf, cbuf):
    # contiguous 1-D loop with no branch: SIMD (the regularizers' per-block passes use it)
    for k in range(k0, k1):
        sbuf[k - k0], cbuf[k - k0] = _sincos(-dt[k] * w)


# The hot kernels below run one loop per case (series or libm trigonometry, Jacobian or
# not, fused image adjoint or not) rather than branching inside one loop: a loop-invariant
# branch in the body is not hoisted by LLVM here, and it stops the loop's vectorization
# (measured: 13x slower for the rotation warp).

@njit(cache=True)
def _sincos_any(a, small):
    if small:
        return _sincos(a)
    return math.sin(a), math.cos(a)


@njit(cache=True, error_model="numpy")
def _similarity_event(x, y, t, sn, c, vx, vy, s, cx, cy):
    """Centred warped point ``(ox, oy)`` and ``1 / beta`` of one event."""
    ib = 1.0 / (1.0 + t * s)  # s is 0 for SE(2)
    u = x - cx - t * vx
    v = y - cy - t * vy
    return (c * u - sn * v) * ib, (sn * u + c * v) * ib, ib


@njit(cache=True, error_model="numpy", inline="always")
def _similarity_jac_loop(small, scaled, args):
    x, y, dt, vx, vy, w, s, cx, cy, xw, yw, jx, jy = args
    p = 4 if scaled else 3
    # flat views: strided stores into 1-D arrays vectorize, 2-D item stores do not
    jxf = jx.reshape(jx.size)
    jyf = jy.reshape(jy.size)
    for k in range(x.shape[0]):
        t = dt[k]
        sn, c = _sincos_any(-t * w, small)
        ox, oy, ib = _similarity_event(x[k], y[k], t, sn, c, vx, vy, s, cx, cy)
        xw[k] = cx + ox
        yw[k] = cy + oy
        r = p * k
        jxf[r] = -t * c * ib
        jyf[r] = -t * sn * ib
        jxf[r + 1] = t * sn * ib
        jyf[r + 1] = -t * c * ib
        jxf[r + 2] = t * oy
        jyf[r + 2] = -t * ox
        if scaled:
            jxf[r + 3] = -t * ib * ox
            jyf[r + 3] = -t * ib * oy


@njit(cache=True, error_model="numpy", fastmath=_FAST_FINITE)
def _k_similarity(x, y, dt, vx, vy, w, s, cx, cy, xw, yw, jx, jy, jac, scaled):
    # angles below 1 rad take the series of _sincos (exact to rounding, vectorizes)
    small = _max_abs(dt) * abs(w) < 1.0
    n = x.shape[0]
    if jac:
        a = (x, y, dt, vx, vy, w, s, cx, cy, xw, yw, jx, jy)
        if small and scaled:
            _similarity_jac_loop(True, True, a)
        elif small:
            _similarity_jac_loop(True, False, a)
        else:
            _similarity_jac_loop(False, scaled, a)
    elif small:
        for k in range(n):
            t = dt[k]
            sn, c = _sincos(-t * w)
            ox, oy, _ = _similarity_event(x[k], y[k], t, sn, c, vx, vy, s, cx, cy)
            xw[k] = cx + ox
            yw[k] = cy + oy
    else:
        for k in range(n):
            t = dt[k]
            sn = math.sin(-t * w)
            c = math.cos(-t * w)
            ox, oy, _ = _similarity_event(x[k], y[k], t, sn, c, vx, vy, s, cx, cy)
            xw[k] = cx + ox
            yw[k] = cy + oy


@njit(cache=True, error_model="numpy")
def _pad_image(g, shift, pad):
    """``g`` (H, W) into the flat ``pad`` ((H + 2) (W + 2),) with a one-pixel ring of
    ``shift`` around it, so the fused adjoints need no bounds tests."""
    h, wd = g.shape
    wp = wd + 2
    for j in range(wp):
        pad[j] = shift
        pad[(h + 1) * wp + j] = shift
    for i in range(h):
        r = (i + 1) * wp
        pad[r] = shift
        for j in range(wd):
            pad[r + 1 + j] = g[i, j]
        pad[r + wd + 1] = shift


@njit(cache=True, error_model="numpy")
def _similarity_vjp_event(ox, oy, t, sn, c, s, gX, gY):
    """``gX dxw/dtheta + gY dyw/dtheta`` (4 terms) from the centred warped point: the
    Jacobian of :func:`_k_similarity`, contracted instead of stored."""
    ib = 1.0 / (1.0 + t * s)
    tib = t * ib
    return (-tib * (gX * c + gY * sn), tib * (gX * sn - gY * c), t * (gX * oy - gY * ox),
            -tib * (gX * ox + gY * oy))


@njit(cache=True, error_model="numpy")
def _k_zoom(x, y, dt, h, cx, cy, xw, yw, jx, jy, jac):
    if not jac:
        for k in range(x.shape[0]):
            s = 1.0 - dt[k] * h
            xw[k] = cx + s * (x[k] - cx)
            yw[k] = cy + s * (y[k] - cy)
        return
    jxf = jx.reshape(jx.size)
    jyf = jy.reshape(jy.size)
    for k in range(x.shape[0]):
        xc = x[k] - cx
        yc = y[k] - cy
        s = 1.0 - dt[k] * h
        xw[k] = cx + s * xc
        yw[k] = cy + s * yc
        jxf[k] = -dt[k] * xc
        jyf[k] = -dt[k] * yc


@njit(cache=True, error_model="numpy")
def _k_translation(x, y, dt, vx, vy, xw, yw, jx, jy, jac):
    for k in range(x.shape[0]):
        xw[k] = x[k] - dt[k] * vx
        yw[k] = y[k] - dt[k] * vy
    if jac:
        jxf = jx.reshape(jx.size)
        jyf = jy.reshape(jy.size)
        for k in range(x.shape[0]):
            jxf[2 * k] = -dt[k]
            jxf[2 * k + 1] = 0.0
            jyf[2 * k] = 0.0
            jyf[2 * k + 1] = -dt[k]


@njit(cache=True, error_model="numpy")
def _inplane_event(x, y, t, vx, vy, c, sn, kk, cx, cy):
    """Warped pixel and the rotated centred point ``R(phi) (x - c)`` of one event."""
    xc = x - cx
    yc = y - cy
    r0 = c * xc - sn * yc
    r1 = sn * xc + c * yc
    return x - t * (vx + kk * r0 - xc), y - t * (vy + kk * r1 - yc), r0, r1


@njit(cache=True, error_model="numpy", fastmath=_FAST_FINITE)
def _k_inplane(x, y, dt, vx, vy, phi, hz, cx, cy, xw, yw, jx, jy, jac):
    c = math.cos(phi)
    sn = math.sin(phi)
    kk = hz + 1.0
    if not jac:
        for k in range(x.shape[0]):
            xw[k], yw[k], _, _ = _inplane_event(x[k], y[k], dt[k], vx, vy, c, sn, kk, cx, cy)
        return
    jxf = jx.reshape(jx.size)
    jyf = jy.reshape(jy.size)
    for k in range(x.shape[0]):
        t = dt[k]
        xw[k], yw[k], r0, r1 = _inplane_event(x[k], y[k], t, vx, vy, c, sn, kk, cx, cy)
        jxf[4 * k] = -t
        jyf[4 * k] = 0.0
        jxf[4 * k + 1] = 0.0
        jyf[4 * k + 1] = -t
        jxf[4 * k + 2] = t * kk * r1
        jyf[4 * k + 2] = -t * kk * r0
        jxf[4 * k + 3] = -t * r0
        jyf[4 * k + 3] = -t * r1


@njit(cache=True, error_model="numpy", fastmath=_FAST_FINITE)
def _k_affine(x, y, dt, th, cx, cy, xw, yw, jx, jy, jac):
    vx, vy, g11, g12, g21, g22 = th[0], th[1], th[2], th[3], th[4], th[5]
    if not jac:
        for k in range(x.shape[0]):
            w0, w1, _, _, _, _ = _affine_event(x[k], y[k], dt[k], vx, vy, g11, g12, g21, g22,
                                               cx, cy)
            xw[k] = cx + w0
            yw[k] = cy + w1
        return
    # flat views: strided stores into 1-D arrays vectorize, 2-D item stores do not
    jxf = jx.reshape(jx.size)
    jyf = jy.reshape(jy.size)
    for k in range(x.shape[0]):
        t = dt[k]
        w0, w1, a00, a01, a10, a11 = _affine_event(x[k], y[k], t, vx, vy, g11, g12, g21, g22,
                                                   cx, cy)
        xw[k] = cx + w0
        yw[k] = cy + w1
        r = 6 * k
        jxf[r] = -t * a00
        jyf[r] = -t * a10
        jxf[r + 1] = -t * a01
        jyf[r + 1] = -t * a11
        jxf[r + 2] = -t * a00 * w0
        jyf[r + 2] = -t * a10 * w0
        jxf[r + 3] = -t * a00 * w1
        jyf[r + 3] = -t * a10 * w1
        jxf[r + 4] = -t * a01 * w0
        jyf[r + 4] = -t * a11 * w0
        jxf[r + 5] = -t * a01 * w1
        jyf[r + 5] = -t * a11 * w1


@njit(cache=True, error_model="numpy")
def _affine_event(x, y, t, vx, vy, g11, g12, g21, g22, cx, cy):
    """Centred warped point ``(w0, w1)`` of one event and ``A(t)^-1`` (4 entries)."""
    a00 = 1.0 + t * g22
    a01 = -t * g12
    a10 = -t * g21
    a11 = 1.0 + t * g11
    idet = 1.0 / (a00 * a11 - a01 * a10)
    a00 *= idet
    a01 *= idet
    a10 *= idet
    a11 *= idet
    u = x - cx - t * vx
    v = y - cy - t * vy
    return a00 * u + a01 * v, a10 * u + a11 * v, a00, a01, a10, a11


@njit(cache=True, error_model="numpy", fastmath=_FAST_FINITE)
def _k_homography(x, y, dt, th, cx, cy, xw, yw, jx, jy, jac):
    inv = np.empty((3, 3))
    q = np.empty(3)
    for k in range(x.shape[0]):
        t = dt[k]
        h00 = 1.0 + t * th[0]
        h01 = t * th[1]
        h02 = t * th[2]
        h10 = t * th[3]
        h11 = 1.0 + t * th[4]
        h12 = t * th[5]
        h20 = t * th[6]
        h21 = t * th[7]
        h22 = 1.0
        c00 = h11 * h22 - h12 * h21
        c01 = h02 * h21 - h01 * h22
        c02 = h01 * h12 - h02 * h11
        idet = 1.0 / (h00 * c00 + h10 * c01 + h20 * c02)
        inv[0, 0] = c00 * idet
        inv[0, 1] = c01 * idet
        inv[0, 2] = c02 * idet
        inv[1, 0] = (h12 * h20 - h10 * h22) * idet
        inv[1, 1] = (h00 * h22 - h02 * h20) * idet
        inv[1, 2] = (h02 * h10 - h00 * h12) * idet
        inv[2, 0] = (h10 * h21 - h11 * h20) * idet
        inv[2, 1] = (h01 * h20 - h00 * h21) * idet
        inv[2, 2] = (h00 * h11 - h01 * h10) * idet
        u = x[k] - cx
        v = y[k] - cy
        for i in range(3):
            q[i] = inv[i, 0] * u + inv[i, 1] * v + inv[i, 2]
        iz = 1.0 / q[2]
        ox = q[0] * iz
        oy = q[1] * iz
        xw[k] = cx + ox
        yw[k] = cy + oy
        if jac:
            # d(H^-1)/dg_ij = -t H^-1 E_ij H^-1, so dq = -t inv[:, i] q_j
            for p in range(8):
                i = p // 3
                j = p % 3
                s = -t * q[j]
                d0 = s * inv[0, i]
                d1 = s * inv[1, i]
                d2 = s * inv[2, i]
                jx[k, p] = (d0 - ox * d2) * iz
                jy[k, p] = (d1 - oy * d2) * iz


@njit(cache=True, error_model="numpy")
def _rod_block(dt, k0, k1, ww, mode, abuf, bbuf, cbuf):
    # modes 0 and 1 are branch-free (SIMD); 2 has angles above 1 rad
    if mode == 0:
        for k in range(k0, k1):
            t = dt[k]
            abuf[k - k0], bbuf[k - k0], cbuf[k - k0] = _rod_coeffs_short(t * t * ww)
    elif mode == 1:
        for k in range(k0, k1):
            t = dt[k]
            abuf[k - k0], bbuf[k - k0], cbuf[k - k0] = _rod_coeffs(t * t * ww)
    else:
        for k in range(k0, k1):
            t = dt[k]
            z = t * t * ww
            if z < 1.0:
                abuf[k - k0], bbuf[k - k0], cbuf[k - k0] = _rod_coeffs(z)
            else:
                abuf[k - k0], bbuf[k - k0], cbuf[k - k0] = _rod_coeffs_exact(z)


@njit(cache=True, error_model="numpy", inline="always")
def _rot_point(x, y, t, a, b, wx, wy, wz, i00, i01, i02, i10, i11, i12, i20, i21, i22):
    """Rodrigues rotation of K^-1 (x, y, 1) by t omega, with its projection."""
    xn = i00 * x + i01 * y + i02
    yn = i10 * x + i11 * y + i12
    zn = i20 * x + i21 * y + i22
    c1x = wy * zn - wz * yn
    c1y = wz * xn - wx * zn
    c1z = wx * yn - wy * xn
    c2x = wy * c1z - wz * c1y
    c2y = wz * c1x - wx * c1z
    c2z = wx * c1y - wy * c1x
    at = a * t
    bt = b * t * t
    q0 = xn + at * c1x + bt * c2x
    q1 = yn + at * c1y + bt * c2y
    q2 = zn + at * c1z + bt * c2z
    iz = 1.0 / q2
    return q0 * iz, q1 * iz, q0, q1, q2, iz


@njit(cache=True, inline="always")
def _rod_mode(z, mode):
    """Rodrigues coefficients for the series mode of :func:`_rot_rates` (a constant mode
    folds the branches away; mode 2 keeps a per-event branch)."""
    if mode == 0:
        return _rod_coeffs_short(z)
    if mode == 1 or z < 1.0:
        return _rod_coeffs(z)
    return _rod_coeffs_exact(z)


@njit(cache=True, error_model="numpy", inline="always")
def _rows01(m):
    """The first two rows of the 3x3 matrix ``m`` as six scalars: the kernels hold K and
    K^-1 in registers (their output arrays might alias the matrices, which would force a
    reload per event)."""
    return m[0, 0], m[0, 1], m[0, 2], m[1, 0], m[1, 1], m[1, 2]


@njit(cache=True, error_model="numpy")
def _rot_warp_event(x, y, t, a, b, wx, wy, wz, k00, k01, k02, k10, k11, k12, i00, i01, i02,
                    i10, i11, i12):
    """Warped pixel of one event: :func:`_rot_warp_norm`, then K."""
    X, Y = _rot_warp_norm(x, y, t, a, b, wx, wy, wz, i00, i01, i02, i10, i11, i12)
    return k00 * X + k01 * Y + k02, k10 * X + k11 * Y + k12


@njit(cache=True, error_model="numpy", inline="always")
def _rot_warp_norm(x, y, t, a, b, wx, wy, wz, i00, i01, i02, i10, i11, i12):
    """Warped normalized point of one event: :func:`_rot_point` with K^-1's last row
    (0, 0, 1) written in."""
    xn = i00 * x + i01 * y + i02
    yn = i10 * x + i11 * y + i12
    c1x = wy - wz * yn
    c1y = wz * xn - wx
    c1z = wx * yn - wy * xn
    at = a * t
    bt = b * t * t
    q0 = xn + at * c1x + bt * (wy * c1z - wz * c1y)
    q1 = yn + at * c1y + bt * (wz * c1x - wx * c1z)
    iz = 1.0 / (1.0 + at * c1z + bt * (wx * c1y - wy * c1x))
    return q0 * iz, q1 * iz


def _rot_warp_case(mode, jac):
    """The rotation warp kernel in series mode ``mode`` (:func:`_rot_rates`), with the
    Jacobian (``jac``) or not: one case, compiled on first use (:func:`evmotion.jitcache.kernel_case`)."""
    if jac:
        @njit(cache=True, error_model="numpy", fastmath=_FAST_FINITE)
        def rot_warp_jac(x, y, dt, w, Kmat, Kinv, xw, yw, jx, jy):
            _rot_jac_loop(mode, (x, y, dt, xw, yw, jx, jy, w, Kmat, Kinv))

        return rot_warp_jac

    @njit(cache=True, error_model="numpy", fastmath=_FAST_FINITE)
    def rot_warp(x, y, dt, w, Kmat, Kinv, xw, yw, jx, jy):
        wx, wy, wz = w[0], w[1], w[2]
        ww = wx * wx + wy * wy + wz * wz
        k00, k01, k02, k10, k11, k12 = _rows01(Kmat)
        i00, i01, i02, i10, i11, i12 = _rows01(Kinv)
        for k in range(x.shape[0]):
            t = dt[k]
            a, b, _ = _rod_mode(t * t * ww, mode)
            xw[k], yw[k] = _rot_warp_event(x[k], y[k], t, a, b, wx, wy, wz, k00, k01, k02,
                                           k10, k11, k12, i00, i01, i02, i10, i11, i12)

    return rot_warp


@njit(cache=True, error_model="numpy", inline="always")
def _rot_jac_event(x, y, t, a, b, c, wx, wy, wz, ww, k00, k01, k02, k10, k11, k12, i00, i01,
                   i02, i10, i11, i12, i20, i21, i22):
    """Warped pixel and its omega-derivatives ``(xw, yw, jx0, jx1, jx2, jy0, jy1, jy2)``."""
    X, Y, _, _, _, _ = _rot_point(x, y, t, a, b, wx, wy, wz, i00, i01, i02, i10, i11, i12, i20,
                                  i21, i22)
    # d(X, Y)/d omega = -t L J_l(t omega) with L the rotational interaction matrix
    # at the warped point, rows L0 = (XY, -(1 + X^2), Y), L1 = (1 + Y^2, -XY, -X),
    # and J_l = g Id + b t omega^ + c t^2 omega omega^T, g = 1 - c t^2 |omega|^2:
    # row u of L J_l is g u + b t (u x omega) + c t^2 (u . omega) omega
    bt1 = b * t
    ct2 = c * t * t
    g = 1.0 - ct2 * ww
    xy = X * Y
    u0, u1, u2 = xy, -1.0 - X * X, Y
    v0, v1, v2 = 1.0 + Y * Y, -xy, -X
    su = ct2 * (u0 * wx + u1 * wy + u2 * wz)
    sv = ct2 * (v0 * wx + v1 * wy + v2 * wz)
    dx0 = -t * (g * u0 + bt1 * (u1 * wz - u2 * wy) + su * wx)
    dx1 = -t * (g * u1 + bt1 * (u2 * wx - u0 * wz) + su * wy)
    dx2 = -t * (g * u2 + bt1 * (u0 * wy - u1 * wx) + su * wz)
    dy0 = -t * (g * v0 + bt1 * (v1 * wz - v2 * wy) + sv * wx)
    dy1 = -t * (g * v1 + bt1 * (v2 * wx - v0 * wz) + sv * wy)
    dy2 = -t * (g * v2 + bt1 * (v0 * wy - v1 * wx) + sv * wz)
    return (k00 * X + k01 * Y + k02, k10 * X + k11 * Y + k12, k00 * dx0 + k01 * dy0,
            k00 * dx1 + k01 * dy1, k00 * dx2 + k01 * dy2, k10 * dx0 + k11 * dy0,
            k10 * dx1 + k11 * dy1, k10 * dx2 + k11 * dy2)


@njit(cache=True, error_model="numpy", inline="always")
def _rot_jac_loop(mode, args):
    x, y, dt, xw, yw, jx, jy, w, Kmat, Kinv = args
    wx, wy, wz = w[0], w[1], w[2]
    ww = wx * wx + wy * wy + wz * wz
    k00, k01, k02, k10, k11, k12 = _rows01(Kmat)
    i00, i01, i02, i10, i11, i12 = _rows01(Kinv)
    i20, i21, i22 = Kinv[2, 0], Kinv[2, 1], Kinv[2, 2]
    # flat views: stride-3 stores into 1-D arrays vectorize, 2-D item stores do not
    jxf = jx.reshape(jx.size)
    jyf = jy.reshape(jy.size)
    for k in range(x.shape[0]):
        t = dt[k]
        a, b, c = _rod_mode(t * t * ww, mode)
        xw[k], yw[k], jxf[3 * k], jxf[3 * k + 1], jxf[3 * k + 2], jyf[3 * k], jyf[3 * k + 1], \
            jyf[3 * k + 2] = _rot_jac_event(x[k], y[k], t, a, b, c, wx, wy, wz, ww, k00, k01,
                                            k02, k10, k11, k12, i00, i01, i02, i10, i11, i12,
                                            i20, i21, i22)


@njit(cache=True, error_model="numpy")
def _rot_vjp_event(X, Y, t, b, c, wx, wy, wz, ww, gX, gY):
    """``gX dX/domega + gY dY/domega`` (3 terms) at the warped normalized point (X, Y);
    the formula of the Jacobian in :func:`_rot_jac_event`, contracted instead of stored."""
    return _rot_vjp_u(X, Y, t, b, c, wx, wy, wz, ww, gX, gY, 0.0, 0.0, 0.0)


@njit(cache=True, error_model="numpy", inline="always")
def _rot_vjp_u(X, Y, t, b, c, wx, wy, wz, ww, gX, gY, e0, e1, e2):
    """:func:`_rot_vjp_event` with ``e`` added to its vector ``u`` (``-t J_l^T u`` is the
    result)."""
    bt1 = b * t
    ct2 = c * t * t
    g = 1.0 - ct2 * ww
    xy = X * Y
    # contract the rows first: gX L0 + gY L1, a single 3-vector u
    u0 = gX * xy + gY * (1.0 + Y * Y) + e0
    u1 = -gX * (1.0 + X * X) - gY * xy + e1
    u2 = gX * Y - gY * X + e2
    su = ct2 * (u0 * wx + u1 * wy + u2 * wz)
    return (-t * (g * u0 + bt1 * (u1 * wz - u2 * wy) + su * wx),
            -t * (g * u1 + bt1 * (u2 * wx - u0 * wz) + su * wy),
            -t * (g * u2 + bt1 * (u0 * wy - u1 * wx) + su * wz))


@njit(cache=True, error_model="numpy")
def _rot_adj_event(xv, yv, t, b, c, gx, gy, wx, wy, wz, ww, k00, k01, k10, k11, i00, i01, i02,
                   i10, i11, i12):
    """:func:`_rot_vjp_event` from the warped pixel and its pixel gradient: the normalized
    point comes back through K^-1 (affine), the gradient through K^T, so no division."""
    X = i00 * xv + i01 * yv + i02
    Y = i10 * xv + i11 * yv + i12
    return _rot_vjp_event(X, Y, t, b, c, wx, wy, wz, ww, gx * k00 + gy * k10,
                          gx * k01 + gy * k11)


@njit(cache=True, inline="always")
def _rot_rates(dt, w):
    """omega's components, |omega|^2 and the Rodrigues series mode for the window's largest
    |dt| (0: short series, 1: long series, 2: closed form)."""
    wx, wy, wz = w[0], w[1], w[2]
    ww = wx * wx + wy * wy + wz * wz
    tm = _max_abs(dt)
    zmax = tm * tm * ww
    return wx, wy, wz, ww, 0 if zmax < 0.05 else (1 if zmax < 1.0 else 2)


# ---------------------------------------------------------------------------------------
# Fused adjoints: dL/dtheta = sum_k gx_k dxw_k/dtheta + gy_k dyw_k/dtheta with the Jacobian
# recomputed per event, never stored. With a padded image (the bilinear IWE adjoint of the
# objective) the pixel gradients are gathered in the same loop, which is kept free of
# branches so that it vectorizes (AVX-512 gathers): an event with no vote in the image (or
# NaN) is replaced by a clamped one of weight 0, so that its contribution is exactly 0 (the
# composed adjoint skips it). Each kernel runs one loop per case (series mode, weights or
# not): the case reaches the inlined loop as a constant and its branches fold away. The
# helpers called inside the loops take scalars only: an array argument costs reference
# counting per call, which stops the vectorization.

@njit(cache=True, error_model="numpy")
def _pad_index(xv, yv, t, wk, scale, h, wd):
    """``(xc, yc, t, a, fx, fy, i)`` of an event at ``(xv, yv)`` px: its pixel, dt and
    weight ``a = wk scale``, or a clamped pixel with ``t = a = 0`` where it has no vote in
    the (h, wd) image (or is NaN); then its bilinear offsets and the flat index in the image
    padded by :func:`_pad_image` of its cell's top-left pixel."""
    inside = (xv > -1.0) & (xv < wd) & (yv > -1.0) & (yv < h)
    xc = xv if inside else -1.0
    yc = yv if inside else -1.0
    x0 = math.floor(xc)
    y0 = math.floor(yc)
    i = (int(y0) + 1) * (wd + 2) + int(x0) + 1
    return (xc, yc, t if inside else 0.0, wk * scale if inside else 0.0, xc - x0, yc - y0, i)


@njit(cache=True, error_model="numpy")
def _cell_diff(a, fx, fy, g00, g01, g10, g11):
    """``a`` times the x and y derivatives of the bilinear interpolation in a cell: the
    values of :func:`evmotion.core.iwe._cell_grad`, whose pixels outside the image count 0
    and here ``shift`` (the padding), so interior cells agree bit for bit."""
    return (a * ((g01 - g00) * (1.0 - fy) + (g11 - g10) * fy),
            a * ((g10 - g00) * (1.0 - fx) + (g11 - g01) * fx))


@njit(cache=True, error_model="numpy", inline="always")
def _bilinear_sample(fx, fy, s00, s01, s10, s11):
    """The bilinear interpolation of a cell's corner values at offsets (fx, fy): the
    derivative of ``sum(g * IWE)`` with respect to the event's IWE weight."""
    return (s00 * (1.0 - fx) * (1.0 - fy) + s01 * fx * (1.0 - fy)
            + s10 * (1.0 - fx) * fy + s11 * fx * fy)


@njit(cache=True, error_model="numpy", inline="always")
def _pad_diff(pair, a, fx, fy, e, pad, i, wp, p2):
    """``(gx, gy, gd)``: :func:`_cell_diff` of the cell at flat index ``i`` of the padded
    image ``pad`` (row stride ``wp``); in ``pair`` mode of the values ``g + e b``, ``b`` the
    second padded image (from ``p2``): the pixel gradients of a loss on two IWEs, of ones
    (adjoint ``g``) and of per-event values ``e`` (adjoint ``b``), and ``gd`` the loss'
    derivative with respect to ``e`` (``a`` times ``b`` sampled at the event; 0 outside
    ``pair`` mode)."""
    g00, g01, g10, g11 = pad[i], pad[i + 1], pad[i + wp], pad[i + wp + 1]
    gd = 0.0
    if pair:
        j = i + p2
        b00, b01, b10, b11 = pad[j], pad[j + 1], pad[j + wp], pad[j + wp + 1]
        g00 += e * b00
        g01 += e * b01
        g10 += e * b10
        g11 += e * b11
        gd = a * _bilinear_sample(fx, fy, b00, b01, b10, b11)
    gX, gY = _cell_diff(a, fx, fy, g00, g01, g10, g11)
    return gX, gY, gd


@njit(cache=True, inline="always")
def _rot_bc(z, mode):
    """The Rodrigues coefficients (b, c) in series mode ``mode`` (:func:`_rot_rates`)."""
    _, b, c = _rod_mode(z, mode)
    return b, c


@njit(cache=True, inline="always")
def _rot_prm(prm):
    """The scalars of the rotation adjoint's ``prm``: omega, |omega|^2, K's 2x2 block
    and the first two rows of K^-1."""
    wx, wy, wz = prm[0], prm[1], prm[2]
    return (wx, wy, wz, wx * wx + wy * wy + wz * wz, prm[3], prm[4], prm[5], prm[6], prm[7],
            prm[8], prm[9], prm[10], prm[11], prm[12])


@njit(cache=True, error_model="numpy", inline="always")
def _rot_loop(mode, fuse, use_w, pair, args):
    """The rotation's adjoint loop: its three sums and, in pair mode, that of ``|gd|``
    (:func:`_pad_diff`)."""
    xw, yw, dt, prm, gx, gy, wts, pad, h, wd, scale, _ = args
    wx, wy, wz, ww, k00, k01, k10, k11, i00, i01, i02, i10, i11, i12 = _rot_prm(prm)
    wp = wd + 2
    p2 = (h + 2) * wp  # start of the second image in pair mode
    a0 = a1 = a2 = a3 = 0.0
    for k in range(xw.shape[0]):
        gd = 0.0
        if fuse:
            xv, yv, t, a, fx, fy, i = _pad_index(xw[k], yw[k], dt[k], wts[k] if use_w and
                                                 not pair else 1.0, scale, h, wd)
            gX, gY, gd = _pad_diff(pair, a, fx, fy, wts[k] if pair else 0.0, pad, i, wp, p2)
        else:
            xv, yv, t, gX, gY = xw[k], yw[k], dt[k], gx[k], gy[k]
        b, c = _rot_bc(t * t * ww, mode)
        d0, d1, d2 = _rot_adj_event(xv, yv, t, b, c, gX, gY, wx, wy, wz, ww, k00, k01,
                                    k10, k11, i00, i01, i02, i10, i11, i12)
        a0 += d0
        a1 += d1
        a2 += d2
        a3 += abs(gd)
    return a0, a1, a2, a3


@njit(cache=True, error_model="numpy", inline="always")
def _rot_block_loop(mode, pair, vk, args, blk):
    """:func:`_rot_loop` (fused) over the blocks of :data:`_DIV_BLOCK` events listed in
    ``blk`` (all if empty), in pair mode with the values' derivatives (``vk``: 1 divergence,
    2 det J): the votes' adjoint over every event of a block, then the values' part (linear
    in the pixel gradient, so it splits off exactly: :func:`_rot_value_adj`, or the det J
    weight through :func:`_rot_vjp_event`) only where some event has a nonzero ``gd``: near
    collapse a minority of the events reach a trimmed pixel, clustered (in-line, it cost
    about as much as the rest of the loop). No per-event buffer: each loop only sums, so
    both vectorize. (A list, not flags tested per block: a test in the outer loop slowed
    the inner one by half.)"""
    xw, yw, dt, prm, gx, gy, wts, pad, h, wd, scale, T = args
    wx, wy, wz, ww, k00, k01, k10, k11, i00, i01, i02, i10, i11, i12 = _rot_prm(prm)
    wp = wd + 2
    p2 = (h + 2) * wp  # start of the second image
    listed = blk.shape[0] > 0
    nb = blk.shape[0] if listed else -(-xw.shape[0] // _DIV_BLOCK)
    a0 = a1 = a2 = 0.0
    for bi in range(nb):
        k0 = (blk[bi] if listed else bi) * _DIV_BLOCK
        # views per block, so that the loops index from 0: an index numba cannot prove
        # non-negative gets a wraparound select, and its loads become gathers
        k1 = k0 + _DIV_BLOCK
        xs, ys, ts = xw[k0:k1], yw[k0:k1], dt[k0:k1]
        sub = (xs, ys, ts, prm, gx, gy, wts[k0:k1] if pair else wts, pad, h, wd, scale, T)
        if not pair:
            d0, d1, d2, _ = _rot_loop(mode, True, False, False, sub)
            a0 += d0
            a1 += d1
            a2 += d2
            continue
        d0, d1, d2, active = _rot_loop(mode, True, True, True, sub)
        a0 += d0
        a1 += d1
        a2 += d2
        if vk == 0 or active == 0.0:
            continue
        for k in range(xs.shape[0]):
            xv, yv, t, a, fx, fy, i = _pad_index(xs[k], ys[k], ts[k], 1.0, scale, h, wd)
            _, _, gd = _pad_diff(True, a, fx, fy, 0.0, pad, i, wp, p2)
            ra, b, c = _rod_mode(t * t * ww, mode)
            X = i00 * xv + i01 * yv + i02
            Y = i10 * xv + i11 * yv + i12
            if vk == 1:
                d0, d1, d2 = _rot_value_adj(X, Y, t, ra, b, c, gd, T, wx, wy, wz, ww)
            else:
                kap = _rot_det_weight(X, Y, t, ra, b, wx, wy, wz, ww, gd)
                d0, d1, d2 = _rot_vjp_event(X, Y, t, b, c, wx, wy, wz, ww, kap * X, kap * Y)
            a0 += d0
            a1 += d1
            a2 += d2
    return a0, a1, a2, 0.0


_DIV_BLOCK = 32  # events per block of _rot_block_loop


@njit(cache=True, error_model="numpy", inline="always")
def _rot_matrix(a, b, t, wx, wy, wz, ww):
    """The entries of ``R = exp(t omega^) = Id + a t omega^ + b t^2 (omega omega^T -
    |omega|^2 Id)``, row by row, from the Rodrigues coefficients ``a, b``."""
    at = a * t
    bt = b * t * t
    return (1.0 + bt * (wx * wx - ww), -at * wz + bt * wx * wy, at * wy + bt * wx * wz,
            at * wz + bt * wx * wy, 1.0 + bt * (wy * wy - ww), -at * wx + bt * wy * wz,
            -at * wy + bt * wx * wz, at * wx + bt * wy * wz, 1.0 + bt * (wz * wz - ww))


@njit(cache=True, error_model="numpy", inline="always")
def _rot_det_weight(X, Y, t, a, b, wx, wy, wz, ww, gd):
    """``kap``: ``gd`` times the omega-derivative of the event's ``|det J| - 1`` is that of
    ``kap (X, Y)`` as a normalized pixel gradient (:func:`_rot_value_adj`)."""
    _, _, r02, _, _, r12, _, _, r22 = _rot_matrix(a, b, t, wx, wy, wz, ww)
    iz = r02 * X + r12 * Y + r22
    return gd * 3.0 * abs(iz * iz * iz) / (1.0 + X * X + Y * Y)


@njit(cache=True, error_model="numpy", inline="always")
def _rot_value_adj(X, Y, t, a, b, c, gd, T, wx, wy, wz, ww):
    """``gd`` times the omega-derivative of the event's divergence times ``T`` (its
    ``|det J| - 1``: :func:`_rot_det_weight`), from the warped normalized point (X, Y)
    alone.

    The value is a function ``D(X, Y, omega)`` (:func:`evmotion.core.regularizers.
    _rot_value_event`), so ``dD/domega = D_X dX/domega + D_Y dY/domega + D_omega``: the
    first two terms are a pixel gradient for :func:`_rot_vjp_event`. Since ``|q| = |v|``
    (q = R v), ``q_z^2 (1 + X^2 + Y^2) = |v|^2``, and ``|det J| = |q_z|^-3`` depends on
    omega through X, Y only:
    ``d|det J| = 3 |det J| (X dX + Y dY) / (1 + X^2 + Y^2)``. For the divergence ``tr(A
    J)``, ``D_omega`` comes from ``A`` (linear in omega) and from ``R`` with ``dR/domega_j
    = t (J_l e_j)^ R``: ``sum_mn (dD/dR)_mn (dR/domega_j)_mn = t (J_l e_j) . n``, ``n``
    the axial vector of ``R M^T - M R^T``, ``M = dD/dR``; :func:`_rot_vjp_u` contracts
    ``-t J_l^T u``, so ``n`` enters as ``u -= gd n``."""
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = _rot_matrix(a, b, t, wx, wy, wz, ww)
    iz = r02 * X + r12 * Y + r22
    f = gd * T
    p00 = r00 - X * r20
    p01 = r01 - X * r21
    p10 = r10 - Y * r20
    p11 = r11 - Y * r21
    a00 = 2.0 * wy * X - wx * Y
    a01 = -wz - wx * X
    a10 = wz + wy * Y
    a11 = wy * X - 2.0 * wx * Y
    S = a00 * p00 + a01 * p10 + a10 * p01 + a11 * p11  # D = S iz
    # D_X, D_Y into the pixel gradient
    sx = 2.0 * wy * p00 - a00 * r20 - wx * p10 - a10 * r21 + wy * p11
    sy = -wx * p00 - a01 * r20 + wy * p01 - a11 * r21 - 2.0 * wx * p11
    gXd = f * (iz * sx + S * r02)
    gYd = f * (iz * sy + S * r12)
    # M = dD/dR: rows (m0, m1, m2)
    m00 = a00 * iz
    m01 = a10 * iz
    m10 = a01 * iz
    m11 = a11 * iz
    m20 = -(X * a00 + Y * a01) * iz
    m21 = -(X * a10 + Y * a11) * iz
    m02 = S * X
    m12 = S * Y
    # N = R M^T: N_mn = R_m . M_n; n = (N12 - N21, N20 - N02, N01 - N10)
    n0 = (r10 * m20 + r11 * m21 + r12 * S) - (r20 * m10 + r21 * m11 + r22 * m12)
    n1 = (r20 * m00 + r21 * m01 + r22 * m02) - (r00 * m20 + r01 * m21 + r02 * S)
    n2 = (r00 * m10 + r01 * m11 + r02 * m12) - (r10 * m00 + r11 * m01 + r12 * m02)
    # D_omega through A (a00..a11 linear in omega), J = p iz
    ea0 = -Y * p00 - X * p10 - 2.0 * Y * p11
    ea1 = 2.0 * X * p00 + Y * p01 + X * p11
    ea2 = p01 - p10
    d0, d1, d2 = _rot_vjp_u(X, Y, t, b, c, wx, wy, wz, ww, gXd, gYd, -f * n0, -f * n1, -f * n2)
    fi = f * iz
    return d0 + fi * ea0, d1 + fi * ea1, d2 + fi * ea2


def _rot_adj_plain(mode, fuse, use_w):
    """The rotation adjoint (:func:`_rot_loop`) in one case, ``out`` (3,) = ``jx^T gx + jy^T
    gy`` with the Jacobian recomputed per event from the warped pixels ``xw, yw`` (``prm``:
    omega, K's 2x2 block, the first two rows of K^-1); with a padded image ``pad``
    (:func:`_pad_image`, ``fuse``) the pixel gradients come from it (weights ``wts`` times
    ``scale`` where ``use_w``), not from ``gx, gy``."""

    @njit(cache=True, error_model="numpy", fastmath=_FAST_FINITE)
    def rot_adj(xw, yw, dt, prm, gx, gy, wts, pad, h, wd, scale, T, out):
        acc = _rot_loop(mode, fuse, use_w, False,
                        (xw, yw, dt, prm, gx, gy, wts, pad, h, wd, scale, T))
        for j in range(3):
            out[j] = acc[j]

    return rot_adj


def _rot_adj_blocks(mode, pair, vk):
    """The rotation adjoint over listed blocks of events (:func:`_rot_block_loop`, ``blk``
    int64, empty: all), with one padded image and unit weights, or two (``pair``, ``wts``
    the per-event values) with ``vk`` saying whether the values are held fixed (0) or are
    the warp's divergence times ``T`` (1) or ``|det J| - 1`` (2), whose derivatives are
    then chained as well (:data:`_VALUE_KINDS`)."""

    @njit(cache=True, error_model="numpy", fastmath=_FAST_FINITE)
    def rot_adj_blocks(xw, yw, dt, prm, gx, gy, wts, pad, h, wd, scale, T, blk, out):
        acc = _rot_block_loop(mode, pair, vk,
                              (xw, yw, dt, prm, gx, gy, wts, pad, h, wd, scale, T), blk)
        for j in range(3):
            out[j] = acc[j]

    return rot_adj_blocks


def _rot_series_mode(dt, w) -> int:
    """The Rodrigues series mode of :func:`_rot_rates` for the window's largest |dt|."""
    tm = _max_abs(dt)
    zmax = tm * tm * (w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    return 0 if zmax < 0.05 else (1 if zmax < 1.0 else 2)


def _rotation_adj(xw, yw, dt, prm, gx, gy, wts, pad, h, wd, scale, vk, T, blk, out):
    """The rotation adjoint: picks the case kernel (see :func:`_rot_adj_plain`,
    :func:`_rot_adj_blocks`; blocks are visited in pair mode or with one image and unit
    weights)."""
    mode = _rot_series_mode(dt, prm)
    fuse = pad.shape[0] > 0
    if not fuse:
        kernel_case(_rot_adj_plain, mode, False, False)(xw, yw, dt, prm, gx, gy, wts, pad,
                                                        h, wd, scale, T, out)
    elif pad.shape[0] == 2 * (h + 2) * (wd + 2):
        kernel_case(_rot_adj_blocks, mode, True, vk if vk in (1, 2) else 0)(
            xw, yw, dt, prm, gx, gy, wts, pad, h, wd, scale, T, blk, out)
    elif blk.shape[0] > 0:
        kernel_case(_rot_adj_blocks, mode, False, 0)(xw, yw, dt, prm, gx, gy, wts, pad, h,
                                                     wd, scale, T, blk, out)
    else:
        kernel_case(_rot_adj_plain, mode, True, wts.shape[0] > 0)(
            xw, yw, dt, prm, gx, gy, wts, pad, h, wd, scale, T, out)


@njit(cache=True, error_model="numpy", inline="always")
def _similarity_loop(small, fuse, use_w, pair, vk, args):
    xw, yw, dt, prm, gx, gy, wts, pad, h, wd, scale, T = args
    w, s, cx, cy = prm[0], prm[1], prm[2], prm[3]
    wp = wd + 2
    p2 = (h + 2) * wp  # start of the second image in pair mode
    a0 = a1 = a2 = a3 = 0.0
    for k in range(xw.shape[0]):
        gd = 0.0
        if fuse:
            xv, yv, t, a, fx, fy, i = _pad_index(xw[k], yw[k], dt[k], wts[k] if use_w and
                                                 not pair else 1.0, scale, h, wd)
        else:
            xv, yv, t = xw[k], yw[k], dt[k]
        sn, c = _sincos_any(-t * w, small)
        ib = 1.0 / (1.0 + t * s)
        ib2 = ib * ib
        if fuse:
            # the values (A.40)/(A.42) from t (cheaper than reading them; sin(t w) = -sn)
            e = (T * (-2.0 * s * ib2 * c + 2.0 * w * ib * sn) if vk == 1 else
                 ib2 - 1.0 if vk == 2 else wts[k] if pair else 0.0)
            gX, gY, gd = _pad_diff(pair, a, fx, fy, e, pad, i, wp, p2)
        else:
            gX, gY = gx[k], gy[k]
        d0, d1, d2, d3 = _similarity_vjp_event(xv - cx, yv - cy, t, sn, c, s, gX, gY)
        a0 += d0
        a1 += d1
        a2 += d2
        a3 += d3
        # the values' derivatives
        if vk == 1:
            f = gd * T
            a2 += f * (-2.0 * s * ib2 * t * sn + 2.0 * ib * sn - 2.0 * w * ib * t * c)
            a3 += f * (-2.0 * c * ib2 + 4.0 * s * t * c * ib2 * ib - 2.0 * w * t * sn * ib2)
        elif vk == 2:
            a3 -= gd * 2.0 * t * ib2 * ib
    return a0, a1, a2, a3


def _similarity_adj_case(small, fuse, use_w, pair, vk):
    """:func:`_rot_adj_plain` for SE(2) and the similarity (``prm``: wz, s, c; ``out``
    (3,) or (4,)), one case of :func:`_similarity_loop`."""

    @njit(cache=True, error_model="numpy", fastmath=_FAST_FINITE)
    def similarity_adj(xw, yw, dt, prm, gx, gy, wts, pad, h, wd, scale, T, out):
        acc = _similarity_loop(small, fuse, use_w, pair, vk,
                               (xw, yw, dt, prm, gx, gy, wts, pad, h, wd, scale, T))
        for j in range(out.shape[0]):
            out[j] = acc[j]

    return similarity_adj


def _similarity_adj(xw, yw, dt, prm, gx, gy, wts, pad, h, wd, scale, vk, T, out):
    """The SE(2)/similarity adjoint: picks the case kernel of :func:`_similarity_adj_case`
    (angles below 1 rad take the series of :func:`_sincos`)."""
    small = bool(_max_abs(dt) * abs(prm[0]) < 1.0)
    if pad.shape[0] == 0:
        key = (small, False, False, False, 0)
    elif pad.shape[0] == 2 * (h + 2) * (wd + 2):
        key = (small, True, True, True, vk if vk in (1, 2) else 0)
    else:
        key = (small, True, wts.shape[0] > 0, False, 0)
    kernel_case(_similarity_adj_case, *key)(xw, yw, dt, prm, gx, gy, wts, pad, h, wd, scale,
                                            T, out)


@njit(cache=True, error_model="numpy", inline="always")
def _simple_loop(kind, fuse, use_w, pair, vk, args):
    """Zoom (kind 0), translation (1), in-plane (2): the zoom and in-plane warps are
    recomputed from the events (cheaper than reading their warped pixels as well)."""
    x, y, xw, yw, dt, prm, gx, gy, wts, pad, h, wd, scale, T = args
    cx, cy = prm[0], prm[1]
    hz = c = sn = kk = vx = vy = 0.0
    if kind == 0:
        hz = prm[2]
    elif kind == 2:
        c, sn, kk, vx, vy = prm[2], prm[3], prm[4], prm[5], prm[6]
    wp = wd + 2
    p2 = (h + 2) * wp  # start of the second image in pair mode
    a0 = a1 = a2 = a3 = 0.0
    for k in range(xw.shape[0]):
        t = dt[k]
        xc = x[k] - cx
        yc = y[k] - cy
        if kind == 0:
            s = 1.0 - t * hz
            xv0 = cx + s * xc
            yv0 = cy + s * yc
        elif kind == 2:
            xv0, yv0, _, _ = _inplane_event(x[k], y[k], t, vx, vy, c, sn, kk, cx, cy)
        else:
            xv0 = xw[k]
            yv0 = yw[k]
        gd = 0.0
        if fuse:
            # the values from t (cheaper than reading them): (3.7), (A.25)/(A.27)
            if kind == 0 and vk == 1:
                e = -2.0 * hz * T
            elif kind == 0 and vk == 2:
                e = (1.0 - t * hz) * (1.0 - t * hz) - 1.0
            elif kind == 2 and vk == 1:
                e = T * (2.0 - 2.0 * kk * c)
            elif kind == 2 and vk == 2:
                e = abs((1.0 + t) * (1.0 + t) - 2.0 * (1.0 + t) * t * kk * c
                        + t * t * kk * kk) - 1.0
            else:
                e = wts[k] if pair else 0.0
            xv, yv, t, a, fx, fy, i = _pad_index(xv0, yv0, t, wts[k] if use_w and not pair
                                                 else 1.0, scale, h, wd)
            gX, gY, gd = _pad_diff(pair, a, fx, fy, e, pad, i, wp, p2)
            # where the event has no vote its weight is 0: any finite point will do
            ok = xv == xv0
            xc = xc if ok else 0.0
            yc = yc if ok else 0.0
        else:
            gX, gY = gx[k], gy[k]
        if kind == 0:
            a0 -= t * (gX * xc + gY * yc)
        else:
            a0 -= t * gX
            a1 -= t * gY
        if kind == 2:
            r0 = c * xc - sn * yc
            r1 = sn * xc + c * yc
            a2 += t * kk * (gX * r1 - gY * r0)
            a3 -= t * (gX * r0 + gY * r1)
        # the values' derivatives: (3.7) for the zoom, (A.25)/(A.27) in-plane
        if kind == 0 and vk == 1:
            a0 -= gd * 2.0 * T
        elif kind == 0 and vk == 2:
            a0 -= gd * 2.0 * t * (1.0 - t * hz)
        elif kind == 2 and vk == 1:
            a2 += gd * T * 2.0 * kk * sn
            a3 -= gd * T * 2.0 * c
        elif kind == 2 and vk == 2:
            e = 1.0 + t
            det = e * e - 2.0 * e * t * kk * c + t * t * kk * kk
            f = gd if det >= 0 else -gd
            a2 += f * (2.0 * e * t * kk * sn)
            a3 += f * (-2.0 * e * t * c + 2.0 * t * t * kk)
    return a0, a1, a2, a3


def _simple_adj_case(kind, fuse, use_w, pair, vk):
    """:func:`_rot_adj_plain` for the zoom, translation and in-plane warps (``kind`` 0, 1,
    2; ``prm``: c, then h_z (zoom) or cos phi, sin phi, h_z + 1, vx, vy (in-plane)), one
    case of :func:`_simple_loop`."""

    @njit(cache=True, error_model="numpy", fastmath=_FAST_FINITE)
    def simple_adj(x, y, xw, yw, dt, prm, gx, gy, wts, pad, h, wd, scale, T, out):
        acc = _simple_loop(kind, fuse, use_w, pair, vk,
                           (x, y, xw, yw, dt, prm, gx, gy, wts, pad, h, wd, scale, T))
        for j in range(out.shape[0]):
            out[j] = acc[j]

    return simple_adj


def _simple_adj(kind, x, y, xw, yw, dt, prm, gx, gy, wts, pad, h, wd, scale, vk, T, out):
    """The zoom/translation/in-plane adjoint: picks the case kernel of
    :func:`_simple_adj_case`."""
    if pad.shape[0] == 0:
        key = (kind, False, False, False, 0)
    elif pad.shape[0] == 2 * (h + 2) * (wd + 2):
        # translation: divergence 0 and det J = 1, whatever theta
        key = (kind, True, True, True, 0 if kind == 1 or vk not in (1, 2) else vk)
    else:
        key = (kind, True, wts.shape[0] > 0, False, 0)
    kernel_case(_simple_adj_case, *key)(x, y, xw, yw, dt, prm, gx, gy, wts, pad, h, wd,
                                        scale, T, out)


@njit(cache=True, error_model="numpy", fastmath=_FAST_FINITE)
def _k_rot_divdet(x, y, dt, w, Kinv, want_div, val, grad, gw, out):
    """Divergence (3.23 at any dt) or det J (3.24) of the rotation warp into ``val`` and,
    if ``grad`` (N, 3) has rows, their analytic omega-derivatives; if ``gw`` (N,) has rows,
    instead ``out[j] += sum_k gw[k] d val_k / d omega_j`` (events with ``gw[k] == 0`` skip
    the derivative: a trimmed mean's adjoint is zero off its selected pixels). Both are
    invariant under the affine map K, so they are computed in normalized coordinates,
    where the warp is ``X = pi(R v)`` with ``R = exp(dt omega^)``: det J = 1 / q_z^3
    (det R = 1), and since the flow is the rotational field ``F(X) = pi'(q) (omega x q)`` evaluated at the warped point,
    div f = tr(dF/dX dX/dx). Derivatives use dR/d omega_j = dt (J_l e_j)^ R."""
    wx, wy, wz, ww, mode = _rot_rates(dt, w)
    i00, i01, i02, i10, i11, i12 = _rows01(Kinv)
    mode_g = 1 if grad.shape[0] > 0 else (2 if gw.shape[0] > 0 else 0)
    abuf = np.empty(_BLOCK)
    bbuf = np.empty(_BLOCK)
    cbuf = np.empty(_BLOCK)
    n = x.shape[0]
    for k0 in range(0, n, _BLOCK):
        k1 = min(k0 + _BLOCK, n)
        _rod_block(dt, k0, k1, ww, mode, abuf, bbuf, cbuf)
        _rot_divdet_block(x, y, dt, wx, wy, wz, ww, i00, i01, i02, i10, i11, i12, want_div,
                          mode_g, k0, k1, abuf, bbuf, cbuf, val, grad, gw, out)


@njit(cache=True, error_model="numpy", inline="always")
def _rot_divdet_block(x, y, dt, wx, wy, wz, ww, i00, i01, i02, i10, i11, i12, want_div,
                      mode_g, k0, k1, abuf, bbuf, cbuf, val, grad, gw, out):
    for k in range(k0, k1):
        t = dt[k]
        a = abuf[k - k0]
        b = bbuf[k - k0]
        c = cbuf[k - k0]
        at = a * t
        bt = b * t * t
        xn = i00 * x[k] + i01 * y[k] + i02
        yn = i10 * x[k] + i11 * y[k] + i12
        # R = Id + at omega^ + bt (omega omega^T - |omega|^2 Id); columns 0, 1 and row 2
        r00 = 1.0 + bt * (wx * wx - ww)
        r11 = 1.0 + bt * (wy * wy - ww)
        r01 = -at * wz + bt * wx * wy
        r10 = at * wz + bt * wx * wy
        r02 = at * wy + bt * wx * wz
        r20 = -at * wy + bt * wx * wz
        r12 = -at * wx + bt * wy * wz
        r21 = at * wx + bt * wy * wz
        r22 = 1.0 + bt * (wz * wz - ww)
        q0 = r00 * xn + r01 * yn + r02
        q1 = r10 * xn + r11 * yn + r12
        q2 = r20 * xn + r21 * yn + r22
        iz = 1.0 / q2
        X = q0 * iz
        Y = q1 * iz
        if not want_div:
            val[k] = iz * iz * iz
        # J = dX/dx_n (2x2), A = dF/dX (2x2)
        j00 = (r00 - X * r20) * iz
        j01 = (r01 - X * r21) * iz
        j10 = (r10 - Y * r20) * iz
        j11 = (r11 - Y * r21) * iz
        a00 = 2.0 * wy * X - wx * Y
        a01 = -wz - wx * X
        a10 = wz + wy * Y
        a11 = wy * X - 2.0 * wx * Y
        if want_div:
            val[k] = a00 * j00 + a01 * j10 + a10 * j01 + a11 * j11
        if mode_g == 0 or (mode_g == 2 and gw[k] == 0.0):
            continue
        # columns of t J_l(t omega); every d(.)/d omega_j = (t J_l e_j) x (.)
        bt1 = b * t * t
        ct2 = c * t * t * t
        dg = t - ct2 * ww
        cx_ = ct2 * wx
        cy_ = ct2 * wy
        cz_ = ct2 * wz
        if not want_div:
            s3 = -3.0 * iz * iz * iz * iz
            g0 = s3 * ((cx_ * wx + dg) * q1 - (cy_ * wx + bt1 * wz) * q0)
            g1 = s3 * ((cx_ * wy - bt1 * wz) * q1 - (cy_ * wy + dg) * q0)
            g2 = s3 * ((cx_ * wz + bt1 * wy) * q1 - (cy_ * wz - bt1 * wx) * q0)
        else:
            g0 = _rot_div_dir(cx_ * wx + dg, cy_ * wx + bt1 * wz, cz_ * wx - bt1 * wy,
                              1.0, 0.0, 0.0, wx, wy, q0, q1, q2, X, Y, iz, r00, r01, r10,
                              r11, r20, r21, j00, j01, j10, j11, a00, a01, a10, a11)
            g1 = _rot_div_dir(cx_ * wy - bt1 * wz, cy_ * wy + dg, cz_ * wy + bt1 * wx,
                              0.0, 1.0, 0.0, wx, wy, q0, q1, q2, X, Y, iz, r00, r01, r10,
                              r11, r20, r21, j00, j01, j10, j11, a00, a01, a10, a11)
            g2 = _rot_div_dir(cx_ * wz + bt1 * wy, cy_ * wz - bt1 * wx, cz_ * wz + dg,
                              0.0, 0.0, 1.0, wx, wy, q0, q1, q2, X, Y, iz, r00, r01, r10,
                              r11, r20, r21, j00, j01, j10, j11, a00, a01, a10, a11)
        if mode_g == 1:
            grad[k, 0] = g0
            grad[k, 1] = g1
            grad[k, 2] = g2
        else:
            f = gw[k]
            out[0] += f * g0
            out[1] += f * g1
            out[2] += f * g2


@njit(cache=True, error_model="numpy", inline="always")
def _rot_div_dir(l0, l1, l2, e0, e1, e2, wx, wy, q0, q1, q2, X, Y, iz, r00, r01, r10, r11,
                 r20, r21, j00, j01, j10, j11, a00, a01, a10, a11):
    """Derivative of tr(A J) along omega_j, given l = t J_l(t omega) e_j and e = e_j."""
    dq0 = l1 * q2 - l2 * q1
    dq1 = l2 * q0 - l0 * q2
    dq2 = l0 * q1 - l1 * q0
    dX = (dq0 - X * dq2) * iz
    dY = (dq1 - Y * dq2) * iz
    dr00 = l1 * r20 - l2 * r10
    dr10 = l2 * r00 - l0 * r20
    dr20 = l0 * r10 - l1 * r00
    dr01 = l1 * r21 - l2 * r11
    dr11 = l2 * r01 - l0 * r21
    dr21 = l0 * r11 - l1 * r01
    dz = dq2 * iz
    dj00 = (dr00 - dX * r20 - X * dr20) * iz - j00 * dz
    dj01 = (dr01 - dX * r21 - X * dr21) * iz - j01 * dz
    dj10 = (dr10 - dY * r20 - Y * dr20) * iz - j10 * dz
    dj11 = (dr11 - dY * r21 - Y * dr21) * iz - j11 * dz
    da00 = 2.0 * (e1 * X + wy * dX) - e0 * Y - wx * dY
    da01 = -e2 - e0 * X - wx * dX
    da10 = e2 + e1 * Y + wy * dY
    da11 = e1 * X + wy * dX - 2.0 * (e0 * Y + wx * dY)
    return (da00 * j00 + da01 * j10 + da10 * j01 + da11 * j11
            + a00 * dj00 + a01 * dj10 + a10 * dj01 + a11 * dj11)


@njit(cache=True, error_model="numpy")
def _k_hom_divdet(x, y, dt, G, cx, cy, div, det):
    """Divergence and det J of x' ~ (Id + dt G)^-1 x in centred pixels (both invariant under
    the centring), complex so that a complex G gives complex-step derivatives:
    M = H^-1, dM/dt = -M G M."""
    M = np.empty((3, 3), dtype=np.complex128)
    for k in range(x.shape[0]):
        t = dt[k]
        h00 = 1.0 + t * G[0, 0]
        h01 = t * G[0, 1]
        h02 = t * G[0, 2]
        h10 = t * G[1, 0]
        h11 = 1.0 + t * G[1, 1]
        h12 = t * G[1, 2]
        h20 = t * G[2, 0]
        h21 = t * G[2, 1]
        h22 = 1.0 + t * G[2, 2]
        c00 = h11 * h22 - h12 * h21
        c01 = h02 * h21 - h01 * h22
        c02 = h01 * h12 - h02 * h11
        dh = h00 * c00 + h10 * c01 + h20 * c02
        idet = 1.0 / dh
        M[0, 0] = c00 * idet
        M[0, 1] = c01 * idet
        M[0, 2] = c02 * idet
        M[1, 0] = (h12 * h20 - h10 * h22) * idet
        M[1, 1] = (h00 * h22 - h02 * h20) * idet
        M[1, 2] = (h02 * h10 - h00 * h12) * idet
        M[2, 0] = (h10 * h21 - h11 * h20) * idet
        M[2, 1] = (h01 * h20 - h00 * h21) * idet
        M[2, 2] = (h00 * h11 - h01 * h10) * idet
        u = x[k] - cx
        v = y[k] - cy
        q0 = M[0, 0] * u + M[0, 1] * v + M[0, 2]
        q1 = M[1, 0] * u + M[1, 1] * v + M[1, 2]
        q2 = M[2, 0] * u + M[2, 1] * v + M[2, 2]
        # p = dM/dt x = -M G q
        g0 = G[0, 0] * q0 + G[0, 1] * q1 + G[0, 2] * q2
        g1 = G[1, 0] * q0 + G[1, 1] * q1 + G[1, 2] * q2
        g2 = G[2, 0] * q0 + G[2, 1] * q1 + G[2, 2] * q2
        p0 = -(M[0, 0] * g0 + M[0, 1] * g1 + M[0, 2] * g2)
        p2 = -(M[2, 0] * g0 + M[2, 1] * g1 + M[2, 2] * g2)
        p1 = -(M[1, 0] * g0 + M[1, 1] * g1 + M[1, 2] * g2)
        iq = 1.0 / q2
        iq2 = iq * iq
        d = 0.0j
        for i in range(2):
            a0 = M[0, i]
            a1 = M[1, i]
            a2 = M[2, i]
            # b = dM/dt e_i = -M G a
            e0 = G[0, 0] * a0 + G[0, 1] * a1 + G[0, 2] * a2
            e1 = G[1, 0] * a0 + G[1, 1] * a1 + G[1, 2] * a2
            e2 = G[2, 0] * a0 + G[2, 1] * a1 + G[2, 2] * a2
            bi = -(M[i, 0] * e0 + M[i, 1] * e1 + M[i, 2] * e2)
            b2 = -(M[2, 0] * e0 + M[2, 1] * e1 + M[2, 2] * e2)
            qi = q0 if i == 0 else q1
            pi = p0 if i == 0 else p1
            ai = a0 if i == 0 else a1
            d += (bi * iq - (pi * a2 + ai * p2 + qi * b2) * iq2
                  + 2.0 * qi * p2 * a2 * iq2 * iq)
        div[k] = d
        det[k] = idet * iq2 * iq


_EMPTY2 = np.zeros((0, 0))
_EMPTY1 = np.zeros(0)
_NO_BLOCKS = np.zeros(0, np.int64)  # the kernels' block list: every event


# ---------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class Warp:
    """A parametric warp (see the module docstring for conventions).

    Attributes
    ----------
    name : str
    n_params : int
    param_names : tuple of str
    param_units : tuple of str
    sensor_size : (int, int)
        ``(height, width)`` in pixels.
    center : (float, float)
        ``(cx, cy)`` pixel position of the origin of the centred coordinates.
    K : ndarray (3, 3) or None
        Camera intrinsics (pixels); required by ``rotation``.
    """

    name: str
    param_names: tuple[str, ...]
    param_units: tuple[str, ...]
    sensor_size: tuple[int, int]
    center: tuple[float, float]
    K: np.ndarray | None = None

    def __post_init__(self):
        kinv = None if self.K is None else np.linalg.inv(self.K)
        object.__setattr__(self, "_kinv", kinv)

    @property
    def n_params(self) -> int:
        return len(self.param_names)

    def identity(self) -> np.ndarray:
        """Parameters of the identity warp, float64 (P,)."""
        return np.zeros(self.n_params)

    # -- argument checks -----------------------------------------------------------------
    def _theta(self, theta, allow_complex: bool = False) -> np.ndarray:
        th = np.asarray(theta)
        if th.shape != (self.n_params,):
            raise ParameterError(f"warp '{self.name}' takes theta of shape ({self.n_params},) "
                                 f"{self.param_names}, got shape {th.shape}")
        if np.iscomplexobj(th) and allow_complex:
            return th.astype(np.complex128)
        th = th.astype(np.float64)
        if not all(map(math.isfinite, th.tolist())):  # cheaper than numpy for P <= 8
            raise ParameterError(f"warp '{self.name}': theta must be finite, got {th!r}")
        return th

    @staticmethod
    def _events(x, y, dt):
        x = np.ascontiguousarray(x, dtype=np.float64)
        y = np.ascontiguousarray(y, dtype=np.float64)
        dt = np.ascontiguousarray(dt, dtype=np.float64)
        if x.ndim != 1 or x.shape != y.shape or x.shape != dt.shape:
            raise ParameterError(f"x, y, dt must be 1-D arrays of equal length, got shapes "
                                 f"{x.shape}, {y.shape}, {dt.shape}")
        return x, y, dt

    # -- hot path --------------------------------------------------------------------------
    def warp(self, x, y, dt, theta, jacobian: bool = False):
        """Warp events to ``t_ref``.

        Parameters
        ----------
        x, y : array (N,)
            Event pixels.
        dt : array (N,)
            ``t_k - t_ref`` in seconds.
        theta : array (P,)
            Parameters (rates per second, see ``param_units``).
        jacobian : bool
            Also return ``jx, jy`` (N, P): ``d x'/d theta`` and ``d y'/d theta``.

        Returns
        -------
        xw, yw : array (N,) -- warped pixels; and ``jx, jy`` if ``jacobian``.

        Examples
        --------
        >>> w = make_warp("translation", sensor_size=(10, 10))
        >>> w.warp(np.array([5.0]), np.array([5.0]), np.array([0.1]), np.array([10.0, 0.0]))
        (array([4.]), array([5.]))
        """
        x, y, dt = self._events(x, y, dt)
        n = x.shape[0]
        xw = np.empty(n)
        yw = np.empty(n)
        if jacobian:
            jx = np.empty((n, self.n_params))
            jy = np.empty((n, self.n_params))
            self.warp_into(x, y, dt, theta, xw, yw, jx, jy)
            return xw, yw, jx, jy
        self.warp_into(x, y, dt, theta, xw, yw)
        return xw, yw

    def warp_into(self, x, y, dt, theta, xw, yw, jx=None, jy=None) -> None:
        """Allocation-free :meth:`warp`: writes into ``xw, yw`` (N,) and, if given,
        ``jx, jy`` (N, P); all float64 C-contiguous. Inputs must be float64 contiguous."""
        th = self._theta(theta)
        jac = jx is not None
        n = np.shape(x)[0] if np.ndim(x) == 1 else -1
        for nm, a in (("x", x), ("y", y), ("dt", dt), ("xw", xw), ("yw", yw)):
            if not (isinstance(a, np.ndarray) and a.dtype == np.float64 and a.shape == (n,)
                    and a.flags.c_contiguous):
                raise ParameterError(f"warp_into: '{nm}' must be a C-contiguous float64 array "
                                     f"of shape (N,) like x, got {getattr(a, 'dtype', type(a))} "
                                     f"{np.shape(a)}")
        if jac:
            for nm, a in (("jx", jx), ("jy", jy)):
                if not (isinstance(a, np.ndarray) and a.dtype == np.float64
                        and a.shape == (n, self.n_params) and a.flags.c_contiguous):
                    raise ParameterError(f"warp_into: '{nm}' must be a C-contiguous float64 "
                                         f"array of shape ({n}, {self.n_params}), got "
                                         f"{np.shape(a)}")
        else:
            jx = jy = _EMPTY2
        self._kernel(x, y, dt, th, xw, yw, jx, jy, jac)

    def _kernel(self, x, y, dt, th, xw, yw, jx, jy, jac):  # pragma: no cover - abstract
        raise NotImplementedError

    # -- matrices in homogeneous pixel coordinates ------------------------------------------
    def _mats_c(self, dt, th):  # pragma: no cover - abstract
        """``M`` and ``dM/dt`` (N, 3, 3) in the warp's own (centred/normalized) coordinates."""
        raise NotImplementedError

    def _conj(self):
        """(T, T^-1): pixel <- own coordinates."""
        cx, cy = self.center
        T = np.array([[1.0, 0, cx], [0, 1.0, cy], [0, 0, 1.0]])
        Ti = np.array([[1.0, 0, -cx], [0, 1.0, -cy], [0, 0, 1.0]])
        return T, Ti

    def matrices(self, dt, theta):
        """``M(dt)`` and ``dM/dt`` (N, 3, 3) acting on homogeneous sensor pixels.

        ``x' ~ M (x, y, 1)^T``. Accepts complex ``theta`` (used for complex-step
        derivatives)."""
        th = self._theta(theta, allow_complex=True)
        dt = np.atleast_1d(np.asarray(dt, dtype=np.float64))
        M, Md = self._mats_c(dt, th)
        T, Ti = self._conj()
        return T @ M @ Ti, T @ Md @ Ti

    def _geom(self, x, y, dt, theta):
        M, Md = self.matrices(dt, theta)
        xt = np.stack([x, y, np.ones_like(x)], axis=-1)[..., None]
        q = (M @ xt)[..., 0]
        p = (Md @ xt)[..., 0]
        return M, Md, q, p

    # -- differential quantities ----------------------------------------------------------
    def flow(self, x, y, dt, theta):
        """(3.8) ``f = dW/dt`` at each event, px/s: returns ``fx, fy`` (N,).

        It is minus the image velocity of the scene (see :meth:`optical_flow`)."""
        x, y, dt = self._events(x, y, dt)
        _, _, q, p = self._geom(x, y, dt, self._theta(theta))
        xw = q[:, 0] / q[:, 2]
        yw = q[:, 1] / q[:, 2]
        return (p[:, 0] - xw * p[:, 2]) / q[:, 2], (p[:, 1] - yw * p[:, 2]) / q[:, 2]

    def optical_flow(self, x, y, theta):
        """Image velocity (u, v) in px/s of the scene point at pixel ``(x, y)`` at ``t_ref``
        (the motion field the warp models; u right, v down)."""
        x, y, _ = self._events(x, y, np.zeros(np.shape(x)))
        fx, fy = self.flow(x, y, np.zeros_like(x), theta)
        return -fx, -fy

    def jacobian(self, x, y, dt, theta) -> np.ndarray:
        """(3.13) ``J = dW/dx`` at each event, (N, 2, 2), rows (x', y'), columns (x, y)."""
        x, y, dt = self._events(x, y, dt)
        M, _, q, _ = self._geom(x, y, dt, self._theta(theta))
        w = q[:, :2] / q[:, 2:3]
        J = (M[:, :2, :2] - w[:, :, None] * M[:, 2:3, :2]) / q[:, 2, None, None]
        return J

    def _det(self, x, y, dt, th):
        M, _, q, _ = self._geom(x, y, dt, th)
        return np.linalg.det(M) / q[:, 2] ** 3

    def _div(self, x, y, dt, th):
        M, Md, q, p = self._geom(x, y, dt, th)
        q3 = q[:, 2]
        out = 0.0
        for i in range(2):
            a = M[:, :, i]
            b = Md[:, :, i]
            out = (out + b[:, i] / q3
                   - (p[:, i] * a[:, 2] + a[:, i] * p[:, 2] + q[:, i] * b[:, 2]) / q3 ** 2
                   + 2.0 * q[:, i] * p[:, 2] * a[:, 2] / q3 ** 3)
        return out

    def _rcad(self, x, y, dt, th):
        M, Md, _, _ = self._geom(x, y, dt, th)
        L = -np.linalg.solve(M, Md)
        lx = L[:, 2, 0] * x + L[:, 2, 1] * y + L[:, 2, 2]
        return L[:, 0, 0] + L[:, 1, 1] + L[:, 2, 2] - 3.0 * lx

    def _with_grad(self, fn, x, y, dt, theta, grad: bool):
        th = self._theta(theta)
        val = np.real(fn(x, y, dt, th))
        if not grad:
            return val
        g = np.empty((x.shape[0], self.n_params))
        for j in range(self.n_params):
            tc = th.astype(np.complex128)
            tc[j] += 1j * _CSTEP
            g[:, j] = np.imag(fn(x, y, dt, tc)) / _CSTEP
        return val, g

    def divergence(self, x, y, dt, theta, grad: bool = False):
        """Divergence of the flow (3.8) at each event, 1/s (3.9).

        Returns ``div`` (N,), and ``d div / d theta`` (N, P) if ``grad``."""
        x, y, dt = self._events(x, y, dt)
        return self._with_grad(self._div, x, y, dt, theta, grad)

    def jacobian_det(self, x, y, dt, theta, grad: bool = False):
        """``det(dW/dx)`` at each event (3.13), (A.4): the area amplification factor
        from ``t_k`` to ``t_ref``. Returns (N,), and (N, P) derivatives if ``grad``."""
        x, y, dt = self._events(x, y, dt)
        return self._with_grad(self._det, x, y, dt, theta, grad)

    def rcad(self, x, y, dt, theta, grad: bool = False):
        """Rate of change of area deformation at each event, 1/s ((3.20), (3.27), (A.6)).

        ``d det(dx(t+h)/dx(t)) / dh`` at ``h = 0`` for the point trajectory through the
        event: positive where the trajectories spread forward in time (warping back to
        ``t_ref`` contracts them)."""
        x, y, dt = self._events(x, y, dt)
        return self._with_grad(self._rcad, x, y, dt, theta, grad)

    def trajectory(self, x_ref, y_ref, dt, theta):
        """Position at ``t_ref + dt`` (seconds) of the point at ``(x_ref, y_ref)`` at
        ``t_ref``: the inverse of :meth:`warp`. Returns ``x, y`` (N,)."""
        x, y, dt = self._events(x_ref, y_ref, dt)
        M, _ = self.matrices(dt, self._theta(theta))
        xt = np.stack([x, y, np.ones_like(x)], axis=-1)[..., None]
        q = np.linalg.solve(M, xt)[..., 0]
        return q[:, 0] / q[:, 2], q[:, 1] / q[:, 2]

    def _area_log(self, x, y, t, th):
        Mi = np.linalg.inv(self.matrices(np.array([t]), th)[0][0])
        q3 = Mi[2, 0] * x + Mi[2, 1] * y + Mi[2, 2]
        return -3.0 * np.log(q3 * np.sign(np.real(q3))) + np.log(
            np.linalg.det(Mi) * np.sign(np.real(np.linalg.det(Mi))))

    def area_log_ratio(self, x_ref, y_ref, t0: float, t1: float, theta, grad: bool = False):
        """RCAD integrated along the trajectory through ``(x_ref, y_ref)`` at ``t_ref`` over
        ``[t0, t1]`` (seconds relative to ``t_ref``); dimensionless.

        Equals ``log|det dx(t1)/dx_ref| - log|det dx(t0)/dx_ref|`` (Liouville), which is
        (3.21) for the zoom, (3.28) for the rotation, (A.44)/(A.53) for similarity/affine.
        Returns (N,), and (N, P) derivatives if ``grad``."""
        x, y, _ = self._events(x_ref, y_ref, np.zeros(np.shape(x_ref)))

        def fn(x, y, _dt, th):
            return self._area_log(x, y, t1, th) - self._area_log(x, y, t0, th)

        return self._with_grad(fn, x, y, x, theta, grad)


class _FusedAdjoint:
    """Warps whose adjoint kernel recomputes the parameter Jacobian per event, so the chain
    rule needs no (N, P) Jacobian buffers (the hot path of gradient-based CMax). Each such
    warp defines ``_adj(x, y, dt, xw, yw, th, gx, gy, wts, pad, h, wd, scale, out, vk=0,
    T=1.0, blk=_NO_BLOCKS)`` (``vk``, ``T``: :meth:`reduce_pair`'s ``derivs``, ``T``;
    ``blk``: the blocks of events to visit, where ``_blocked``)."""

    #: Whether ``_adj`` visits listed blocks of events only (:meth:`reduce_pair`'s
    #: ``blocks``); elsewhere ``blocks`` is ignored (same result, every event visited).
    _blocked = False

    def vjp(self, x, y, dt, xw, yw, theta, gx, gy, out) -> np.ndarray:
        """``out = jx^T gx + jy^T gy`` (P,): per-event pixel gradients ``gx, gy`` (N,)
        chained through the warp without storing its Jacobians.

        ``x, y`` are the events (px), ``xw, yw`` the same events warped with ``theta``
        (:meth:`Warp.warp_into`), ``dt`` seconds from ``t_ref``; all float64 contiguous
        (N,). Each warp reads what is cheapest: the warped pixels (rotation, SE(2),
        similarity, translation) or the events, recomputing the warp (zoom, in-plane).

        Examples
        --------
        >>> w = make_warp("translation", sensor_size=(10, 10))
        >>> x = np.array([5.0]); dt = np.array([0.5]); th = np.array([2.0, 0.0])
        >>> xw, yw = w.warp(x, x, dt, th)
        >>> w.vjp(x, x, dt, xw, yw, th, np.array([1.0]), np.array([0.0]), np.empty(2))
        array([-0.5,  0. ])
        """
        self._adj(x, y, dt, xw, yw, self._theta(theta), gx, gy, _EMPTY1, _EMPTY1, 0, 0, 1.0,
                  out)
        return out

    def reduce_bilinear(self, x, y, dt, xw, yw, theta, grad_iwe, out, weights=None,
                        shift: float = 0.0, scale: float = 1.0,
                        work: np.ndarray | None = None) -> np.ndarray:
        """:func:`evmotion.core.iwe.accumulate_backward_reduce` fused with the warp.

        ``out`` (P,) = dL/dtheta for ``dL/dIWE = scale (grad_iwe - shift)`` and the
        bilinear IWE of ``xw, yw`` (optional per-event ``weights``), in one pass over the
        events, with the Jacobians recomputed, not stored. Arguments as in :meth:`vjp`;
        ``grad_iwe`` is (H, W) float64 C-contiguous. ``work`` is an optional float64
        buffer of at least ``(H + 2) (W + 2)`` values for the padded image (allocated when
        absent).

        Examples
        --------
        >>> w = make_warp("translation", sensor_size=(3, 3))
        >>> x = np.array([1.25]); y = np.array([1.5]); dt = np.array([1.0])
        >>> g = np.zeros((3, 3)); g[1, 2] = 1.0
        >>> w.reduce_bilinear(x, y, dt, x, y, np.zeros(2), g, np.empty(2))
        array([-0.5 ,  0.25])
        """
        g = grad_iwe
        if not (isinstance(g, np.ndarray) and g.dtype == np.float64 and g.ndim == 2
                and g.flags.c_contiguous):
            raise ParameterError(f"grad_iwe must be a C-contiguous float64 (H, W) array, got "
                                 f"{getattr(g, 'dtype', type(g))} {np.shape(g)}")
        h, wd = g.shape
        size = (h + 2) * (wd + 2)
        pad = np.empty(size) if work is None or work.shape[0] < size else work[:size]
        _pad_image(g, float(shift), pad)
        w = _EMPTY1 if weights is None else weights
        self._adj(x, y, dt, xw, yw, self._theta(theta), _EMPTY1, _EMPTY1, w, pad, h, wd,
                  float(scale), out)
        return out

    def reduce_pair(self, x, y, dt, xw, yw, theta, pads, values, h, wd, out,
                    scale: float = 1.0, derivs: str | None = None,
                    T: float = 1.0, blocks: np.ndarray | None = None) -> np.ndarray:
        """:meth:`reduce_bilinear` for a loss on two bilinear IWEs of ``xw, yw``, of ones
        and of per-event ``values``: ``out`` (P,) = dL/dtheta given ``dL/dIWE_ones = A``
        and ``dL/dIWE_values = B``, one pass over the events with the Jacobians recomputed,
        not stored. ``pads`` (2 (h + 2) (wd + 2),) float64 holds ``A`` then ``B``, each an
        (h, wd) image padded by a ring of zeros (row-major); ``values`` (N,) float64
        contiguous; the result is multiplied by ``scale``; other arguments as in
        :meth:`vjp`.

        ``derivs``: None holds the values fixed; ``"divergence"`` (the values are this
        warp's divergence times ``T``) or ``"deformation"`` (``|det J| - 1``) chains their
        theta-derivatives too, in the same pass (the DIWE/IWA penalties of
        :mod:`evmotion.core.regularizers`); the warps whose values depend on dt only
        (closed forms) then recompute them instead of reading ``values``. ``blocks``
        (uint8, one per block of :data:`evmotion.core.trim.BLOCK` events, optional): 0 for
        the blocks none of whose events reaches a nonzero pixel of ``B``, which then skip
        it (the flags of :func:`evmotion.core.trim.flag_blocks`); the result is the same.

        Examples
        --------
        >>> w = make_warp("translation", sensor_size=(1, 2))
        >>> x = np.array([0.25]); y = np.zeros(1); dt = np.array([1.0])
        >>> pads = np.zeros((2, 3, 4)); pads[0, 1, 2] = 1.0; pads[1, 1, 2] = 2.0
        >>> w.reduce_pair(x, y, dt, x, y, np.zeros(2), pads.ravel(), np.array([0.5]), 1,
        ...               2, np.empty(2))
        array([-2. ,  0.5])
        """
        if pads.shape[0] != 2 * (h + 2) * (wd + 2):
            raise ParameterError(f"pads must hold two padded ({h}, {wd}) images, got "
                                 f"{pads.shape[0]} values")
        if derivs not in _VALUE_KINDS:
            raise ParameterError(f"derivs must be one of {sorted(_VALUE_KINDS, key=str)}, "
                                 f"got {derivs!r}")
        th = self._theta(theta)
        vk = _VALUE_KINDS[derivs]
        if blocks is None or not self._blocked:
            self._adj(x, y, dt, xw, yw, th, _EMPTY1, _EMPTY1, values, pads, h, wd,
                      float(scale), out, vk, float(T))
            return out
        nb = -(-xw.shape[0] // _DIV_BLOCK)
        if not (isinstance(blocks, np.ndarray) and blocks.dtype == np.uint8
                and blocks.shape == (nb,)):
            raise ParameterError(f"blocks must hold one uint8 flag per {_DIV_BLOCK} events "
                                 f"({nb}), got {getattr(blocks, 'dtype', type(blocks))} "
                                 f"{np.shape(blocks)}")
        # the flagged blocks with both images, the others with the first only
        pair, single = np.flatnonzero(blocks), np.flatnonzero(blocks == 0)
        out[:] = 0.0
        part = np.empty_like(out)
        if pair.shape[0]:
            self._adj(x, y, dt, xw, yw, th, _EMPTY1, _EMPTY1, values, pads, h, wd,
                      float(scale), part, vk, float(T), pair)
            out += part
        if single.shape[0]:
            self._adj(x, y, dt, xw, yw, th, _EMPTY1, _EMPTY1, _EMPTY1,
                      pads[:pads.shape[0] // 2], h, wd, float(scale), part, 0, float(T), single)
            out += part
        return out


#: :meth:`_FusedAdjoint.reduce_pair`'s ``derivs`` -> the kernels' value kind ``vk``.
_VALUE_KINDS = {None: 0, "divergence": 1, "deformation": 2}


# ---------------------------------------------------------------------------------------

def _stack33(rows, n):
    return np.moveaxis(np.array([[np.broadcast_to(v, (n,)) for v in r] for r in rows]), -1, 0)


class ZoomWarp(_FusedAdjoint, Warp):
    """1-DOF zoom (3.7): ``x' = c + (1 - dt h_z)(x - c)``, ``h_z`` in 1/s.

    div f = -2 h_z, det J = (1 - dt h_z)^2."""

    def _kernel(self, x, y, dt, th, xw, yw, jx, jy, jac):
        _k_zoom(x, y, dt, th[0], self.center[0], self.center[1], xw, yw, jx, jy, jac)

    def _adj(self, x, y, dt, xw, yw, th, gx, gy, wts, pad, h, wd, scale, out, vk=0, T=1.0,
             blk=_NO_BLOCKS):
        prm = np.array([self.center[0], self.center[1], th[0]])
        _simple_adj(0, x, y, xw, yw, dt, prm, gx, gy, wts, pad, h, wd, scale, vk, T, out)

    def _mats_c(self, dt, th):
        n = dt.shape[0]
        s = 1 - dt * th[0]
        o, i = 0 * s, 1 + 0 * s
        M = _stack33([[s, o, o], [o, s, o], [o, o, i]], n)
        h = -th[0] + 0 * dt
        Md = _stack33([[h, o, o], [o, h, o], [o, o, o]], n)
        return M, Md


class TranslationWarp(_FusedAdjoint, Warp):
    """2-DOF feature flow (3.5.1): ``x' = x - dt v``, ``v`` in px/s. div 0, det 1."""

    def _kernel(self, x, y, dt, th, xw, yw, jx, jy, jac):
        _k_translation(x, y, dt, th[0], th[1], xw, yw, jx, jy, jac)

    def _adj(self, x, y, dt, xw, yw, th, gx, gy, wts, pad, h, wd, scale, out, vk=0, T=1.0,
             blk=_NO_BLOCKS):
        _simple_adj(1, x, y, xw, yw, dt, np.array(self.center), gx, gy, wts, pad, h, wd,
                      scale, vk, T, out)

    def _mats_c(self, dt, th):
        n = dt.shape[0]
        z = 0 * dt * th[0]
        o, i = z, 1 + z
        M = _stack33([[i, o, -dt * th[0]], [o, i, -dt * th[1]], [o, o, i]], n)
        Md = _stack33([[o, o, -th[0] + z], [o, o, -th[1] + z], [o, o, o]], n)
        return M, Md


def _rot2(a):
    c, s = np.cos(a), np.sin(a)
    return c, s


class SimilarityWarp(_FusedAdjoint, Warp):
    """4-DOF similarity Sim(2) (A.36): ``x' = c + beta^-1 R(dt w_z)(x - c - dt v)``,
    ``beta = 1 + dt s``; theta = (vx, vy [px/s], wz [rad/s], s [1/s]).

    ``wz`` follows the rotation warp's convention: the camera's angular velocity about its
    optical axis, right-handed in the camera frame (x right, y down, z forward), so the
    image content turns by ``-wz`` (counter-clockwise on screen for ``wz > 0``) and a camera
    rotating about z gives the same ``wz`` from ``rotation`` and ``se2``. The thesis (A.11,
    A.36) writes ``R(-dt w_z)``, i.e. the image's rotation rate: its ``w_z`` is minus this one.
    ``R(a)`` is ``[[cos a, -sin a], [sin a, cos a]]`` acting on (x, y) pixel offsets.

    With ``scaled=False`` it is the 3-DOF planar SE(2) warp (A.11), theta = (vx, vy, wz)."""

    scaled = True

    def _kernel(self, x, y, dt, th, xw, yw, jx, jy, jac):
        s = th[3] if self.scaled else 0.0
        # the kernels take the image rotation rate -wz (A.11's sign, see the class docstring)
        _k_similarity(x, y, dt, th[0], th[1], -th[2], s, self.center[0], self.center[1],
                      xw, yw, jx, jy, jac, self.scaled)
        if jac:
            jx[:, 2] *= -1.0
            jy[:, 2] *= -1.0

    def _adj(self, x, y, dt, xw, yw, th, gx, gy, wts, pad, h, wd, scale, out, vk=0, T=1.0,
             blk=_NO_BLOCKS):
        prm = np.array([-th[2], th[3] if self.scaled else 0.0, self.center[0], self.center[1]])
        _similarity_adj(xw, yw, dt, prm, gx, gy, wts, pad, h, wd, scale, vk, T, out)
        out[2] = -out[2]

    def _mats_c(self, dt, th):
        n = dt.shape[0]
        s = th[3] if self.scaled else 0.0
        w = -th[2]
        c, sn = _rot2(-dt * w)
        ib = 1.0 / (1.0 + dt * s)
        # A = R(-dt w)/beta, b = -A dt v
        a00, a01, a10, a11 = c * ib, -sn * ib, sn * ib, c * ib
        b0 = -(a00 * th[0] + a01 * th[1]) * dt
        b1 = -(a10 * th[0] + a11 * th[1]) * dt
        # dA/dt = (dR/dt)/beta - R s/beta^2, dR/dt = -w R'(a)
        dib = -s * ib * ib
        d00 = w * sn * ib + c * dib
        d01 = w * c * ib - sn * dib
        d10 = -w * c * ib + sn * dib
        d11 = w * sn * ib + c * dib
        e0 = -(d00 * th[0] + d01 * th[1]) * dt - (a00 * th[0] + a01 * th[1])
        e1 = -(d10 * th[0] + d11 * th[1]) * dt - (a10 * th[0] + a11 * th[1])
        o = 0 * a00
        i = 1 + o
        M = _stack33([[a00, a01, b0], [a10, a11, b1], [o, o, i]], n)
        Md = _stack33([[d00, d01, e0], [d10, d11, e1], [o, o, o]], n)
        return M, Md


class SE2Warp(SimilarityWarp):
    """3-DOF planar motion SE(2) (A.11): ``x' = c + R(dt w_z)(x - c - dt v)``;
    theta = (vx, vy [px/s], wz [rad/s]). div f = -2 wz sin(dt wz) (A.13), det J = 1.

    ``wz`` is the camera's angular velocity about the optical axis with the rotation warp's
    sign (right-handed, camera frame x right, y down, z forward; see
    :class:`SimilarityWarp`): the thesis' A.11 ``w_z`` is minus this one."""

    scaled = False


class InPlaneWarp(_FusedAdjoint, Warp):
    """4-DOF in-plane approximation (A.22):
    ``x' = x - dt (v + ((h_z + 1) R(phi) - Id)(x - c))``; theta = (vx, vy [px/s],
    phi [rad/s, small-angle rate], hz [1/s]). div f = 2 - 2 (h_z + 1) cos(phi) (A.25)."""

    def _kernel(self, x, y, dt, th, xw, yw, jx, jy, jac):
        _k_inplane(x, y, dt, th[0], th[1], th[2], th[3], self.center[0], self.center[1],
                   xw, yw, jx, jy, jac)

    def _adj(self, x, y, dt, xw, yw, th, gx, gy, wts, pad, h, wd, scale, out, vk=0, T=1.0,
             blk=_NO_BLOCKS):
        # the rotation as _k_inplane computes it (libm through numba and math alike)
        prm = np.array([self.center[0], self.center[1], math.cos(th[2]), math.sin(th[2]),
                        th[3] + 1.0, th[0], th[1]])
        _simple_adj(2, x, y, xw, yw, dt, prm, gx, gy, wts, pad, h, wd, scale, vk, T, out)

    def _mats_c(self, dt, th):
        n = dt.shape[0]
        c, s = _rot2(th[2])
        k = th[3] + 1
        z = 0 * dt * th[0]
        o, i = z, 1 + z
        M = _stack33([[1 + dt - dt * k * c, dt * k * s, -dt * th[0]],
                      [-dt * k * s, 1 + dt - dt * k * c, -dt * th[1]], [o, o, i]], n)
        Md = _stack33([[1 - k * c + z, k * s + z, -th[0] + z],
                       [-k * s + z, 1 - k * c + z, -th[1] + z], [o, o, o]], n)
        return M, Md


def _hom_divdet(warp, x, y, dt, G):
    n = x.shape[0]
    div = np.empty(n, dtype=np.complex128)
    det = np.empty(n, dtype=np.complex128)
    _k_hom_divdet(x, y, dt, G.astype(np.complex128), warp.center[0], warp.center[1], div, det)
    return div, det



class AffineWarp(Warp):
    """6-DOF affine (A.47): ``x' = c + A^-1(dt)(x - c - dt v)`` with ``A(dt) = Id + dt G``;
    theta = (vx, vy [px/s], g11, g12, g21, g22 [1/s])."""

    def _kernel(self, x, y, dt, th, xw, yw, jx, jy, jac):
        _k_affine(x, y, dt, th, self.center[0], self.center[1], xw, yw, jx, jy, jac)

    def _G(self, th):
        z = 0 * th[0]
        return np.array([[th[2], th[3], th[0]], [th[4], th[5], th[1]], [z, z, z]])

    def _div(self, x, y, dt, th):
        return _hom_divdet(self, x, y, dt, self._G(th))[0]

    def _det(self, x, y, dt, th):
        return _hom_divdet(self, x, y, dt, self._G(th))[1]

    def _mats_c(self, dt, th):
        n = dt.shape[0]
        G = np.array([[th[2], th[3]], [th[4], th[5]]])
        A = np.eye(2) + dt[:, None, None] * G
        Ai = np.linalg.inv(A)
        v = np.array([th[0], th[1]])
        b = -(Ai @ v) * dt[:, None]
        Aid = -Ai @ G @ Ai
        bd = -(Aid @ v) * dt[:, None] - Ai @ v
        M = np.zeros((n, 3, 3), dtype=Ai.dtype)
        Md = np.zeros((n, 3, 3), dtype=Ai.dtype)
        M[:, :2, :2] = Ai
        M[:, :2, 2] = b
        M[:, 2, 2] = 1
        Md[:, :2, :2] = Aid
        Md[:, :2, 2] = bd
        return M, Md


class HomographyWarp(Warp):
    """8-DOF homography (A.1): ``x' ~ H(dt)^-1 x`` in centred pixels, trajectory
    ``H(dt) = Id + dt G`` with ``G = [[g11, g12, g13], [g21, g22, g23], [g31, g32, 0]]``
    (g13, g23 in px/s; g31, g32 in 1/(px s); the others in 1/s)."""

    def _kernel(self, x, y, dt, th, xw, yw, jx, jy, jac):
        _k_homography(x, y, dt, th, self.center[0], self.center[1], xw, yw, jx, jy, jac)

    def _G(self, th):
        return np.array([[th[0], th[1], th[2]], [th[3], th[4], th[5]], [th[6], th[7], 0 * th[0]]])

    def _div(self, x, y, dt, th):
        return _hom_divdet(self, x, y, dt, self._G(th))[0]

    def _det(self, x, y, dt, th):
        return _hom_divdet(self, x, y, dt, self._G(th))[1]

    def _mats_c(self, dt, th):
        G = np.array([[th[0], th[1], th[2]], [th[3], th[4], th[5]], [th[6], th[7], 0 * th[0]]])
        H = np.eye(3) + dt[:, None, None] * G
        M = np.linalg.inv(H)
        return M, -M @ G @ M


class RotationWarp(_FusedAdjoint, Warp):
    """3-DOF camera rotation (3.22): ``x'_n ~ exp(dt omega^) x_n`` in normalized
    coordinates ``x_n = K^-1 (x, y, 1)``; theta = omega (wx, wy, wz) in rad/s, camera frame
    x right, y down, z forward. div f = 3 (x_n wy - y_n wx) at dt = 0 (3.23)."""

    _blocked = True

    def _kernel(self, x, y, dt, th, xw, yw, jx, jy, jac):
        kernel_case(_rot_warp_case, _rot_series_mode(dt, th), bool(jac))(
            x, y, dt, th, self.K, self._kinv, xw, yw, jx, jy)

    def _conj(self):
        return self.K, self._kinv

    def _adj(self, x, y, dt, xw, yw, th, gx, gy, wts, pad, h, wd, scale, out, vk=0, T=1.0,
             blk=_NO_BLOCKS):
        K, Ki = self.K, self._kinv
        prm = np.array([th[0], th[1], th[2], K[0, 0], K[0, 1], K[1, 0], K[1, 1], Ki[0, 0],
                        Ki[0, 1], Ki[0, 2], Ki[1, 0], Ki[1, 1], Ki[1, 2]])
        _rotation_adj(xw, yw, dt, prm, gx, gy, wts, pad, h, wd, scale, vk, T, blk, out)

    def _divdet(self, x, y, dt, theta, want_div, grad):
        x, y, dt = self._events(x, y, dt)
        th = self._theta(theta)
        n = x.shape[0]
        val = np.empty(n)
        g = np.empty((n, 3)) if grad else _EMPTY2
        _k_rot_divdet(x, y, dt, th, self._kinv, want_div, val, g, _EMPTY1, _EMPTY1)
        return (val, g) if grad else val

    def divergence(self, x, y, dt, theta, grad: bool = False):
        """:meth:`Warp.divergence` with analytic (not complex-step) omega-derivatives."""
        return self._divdet(x, y, dt, theta, True, grad)

    def jacobian_det(self, x, y, dt, theta, grad: bool = False):
        """:meth:`Warp.jacobian_det` with analytic omega-derivatives."""
        return self._divdet(x, y, dt, theta, False, grad)

    def _mats_c(self, dt, th):
        r = dt[:, None] * th[None, :]
        R = rodrigues(r)
        return R, _hat(th).astype(R.dtype) @ R


# ---------------------------------------------------------------------------------------

_SPECS = {
    "zoom": (ZoomWarp, ("hz",), ("1/s",)),
    "translation": (TranslationWarp, ("vx", "vy"), ("px/s", "px/s")),
    "rotation": (RotationWarp, ("wx", "wy", "wz"), ("rad/s",) * 3),
    "se2": (SE2Warp, ("vx", "vy", "wz"), ("px/s", "px/s", "rad/s")),
    "inplane": (InPlaneWarp, ("vx", "vy", "phi", "hz"), ("px/s", "px/s", "rad/s", "1/s")),
    "similarity": (SimilarityWarp, ("vx", "vy", "wz", "s"), ("px/s", "px/s", "rad/s", "1/s")),
    "affine": (AffineWarp, ("vx", "vy", "g11", "g12", "g21", "g22"),
               ("px/s", "px/s") + ("1/s",) * 4),
    "homography": (HomographyWarp, ("g11", "g12", "g13", "g21", "g22", "g23", "g31", "g32"),
                   ("1/s", "1/s", "px/s", "1/s", "1/s", "px/s", "1/(px s)", "1/(px s)")),
}

#: Names of the warps :func:`make_warp` builds, with their number of parameters.
WARPS: dict[str, int] = {k: len(v[1]) for k, v in _SPECS.items()}


def make_warp(name: str, sensor_size: tuple[int, int], K: np.ndarray | None = None,
              center: tuple[float, float] | None = None) -> Warp:
    """Build a warp by name.

    Parameters
    ----------
    name : str
        One of :data:`WARPS`: zoom (1 DOF), translation (2), rotation (3), se2 (3),
        inplane (4), similarity (4), affine (6), homography (8).
    sensor_size : (int, int)
        ``(height, width)`` in pixels.
    K : array (3, 3), optional
        Camera intrinsics in pixels; required for ``rotation``.
    center : (float, float), optional
        Pixel ``(cx, cy)`` of the centred coordinates; default the image centre
        ``((W - 1) / 2, (H - 1) / 2)``.

    Examples
    --------
    >>> K = np.array([[200.0, 0, 120], [0, 200.0, 90], [0, 0, 1]])
    >>> w = make_warp("rotation", sensor_size=(180, 240), K=K)
    >>> w.param_names, w.param_units[0]
    (('wx', 'wy', 'wz'), 'rad/s')
    """
    if name not in _SPECS:
        raise ParameterError(f"unknown warp '{name}'; choose one of {sorted(_SPECS)}")
    h, w = _shape(sensor_size, "sensor_size")
    cls, names, units = _SPECS[name]
    Kmat = None
    if K is not None:
        Kmat = np.ascontiguousarray(K, dtype=np.float64)
        if Kmat.shape != (3, 3) or not np.all(np.isfinite(Kmat)) or \
                abs(np.linalg.det(Kmat)) < 1e-12 or np.any(Kmat[2] != (0, 0, 1)):
            raise CalibrationError(f"K must be a finite invertible 3x3 intrinsics matrix with "
                                   f"last row (0, 0, 1), got {np.asarray(K).tolist()!r}")
    elif name == "rotation":
        raise CalibrationError("the rotation warp needs the camera intrinsics K (3x3, pixels)")
    if center is None:
        center = ((w - 1) / 2.0, (h - 1) / 2.0)
    center = (float(center[0]), float(center[1]))
    return cls(name=name, param_names=names, param_units=units, sensor_size=(h, w),
               center=center, K=Kmat)
