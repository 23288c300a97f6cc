"""Fused adjoints: parameter gradients chained through a warp without storing its Jacobian.

``dL/dtheta = sum_k gx_k dxw_k/dtheta + gy_k dyw_k/dtheta`` with the Jacobian recomputed per
event, never stored. With a padded image (the bilinear IWE adjoint of the objective) the
pixel gradients are gathered in the same loop, which is kept free of branches so that it
vectorizes (AVX-512 gathers): an event with no vote in the image (or NaN) is replaced by a
clamped one of weight 0, so that its contribution is exactly 0 (the composed adjoint skips
it). Each family's kernel runs one loop per case (series mode, weights or not): the case
reaches the inlined loop as a constant and its branches fold away. The helpers called inside
the loops take scalars only: an array argument costs reference counting per call, which
stops the vectorization.

This module holds the pixel-side helpers the families' loops share and the
:class:`FusedAdjoint` mixin (``vjp``, ``reduce_bilinear``, ``reduce_pair``) a warp gets by
defining ``_adj``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from evmotion.core.warps.common import EMPTY1
from evmotion.errors import ParameterError

__all__ = ["DIV_BLOCK", "VALUE_KINDS", "FusedAdjoint", "bilinear_sample", "cell_diff",
           "pad_diff", "pad_image", "pad_index"]

#: Events per block of the rotation's block loop (the blocks of ``reduce_pair``'s
#: ``blocks``, :mod:`evmotion.core.trim`).
DIV_BLOCK = 32

@njit(cache=True, error_model="numpy")
def pad_image(g, shift, pad):
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
def pad_index(xv, yv, t, wk, scale, h, wd):
    """``(xc, yc, t, a, fx, fy, i)`` of an event at ``(xv, yv)`` px: its pixel, dt and
    weight ``a = wk scale``, or a clamped pixel with ``t = a = 0`` where it has no vote in
    the (h, wd) image (or is NaN); then its bilinear offsets and the flat index in the image
    padded by :func:`pad_image` of its cell's top-left pixel."""
    inside = (xv > -1.0) & (xv < wd) & (yv > -1.0) & (yv < h)
    xc = xv if inside else -1.0
    yc = yv if inside else -1.0
    x0 = math.floor(xc)
    y0 = math.floor(yc)
    i = (int(y0) + 1) * (wd + 2) + int(x0) + 1
    return (xc, yc, t if inside else 0.0, wk * scale if inside else 0.0, xc - x0, yc - y0, i)


@njit(cache=True, error_model="numpy")
def cell_diff(a, fx, fy, g00, g01, g10, g11):
    """``a`` times the x and y derivatives of the bilinear interpolation in a cell: the
    values of :func:`evmotion.core.iwe._cell_grad`, whose pixels outside the image count 0
    and here ``shift`` (the padding), so interior cells agree bit for bit."""
    return (a * ((g01 - g00) * (1.0 - fy) + (g11 - g10) * fy),
            a * ((g10 - g00) * (1.0 - fx) + (g11 - g01) * fx))


@njit(cache=True, error_model="numpy", inline="always")
def bilinear_sample(fx, fy, s00, s01, s10, s11):
    """The bilinear interpolation of a cell's corner values at offsets (fx, fy): the
    derivative of ``sum(g * IWE)`` with respect to the event's IWE weight."""
    return (s00 * (1.0 - fx) * (1.0 - fy) + s01 * fx * (1.0 - fy)
            + s10 * (1.0 - fx) * fy + s11 * fx * fy)


@njit(cache=True, error_model="numpy", inline="always")
def pad_diff(pair, a, fx, fy, e, pad, i, wp, p2):
    """``(gx, gy, gd)``: :func:`cell_diff` of the cell at flat index ``i`` of the padded
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
        gd = a * bilinear_sample(fx, fy, b00, b01, b10, b11)
    gX, gY = cell_diff(a, fx, fy, g00, g01, g10, g11)
    return gX, gY, gd


#: :meth:`FusedAdjoint.reduce_pair`'s ``derivs`` -> the kernels' value kind ``vk``.
VALUE_KINDS = {None: 0, "divergence": 1, "deformation": 2}


class FusedAdjoint:
    """Warps whose adjoint kernel recomputes the parameter Jacobian per event, so the chain
    rule needs no (N, P) Jacobian buffers (the hot path of gradient-based CMax). Each such
    warp defines ``_adj(x, y, dt, xw, yw, th, gx, gy, wts, pad, h, wd, scale, out, vk=0,
    T=1.0, blk=NO_BLOCKS)`` (``vk``, ``T``: :meth:`reduce_pair`'s ``derivs``, ``T``;
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
        >>> from evmotion.core.warps import make_warp
        >>> w = make_warp("translation", sensor_size=(10, 10))
        >>> x = np.array([5.0]); dt = np.array([0.5]); th = np.array([2.0, 0.0])
        >>> xw, yw = w.warp(x, x, dt, th)
        >>> w.vjp(x, x, dt, xw, yw, th, np.array([1.0]), np.array([0.0]), np.empty(2))
        array([-0.5,  0. ])
        """
        self._adj(x, y, dt, xw, yw, self.check_theta(theta), gx, gy, EMPTY1, EMPTY1, 0, 0, 1.0,
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
        >>> from evmotion.core.warps import make_warp
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
        pad_image(g, float(shift), pad)
        w = EMPTY1 if weights is None else weights
        self._adj(x, y, dt, xw, yw, self.check_theta(theta), EMPTY1, EMPTY1, w, pad, h, wd,
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
        :mod:`evmotion.core.collapse`); the warps whose values depend on dt only
        (closed forms) then recompute them instead of reading ``values``. ``blocks``
        (uint8, one per block of :data:`evmotion.core.trim.BLOCK` events, optional): 0 for
        the blocks none of whose events reaches a nonzero pixel of ``B``, which then skip
        it (the flags of :func:`evmotion.core.trim.flag_blocks`); the result is the same.

        Examples
        --------
        >>> from evmotion.core.warps import make_warp
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
        if derivs not in VALUE_KINDS:
            raise ParameterError(f"derivs must be one of {sorted(VALUE_KINDS, key=str)}, "
                                 f"got {derivs!r}")
        th = self.check_theta(theta)
        vk = VALUE_KINDS[derivs]
        if blocks is None or not self._blocked:
            self._adj(x, y, dt, xw, yw, th, EMPTY1, EMPTY1, values, pads, h, wd,
                      float(scale), out, vk, float(T))
            return out
        nb = -(-xw.shape[0] // DIV_BLOCK)
        if not (isinstance(blocks, np.ndarray) and blocks.dtype == np.uint8
                and blocks.shape == (nb,)):
            raise ParameterError(f"blocks must hold one uint8 flag per {DIV_BLOCK} events "
                                 f"({nb}), got {getattr(blocks, 'dtype', type(blocks))} "
                                 f"{np.shape(blocks)}")
        # the flagged blocks with both images, the others with the first only
        pair, single = np.flatnonzero(blocks), np.flatnonzero(blocks == 0)
        out[:] = 0.0
        part = np.empty_like(out)
        if pair.shape[0]:
            self._adj(x, y, dt, xw, yw, th, EMPTY1, EMPTY1, values, pads, h, wd,
                      float(scale), part, vk, float(T), pair)
            out += part
        if single.shape[0]:
            self._adj(x, y, dt, xw, yw, th, EMPTY1, EMPTY1, EMPTY1,
                      pads[:pads.shape[0] // 2], h, wd, float(scale), part, 0, float(T), single)
            out += part
        return out
