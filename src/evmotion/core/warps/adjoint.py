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

The kernels take their arguments grouped: the events ``ev = (x, y, dt, xw, yw)``, the
warp's parameter array ``prm`` and the pixel side ``src`` (:class:`AdjointInput`, as a plain
tuple). This module holds the pixel-side helpers the families' loops share and the
:class:`FusedAdjoint` mixin (``vjp``, ``reduce_bilinear``, ``reduce_pair``) a warp gets by
defining ``_adj``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from evmotion.core.warps.common import EMPTY1, NO_BLOCKS
from evmotion.errors import ParameterError

__all__ = ["DIV_BLOCK", "VALUE_KINDS", "AdjointInput", "FusedAdjoint", "bilinear_sample",
           "cell_diff", "event_cell", "pad_diff", "pad_image", "pad_index", "src_diff",
           "store_sums", "warped_cell"]

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


@njit(cache=True, error_model="numpy", inline="always")
def event_cell(xv, yv, t, k, use_w, pair, src):
    """:func:`pad_index` of event ``k`` at ``(xv, yv)`` px for the pixel side ``src``
    (:meth:`AdjointInput.kernel_args`): its weight is ``wts[k]`` where ``use_w`` (one
    image with weights), else 1, times ``scale``."""
    _, _, wts, _, h, wd, scale, _ = src
    return pad_index(xv, yv, t, wts[k] if use_w and not pair else 1.0, scale, h, wd)


@njit(cache=True, error_model="numpy", inline="always")
def warped_cell(fuse, use_w, pair, k, ev, src):
    """``(xv, yv, t, a, fx, fy, i)`` of event ``k`` of ``ev = (x, y, dt, xw, yw)``: its
    :func:`event_cell` where ``fuse`` (a padded image), else its warped pixel and dt (the
    rest 0: the pixel gradients come from ``gx, gy``)."""
    _, _, dt, xw, yw = ev
    if fuse:
        return event_cell(xw[k], yw[k], dt[k], k, use_w, pair, src)
    return xw[k], yw[k], dt[k], 0.0, 0.0, 0.0, 0


@njit(cache=True, error_model="numpy", inline="always")
def src_diff(pair, a, fx, fy, e, i, src):
    """:func:`pad_diff` in the padded image(s) of the pixel side ``src``."""
    _, _, _, pad, h, wd, _, _ = src
    wp = wd + 2
    return pad_diff(pair, a, fx, fy, e, pad, i, wp, (h + 2) * wp)


@njit(cache=True, error_model="numpy", inline="always")
def store_sums(acc, out):
    """``out[j] = acc[j]``: a loop's sums (a tuple) into the (P,) result."""
    for j in range(out.shape[0]):
        out[j] = acc[j]


#: :meth:`FusedAdjoint.reduce_pair`'s ``derivs`` -> the kernels' value kind ``vk``.
VALUE_KINDS = {None: 0, "divergence": 1, "deformation": 2}


class AdjointInput(NamedTuple):
    """The pixel side of a fused adjoint pass (``FusedAdjoint._adj``'s ``src``).

    Attributes
    ----------
    gx, gy : array (N,)
        Per-event pixel gradients (:meth:`FusedAdjoint.vjp`); empty where ``pad`` is given.
    wts : array (N,)
        With one padded image, optional per-event weights (empty: none); with two (pair
        mode), the per-event values.
    pad : array
        Empty (``vjp``), one (h + 2) (wd + 2) padded image (:func:`pad_image`) or two
        (pair mode, :meth:`FusedAdjoint.reduce_pair`), flat float64.
    h, wd : int
        The image's size, px.
    scale : float
        Factor of the pixel gradients.
    T : float
        The window's span (s): the divergence values are the divergence times ``T``.
    vk : int
        The values' kind in pair mode (:data:`VALUE_KINDS`).
    blk : array of int64
        The blocks of :data:`DIV_BLOCK` events to visit (empty: every), where the warp is
        ``_blocked``.
    """

    gx: np.ndarray = EMPTY1
    gy: np.ndarray = EMPTY1
    wts: np.ndarray = EMPTY1
    pad: np.ndarray = EMPTY1
    h: int = 0
    wd: int = 0
    scale: float = 1.0
    T: float = 1.0
    vk: int = 0
    blk: np.ndarray = NO_BLOCKS

    def kernel_args(self) -> tuple:
        """The plain tuple the kernels take: ``(gx, gy, wts, pad, h, wd, scale, T)`` (a
        slice: the callers build ``h, wd`` as ints and ``scale, T`` as floats, so that
        every call has the kernels' one signature)."""
        return self[:8]

    def case(self, derivs: bool = True) -> tuple[bool, bool, bool, int]:
        """``(fuse, use_w, pair, vk)``: whether the pixel gradients come from a padded image,
        weights are given (one image), two images are (pair mode) and the values' kind
        (pair mode; 0 unless ``derivs``: the warp's values do not depend on theta)."""
        if self.pad.shape[0] == 0:
            return False, False, False, 0
        if self.pad.shape[0] == 2 * (self.h + 2) * (self.wd + 2):
            return True, True, True, self.vk if derivs and self.vk in (1, 2) else 0
        return True, self.wts.shape[0] > 0, False, 0


class FusedAdjoint:
    """Warps whose adjoint kernel recomputes the parameter Jacobian per event, so the chain
    rule needs no (N, P) Jacobian buffers (the hot path of gradient-based CMax). Each such
    warp defines ``_adj(x, y, dt, xw, yw, th, src, out)``: ``out`` (P,) from the events, the
    checked parameters and the pixel side ``src`` (:class:`AdjointInput`)."""

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
        self._adj(x, y, dt, xw, yw, self.check_theta(theta), AdjointInput(gx, gy), out)
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
        src = AdjointInput(wts=EMPTY1 if weights is None else weights, pad=pad, h=h, wd=wd,
                           scale=float(scale))
        self._adj(x, y, dt, xw, yw, self.check_theta(theta), src, out)
        return out

    def reduce_pair(self, x, y, dt, xw, yw, theta, pads, values, out,
                    scale: float = 1.0, derivs: str | None = None,
                    T: float = 1.0, blocks: np.ndarray | None = None) -> np.ndarray:
        """:meth:`reduce_bilinear` for a loss on two bilinear IWEs of ``xw, yw``, of ones
        and of per-event ``values``: ``out`` (P,) = dL/dtheta given ``dL/dIWE_ones = A``
        and ``dL/dIWE_values = B``, one pass over the events with the Jacobians recomputed,
        not stored. ``pads`` (2, H + 2, W + 2) float64 C-contiguous holds ``A`` then ``B``,
        each an (H, W) image padded by a ring of zeros; ``values`` (N,) float64
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
        >>> w.reduce_pair(x, y, dt, x, y, np.zeros(2), pads, np.array([0.5]), np.empty(2))
        array([-2. ,  0.5])
        """
        if not (isinstance(pads, np.ndarray) and pads.dtype == np.float64 and pads.ndim == 3
                and pads.shape[0] == 2 and min(pads.shape[1:]) > 2
                and pads.flags.c_contiguous):
            raise ParameterError(f"pads must be two padded images, a C-contiguous float64 "
                                 f"(2, H + 2, W + 2) array, got "
                                 f"{getattr(pads, 'dtype', type(pads))} {np.shape(pads)}")
        if derivs not in VALUE_KINDS:
            raise ParameterError(f"derivs must be one of {sorted(VALUE_KINDS, key=str)}, "
                                 f"got {derivs!r}")
        th = self.check_theta(theta)
        flat = pads.reshape(-1)
        src = AdjointInput(wts=values, pad=flat, h=pads.shape[1] - 2, wd=pads.shape[2] - 2,
                           scale=float(scale), T=float(T), vk=VALUE_KINDS[derivs])
        if blocks is None or not self._blocked:
            self._adj(x, y, dt, xw, yw, th, src, out)
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
            self._adj(x, y, dt, xw, yw, th, src._replace(blk=pair), part)
            out += part
        if single.shape[0]:
            one = src._replace(wts=EMPTY1, pad=flat[:flat.shape[0] // 2], vk=0, blk=single)
            self._adj(x, y, dt, xw, yw, th, one, part)
            out += part
        return out
