"""Numba kernels of the event-based BOS solver (:mod:`evmotion.methods.bos`).

The objective at one pyramid level is evaluated over an ``(h, w)`` grid of (possibly pooled)
pixels from four dense fields -- the displacement ``du, dv`` over the window and the frame
translation ``pu, pv``, all in original pixels -- that are bilinear upsamplings of patch-grid
parameters (:func:`upsample`, adjoint :func:`upsample_adjoint`). :func:`objective_grad`
returns the objective and its gradient with respect to the four dense fields, in three
passes over the grid (prediction, residual, gradient). Plain-numpy references live in
:mod:`evmotion.methods._bos_reference`.

Smooth L1: every absolute value is the Charbonnier ``sqrt(r^2 + eps^2) - eps``, so that the
objective is differentiable; ``eps`` is small (see :class:`evmotion.methods.bos.BosOptions`).
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["interp_index", "objective_grad", "upsample", "upsample_adjoint"]


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


@njit(cache=True)
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


@njit(cache=True)
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
            for j in range(w):
                v = g[c, i, j]
                tmp[i0, j] += (1.0 - f) * v
                tmp[i1, j] += f * v
        out[c] = 0.0
        for a in range(nh):
            for j in range(w):
                j0 = ix[j]
                j1 = min(j0 + 1, nw - 1)
                f = fx[j]
                v = tmp[a, j]
                out[c, a, j0] += (1.0 - f) * v
                out[c, a, j1] += f * v


@njit(cache=True, inline="always")
def _sample(gx, gy, i, j, pu, pv, inv_k):
    """Bilinear samples of ``gx, gy`` at (row i + pv/k, col j + pu/k), clamped to the grid, and
    their derivatives with respect to pu and pv (zero where the point is clamped)."""
    h, w = gx.shape
    yy = i + pv * inv_k
    xx = j + pu * inv_k
    iny = 1.0
    inx = 1.0
    if yy < 0.0:
        yy = 0.0
        iny = 0.0
    elif yy > h - 1.0:
        yy = h - 1.0
        iny = 0.0
    if xx < 0.0:
        xx = 0.0
        inx = 0.0
    elif xx > w - 1.0:
        xx = w - 1.0
        inx = 0.0
    y0 = min(int(yy), h - 2)
    x0 = min(int(xx), w - 2)
    fy = yy - y0
    fx = xx - x0
    a00 = gx[y0, x0]
    a01 = gx[y0, x0 + 1]
    a10 = gx[y0 + 1, x0]
    a11 = gx[y0 + 1, x0 + 1]
    b00 = gy[y0, x0]
    b01 = gy[y0, x0 + 1]
    b10 = gy[y0 + 1, x0]
    b11 = gy[y0 + 1, x0 + 1]
    sx = (1.0 - fy) * ((1.0 - fx) * a00 + fx * a01) + fy * ((1.0 - fx) * a10 + fx * a11)
    sy = (1.0 - fy) * ((1.0 - fx) * b00 + fx * b01) + fy * ((1.0 - fx) * b10 + fx * b11)
    dxu = inx * inv_k * ((1.0 - fy) * (a01 - a00) + fy * (a11 - a10))
    dxv = iny * inv_k * ((1.0 - fx) * (a10 - a00) + fx * (a11 - a01))
    dyu = inx * inv_k * ((1.0 - fy) * (b01 - b00) + fy * (b11 - b10))
    dyv = iny * inv_k * ((1.0 - fx) * (b10 - b00) + fx * (b11 - b01))
    return sx, sy, dxu, dxv, dyu, dyv


@njit(cache=True, inline="always")
def _charb(r, eps):
    s = np.sqrt(r * r + eps * eps)
    return s - eps, r / s


@njit(cache=True)
def objective_grad(fields, gx, gy, meas, weight, s_meas, inv_k, lam_tv, lam_p, eps_d, eps_r,
                   normalized, use_p, pred, grad):
    """Objective (6.10) at one level and its gradient with respect to the dense fields.

    Parameters
    ----------
    fields : (4, h, w) float
        Dense ``du, dv`` (displacement over the window, px) and ``pu, pv`` (frame
        translation, px).
    gx, gy : (h, w) float
        Gradient of the log frame per original pixel.
    meas : (h, w) float
        Measured increment (events, smoothed; in log units when calibrated).
    weight : (h, w) float
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
        Warp the frame gradient by ``p`` (else p is ignored and its gradient is zero).
    pred : (h, w) float
        Work buffer (the predicted increment on return).
    grad : (4, h, w) float
        Output: gradient with respect to ``fields``.

    Returns
    -------
    (total, data, tv, p) : floats
        The objective and its three terms (regularizers without their lambdas).
    """
    h, w = gx.shape
    n = h * w
    inv_n = 1.0 / n
    du = fields[0]
    dv = fields[1]
    pu = fields[2]
    pv = fields[3]
    # pass 1: prediction -grad L(x + p) . d
    ss = 0.0
    for i in range(h):
        for j in range(w):
            if use_p:
                sx, sy, _a, _b, _c, _d = _sample(gx, gy, i, j, pu[i, j], pv[i, j], inv_k)
            else:
                sx = gx[i, j]
                sy = gy[i, j]
            v = -(sx * du[i, j] + sy * dv[i, j])
            pred[i, j] = v
            ss += v * v
    s_pred = np.sqrt(ss * inv_n + 1e-30)
    inv_sm = 1.0 / s_meas
    inv_sp = 1.0 / s_pred
    # pass 2: residual, data term, and sum(G * pred) for the normalization's gradient
    e_data = 0.0
    gp = 0.0
    for i in range(h):
        for j in range(w):
            if normalized:
                r = pred[i, j] * inv_sp - meas[i, j] * inv_sm
            else:
                r = (pred[i, j] - meas[i, j]) * inv_sm
            val, der = _charb(r, eps_d)
            e_data += val
            gp += der * pred[i, j]
            grad[0, i, j] = der * inv_n
    e_data *= inv_n
    kk = gp * inv_n * inv_n * inv_sp * inv_sp * inv_sp
    # pass 3: gradient with respect to the dense fields, TV and |p|
    e_tv = 0.0
    e_p = 0.0
    ct = lam_tv * inv_n * inv_k
    for i in range(h):
        for j in range(w):
            if normalized:
                dp = grad[0, i, j] * inv_sp - pred[i, j] * kk
            else:
                dp = grad[0, i, j] * inv_sm
            if use_p:
                sx, sy, dxu, dxv, dyu, dyv = _sample(gx, gy, i, j, pu[i, j], pv[i, j], inv_k)
                g_pu = -(du[i, j] * dxu + dv[i, j] * dyu) * dp
                g_pv = -(du[i, j] * dxv + dv[i, j] * dyv) * dp
                a, b = _charb(pu[i, j], eps_r)
                c, d = _charb(pv[i, j], eps_r)
                e_p += a + c
                g_pu += lam_p * inv_n * b
                g_pv += lam_p * inv_n * d
            else:
                sx = gx[i, j]
                sy = gy[i, j]
                g_pu = 0.0
                g_pv = 0.0
            g_du = -sx * dp
            g_dv = -sy * dp
            wt = weight[i, j]
            if j + 1 < w:
                a, b = _charb((du[i, j + 1] - du[i, j]) * inv_k, eps_r)
                c, d = _charb((dv[i, j + 1] - dv[i, j]) * inv_k, eps_r)
                e_tv += wt * (a + c)
                g_du -= ct * wt * b
                g_dv -= ct * wt * d
            if i + 1 < h:
                a, b = _charb((du[i + 1, j] - du[i, j]) * inv_k, eps_r)
                c, d = _charb((dv[i + 1, j] - dv[i, j]) * inv_k, eps_r)
                e_tv += wt * (a + c)
                g_du -= ct * wt * b
                g_dv -= ct * wt * d
            if j > 0:
                wl = weight[i, j - 1]
                _a, b = _charb((du[i, j] - du[i, j - 1]) * inv_k, eps_r)
                _c, d = _charb((dv[i, j] - dv[i, j - 1]) * inv_k, eps_r)
                g_du += ct * wl * b
                g_dv += ct * wl * d
            if i > 0:
                wu = weight[i - 1, j]
                _a, b = _charb((du[i, j] - du[i - 1, j]) * inv_k, eps_r)
                _c, d = _charb((dv[i, j] - dv[i - 1, j]) * inv_k, eps_r)
                g_du += ct * wu * b
                g_dv += ct * wu * d
            grad[0, i, j] = g_du
            grad[1, i, j] = g_dv
            grad[2, i, j] = g_pu
            grad[3, i, j] = g_pv
    e_tv *= inv_n
    e_p *= inv_n
    total = e_data + lam_tv * e_tv + lam_p * e_p
    return total, e_data, e_tv, e_p
