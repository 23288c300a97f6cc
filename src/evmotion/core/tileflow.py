"""Tile parameterization of a dense flow field and the fused IWE kernels of ch. 4.

A flow field is described by one vector per tile of a regular ``ny x nx`` grid. The vector
sits at the tile centre; the flow anywhere else is the bilinear interpolation between the
four nearest centres (linear extrapolation in the outer half tiles, beyond the outermost
centres). The flow is
evaluated at each event's *sub-pixel* position, not at its integer pixel.

Geometry: the centre of tile ``i`` along an axis of ``L`` pixels split into ``n`` tiles
is at pixel coordinate ``(i + 0.5) * L / n - 0.5`` (pixel centres are integers, origin
top-left, x = column, y = row).

The numba kernels warp events with ``x' = x + dtn * u`` (``dtn`` is the event time minus
the reference time, in whatever unit ``u`` is expressed per; multicm uses the fraction of
the window), accumulate the image of warped events (IWE) by quadratic B-spline voting and
back-propagate a gradient on the IWE to per-event flow gradients.
"""

from __future__ import annotations

import numpy as np
from numba import njit

# the grid's numpy half lives apart, so that what needs only it (the network's refinement)
# does not import numba
from evmotion.core.tilegrid import (
    TileGrid,
    axis_matrix,
    dense_flow,
    event_tile_means,
    event_weights,
    pixel_tiles,
    resample,
    scale_grid,
    tile_means,
)

__all__ = [
    "TileGrid",
    "axis_matrix",
    "dense_flow",
    "event_tile_means",
    "event_weights",
    "interpolate",
    "interpolate_adjoint",
    "iwe_backward",
    "iwe_forward",
    "pixel_tiles",
    "resample",
    "scale_grid",
    "tile_means",
]


@njit(cache=True)
def _interp(params, idx, w, out):
    n = idx.shape[0]
    for k in range(n):
        u = 0.0
        v = 0.0
        for c in range(4):
            j = idx[k, c]
            u += w[k, c] * params[j, 0]
            v += w[k, c] * params[j, 1]
        out[k, 0] = u
        out[k, 1] = v


@njit(cache=True)
def _interp_adj(g, idx, w, out):
    n = idx.shape[0]
    for k in range(n):
        for c in range(4):
            j = idx[k, c]
            out[j, 0] += w[k, c] * g[k, 0]
            out[j, 1] += w[k, c] * g[k, 1]


def interpolate(params: np.ndarray, idx: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Per-event flow ``(N, 2)`` from tile parameters ``(ny, nx, 2)`` and a stencil.

    Examples
    --------
    >>> g = TileGrid(1, 2, (2, 4))
    >>> idx, w = event_weights(np.array([1.5]), np.array([0.0]), g)
    >>> interpolate(np.array([[[0.0, 0.0], [2.0, 4.0]]]), idx, w).tolist()
    [[1.0, 2.0]]
    """
    p = np.ascontiguousarray(params, dtype=np.float64).reshape(-1, 2)
    out = np.empty((idx.shape[0], 2))
    _interp(p, idx, w, out)
    return out


def interpolate_adjoint(g: np.ndarray, idx: np.ndarray, w: np.ndarray,
                        grid: TileGrid) -> np.ndarray:
    """Adjoint of :func:`interpolate`: per-event gradients ``(N, 2)`` to ``(ny, nx, 2)``."""
    out = np.zeros((grid.ny * grid.nx, 2))
    _interp_adj(np.ascontiguousarray(g, dtype=np.float64), idx, w, out)
    return out.reshape(grid.ny, grid.nx, 2)


# ------------------------------------------------------------------------- IWE kernels
# Quadratic B-spline weights of pixels c-1, c, c+1 for an offset d = pos - c in
# [-0.5, 0.5]: 0.5 (0.5 - d)^2, 0.75 - d^2, 0.5 (0.5 + d)^2. C1 in the position, so the
# focus has no kinks at integer shifts (bilinear voting has one exactly at the zero-flow
# start). Written out with scalars and an interior fast path: this is the hot loop.
@njit(cache=True, fastmath=True, inline="always")
def _bspline_cell(xw, yw):
    """Centre pixel (cx, cy), offsets (dx, dy) and the three B-spline weights per axis."""
    cx = int(np.floor(xw + 0.5))
    cy = int(np.floor(yw + 0.5))
    dx = xw - cx
    dy = yw - cy
    ax = 0.5 - dx
    bx = 0.5 + dx
    ay = 0.5 - dy
    by = 0.5 + dy
    return (cx, cy, dx, dy, 0.5 * ax * ax, 0.75 - dx * dx, 0.5 * bx * bx,
            0.5 * ay * ay, 0.75 - dy * dy, 0.5 * by * by)


@njit(cache=True, fastmath=True)
def _iwe_fwd(x, y, flow, dtn, iwe):
    h, w = iwe.shape
    for k in range(x.shape[0]):
        xw = x[k] + dtn[k] * flow[k, 0]
        yw = y[k] + dtn[k] * flow[k, 1]
        if not (xw > -1.5 and xw < w + 0.5 and yw > -1.5 and yw < h + 0.5):
            continue
        cx, cy, dx, dy, wx0, wx1, wx2, wy0, wy1, wy2 = _bspline_cell(xw, yw)
        if cx >= 1 and cx < w - 1 and cy >= 1 and cy < h - 1:
            iwe[cy - 1, cx - 1] += wy0 * wx0
            iwe[cy - 1, cx] += wy0 * wx1
            iwe[cy - 1, cx + 1] += wy0 * wx2
            iwe[cy, cx - 1] += wy1 * wx0
            iwe[cy, cx] += wy1 * wx1
            iwe[cy, cx + 1] += wy1 * wx2
            iwe[cy + 1, cx - 1] += wy2 * wx0
            iwe[cy + 1, cx] += wy2 * wx1
            iwe[cy + 1, cx + 1] += wy2 * wx2
            continue
        for a in range(3):
            yy = cy - 1 + a
            if yy < 0 or yy >= h:
                continue
            wy = wy0 if a == 0 else (wy1 if a == 1 else wy2)
            for b in range(3):
                xx = cx - 1 + b
                if xx >= 0 and xx < w:
                    iwe[yy, xx] += wy * (wx0 if b == 0 else (wx1 if b == 1 else wx2))


@njit(cache=True, fastmath=True)
def iwe_bwd(x, y, flow, dtn, giwe, gflow):
    """Adjoint of the quadratic B-spline IWE of events ``x, y`` (N,) px moved by
    ``dtn * flow`` (per-event flow (N, 2) px per unit of ``dtn``): adds ``dL/dflow`` to
    ``gflow`` (N, 2) given ``dL/dIWE = giwe`` (H, W); events off the image add nothing."""
    h, w = giwe.shape
    for k in range(x.shape[0]):
        xw = x[k] + dtn[k] * flow[k, 0]
        yw = y[k] + dtn[k] * flow[k, 1]
        if not (xw > -1.5 and xw < w + 0.5 and yw > -1.5 and yw < h + 0.5):
            continue
        cx, cy, dx, dy, wx0, wx1, wx2, wy0, wy1, wy2 = _bspline_cell(xw, yw)
        # derivatives of the weights: -a, -2d, b
        ax = 0.5 - dx
        bx = 0.5 + dx
        ay = 0.5 - dy
        by = 0.5 + dy
        if cx >= 1 and cx < w - 1 and cy >= 1 and cy < h - 1:
            g00 = giwe[cy - 1, cx - 1]
            g01 = giwe[cy - 1, cx]
            g02 = giwe[cy - 1, cx + 1]
            g10 = giwe[cy, cx - 1]
            g11 = giwe[cy, cx]
            g12 = giwe[cy, cx + 1]
            g20 = giwe[cy + 1, cx - 1]
            g21 = giwe[cy + 1, cx]
            g22 = giwe[cy + 1, cx + 1]
        else:
            g00 = _at(giwe, cy - 1, cx - 1)
            g01 = _at(giwe, cy - 1, cx)
            g02 = _at(giwe, cy - 1, cx + 1)
            g10 = _at(giwe, cy, cx - 1)
            g11 = _at(giwe, cy, cx)
            g12 = _at(giwe, cy, cx + 1)
            g20 = _at(giwe, cy + 1, cx - 1)
            g21 = _at(giwe, cy + 1, cx)
            g22 = _at(giwe, cy + 1, cx + 1)
        r0x = -ax * g00 - 2.0 * dx * g01 + bx * g02
        r1x = -ax * g10 - 2.0 * dx * g11 + bx * g12
        r2x = -ax * g20 - 2.0 * dx * g21 + bx * g22
        gx = wy0 * r0x + wy1 * r1x + wy2 * r2x
        r0 = wx0 * g00 + wx1 * g01 + wx2 * g02
        r1 = wx0 * g10 + wx1 * g11 + wx2 * g12
        r2 = wx0 * g20 + wx1 * g21 + wx2 * g22
        gy = -ay * r0 - 2.0 * dy * r1 + by * r2
        gflow[k, 0] += dtn[k] * gx
        gflow[k, 1] += dtn[k] * gy


@njit(cache=True)
def _at(img, i, j):
    h, w = img.shape
    if i < 0 or i >= h or j < 0 or j >= w:
        return 0.0
    return img[i, j]


def iwe_forward(x: np.ndarray, y: np.ndarray, flow: np.ndarray, dtn: np.ndarray,
                shape: tuple[int, int]) -> np.ndarray:
    """Image of warped events ``I(x')`` with ``x' = x + dtn * flow``.

    Each event votes with quadratic B-spline weights (3 x 3 pixels, sum 1, standard
    deviation 0.5 px): a compact, C1-smooth stand-in for the thesis' Gaussian (epsilon =
    1 px; the Sobel gradient of the focus objective smooths further) that is ~10x cheaper
    than the Gaussian kernel of :mod:`evmotion.core.iwe`. Bilinear voting is not enough
    here: its kink at integer shifts makes the zero-flow start a spurious local optimum.

    Parameters
    ----------
    x, y : ndarray (N,) float64
        Event positions (px).
    flow : ndarray (N, 2) float64
        Per-event flow (px per unit of ``dtn``).
    dtn : ndarray (N,) float64
        Event time minus reference time, in the unit the flow is expressed per.
    shape : (H, W)

    Returns
    -------
    ndarray (H, W) float64; events warped outside the image are dropped.

    Examples
    --------
    >>> iwe = iwe_forward(np.array([1.0]), np.array([1.0]), np.array([[1.0, 0.0]]),
    ...                   np.array([0.5]), (3, 3))
    >>> iwe[1].round(3).tolist()
    [0.0, 0.375, 0.375]
    """
    iwe = np.zeros(shape)
    _iwe_fwd(x, y, flow, dtn, iwe)
    return iwe


def iwe_backward(x: np.ndarray, y: np.ndarray, flow: np.ndarray, dtn: np.ndarray,
                 grad_iwe: np.ndarray) -> np.ndarray:
    """Per-event flow gradient ``(N, 2)`` of ``sum(grad_iwe * I)`` (adjoint of
    :func:`iwe_forward` with respect to ``flow``)."""
    g = np.zeros((x.shape[0], 2))
    iwe_bwd(x, y, flow, dtn, np.ascontiguousarray(grad_iwe, dtype=np.float64), g)
    return g
