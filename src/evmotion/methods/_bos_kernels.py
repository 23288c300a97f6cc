"""Numba kernels of the event-based BOS solver (:mod:`evmotion.methods.bos`).

The objective at one pyramid level is evaluated over an ``(h, w)`` grid of (possibly pooled)
pixels from four dense fields -- the displacement ``du, dv`` over the window and the frame
translation ``pu, pv``, all in original pixels -- that are bilinear upsamplings of patch-grid
parameters (:func:`upsample`, adjoint :func:`upsample_adjoint`). :func:`objective_grad`
returns the objective and its gradient with respect to the four dense fields, in three
passes over the grid (prediction, residual, gradient) and one per TV field. The frame
translated by p enters to first order, ``grad L(x + p) = grad L + H p`` (H the Hessian of the
smoothed log frame): p is a small correction (the authors bound it to +-0.4 px), and the
expansion keeps the objective smooth in p and the loops vectorizable. Plain-numpy references live in
:mod:`evmotion.methods._bos_reference`.

Smooth L1: every absolute value is the Charbonnier ``sqrt(r^2 + eps^2) - eps``, so that the
objective is differentiable; ``eps`` is small (see :class:`evmotion.methods.bos.BosOptions`).
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["interp_index", "objective_grad", "upsample", "upsample_adjoint"]

# the numpy error model (no zero-division checks) and fastmath let the pixel loops vectorize
_JIT = dict(cache=True, fastmath=True, error_model="numpy")


def interp_index(n_out: int, step_out: float, n_in: int, step_in: float):
    """Bilinear interpolation indices from a grid of ``n_in`` cells of ``step_in`` px to one of
    ``n_out`` cells of ``step_out`` px, both starting at pixel 0 and sampled at cell centres
    (``c = i * step + (step - 1) / 2`` in pixel coordinates). Points beyond the outer centres
    take the border value. Returns ``(i0, frac)``: ``out[i] = (1 - frac) in[i0] + frac in[i0+1]``.
    """
    c = np.arange(n_out) * step_out + (step_out - 1.0) / 2.0
    u = np.clip((c - (step_in - 1.0) / 2.0) / step_in, 0.0, n_in - 1.0)
    i0 = np.minimum(np.floor(u).astype(np.int64), max(n_in - 2, 0))
    return np.ascontiguousarray(i0), np.ascontiguousarray(u - i0)


@njit(**_JIT)
def upsample(x, iy, fy, ix, fx, out):
    """``out[c] = A_y x[c] A_x^T`` for every channel: bilinear from (c, nh, nw) to (c, h, w)."""
    nc, nh, nw = x.shape
    h = iy.shape[0]
    w = ix.shape[0]
    tmp = np.empty((nh, w), dtype=np.float64)
    for c in range(nc):
        for a in range(nh):
            for j in range(w):
                j0 = ix[j]
                j1 = min(j0 + 1, nw - 1)
                f = fx[j]
                tmp[a, j] = (1.0 - f) * x[c, a, j0] + f * x[c, a, j1]
        for i in range(h):
            i0 = iy[i]
            i1 = min(i0 + 1, nh - 1)
            g = fy[i]
            for j in range(w):
                out[c, i, j] = (1.0 - g) * tmp[i0, j] + g * tmp[i1, j]


@njit(**_JIT)
def upsample_adjoint(g, iy, fy, ix, fx, out):
    """Adjoint of :func:`upsample`: ``out[c] = A_y^T g[c] A_x`` (overwrites ``out``)."""
    nc, h, w = g.shape
    nh = out.shape[1]
    nw = out.shape[2]
    tmp = np.empty((nh, w), dtype=np.float64)
    for c in range(nc):
        tmp[:] = 0.0
        for i in range(h):
            i0 = iy[i]
            i1 = min(i0 + 1, nh - 1)
            f = fy[i]
            gi = g[c, i]
            t0 = tmp[i0]
            t1 = tmp[i1]
            for j in range(w):
                t0[j] += (1.0 - f) * gi[j]
            for j in range(w):
                t1[j] += f * gi[j]
        out[c] = 0.0
        for a in range(nh):
            for j in range(w):
                j0 = ix[j]
                j1 = min(j0 + 1, nw - 1)
                f = fx[j]
                v = tmp[a, j]
                out[c, a, j0] += (1.0 - f) * v
                out[c, a, j1] += f * v


@njit(**_JIT)
def _predict(fields, gimg, use_p, work):
    """Pass 1: prediction ``-grad L(x + p) . d`` into ``work[0]``, with the frame gradient
    translated by p to first order (``grad L + H p``, H the Hessian); the translated
    gradient into ``work[1:3]`` and ``-d/dp pred`` into ``work[3:5]``. Returns sum(pred^2).
    Arrays are flat (c, n)."""
    du = fields[0]
    dv = fields[1]
    gx = gimg[0]
    gy = gimg[1]
    pred = work[0]
    ss = 0.0
    if use_p:
        pu = fields[2]
        pv = fields[3]
        hxx = gimg[2]
        hxy = gimg[3]
        hyy = gimg[4]
        wsx = work[1]
        wsy = work[2]
        whu = work[3]
        whv = work[4]
        for i in range(du.size):
            a = du[i]
            b = dv[i]
            sx = gx[i] + hxx[i] * pu[i] + hxy[i] * pv[i]
            sy = gy[i] + hxy[i] * pu[i] + hyy[i] * pv[i]
            v = -(sx * a + sy * b)
            pred[i] = v
            wsx[i] = sx
            wsy[i] = sy
            whu[i] = a * hxx[i] + b * hxy[i]
            whv[i] = a * hxy[i] + b * hyy[i]
            ss += v * v
    else:
        for i in range(du.size):
            v = -(gx[i] * du[i] + gy[i] * dv[i])
            pred[i] = v
            ss += v * v
    return ss


@njit(**_JIT)
def _data_terms(meas, a_pred, a_meas, eps_d, work):
    """Pass 2: Charbonnier of the residual ``a_pred pred - a_meas meas``; its derivative
    into ``work[5]``. Returns (sum rho, sum rho' * pred)."""
    pred = work[0]
    der = work[5]
    e = 0.0
    gp = 0.0
    e2 = eps_d * eps_d
    for i in range(meas.size):
        r = pred[i] * a_pred - meas[i] * a_meas
        sq = np.sqrt(r * r + e2)
        d = r / sq
        e += sq - eps_d
        gp += d * pred[i]
        der[i] = d
    return e, gp


@njit(**_JIT)
def _data_grad(fields, gimg, c_der, c_pred, lam_p_n, eps_r, use_p, work, grad):
    """Pass 3: gradient of the data term (``dE/dpred = c_der rho' - c_pred pred``) and of
    lambda_p |p| with respect to the fields. Returns sum |p| (Charbonnier)."""
    pred = work[0]
    der = work[5]
    e2 = eps_r * eps_r
    ep = 0.0
    g0 = grad[0]
    g1 = grad[1]
    g2 = grad[2]
    g3 = grad[3]
    if use_p:
        pu = fields[2]
        pv = fields[3]
        wsx = work[1]
        wsy = work[2]
        whu = work[3]
        whv = work[4]
        for i in range(pred.size):
            dp = c_der * der[i] - c_pred * pred[i]
            a = pu[i]
            b = pv[i]
            sa = np.sqrt(a * a + e2)
            sb = np.sqrt(b * b + e2)
            ep += sa + sb - (eps_r + eps_r)
            g0[i] = -wsx[i] * dp
            g1[i] = -wsy[i] * dp
            g2[i] = -whu[i] * dp + lam_p_n * a / sa
            g3[i] = -whv[i] * dp + lam_p_n * b / sb
    else:
        gx = gimg[0]
        gy = gimg[1]
        for i in range(pred.size):
            dp = c_der * der[i] - c_pred * pred[i]
            g0[i] = -gx[i] * dp
            g1[i] = -gy[i] * dp
            g2[i] = 0.0
            g3[i] = 0.0
    return ep


@njit(**_JIT)
def _tv(f, weight, inv_k, ct, eps_r, g, bx, by, byp):
    """Weighted TV of one dense (h, w) field (forward differences, Charbonnier); adds ``ct``
    times its gradient to ``g``. Returns the (unscaled) sum. Row by row: the derivatives of
    the row's x and y differences go to buffers, then each gradient entry is written once
    (so that every loop vectorizes)."""
    h, w = f.shape
    e2 = eps_r * eps_r
    e = 0.0
    byp[:] = 0
    bx[w - 1] = 0
    for i in range(h):
        fr = f[i]
        wr = weight[i]
        for j in range(w - 1):
            d = (fr[j + 1] - fr[j]) * inv_k
            sq = np.sqrt(d * d + e2)
            e += wr[j] * (sq - eps_r)
            bx[j] = ct * wr[j] * d / sq
        if i + 1 < h:
            fn = f[i + 1]
            for j in range(w):
                d = (fn[j] - fr[j]) * inv_k
                sq = np.sqrt(d * d + e2)
                e += wr[j] * (sq - eps_r)
                by[j] = ct * wr[j] * d / sq
        else:
            by[:] = 0
        gr = g[i]
        gr[0] += byp[0] - by[0] - bx[0]
        for j in range(1, w):
            gr[j] += bx[j - 1] - bx[j] + byp[j] - by[j]
        byp[:] = by
    return e


def objective_grad(fields, gimg, meas, weight, s_meas, inv_k, lam_tv, lam_p, eps_d, eps_r,
                   normalized, use_p, work, grad):
    """Objective (6.10) at one level and its gradient with respect to the dense fields.

    Parameters
    ----------
    fields : (4, h, w) float32 or float64
        Dense ``du, dv`` (displacement over the window, px) and ``pu, pv`` (frame
        translation, px).
    gimg : (5, h, w), same dtype
        Gradient of the log frame per original pixel ``gx, gy`` and its Hessian
        ``hxx, hxy, hyy``: the frame translated by p has gradient ``grad L + H p``.
    meas : (h, w), same dtype
        Measured increment (events, smoothed; in log units when calibrated).
    weight : (h, w), same dtype
        TV weight ``w = 1 - alpha b``.
    s_meas : float
        RMS of ``meas`` (its normalization).
    inv_k : float
        1 / pooling factor (pixels of this grid per original pixel).
    lam_tv, lam_p, eps_d, eps_r : float
        Weights of TV and |p|, Charbonnier eps of the data term and of the regularizers.
    normalized : bool
        Data term of normalized increments (6.11) if True, else ``(pred - meas) / s_meas``.
    use_p : bool
        Translate the frame by ``p`` (else p is ignored and its gradient is zero).
    work : (6, h, w), same dtype
        Work buffers; ``work[0]`` holds the predicted increment on return.
    grad : (4, h, w), same dtype
        Output: gradient with respect to ``fields``.

    Returns
    -------
    (total, data, tv, p) : floats
        The objective and its three terms (regularizers without their lambdas).
    """
    nc, h, w = fields.shape
    sc = fields.dtype.type  # scalars in the arrays' precision keep float32 loops in float32
    n = h * w
    inv_n = 1.0 / n
    flat_f = fields.reshape(nc, n)
    flat_g = gimg.reshape(gimg.shape[0], n)
    flat_w = work.reshape(work.shape[0], n)
    flat_grad = grad.reshape(nc, n)
    ss = _predict(flat_f, flat_g, use_p, flat_w)
    inv_sp = 1.0 / np.sqrt(ss * inv_n + 1e-30)
    inv_sm = 1.0 / s_meas
    a_pred = inv_sp if normalized else inv_sm
    e_data, gp = _data_terms(meas.reshape(n), sc(a_pred), sc(inv_sm), sc(eps_d), flat_w)
    e_data *= inv_n
    if normalized:
        c_der = inv_n * inv_sp
        c_pred = gp * inv_n * inv_n * inv_sp * inv_sp * inv_sp
    else:
        c_der = inv_n * inv_sm
        c_pred = 0.0
    e_p = _data_grad(flat_f, flat_g, sc(c_der), sc(c_pred), sc(lam_p * inv_n), sc(eps_r),
                     use_p, flat_w, flat_grad)
    if not use_p:
        e_p = 0.0
    bufs = np.empty((3, w), dtype=fields.dtype)
    ct = sc(lam_tv * inv_n * inv_k)
    e_tv = 0.0
    for c in range(2):
        e_tv += _tv(fields[c], weight, sc(inv_k), ct, sc(eps_r), grad[c], bufs[0], bufs[1],
                    bufs[2])
    e_tv *= inv_n
    e_p *= inv_n
    total = e_data + lam_tv * e_tv + lam_p * e_p
    return float(total), float(e_data), float(e_tv), float(e_p)
