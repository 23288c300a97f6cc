"""The planar SE(2) (A.11) and similarity Sim(2) (A.36) warps: forward kernels with their
Jacobians (series or libm trigonometry), the fused adjoint and the closed-form collapse
values (A.13)/(A.14), (A.40)/(A.42)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from evmotion.core.warps.adjoint import (
    AdjointInput,
    FusedAdjoint,
    src_diff,
    store_sums,
    warped_cell,
)
from evmotion.core.warps.base import Warp
from evmotion.core.warps.common import BLOCK, FAST_FINITE, max_abs
from evmotion.core.warps.so3 import rod_coeffs_short, sincos_any, sincos_block
from evmotion.jitcache import kernel_case

__all__ = ["SE2Warp", "SimilarityWarp", "similarity_values"]

@njit(cache=True, error_model="numpy")
def _similarity_event(x, y, t, sn, c, prm):
    """Centred warped point ``(ox, oy)`` and ``1 / beta`` of one event (``prm``: vx, vy, the
    image rotation rate, s, cx, cy)."""
    vx, vy, _, s, cx, cy = prm
    ib = 1.0 / (1.0 + t * s)  # s is 0 for SE(2)
    u = x - cx - t * vx
    v = y - cy - t * vy
    return (c * u - sn * v) * ib, (sn * u + c * v) * ib, ib


@njit(cache=True, error_model="numpy", inline="always")
def _similarity_fwd_loop(small, scaled, jac, args):
    """The warp of :func:`_similarity_case` and, if ``jac``, its Jacobian; ``small`` (a
    constant, :func:`~evmotion.core.warps.so3.sincos_any`), ``scaled`` and ``jac`` are
    constants, so the branches fold away."""
    x, y, dt, prm, xw, yw, jx, jy = args
    w, cx, cy = prm[2], prm[4], prm[5]
    p = 4 if scaled else 3
    # flat views: strided stores into 1-D arrays vectorize, 2-D item stores do not
    jxf = jx.reshape(jx.size)
    jyf = jy.reshape(jy.size)
    for k in range(x.shape[0]):
        t = dt[k]
        sn, c = sincos_any(-t * w, small)
        ox, oy, ib = _similarity_event(x[k], y[k], t, sn, c, prm)
        xw[k] = cx + ox
        yw[k] = cy + oy
        if not jac:
            continue
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


def _similarity_case(small, scaled, jac):
    """The SE(2)/similarity warp (``prm``: vx, vy, the image rotation rate, s, cx, cy) and,
    if ``jac``, its Jacobian, in one case of :func:`_similarity_fwd_loop`, compiled on
    first use (one kernel branching to all five had taken 2.8 s from an empty cache)."""

    @njit(cache=True, error_model="numpy", fastmath=FAST_FINITE)
    def similarity_warp(x, y, dt, prm, xw, yw, jx, jy):
        _similarity_fwd_loop(small, scaled, jac, (x, y, dt, prm, xw, yw, jx, jy))

    return similarity_warp


@njit(cache=True, error_model="numpy")
def _similarity_vjp_event(ox, oy, t, sn, c, s, gX, gY):
    """``gX dxw/dtheta + gY dyw/dtheta`` (4 terms) from the centred warped point: the
    Jacobian of :func:`_similarity_case`'s warp, contracted instead of stored."""
    ib = 1.0 / (1.0 + t * s)
    tib = t * ib
    return (-tib * (gX * c + gY * sn), tib * (gX * sn - gY * c), t * (gX * oy - gY * ox),
            -tib * (gX * ox + gY * oy))


@njit(cache=True, error_model="numpy", inline="always")
def _similarity_loop(small, fuse, use_w, pair, vk, ev, prm, src):
    """The SE(2)/similarity adjoint loop over the events ``ev`` (:mod:`~.adjoint`), with
    the values' derivatives in pair mode (``vk``)."""
    gx, gy, wts, _, _, _, _, T = src
    w, s, cx, cy = prm[0], prm[1], prm[2], prm[3]
    a0 = a1 = a2 = a3 = 0.0
    for k in range(ev[3].shape[0]):
        gd = 0.0
        xv, yv, t, a, fx, fy, i = warped_cell(fuse, use_w, pair, k, ev, src)
        sn, c = sincos_any(-t * w, small)
        ib = 1.0 / (1.0 + t * s)
        ib2 = ib * ib
        if fuse:
            # the values (A.40)/(A.42) from t (cheaper than reading them; sin(t w) = -sn)
            e = (T * (-2.0 * s * ib2 * c + 2.0 * w * ib * sn) if vk == 1 else
                 ib2 - 1.0 if vk == 2 else wts[k] if pair else 0.0)
            gX, gY, gd = src_diff(pair, a, fx, fy, e, i, src)
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
    """The SE(2)/similarity adjoint (``prm``: the image rotation rate, s, cx, cy; ``out``
    (3,) or (4,)), one case of :func:`_similarity_loop`."""

    @njit(cache=True, error_model="numpy", fastmath=FAST_FINITE)
    def similarity_adj(ev, prm, src, out):
        store_sums(_similarity_loop(small, fuse, use_w, pair, vk, ev, prm, src), out)

    return similarity_adj


def _similarity_adj(ev, prm, src: AdjointInput, out):
    """The SE(2)/similarity adjoint: picks the case kernel of :func:`_similarity_adj_case`
    (angles below 1 rad take the series of :func:`sincos`)."""
    small = bool(max_abs(ev[2]) * abs(prm[0]) < 1.0)
    kernel_case(_similarity_adj_case, small, *src.case())(ev, prm, src.kernel_args(), out)


@njit(cache=True, error_model="numpy", fastmath=FAST_FINITE)
def similarity_values(is_div, dt, th, T, d, g, want_g):
    """Per-event closed forms of SE(2) (A.13)/(A.14) (P = 3, s = 0) and of the similarity
    (A.40)/(A.42): ``d_k`` (divergence times ``T``, or ``|det J| - 1``) into ``d`` and, if
    ``want_g``, ``dd_k/dtheta`` into ``g`` (N, P)."""
    n = dt.shape[0]
    P = th.shape[0]
    if want_g:
        g[:, :] = 0.0
    w = th[2]
    s = th[3] if P == 4 else 0.0
    amax = max_abs(dt) * abs(w)
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
            sa, cb, _ = rod_coeffs_short(z)
            ib = 1.0 / (1.0 + t * s)
            d[k] = T * (-2.0 * s * ib * ib * (1.0 - z * cb) + 2.0 * w * ib * (a * sa))
        return
    sbuf = np.empty(BLOCK)
    cbuf = np.empty(BLOCK)
    for k0 in range(0, n, BLOCK):
        k1 = min(k0 + BLOCK, n)
        if not is_div:
            for k in range(k0, k1):
                t = dt[k]
                ib = 1.0 / (1.0 + t * s)
                d[k] = ib * ib - 1.0
                if want_g and P == 4:
                    g[k, 3] = -2.0 * t * ib * ib * ib
            continue
        if small:
            sincos_block(dt, k0, k1, w, sbuf, cbuf)  # of -dt w
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


class SimilarityWarp(FusedAdjoint, Warp):
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

    # the kernels below take the image rotation rate -wz (A.11's sign, see the docstring):
    # parameters are flipped going in, the wz derivatives coming out

    def _kernel(self, x, y, dt, th, xw, yw, jx, jy, jac):
        prm = (float(th[0]), float(th[1]), -float(th[2]), float(th[3]) if self.scaled else 0.0,
               float(self.center[0]), float(self.center[1]))
        # angles below 1 rad take the series of sincos (exact to rounding, vectorizes)
        small = bool(max_abs(dt) * abs(prm[2]) < 1.0)
        kernel_case(_similarity_case, small, bool(jac and self.scaled), bool(jac))(
            x, y, dt, prm, xw, yw, jx, jy)
        if jac:
            jx[:, 2] *= -1.0
            jy[:, 2] *= -1.0

    def _adj(self, x, y, dt, xw, yw, th, src, out):
        prm = np.array([-th[2], th[3] if self.scaled else 0.0, self.center[0], self.center[1]])
        _similarity_adj((x, y, dt, xw, yw), prm, src, out)
        out[2] = -out[2]

    def event_values(self, is_div, dt, th, T, d, g, want_g) -> None:
        """Closed-form per-event collapse values: ``d`` (N,) = divergence times ``T`` (1/s
        times s) if ``is_div``, else ``|det J| - 1``, and their ``theta``-derivatives into
        ``g`` (N, P) if ``want_g``; ``th`` checked float64 (P,), ``dt`` float64 (N,)."""
        image_th = th.copy()
        image_th[2] = -th[2]
        similarity_values(is_div, dt, image_th, T, d, g, want_g)
        if want_g:
            g[:, 2] *= -1.0


class SE2Warp(SimilarityWarp):
    """3-DOF planar motion SE(2) (A.11): ``x' = c + R(dt w_z)(x - c - dt v)``;
    theta = (vx, vy [px/s], wz [rad/s]). div f = -2 wz sin(dt wz) (A.13), det J = 1.

    ``wz`` is the camera's angular velocity about the optical axis with the rotation warp's
    sign (right-handed, camera frame x right, y down, z forward; see
    :class:`SimilarityWarp`): the thesis' A.11 ``w_z`` is minus this one."""

    scaled = False
