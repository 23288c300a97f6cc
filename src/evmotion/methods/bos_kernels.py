"""Numba kernels of the event-based BOS solver (:mod:`evmotion.methods.bos`).

The objective at one pyramid level is evaluated over an ``(h, w)`` grid of (possibly pooled)
pixels from four fields -- the displacement ``du, dv`` over the window and the frame
translation ``pu, pv``, all in original pixels -- that are bilinear upsamplings of patch-grid
values (:func:`upsample`). :func:`objective_grad` returns the objective and its gradient
with respect to the patch-grid values without ever storing the dense fields or their
gradients: the patch values are interpolated along x once (``(4, nh, w)``), each pixel row
is interpolated along y on the fly, and each row's gradient goes straight into the adjoint
of that y interpolation. Three passes over the grid (prediction, residual sums, gradient)
read the frame's derivatives, the prediction and the measurement only: the memory traffic
that bounds these loops.

The frame translated by p enters to first order, ``grad L(x + p) = grad L + H p`` (H the
Hessian of the smoothed log frame): p is a small correction (bounded, see
:class:`evmotion.methods.bos.BosOptions`), and the expansion keeps the objective smooth in p
and the loops vectorizable. Plain-numpy references live in
``tests/_bos_reference.py``.

Smooth L1: every absolute value is the Charbonnier ``sqrt(r^2 + eps^2) - eps``, so that the
objective is differentiable; ``eps`` is small (see :class:`evmotion.methods.bos.BosOptions`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

__all__ = ["LevelBuffers", "LevelGrid", "LevelImages", "ObjectiveTerms", "interp_index",
           "objective_grad", "upsample"]

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


@njit(cache=True, inline="always")
def _tap(idx, frac, i, n):
    """``(i0, i1, f)``: output ``i`` of the interpolation ``(idx, frac)``
    (:func:`interp_index`) from ``n`` inputs is ``(1 - f) in[i0] + f in[i1]``."""
    i0 = idx[i]
    return i0, min(i0 + 1, n - 1), frac[i]


@njit(**_JIT)
def _interp_x(x, ix, fx, out):
    """``out[c, a] = x[c, a] A_x^T``: (c, nh, nw) to (c, nh, w)."""
    nc, nh, nw = x.shape
    w = ix.shape[0]
    for c in range(nc):
        for a in range(nh):
            for j in range(w):
                j0, j1, f = _tap(ix, fx, j, nw)
                out[c, a, j] = (1.0 - f) * x[c, a, j0] + f * x[c, a, j1]


@njit(**_JIT)
def _interp_x_adjoint(t, ix, fx, out):
    """Adjoint of :func:`_interp_x`: (c, nh, w) to (c, nh, nw), overwriting ``out``."""
    nc, nh, w = t.shape
    nw = out.shape[2]
    out[:] = 0.0
    for c in range(nc):
        for a in range(nh):
            for j in range(w):
                j0, j1, f = _tap(ix, fx, j, nw)
                v = t[c, a, j]
                out[c, a, j0] += (1.0 - f) * v
                out[c, a, j1] += f * v


@njit(**_JIT)
def upsample(x, iy, fy, ix, fx, out):
    """``out[c] = A_y x[c] A_x^T`` for every channel: bilinear from (c, nh, nw) to (c, h, w)."""
    nc, nh, nw = x.shape
    h = iy.shape[0]
    tmp = np.empty((nc, nh, ix.shape[0]), dtype=np.float64)
    _interp_x(x, ix, fx, tmp)
    for c in range(nc):
        for i in range(h):
            _row(tmp, iy, fy, c, i, out[c, i])


@njit(**_JIT)
def _row(xr, iy, fy, c, i, out):
    """Row i of channel c of the dense field from its x-interpolated patch rows."""
    i0, i1, g = _tap(iy, fy, i, xr.shape[1])
    a = xr[c, i0]
    b = xr[c, i1]
    for j in range(out.shape[0]):
        out[j] = (1 - g) * a[j] + g * b[j]


@njit(**_JIT)
def _fill_rows(xr, iy, fy, i, use_p, rows):
    """Row ``i`` of the y-interpolated displacement (into ``rows[0:2]``) and, when
    ``use_p``, of the shift field (into ``rows[2:4]``)."""
    _row(xr, iy, fy, 0, i, rows[0])
    _row(xr, iy, fy, 1, i, rows[1])
    if use_p:
        _row(xr, iy, fy, 2, i, rows[2])
        _row(xr, iy, fy, 3, i, rows[3])


@njit(**_JIT)
def _predict(xr, iy, fy, gimg, use_p, pred, rows):
    """Pass 1: prediction ``-(grad L + H p) . d`` into ``pred``; returns sum(pred^2)."""
    h, w = pred.shape
    ss = 0.0
    du = rows[0]
    dv = rows[1]
    pu = rows[2]
    pv = rows[3]
    for i in range(h):
        _fill_rows(xr, iy, fy, i, use_p, rows)
        gx = gimg[0, i]
        gy = gimg[1, i]
        pr = pred[i]
        if use_p:
            hxx = gimg[2, i]
            hxy = gimg[3, i]
            hyy = gimg[4, i]
            for j in range(w):
                sx = gx[j] + hxx[j] * pu[j] + hxy[j] * pv[j]
                sy = gy[j] + hxy[j] * pu[j] + hyy[j] * pv[j]
                v = -(sx * du[j] + sy * dv[j])
                pr[j] = v
                ss += v * v
        else:
            for j in range(w):
                v = -(gx[j] * du[j] + gy[j] * dv[j])
                pr[j] = v
                ss += v * v
    return ss


@njit(**_JIT)
def _data_sums(pred, meas, a_pred, a_meas, eps_d):
    """Pass 2: sum of the Charbonnier of ``a_pred pred - a_meas meas`` and sum rho' pred."""
    p = pred.ravel()
    m = meas.ravel()
    e2 = eps_d * eps_d
    e = 0.0
    gp = 0.0
    for i in range(p.size):
        r = p[i] * a_pred - m[i] * a_meas
        sq = np.sqrt(r * r + e2)
        e += sq - eps_d
        gp += r / sq * p[i]
    return e, gp


@njit(**_JIT)
def _tv_row(f, fn, wr, has_next, tv, g, bx, by, byp):
    """TV of one field at one row (x difference, y difference to the next row; ``tv``:
    ``(inv_k, ct, eps_r)``): adds ``ct`` times the derivatives to the row's gradient ``g``
    (the previous row's y terms come in ``byp``, this row's are left there). Returns the
    row's (unscaled) TV."""
    inv_k, ct, eps_r = tv
    w = f.shape[0]
    e2 = eps_r * eps_r
    e = 0.0
    for j in range(w - 1):
        d = (f[j + 1] - f[j]) * inv_k
        sq = np.sqrt(d * d + e2)
        e += wr[j] * (sq - eps_r)
        bx[j] = ct * wr[j] * d / sq
    bx[w - 1] = 0
    if has_next:
        for j in range(w):
            d = (fn[j] - f[j]) * inv_k
            sq = np.sqrt(d * d + e2)
            e += wr[j] * (sq - eps_r)
            by[j] = ct * wr[j] * d / sq
    else:
        by[:] = 0
    g[0] += byp[0] - by[0] - bx[0]
    for j in range(1, w):
        g[j] += bx[j - 1] - bx[j] + byp[j] - by[j]
    byp[:] = by
    return e


@njit(**_JIT)
def _grad(xr, iy, fy, images, coef, use_p, work):
    """Pass 3: gradient with respect to the x-interpolated patch rows ``t`` of ``work = (t,
    rows, grows, tvb)`` (the adjoint of the y interpolation applied row by row), from
    ``images = (gimg, pred, meas, weight)`` and the scalars ``coef = (a_pred, a_meas,
    eps_d, c_der, c_pred, lam_p_n, ct, inv_k, eps_r)`` of :func:`objective_grad`. Returns
    (sum |p|, sum TV), unscaled."""
    gimg, pred, meas, weight = images
    a_pred, a_meas, eps_d, c_der, c_pred, lam_p_n, ct, inv_k, eps_r = coef
    t, rows, grows, tvb = work
    tv = (inv_k, ct, eps_r)
    h, w = pred.shape
    nh = xr.shape[1]
    e2d = eps_d * eps_d
    e2r = eps_r * eps_r
    t[:] = 0
    tvb[:] = 0
    du = rows[0]
    dv = rows[1]
    pu = rows[2]
    pv = rows[3]
    dun = rows[4]
    dvn = rows[5]
    ep = 0.0
    etv = 0.0
    for i in range(h):
        has_next = i + 1 < h
        _fill_rows(xr, iy, fy, i, use_p, rows)
        if has_next:
            _row(xr, iy, fy, 0, i + 1, dun)
            _row(xr, iy, fy, 1, i + 1, dvn)
        gx = gimg[0, i]
        gy = gimg[1, i]
        pr = pred[i]
        mr = meas[i]
        g0 = grows[0]
        g1 = grows[1]
        g2 = grows[2]
        g3 = grows[3]
        if use_p:
            hxx = gimg[2, i]
            hxy = gimg[3, i]
            hyy = gimg[4, i]
            for j in range(w):
                r = pr[j] * a_pred - mr[j] * a_meas
                dp = c_der * r / np.sqrt(r * r + e2d) - c_pred * pr[j]
                a = pu[j]
                b = pv[j]
                sa = np.sqrt(a * a + e2r)
                sb = np.sqrt(b * b + e2r)
                ep += sa + sb - (eps_r + eps_r)
                g0[j] = -(gx[j] + hxx[j] * a + hxy[j] * b) * dp
                g1[j] = -(gy[j] + hxy[j] * a + hyy[j] * b) * dp
                g2[j] = -(du[j] * hxx[j] + dv[j] * hxy[j]) * dp + lam_p_n * a / sa
                g3[j] = -(du[j] * hxy[j] + dv[j] * hyy[j]) * dp + lam_p_n * b / sb
        else:
            for j in range(w):
                r = pr[j] * a_pred - mr[j] * a_meas
                dp = c_der * r / np.sqrt(r * r + e2d) - c_pred * pr[j]
                g0[j] = -gx[j] * dp
                g1[j] = -gy[j] * dp
        wr = weight[i]
        etv += _tv_row(du, dun, wr, has_next, tv, g0, tvb[0], tvb[1], tvb[2])
        etv += _tv_row(dv, dvn, wr, has_next, tv, g1, tvb[3], tvb[4], tvb[5])
        i0, i1, f = _tap(iy, fy, i, nh)
        for c in range(4 if use_p else 2):
            gc = grows[c]
            a0 = t[c, i0]
            for j in range(w):
                a0[j] += (1 - f) * gc[j]
            a1 = t[c, i1]
            for j in range(w):
                a1[j] += f * gc[j]
    return ep, etv


class LevelBuffers:
    """Work arrays of :func:`objective_grad` for a (h, w) grid and (nh, nw) patches."""

    def __init__(self, h: int, w: int, nh: int, dtype):
        self.xr = np.zeros((4, nh, w), dtype)
        self.t = np.zeros((4, nh, w), dtype)
        self.pred = np.zeros((h, w), dtype)
        self.rows = np.zeros((6, w), dtype)
        self.grows = np.zeros((4, w), dtype)
        self.tvb = np.zeros((6, w), dtype)


class LevelGrid(NamedTuple):
    """The grid of one pyramid level: bilinear interpolation from the patches to its rows
    (``iy, fy``) and columns (``ix, fx``) (:func:`interp_index`; ``fy, fx`` in the images'
    precision) and ``inv_k``, 1 / its pooling factor (pixels of this grid per original
    pixel)."""

    iy: np.ndarray
    fy: np.ndarray
    ix: np.ndarray
    fx: np.ndarray
    inv_k: float


class LevelImages(NamedTuple):
    """The images of one pyramid level, all (h, w) but ``gimg``, float32 or float64.

    Attributes
    ----------
    gimg : (5, h, w)
        Gradient of the log frame per original pixel ``gx, gy`` and its Hessian
        ``hxx, hxy, hyy``: the frame translated by p has gradient ``grad L + H p``.
    meas : (h, w)
        Measured increment (events, smoothed; in log units when calibrated).
    weight : (h, w)
        TV weight ``w = 1 - alpha b``.
    s_meas : float
        RMS of ``meas`` (its normalization).
    """

    gimg: np.ndarray
    meas: np.ndarray
    weight: np.ndarray
    s_meas: float


class ObjectiveTerms(NamedTuple):
    """The terms of the objective (6.10): weights of TV and |p| (``lam_tv``, ``lam_p``),
    Charbonnier eps of the data term and of the regularizers (``eps_d``, ``eps_r``), the
    data term of normalized increments (6.11) if ``normalized`` (else ``(pred - meas) /
    s_meas``), and whether the frame is translated by ``p`` (``use_p``; else p is ignored
    and its gradient is zero)."""

    lam_tv: float
    lam_p: float
    eps_d: float
    eps_r: float
    normalized: bool
    use_p: bool


def objective_grad(xpatch, grid: LevelGrid, images: LevelImages, terms: ObjectiveTerms,
                   buf: LevelBuffers, grad):
    """Objective (6.10) at one level and its gradient with respect to the patch values.

    Parameters
    ----------
    xpatch : (4, nh, nw) float
        Patch-grid ``du, dv`` (displacement over the window, px) and ``pu, pv`` (frame
        translation, px).
    grid : LevelGrid
        The level's interpolation from the patches and pooling.
    images : LevelImages
        The frame's derivatives, the measured increment and the TV weight.
    terms : ObjectiveTerms
        Weights, smoothing and variant of the objective's terms.
    buf : LevelBuffers
        Work arrays (``buf.pred`` holds the predicted increment on return).
    grad : (4, nh, nw) float64
        Output: gradient with respect to ``xpatch``.

    Returns
    -------
    (total, data, tv, p) : floats
        The objective and its three terms (regularizers without their lambdas).
    """
    iy, fy, ix, fx, inv_k = grid
    gimg, meas, weight, s_meas = images
    lam_tv, lam_p, eps_d, eps_r, normalized, use_p = terms
    sc = gimg.dtype.type  # scalars in the arrays' precision keep float32 loops in float32
    h, w = meas.shape
    inv_n = 1.0 / (h * w)
    _interp_x(xpatch, ix, fx, buf.xr)
    ss = _predict(buf.xr, iy, fy, gimg, use_p, buf.pred, buf.rows)
    inv_sp = 1.0 / np.sqrt(ss * inv_n + 1e-30)
    inv_sm = 1.0 / s_meas
    a_pred = inv_sp if normalized else inv_sm
    e_data, gp = _data_sums(buf.pred, meas, sc(a_pred), sc(inv_sm), sc(eps_d))
    e_data *= inv_n
    if normalized:
        c_der = inv_n * inv_sp
        c_pred = gp * inv_n * inv_n * inv_sp * inv_sp * inv_sp
    else:
        c_der = inv_n * inv_sm
        c_pred = 0.0
    coef = tuple(sc(v) for v in (a_pred, inv_sm, eps_d, c_der, c_pred, lam_p * inv_n,
                                 lam_tv * inv_n * inv_k, inv_k, eps_r))
    e_p, e_tv = _grad(buf.xr, iy, fy, (gimg, buf.pred, meas, weight), coef, use_p,
                      (buf.t, buf.rows, buf.grows, buf.tvb))
    _interp_x_adjoint(buf.t, ix, fx, grad)
    e_tv *= inv_n
    e_p = e_p * inv_n if use_p else 0.0
    total = e_data + lam_tv * e_tv + lam_p * e_p
    return float(total), float(e_data), float(e_tv), float(e_p)
