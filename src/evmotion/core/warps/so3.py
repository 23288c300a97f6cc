"""SO(3) and trigonometric series for the kernels: Rodrigues coefficients, sin/cos, R.

Angles per event are small in practice (``|dt * w| < 1`` rad): a Horner polynomial there is
exact to rounding and several times cheaper than libm's sin/cos, and branch-free, so that
the loops over events calling it vectorize. The plain-numpy exponential map lives in
:mod:`evmotion.geometry`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["cross", "rod_block", "rod_coeffs", "rod_coeffs_exact", "rod_coeffs_short",
           "rod_mode", "rot_matrix", "sincos", "sincos_any", "sincos_block"]

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
def rod_coeffs(z):
    """sin(a)/a, (1-cos a)/a^2, (a-sin a)/a^3 for z = a^2 < 1: eleven terms each, the
    truncation below 1/21! < 2e-20."""
    return _series(z, 1, 11), _series(z, 2, 11), _series(z, 3, 11)


@njit(cache=True, inline="always")
def sincos(a):
    """sin, cos for |a| < 1 from the series of :func:`rod_coeffs` (sin a = a A(a^2),
    cos a = 1 - a^2 B(a^2)), branch-free so that loops over events vectorize."""
    z = a * a
    sa, cb, _ = rod_coeffs(z)
    return a * sa, 1.0 - z * cb


@njit(cache=True, inline="always")
def rod_coeffs_short(z):
    """:func:`rod_coeffs` for z < 0.05 (|dt omega| < 0.22 rad, the usual case): seven
    terms suffice (truncation below z^7/15! < 1e-21)."""
    return _series(z, 1, 7), _series(z, 2, 7), _series(z, 3, 7)


@njit(cache=True)
def rod_coeffs_exact(z):
    ang = math.sqrt(z)
    sa = math.sin(ang)
    return sa / ang, (1.0 - math.cos(ang)) / z, (ang - sa) / (z * ang)


@njit(cache=True, error_model="numpy")
def sincos_block(dt, k0, k1, w, sbuf, cbuf):
    # contiguous 1-D loop with no branch: SIMD (the regularizers' per-block passes use it)
    for k in range(k0, k1):
        sbuf[k - k0], cbuf[k - k0] = sincos(-dt[k] * w)


@njit(cache=True)
def sincos_any(a, small):
    if small:
        return sincos(a)
    return math.sin(a), math.cos(a)


@njit(cache=True, error_model="numpy")
def rod_block(dt, k0, k1, ww, mode, abuf, bbuf, cbuf):
    """The Rodrigues coefficients of :func:`rod_mode` for the events ``k0 <= k < k1``
    into the buffers (from index 0), ``z = dt^2 |omega|^2``, ``ww = |omega|^2``."""
    # one loop, instantiated per mode with the mode a constant (branch-free, so SIMD, in
    # modes 0 and 1; mode 2 has angles above 1 rad and a branch per event)
    if mode == 0:
        _rod_fill(dt, k0, k1, ww, 0, abuf, bbuf, cbuf)
    elif mode == 1:
        _rod_fill(dt, k0, k1, ww, 1, abuf, bbuf, cbuf)
    else:
        _rod_fill(dt, k0, k1, ww, 2, abuf, bbuf, cbuf)


@njit(cache=True, error_model="numpy", inline="always")
def _rod_fill(dt, k0, k1, ww, mode, abuf, bbuf, cbuf):
    for k in range(k0, k1):
        t = dt[k]
        abuf[k - k0], bbuf[k - k0], cbuf[k - k0] = rod_mode(t * t * ww, mode)


@njit(cache=True, inline="always")
def rod_mode(z, mode):
    """Rodrigues coefficients for the series mode of :func:`_rot_rates` (a constant mode
    folds the branches away; mode 2 keeps a per-event branch)."""
    if mode == 0:
        return rod_coeffs_short(z)
    if mode == 1 or z < 1.0:
        return rod_coeffs(z)
    return rod_coeffs_exact(z)


@njit(cache=True, error_model="numpy", inline="always")
def cross(u, v):
    """The cross product ``u x v`` of two 3-tuples."""
    u0, u1, u2 = u
    v0, v1, v2 = v
    return u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0


@njit(cache=True, error_model="numpy", inline="always")
def rot_matrix(a, b, t, w):
    """The entries of ``R = exp(t omega^) = Id + a t omega^ + b t^2 (omega omega^T -
    |omega|^2 Id)``, row by row, from the Rodrigues coefficients ``a, b`` (``w``: omega
    and |omega|^2, a 4-tuple)."""
    wx, wy, wz, ww = w
    at = a * t
    bt = b * t * t
    return (1.0 + bt * (wx * wx - ww), -at * wz + bt * wx * wy, at * wy + bt * wx * wz,
            at * wz + bt * wx * wy, 1.0 + bt * (wy * wy - ww), -at * wx + bt * wy * wz,
            -at * wy + bt * wx * wz, at * wx + bt * wy * wz, 1.0 + bt * (wz * wz - ww))
