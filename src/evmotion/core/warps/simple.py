"""The zoom (3.7), translation (3.5.1) and in-plane (A.22) warps: warps affine in the pixel
whose divergence and det J depend on dt only. Forward kernels with their Jacobians, one
fused adjoint loop for the three (``kind`` 0, 1, 2), and the closed-form collapse values."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from evmotion.core.warps.adjoint import (
    AdjointInput,
    FusedAdjoint,
    event_cell,
    src_diff,
    store_sums,
)
from evmotion.core.warps.base import Warp
from evmotion.core.warps.common import FAST_FINITE
from evmotion.jitcache import kernel_case

__all__ = ["InPlaneWarp", "TranslationWarp", "ZoomWarp", "simple_values"]

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


@njit(cache=True, error_model="numpy", fastmath=FAST_FINITE)
def _k_inplane(x, y, dt, th, cx, cy, xw, yw, jx, jy, jac):
    vx, vy = th[0], th[1]
    c = math.cos(th[2])
    sn = math.sin(th[2])
    kk = th[3] + 1.0
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


@njit(cache=True, error_model="numpy", inline="always")
def _simple_loop(kind, fuse, use_w, pair, vk, ev, prm, src):
    """Zoom (kind 0), translation (1), in-plane (2): the adjoint loop over the events ``ev``
    (:mod:`~.adjoint`); the zoom and in-plane warps are recomputed from the events (cheaper
    than reading their warped pixels as well)."""
    x, y, dt, xw, yw = ev
    gx, gy, wts, _, _, _, _, T = src
    cx, cy = prm[0], prm[1]
    hz = c = sn = kk = vx = vy = 0.0
    if kind == 0:
        hz = prm[2]
    elif kind == 2:
        c, sn, kk, vx, vy = prm[2], prm[3], prm[4], prm[5], prm[6]
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
            xv, yv, t, a, fx, fy, i = event_cell(xv0, yv0, t, k, use_w, pair, src)
            gX, gY, gd = src_diff(pair, a, fx, fy, e, i, src)
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
    """The fused adjoint of the zoom, translation and in-plane warps (``kind`` 0, 1,
    2; ``prm``: c, then h_z (zoom) or cos phi, sin phi, h_z + 1, vx, vy (in-plane)), one
    case of :func:`_simple_loop`."""

    @njit(cache=True, error_model="numpy", fastmath=FAST_FINITE)
    def simple_adj(ev, prm, src, out):
        store_sums(_simple_loop(kind, fuse, use_w, pair, vk, ev, prm, src), out)

    return simple_adj


def _simple_adj(kind, ev, prm, src: AdjointInput, out):
    """The zoom/translation/in-plane adjoint: picks the case kernel of
    :func:`_simple_adj_case` (translation: divergence 0 and det J = 1, whatever theta)."""
    kernel_case(_simple_adj_case, kind, *src.case(derivs=kind != 1))(
        ev, prm, src.kernel_args(), out)


@njit(cache=True, error_model="numpy", inline="always")
def _simple_values_body(kind, is_div, dt, th, T, d, g, want_g):
    """The loops of :func:`simple_values`."""
    n = dt.shape[0]
    if want_g:
        g[:, :] = 0.0
    if kind == 0 and not want_g:  # zoom values alone: branch-free loops that vectorize
        h = th[0]
        if is_div:
            for k in range(n):
                d[k] = -2.0 * h * T
        else:
            for k in range(n):
                s = 1.0 - dt[k] * h
                d[k] = s * s - 1.0
    elif kind == 0:  # zoom
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
    elif kind == 1:  # translation
        for k in range(n):
            d[k] = 0.0
    else:  # in-plane (kind 2)
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


def _simple_values_case(kind):
    """:func:`simple_values` for the warp ``kind``, compiled on first use."""

    @njit(cache=True, error_model="numpy", fastmath=FAST_FINITE)
    def values(is_div, dt, th, T, d, g, want_g):
        _simple_values_body(kind, is_div, dt, th, T, d, g, want_g)

    return values


def simple_values(kind, is_div, dt, th, T, d, g, want_g):
    """Per-event closed forms of the zoom (kind 0, (3.7)), translation (1) and in-plane (2,
    (A.25)/(A.27)) warps, whose divergence and det J depend on dt only: ``d_k``
    (divergence times ``T``, or ``|det J| - 1``) into ``d`` (N,) and, if ``want_g``,
    ``dd_k/dtheta`` into ``g`` (N, P). One kernel per warp, compiled on first use."""
    kernel_case(_simple_values_case, kind)(is_div, dt, th, T, d, g, want_g)


class ZoomWarp(FusedAdjoint, Warp):
    """1-DOF zoom (3.7): ``x' = c + (1 - dt h_z)(x - c)``, ``h_z`` in 1/s.

    div f = -2 h_z, det J = (1 - dt h_z)^2."""

    #: The divergence is the same for every event ((3.10), (A.25)): the collapse
    #: penalties evaluate it once.
    constant_divergence = True

    def _kernel(self, x, y, dt, th, xw, yw, jx, jy, jac):
        _k_zoom(x, y, dt, th[0], self.center[0], self.center[1], xw, yw, jx, jy, jac)

    def _adj(self, x, y, dt, xw, yw, th, src, out):
        prm = np.array([self.center[0], self.center[1], th[0]])
        _simple_adj(0, (x, y, dt, xw, yw), prm, src, out)

    def event_values(self, is_div, dt, th, T, d, g, want_g) -> None:
        """Closed-form per-event collapse values: ``d`` (N,) = divergence times ``T`` (1/s
        times s) if ``is_div``, else ``|det J| - 1``, and their ``theta``-derivatives into
        ``g`` (N, P) if ``want_g``; ``th`` checked float64 (P,), ``dt`` float64 (N,)."""
        simple_values(0, is_div, dt, th, T, d, g, want_g)


class TranslationWarp(FusedAdjoint, Warp):
    """2-DOF feature flow (3.5.1): ``x' = x - dt v``, ``v`` in px/s. div 0, det 1."""

    #: The divergence is the same for every event ((3.10), (A.25)): the collapse
    #: penalties evaluate it once.
    constant_divergence = True

    def _kernel(self, x, y, dt, th, xw, yw, jx, jy, jac):
        _k_translation(x, y, dt, th[0], th[1], xw, yw, jx, jy, jac)

    def _adj(self, x, y, dt, xw, yw, th, src, out):
        _simple_adj(1, (x, y, dt, xw, yw), np.array(self.center), src, out)

    def event_values(self, is_div, dt, th, T, d, g, want_g) -> None:
        """Closed-form per-event collapse values: ``d`` (N,) = divergence times ``T`` (1/s
        times s) if ``is_div``, else ``|det J| - 1``, and their ``theta``-derivatives into
        ``g`` (N, P) if ``want_g``; ``th`` checked float64 (P,), ``dt`` float64 (N,)."""
        simple_values(1, is_div, dt, th, T, d, g, want_g)


class InPlaneWarp(FusedAdjoint, Warp):
    """4-DOF in-plane approximation (A.22):
    ``x' = x - dt (v + ((h_z + 1) R(phi) - Id)(x - c))``; theta = (vx, vy [px/s],
    phi [rad/s], hz [1/s]): the per-second rate matrix ``(h_z + 1) R(phi) - Id`` rotates at
    ``(h_z + 1) sin(phi)`` rad/s and zooms at ``(h_z + 1) cos(phi) - 1`` per s, which are
    phi and hz only when both are small (se2 / similarity give the rates themselves; a
    2 rad/s roll is phi = -1.107, hz = 1.236). The rotation is the image's (the thesis'
    A.22): the camera's angular velocity about the optical axis, se2's and rotation's
    ``wz``, is minus it. div f = 2 - 2 (h_z + 1) cos(phi) (A.25)."""

    #: The divergence is the same for every event ((3.10), (A.25)): the collapse
    #: penalties evaluate it once.
    constant_divergence = True

    def _kernel(self, x, y, dt, th, xw, yw, jx, jy, jac):
        _k_inplane(x, y, dt, th, self.center[0], self.center[1], xw, yw, jx, jy, jac)

    def _adj(self, x, y, dt, xw, yw, th, src, out):
        # the rotation as _k_inplane computes it (libm through numba and math alike)
        prm = np.array([self.center[0], self.center[1], math.cos(th[2]), math.sin(th[2]),
                        th[3] + 1.0, th[0], th[1]])
        _simple_adj(2, (x, y, dt, xw, yw), prm, src, out)

    def event_values(self, is_div, dt, th, T, d, g, want_g) -> None:
        """Closed-form per-event collapse values: ``d`` (N,) = divergence times ``T`` (1/s
        times s) if ``is_div``, else ``|det J| - 1``, and their ``theta``-derivatives into
        ``g`` (N, P) if ``want_g``; ``th`` checked float64 (P,), ``dt`` float64 (N,)."""
        simple_values(2, is_div, dt, th, T, d, g, want_g)
