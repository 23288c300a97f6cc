"""Image of warped events (IWE, thesis eq. 3.3) and its adjoint.

The IWE sums one smooth "delta" per warped event ``(xw_k, yw_k)``:

* ``kernel="bilinear"`` -- bilinear voting onto the four neighbouring pixels;
* ``kernel="gaussian"`` -- a Gaussian of standard deviation ``sigma`` pixels (the thesis'
  epsilon = 1 px), separable, each axis truncated at ``3 sigma`` and lowered by its value
  there so that the image stays continuous in the event positions (no jump when a pixel
  enters the support; plain truncation breaks finite-difference and line-search
  consistency), normalized to unit integral.

Coordinates are sensor pixels (x = column, y = row, origin top-left); the image is
``(H, W)`` float64. A vote that lands on a pixel outside the image is dropped, so an event
entirely outside the image contributes nothing; :func:`accumulate_backward` drops exactly
the same votes, so the pair is a consistent (forward, adjoint) couple and objectives built
on it stay continuous as events cross the border.

:func:`accumulate_backward` returns ``dL/dxw_k`` and ``dL/dyw_k`` given ``dL/dIWE``; the
chain rule through a warp's Jacobian then gives ``dL/dtheta``. ``*_into`` variants write into
caller-owned buffers for allocation-free hot loops.

Examples
--------
>>> import numpy as np
>>> iwe = accumulate(np.array([1.5]), np.array([2.0]), (4, 4))
>>> iwe[2, 1], iwe[2, 2]
(np.float64(0.5), np.float64(0.5))
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from evmotion.errors import ParameterError
from evmotion.geometry import sensor_shape

__all__ = [
    "KERNELS",
    "accumulate",
    "accumulate_backward",
    "accumulate_backward_into",
    "accumulate_backward_reduce",
    "accumulate_into",
    "dequantize",
]

#: Names of the delta approximations.
KERNELS = ("bilinear", "gaussian")

_NOWEIGHT = np.empty(0)


@njit(cache=True, inline="always")
def _cell(x, y, h, wd):
    """Bilinear cell of the point (x, y) px: ``(votes, ix, iy, fx, fy)`` with ``votes``
    False when no vote lands in the (h, wd) image (also for NaN), else the top-left pixel
    and the fractional offsets."""
    # comparisons with NaN are False
    if not (x > -1.0 and x < wd and y > -1.0 and y < h):
        return False, 0, 0, 0.0, 0.0
    x0 = math.floor(x)
    y0 = math.floor(y)
    return True, int(x0), int(y0), x - x0, y - y0


@njit(cache=True, nogil=True)
def _fwd_bilinear(xw, yw, w, out):
    h, wd = out.shape
    use_w = w.shape[0] > 0
    for k in range(xw.shape[0]):
        inside, ix, iy, fx, fy = _cell(xw[k], yw[k], h, wd)
        if not inside:
            continue
        a = w[k] if use_w else 1.0
        if ix >= 0 and iy >= 0 and ix + 1 < wd and iy + 1 < h:
            # interior cell (the usual case): no per-vote bounds tests
            ay = a * fy
            a1y = a - ay
            out[iy, ix] += a1y * (1.0 - fx)
            out[iy, ix + 1] += a1y * fx
            out[iy + 1, ix] += ay * (1.0 - fx)
            out[iy + 1, ix + 1] += ay * fx
            continue
        if iy >= 0:
            if ix >= 0:
                out[iy, ix] += a * (1.0 - fx) * (1.0 - fy)
            if ix + 1 < wd:
                out[iy, ix + 1] += a * fx * (1.0 - fy)
        if iy + 1 < h:
            if ix >= 0:
                out[iy + 1, ix] += a * (1.0 - fx) * fy
            if ix + 1 < wd:
                out[iy + 1, ix + 1] += a * fx * fy


@njit(cache=True, inline="always")
def _corners(g, ix, iy, h, wd):
    """The four pixels of the bilinear cell with top-left (ix, iy), 0 off the image (one
    branch for the usual interior cell; returned as a tuple, which compiles to faster code
    than scalars assigned in branches)."""
    if ix >= 0 and iy >= 0 and ix + 1 < wd and iy + 1 < h:
        return g[iy, ix], g[iy, ix + 1], g[iy + 1, ix], g[iy + 1, ix + 1]
    return (g[iy, ix] if (iy >= 0 and ix >= 0) else 0.0,
            g[iy, ix + 1] if (iy >= 0 and ix + 1 < wd) else 0.0,
            g[iy + 1, ix] if (iy + 1 < h and ix >= 0) else 0.0,
            g[iy + 1, ix + 1] if (iy + 1 < h and ix + 1 < wd) else 0.0)


@njit(cache=True, nogil=True)
def _bwd_bilinear(xw, yw, w, g, gx, gy):
    h, wd = g.shape
    use_w = w.shape[0] > 0
    for k in range(xw.shape[0]):
        inside, ix, iy, fx, fy = _cell(xw[k], yw[k], h, wd)
        if not inside:
            gx[k] = 0.0
            gy[k] = 0.0
            continue
        g00, g01, g10, g11 = _corners(g, ix, iy, h, wd)
        a = w[k] if use_w else 1.0
        gx[k] = a * ((g01 - g00) * (1.0 - fy) + (g11 - g10) * fy)
        gy[k] = a * ((g10 - g00) * (1.0 - fx) + (g11 - g01) * fx)


_VOTE_BLOCK = 256  # events per block of vote_bilinear: its buffers stay in L1


@njit(cache=True, error_model="numpy", inline="always")
def _vote_cells(use_w, xs, ys, ws, wd, h, ib, w00, w01, w10, w11):
    """Flat index of the top-left pixel and the four vote weights of each event of a block
    whose cell lies inside the (h, wd) image (index -1 otherwise): branch-free, so the
    loop vectorizes; the arithmetic of :func:`evmotion.core.iwe._fwd_bilinear`."""
    for j in range(xs.shape[0]):
        xv = xs[j]
        yv = ys[j]
        interior = (xv >= 0.0) & (xv < wd - 1) & (yv >= 0.0) & (yv < h - 1)
        xc = xv if interior else 0.0
        yc = yv if interior else 0.0
        x0 = math.floor(xc)
        y0 = math.floor(yc)
        fx = xc - x0
        fy = yc - y0
        a = ws[j] if use_w else 1.0
        ay = a * fy
        a1y = a - ay
        ib[j] = int(y0) * wd + int(x0) if interior else -1
        w00[j] = a1y * (1.0 - fx)
        w01[j] = a1y * fx
        w10[j] = ay * (1.0 - fx)
        w11[j] = ay * fx


def vote_bilinear(xw, yw, wts, out):
    """The bilinear IWE of :func:`evmotion.core.iwe.accumulate_into` into ``out`` (H, W),
    equal bit for bit (same votes, same arithmetic, same order of summation), about 25 %
    faster: the cells and vote weights of a block of events are computed first, in a loop
    that vectorizes, then scattered; events whose cell crosses the border take the
    bounds-tested path of the original. Weighted (``wts`` (N,)) or not (``wts`` empty):
    two kernels, each compiled on first use."""
    if wts.shape[0] > 0:
        return _vote_weighted(xw, yw, wts, out)
    return vote_counts(xw, yw, out)


@njit(cache=True, error_model="numpy")
def vote_counts(xw, yw, out):
    """:func:`vote_bilinear` of unit votes."""
    out[:] = 0.0
    # xw stands in for the weights and values, unread without them
    _vote_blocks(xw, yw, xw, False, out, xw, out, False, True)
    return out


@njit(cache=True, error_model="numpy")
def _vote_weighted(xw, yw, wts, out):
    """:func:`vote_bilinear` with per-event weights ``wts``."""
    out[:] = 0.0
    _vote_blocks(xw, yw, wts, True, out, wts, out, False, True)
    return out


@njit(cache=True, error_model="numpy")
def vote_pair(xw, yw, vals, cnt, num, with_cnt):
    """:func:`vote_bilinear` of ones into ``cnt`` (if ``with_cnt``; bit for bit) and, in
    the same pass, into ``num`` the IWE of the per-event ``vals`` (each unit vote weight
    times the value: a pixel of one event holds its value to the rounding of a product)."""
    num[:] = 0.0
    if with_cnt:
        cnt[:] = 0.0
        _vote_blocks(xw, yw, vals, False, cnt, vals, num, True, True)
    else:
        _vote_blocks(xw, yw, vals, False, cnt, vals, num, True, False)


@njit(cache=True, inline="always")
def block_bufs(size):
    """The buffers of a block of ``size`` events for :func:`_vote_cells`: the cells' flat
    index and the four vote weights."""
    return (np.empty(size, np.int64), np.empty(size), np.empty(size), np.empty(size),
            np.empty(size))


@njit(cache=True, error_model="numpy")
def vote_pairs(xw, yw, vals, out):
    """:func:`vote_pair` into one (H, W, 2) image ``out``: each pixel's count next to its
    sum of values (bit for bit those of :func:`vote_pair`), so that a vote updates two
    adjacent numbers (an eighth faster at 500k events)."""
    h, wd = out.shape[0], out.shape[1]
    out[:] = 0.0
    flat = out.reshape(out.size)
    ib, w00, w01, w10, w11 = block_bufs(_VOTE_BLOCK)
    r = 2 * wd
    n = xw.shape[0]
    for k0 in range(0, n, _VOTE_BLOCK):
        k1 = min(k0 + _VOTE_BLOCK, n)
        _vote_cells(False, xw[k0:k1], yw[k0:k1], _NOWEIGHT, wd, h, ib, w00, w01, w10, w11)
        for j in range(k1 - k0):
            i = 2 * ib[j]
            e = vals[k0 + j]
            if i >= 0:
                flat[i] += w00[j]
                flat[i + 1] += e * w00[j]
                flat[i + 2] += w01[j]
                flat[i + 3] += e * w01[j]
                flat[i + r] += w10[j]
                flat[i + r + 1] += e * w10[j]
                flat[i + r + 2] += w11[j]
                flat[i + r + 3] += e * w11[j]
                continue
            inside, ix, iy, fx, fy = _cell(xw[k0 + j], yw[k0 + j], h, wd)
            if not inside:
                continue
            for dy in range(2):
                for dx in range(2):
                    if 0 <= iy + dy < h and 0 <= ix + dx < wd:
                        v = (fx if dx else 1.0 - fx) * (fy if dy else 1.0 - fy)
                        out[iy + dy, ix + dx, 0] += v
                        out[iy + dy, ix + dx, 1] += e * v


@njit(cache=True, error_model="numpy", inline="always")
def _vote_blocks(xw, yw, wts, use_w, out, vals, out2, pair, with_out):
    """The votes of :func:`vote_bilinear` added to ``out`` (if ``with_out``) and, in
    ``pair`` mode, those times ``vals`` to ``out2``."""
    h, wd = out2.shape
    flat = out.reshape(out.size)
    flat2 = out2.reshape(out2.size)
    ib, w00, w01, w10, w11 = block_bufs(_VOTE_BLOCK)
    n = xw.shape[0]
    for k0 in range(0, n, _VOTE_BLOCK):
        vote_block(xw, yw, wts, use_w, out, flat, vals, out2, flat2, pair, with_out, k0,
                    min(k0 + _VOTE_BLOCK, n), ib, w00, w01, w10, w11)


@njit(cache=True, error_model="numpy", inline="always")
def vote_block(xw, yw, wts, use_w, out, flat, vals, out2, flat2, pair, with_out, k0, k1, ib,
                w00, w01, w10, w11):
    """:func:`_vote_blocks` for the events ``k0:k1`` (at most the length of the buffers
    ``ib`` (index) and ``w00`` ... ``w11`` (weights); ``flat``, ``flat2``: flat views of
    ``out``, ``out2``)."""
    h, wd = out2.shape
    _vote_cells(use_w, xw[k0:k1], yw[k0:k1], wts[k0:k1] if use_w else wts, wd, h, ib, w00,
                w01, w10, w11)
    for j in range(k1 - k0):
        i = ib[j]
        e = vals[k0 + j] if pair else 0.0
        if i >= 0:
            if with_out:
                flat[i] += w00[j]
                flat[i + 1] += w01[j]
                flat[i + wd] += w10[j]
                flat[i + wd + 1] += w11[j]
            if pair:
                flat2[i] += e * w00[j]
                flat2[i + 1] += e * w01[j]
                flat2[i + wd] += e * w10[j]
                flat2[i + wd + 1] += e * w11[j]
            continue
        inside, ix, iy, fx, fy = _cell(xw[k0 + j], yw[k0 + j], h, wd)
        if not inside:
            continue
        a = wts[k0 + j] if use_w else 1.0
        for dy in range(2):
            for dx in range(2):
                if 0 <= iy + dy < h and 0 <= ix + dx < wd:
                    v = a * (fx if dx else 1.0 - fx) * (fy if dy else 1.0 - fy)
                    if with_out:
                        out[iy + dy, ix + dx] += v
                    if pair:
                        out2[iy + dy, ix + dx] += e * v


@njit(cache=True, nogil=True)
def _gauss_consts(sigma):
    r = 3.0 * sigma
    inv2s2 = 1.0 / (2.0 * sigma * sigma)
    floor_ = math.exp(-r * r * inv2s2)
    # integral of (exp(-d^2 / 2 s^2) - floor_) over |d| < r: each axis sums to ~1
    z = sigma * math.sqrt(2.0 * math.pi) * math.erf(r / (sigma * math.sqrt(2.0))) - 2.0 * r * floor_
    return r, inv2s2, floor_, 1.0 / z


@njit(cache=True, nogil=True)
def _fwd_gauss(xw, yw, w, sigma, out):
    h, wd = out.shape
    use_w = w.shape[0] > 0
    r, inv2s2, fl, iz = _gauss_consts(sigma)
    for k in range(xw.shape[0]):
        x = xw[k]
        y = yw[k]
        if not (x > -r and x < wd - 1 + r and y > -r and y < h - 1 + r):
            continue
        a = (w[k] if use_w else 1.0) * iz * iz
        for iy in range(max(int(math.ceil(y - r)), 0), min(int(math.floor(y + r)), h - 1) + 1):
            dy = iy - y
            ky = math.exp(-dy * dy * inv2s2) - fl
            if ky <= 0.0:
                continue
            for ix in range(max(int(math.ceil(x - r)), 0),
                            min(int(math.floor(x + r)), wd - 1) + 1):
                dx = ix - x
                kx = math.exp(-dx * dx * inv2s2) - fl
                if kx > 0.0:
                    out[iy, ix] += a * kx * ky


@njit(cache=True, nogil=True)
def _bwd_gauss(xw, yw, w, sigma, g, gx, gy):
    h, wd = g.shape
    use_w = w.shape[0] > 0
    r, inv2s2, fl, iz = _gauss_consts(sigma)
    inv_s2 = 2.0 * inv2s2
    for k in range(xw.shape[0]):
        x = xw[k]
        y = yw[k]
        sx = 0.0
        sy = 0.0
        if x > -r and x < wd - 1 + r and y > -r and y < h - 1 + r:
            for iy in range(max(int(math.ceil(y - r)), 0),
                            min(int(math.floor(y + r)), h - 1) + 1):
                dy = iy - y
                ey = math.exp(-dy * dy * inv2s2)
                ky = ey - fl
                if ky <= 0.0:
                    continue
                # d/dy of ky = ey * (iy - y) / s^2
                dky = ey * dy * inv_s2
                for ix in range(max(int(math.ceil(x - r)), 0),
                                min(int(math.floor(x + r)), wd - 1) + 1):
                    dx = ix - x
                    ex = math.exp(-dx * dx * inv2s2)
                    kx = ex - fl
                    if kx > 0.0:
                        gv = g[iy, ix]
                        sx += gv * ex * dx * inv_s2 * ky
                        sy += gv * kx * dky
        a = (w[k] if use_w else 1.0) * iz * iz
        gx[k] = a * sx
        gy[k] = a * sy


def _prep(xw, yw, weights, name="xw"):
    xw = np.ascontiguousarray(xw, dtype=np.float64)
    yw = np.ascontiguousarray(yw, dtype=np.float64)
    if xw.ndim != 1 or xw.shape != yw.shape:
        raise ParameterError(f"xw and yw must be 1-D arrays of equal length, got shapes "
                             f"{xw.shape} and {yw.shape}")
    if weights is None:
        w = _NOWEIGHT
    else:
        w = np.ascontiguousarray(weights, dtype=np.float64)
        if w.shape != xw.shape:
            raise ParameterError(f"weights must have shape {xw.shape} like the events, "
                                 f"got {w.shape}")
    return xw, yw, w


#: The R2 low-discrepancy sequence (Roberts 2018; the inverses of the plastic number and its
#: square): evenly spread 2-D offsets, deterministic, for :func:`dequantize`.
_R2 = (0.7548776662466927, 0.5698402909980532)


def dequantize(x, y) -> tuple[np.ndarray, np.ndarray]:
    """Float64 copies of event pixels, spread over their pixel when all are whole numbers.

    A sensor reports integer pixels. With every event exactly on a pixel, the identity warp
    is a kink-shaped local maximum of any objective of the bilinear IWE (any motion moves
    all events off their pixels at once), which traps gradient methods at zero motion.
    When all coordinates are whole numbers (whatever their dtype: integers, or floats
    holding integers), each event is moved by an offset in [-0.5, 0.5)^2 px within its
    pixel, the k-th event by the k-th point of the R2 low-discrepancy sequence: no seed, the
    same offsets for the same events, and an even spread. Coordinates with any fractional
    part (undistorted events) are only converted to float64.

    Parameters
    ----------
    x, y : array (N,)
        Event pixels (x = column, y = row), any real dtype.

    Returns
    -------
    x, y : ndarray (N,) float64

    Examples
    --------
    >>> xd, yd = dequantize(np.array([3, 3, 3], np.uint16), np.array([1, 1, 1]))
    >>> bool(np.all(np.abs(xd - 3) < 0.5)), len(set(xd.tolist())) == 3
    (True, True)
    >>> dequantize(np.array([1.25]), np.array([2.0]))[0].tolist()
    [1.25]
    """
    xf = np.array(x, dtype=np.float64)
    yf = np.array(y, dtype=np.float64)
    if xf.size and np.all(xf == np.round(xf)) and np.all(yf == np.round(yf)):
        k = np.arange(1, xf.size + 1, dtype=np.float64)
        xf += np.mod(k * _R2[0], 1.0) - 0.5
        yf += np.mod(k * _R2[1], 1.0) - 0.5
    return xf, yf


def _check_kernel(kernel: str, sigma: float) -> None:
    if kernel not in KERNELS:
        raise ParameterError(f"unknown IWE kernel '{kernel}'; choose one of {KERNELS}")
    if kernel == "gaussian" and not (sigma > 0 and math.isfinite(sigma)):
        raise ParameterError(f"Gaussian IWE needs sigma > 0 (pixels), got {sigma!r}")


def accumulate_into(xw: np.ndarray, yw: np.ndarray, out: np.ndarray,
                    weights: np.ndarray | None = None, kernel: str = "bilinear",
                    sigma: float = 1.0) -> np.ndarray:
    """Allocation-free :func:`accumulate`: zero ``out`` (H, W) float64 C-contiguous and
    accumulate into it. Returns ``out``.

    Examples
    --------
    >>> buf = np.empty((3, 3))
    >>> float(accumulate_into(np.array([1.0]), np.array([1.0]), buf).sum())
    1.0
    """
    if out.dtype != np.float64 or out.ndim != 2 or not out.flags.c_contiguous:
        raise ParameterError("out must be a C-contiguous float64 (H, W) array")
    _check_kernel(kernel, sigma)
    xw, yw, w = _prep(xw, yw, weights)
    out.fill(0.0)
    if kernel == "bilinear":
        _fwd_bilinear(xw, yw, w, out)
    else:
        _fwd_gauss(xw, yw, w, float(sigma), out)
    return out


def accumulate(xw: np.ndarray, yw: np.ndarray, shape: tuple[int, int],
               weights: np.ndarray | None = None, kernel: str = "bilinear",
               sigma: float = 1.0) -> np.ndarray:
    """Image of warped events (3.3).

    Parameters
    ----------
    xw, yw : array (N,)
        Warped event positions in pixels (column, row).
    shape : (int, int)
        ``(H, W)`` of the image in pixels.
    weights : array (N,), optional
        Per-event weight (e.g. polarity +-1, or timestamps); default 1.
    kernel : {"bilinear", "gaussian"}
        Delta approximation; ``"gaussian"`` uses standard deviation ``sigma`` px.
    sigma : float
        Gaussian standard deviation in pixels (the thesis' epsilon, default 1 px).

    Returns
    -------
    iwe : array (H, W) float64
        Sum of weights; votes outside the image are dropped.

    Examples
    --------
    >>> iwe = accumulate(np.array([0.0, 0.0]), np.array([0.0, 0.0]), (2, 2))
    >>> iwe.tolist()
    [[2.0, 0.0], [0.0, 0.0]]
    """
    return accumulate_into(xw, yw, np.empty(sensor_shape(shape)), weights, kernel, sigma)


def accumulate_backward_into(xw: np.ndarray, yw: np.ndarray, grad_iwe: np.ndarray,
                             gx: np.ndarray, gy: np.ndarray,
                             weights: np.ndarray | None = None, kernel: str = "bilinear",
                             sigma: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Allocation-free :func:`accumulate_backward` writing into ``gx, gy`` (N,) float64."""
    _check_kernel(kernel, sigma)
    xw, yw, w = _prep(xw, yw, weights)
    g = np.ascontiguousarray(grad_iwe, dtype=np.float64)
    if g.ndim != 2:
        raise ParameterError(f"grad_iwe must be an (H, W) array, got shape {g.shape}")
    if gx.shape != xw.shape or gy.shape != xw.shape:
        raise ParameterError(f"gx, gy must have shape {xw.shape}")
    if kernel == "bilinear":
        _bwd_bilinear(xw, yw, w, g, gx, gy)
    else:
        _bwd_gauss(xw, yw, w, float(sigma), g, gx, gy)
    return gx, gy


def accumulate_backward(xw: np.ndarray, yw: np.ndarray, shape: tuple[int, int],
                        grad_iwe: np.ndarray, weights: np.ndarray | None = None,
                        kernel: str = "bilinear",
                        sigma: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Adjoint of :func:`accumulate` with respect to the event positions.

    Parameters
    ----------
    xw, yw : array (N,)
        Warped event positions (px), as given to :func:`accumulate`.
    shape : (int, int)
        ``(H, W)``; must match ``grad_iwe``.
    grad_iwe : array (H, W)
        ``dL/dIWE`` of a scalar loss ``L``.
    weights, kernel, sigma
        As in :func:`accumulate`.

    Returns
    -------
    gx, gy : array (N,) float64
        ``dL/dxw_k`` and ``dL/dyw_k`` (per pixel of displacement). Events whose votes
        all fall outside the image get zero.

    Examples
    --------
    >>> g = np.zeros((3, 3)); g[1, 2] = 1.0
    >>> accumulate_backward(np.array([1.25]), np.array([1.5]), (3, 3), g)
    (array([0.5]), array([-0.25]))
    """
    h, w = sensor_shape(shape)
    if np.shape(grad_iwe) != (h, w):
        raise ParameterError(f"grad_iwe has shape {np.shape(grad_iwe)}, expected {(h, w)}")
    n = np.shape(xw)[0] if np.ndim(xw) == 1 else 0
    return accumulate_backward_into(xw, yw, grad_iwe, np.empty(n), np.empty(n), weights,
                                    kernel, sigma)


@njit(cache=True, inline="always")
def _cell_grad(g, ix, iy, fx, fy, shift, h, wd):
    """Derivatives along x and y of the bilinear interpolation of ``g - shift`` in the cell
    with top-left pixel (ix, iy) at offsets (fx, fy); pixels outside the image count 0."""
    if ix >= 0 and iy >= 0 and ix + 1 < wd and iy + 1 < h:
        # interior cell (the usual case): the shift cancels in the differences
        d0 = g[iy, ix + 1] - g[iy, ix]
        d1 = g[iy + 1, ix + 1] - g[iy + 1, ix]
        e0 = g[iy + 1, ix] - g[iy, ix]
        e1 = g[iy + 1, ix + 1] - g[iy, ix + 1]
    else:
        g00 = g[iy, ix] - shift if (iy >= 0 and ix >= 0) else 0.0
        g01 = g[iy, ix + 1] - shift if (iy >= 0 and ix + 1 < wd) else 0.0
        g10 = g[iy + 1, ix] - shift if (iy + 1 < h and ix >= 0) else 0.0
        g11 = g[iy + 1, ix + 1] - shift if (iy + 1 < h and ix + 1 < wd) else 0.0
        d0 = g01 - g00
        d1 = g11 - g10
        e0 = g10 - g00
        e1 = g11 - g01
    return d0 * (1.0 - fy) + d1 * fy, e0 * (1.0 - fx) + e1 * fx


@njit(cache=True, nogil=True)
def _bwd_bilinear_reduce(xw, yw, w, g, shift, scale, jx, jy, out):
    h, wd = g.shape
    use_w = w.shape[0] > 0
    p = out.shape[0]
    # a fresh accumulator: out might alias jx for all the compiler knows
    acc = np.zeros(p)
    for k in range(xw.shape[0]):
        inside, ix, iy, fx, fy = _cell(xw[k], yw[k], h, wd)
        if not inside:
            continue
        a = (w[k] if use_w else 1.0) * scale
        dx, dy = _cell_grad(g, ix, iy, fx, fy, shift, h, wd)
        gx = a * dx
        gy = a * dy
        for j in range(p):
            acc[j] += gx * jx[k, j] + gy * jy[k, j]
    for j in range(p):
        out[j] = acc[j]


def accumulate_backward_reduce(xw: np.ndarray, yw: np.ndarray, grad_iwe: np.ndarray,
                               jx: np.ndarray, jy: np.ndarray, out: np.ndarray,
                               weights: np.ndarray | None = None, shift: float = 0.0,
                               scale: float = 1.0) -> np.ndarray:
    """Fused bilinear adjoint and chain rule: ``out[j] = sum_k dL/dxw_k jx[k, j] +
    dL/dyw_k jy[k, j]`` with ``dL/dIWE = scale * (grad_iwe - shift)``, in one pass and
    without per-event buffers (the hot path of gradient-based CMax).

    Parameters
    ----------
    xw, yw : array (N,) float64 contiguous
    grad_iwe : array (H, W) float64 contiguous
    jx, jy : array (N, P) float64 contiguous
        ``d xw / d theta`` and ``d yw / d theta``.
    out : array (P,) float64
    weights : array (N,), optional
    shift, scale : float
        Affine map of ``grad_iwe`` (the variance objective passes the IWE itself with
        ``shift = mean`` and ``scale = 2 / n_pixels``, so no gradient image is written).

    Returns
    -------
    out

    Examples
    --------
    >>> g = np.zeros((3, 3)); g[1, 2] = 1.0
    >>> j = np.ones((1, 1))
    >>> accumulate_backward_reduce(np.array([1.25]), np.array([1.5]), g, j, j, np.empty(1))
    array([0.25])
    """
    w = _NOWEIGHT if weights is None else weights
    _bwd_bilinear_reduce(xw, yw, w, grad_iwe, float(shift), float(scale), jx, jy, out)
    return out
