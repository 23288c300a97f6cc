"""The RCAD penalty: the rate of change of area deformation integrated over the window,
(3.21)/(3.28), (A.44), (A.53) in closed form, or the (3.28)/(A.6) map over a pixel grid
(rotation, homography) thresholded and averaged; O(1), or O(pixels / stride^2)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from evmotion.core.collapse.values import checked_theta, time_span
from evmotion.core.warps import Warp
from evmotion.core.warps.so3 import rod_coeffs, rod_coeffs_exact
from evmotion.errors import EmptyWindowError

__all__ = ["rcad_checked", "rcad_closed_form", "rcad_value_grad"]

def rcad_closed_form(warp: Warp, th, t0, t1):
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
        _rot_area_coeffs(th, t, warp.K_inv, a, da)
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


def _rcad_reference(warp: Warp, th, t0, t1, shape, margin, stride, grad):
    """The grid penalty of :func:`_k_rcad_grid` (mean of the log area ratio over the grid
    points where it exceeds ``margin``) from the warp's own trajectory matrices
    (:meth:`Warp.area_log_ratio`): for a warp added without a closed form or area
    coefficients (docs/adding_a_warp.rst: its skeleton raised an IndexError here)."""
    h, w = shape
    gy, gx = np.mgrid[stride // 2:h:stride, stride // 2:w:stride]
    val, dval = warp.area_log_ratio(gx.ravel().astype(np.float64),
                                    gy.ravel().astype(np.float64), t0, t1, th, grad=True)
    sel = val > margin
    if not sel.any():
        return 0.0, (np.zeros(warp.n_params) if grad else None)
    return float(val[sel].mean()), (dval[sel].mean(axis=0) if grad else None)


@njit(cache=True, error_model="numpy")
def _rot_area_coeffs(om, t, kinv, a, da):
    """``a = e3^T R(-t omega) K^-1`` and ``da/d omega`` (3, 3): with ``v = K^-1 x``,
    d(e3^T R v)/d omega_j = t (R_0 . v) Jl_1j - t (R_1 . v) Jl_0j, ``Jl = J_l(-t omega)``."""
    p0, p1, p2 = -t * om[0], -t * om[1], -t * om[2]
    z = p0 * p0 + p1 * p1 + p2 * p2
    ca, cb, cc = rod_coeffs(z) if z < 1.0 else rod_coeffs_exact(z)
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


def rcad_value_grad(warp, x, y, dt, theta, shape, margin, stride, grad=True, span=None):
    x, y, dt = Warp.check_events(x, y, dt)
    if x.shape[0] == 0:
        raise EmptyWindowError("the regularizer needs at least one event, got none")
    th = checked_theta(warp, theta)
    t0, t1 = time_span(dt) if span is None else (float(span[0]), float(span[1]))
    return rcad_checked(warp, th, t0, t1, shape, margin, stride, grad)


def rcad_checked(warp, th, t0, t1, shape, margin, stride, grad=True):
    """The RCAD penalty and its gradient for checked arguments: ``th`` a finite float64
    (P,) array, the window's time span ``[t0, t1]`` (s), ``shape`` (H, W), ``margin`` and
    ``stride`` (the map's; rotation and homography) -- what a caller that evaluates one
    window many times (CMax) has checked once."""
    g = np.empty(warp.n_params)
    if warp.name == "rotation":
        # coefficients and grid in one compiled call (c = 0 for a rotation); g is 0 when
        # no point is selected
        value, _ = _k_rcad_rotation(shape[0], shape[1], stride, th, t0, t1, warp.K_inv,
                                    margin, g)
        return float(value), (g if grad else None)
    closed = rcad_closed_form(warp, th, t0, t1)
    if closed is not None:
        return closed
    if warp.name != "homography":
        return _rcad_reference(warp, th, t0, t1, shape, margin, stride, grad)
    a0, da0, c0, dc0 = _area_coeffs(warp, th, t0)
    a1, da1, c1, dc1 = _area_coeffs(warp, th, t1)
    value, n_sel = _k_rcad_grid(shape[0], shape[1], stride, a0, np.ascontiguousarray(da0), c0,
                                a1, np.ascontiguousarray(da1), c1, margin, g)
    if n_sel == 0:
        return 0.0, np.zeros(warp.n_params)
    g += dc1 - dc0
    return float(value), (g if grad else None)
