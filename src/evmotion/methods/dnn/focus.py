"""Torch twins of multicm's multi-reference focus (4.6), for what the network's path
optimizes after the network (:mod:`.planar`, :mod:`.tiles`): the same B-spline images
and Sobel focus as multicm's numba kernels (tested equal), differentiable (the images by
their analytic adjoint), and no numba compilation in a one-window command.
"""

from __future__ import annotations

import numpy as np
import torch

from evmotion.events import EventArray

__all__ = ["REFERENCES", "binned_shape", "bspline_images", "value_grad", "identity_focus", "mean_gradmag", "multi_focus",
           "window_times"]

#: Multi-reference times (fractions of the window) and weights of the focus (4.6).
REFERENCES = ((0.0, 1.0), (0.5, 2.0), (1.0, 1.0))


def binned_shape(shape: tuple[int, int], k: int) -> tuple[int, int]:
    """The shape of an image of ``shape`` binned ``k`` x ``k`` (partial bins kept)."""
    return -(-shape[0] // k), -(-shape[1] // k)


def window_times(events: EventArray) -> np.ndarray:
    """Each event's time as the fraction of the window, ``(t - t_1) / (t_N - t_1)``."""
    t = np.asarray(events.t, np.int64)
    return (t - t[0]).astype(np.float64) / max(int(t[-1] - t[0]), 1)


class _Splat(torch.autograd.Function):
    """The B-spline images of K sets of points on images with a 3 px margin, and their
    analytic adjoint: each point's gradient is the image gradient gathered at its 3 x 3
    taps times the weights' derivatives (autograd through the weights' arithmetic took
    half of a polish evaluation)."""

    @staticmethod
    def forward(ctx, xw, yw, shape):
        h, w = shape
        k = xw.shape[0]
        cx = torch.floor(xw + 0.5)
        cy = torch.floor(yw + 0.5)
        dx, dy = xw - cx, yw - cy
        wx = torch.stack((0.5 * (0.5 - dx) ** 2, 0.75 - dx * dx, 0.5 * (0.5 + dx) ** 2))
        wy = torch.stack((0.5 * (0.5 - dy) ** 2, 0.75 - dy * dy, 0.5 * (0.5 + dy) ** 2))
        # centres clamped to 2 px off the image: every tap off the image lands in the
        # margin, cropped by the caller (no boolean masks: they cost 2/3 of the time)
        hp, wp = h + 6, w + 6
        cyi = cy.clamp(-2, h + 1).long() + 3
        cxi = cx.clamp(-2, w + 1).long() + 3
        taps = torch.arange(-1, 2)
        rows = (cyi[None] + taps[:, None, None]) * wp + (torch.arange(k) * (hp * wp))[:, None]
        idx = rows[:, None] + (cxi[None] + taps[:, None, None])[None]   # (3, 3, K, N)
        img = xw.new_zeros(k * hp * wp).index_add(0, idx.reshape(-1),
                                                   (wy[:, None] * wx[None]).reshape(-1))
        dwx = torch.stack((dx - 0.5, -2.0 * dx, dx + 0.5))
        dwy = torch.stack((dy - 0.5, -2.0 * dy, dy + 0.5))
        ctx.save_for_backward(idx, wx, wy, dwx, dwy)
        return img.reshape(k, hp, wp)

    @staticmethod
    def backward(ctx, grad):
        idx, wx, wy, dwx, dwy = ctx.saved_tensors
        g = grad.reshape(-1)[idx]                                        # (3, 3, K, N)
        gx = (g * (wy[:, None] * dwx[None])).sum((0, 1))
        gy = (g * (dwy[:, None] * wx[None])).sum((0, 1))
        return gx, gy, None


def bspline_images(xw, yw, shape):
    """Quadratic B-spline images (as multicm's ``iwe_forward``) of K sets of points
    ``xw``, ``yw`` (K, N), one index_add for all: 3 x 3 weights per point, taps off the
    image dropped; differentiable in the points. (K, H, W)."""
    return _Splat.apply(xw, yw, tuple(shape))[:, 3:-3, 3:-3]


def mean_gradmag(img):
    """Mean squared Sobel magnitude over the interior pixels (multicm's focus) of each
    image (K, H, W): (K,). The Sobel kernels separably: a central difference along one
    axis, [1 2 1] along the other (half the tensor operations of the 3 x 3 sums)."""
    if img.shape[-2] < 3 or img.shape[-1] < 3:
        return img.new_zeros(img.shape[0])
    dx = img[:, :, 2:] - img[:, :, :-2]
    gx = dx[:, :-2] + 2.0 * dx[:, 1:-1] + dx[:, 2:]
    dy = img[:, 2:] - img[:, :-2]
    gy = dy[:, :, :-2] + 2.0 * dy[:, :, 1:-1] + dy[:, :, 2:]
    return (gx * gx + gy * gy).mean((1, 2))


def identity_focus(x, y, shape) -> float:
    """The focus of the unwarped events, which (4.6) is normalized by."""
    return float(mean_gradmag(bspline_images(x[None], y[None], shape))[0])


def multi_focus(x, y, s, flow, shape, g0: float):
    """Multi-reference focus (4.6) of the per-event flows (N, 2) px per window,
    normalized by the identity warp's ``g0``."""
    refs = x.new_tensor([r for r, _ in REFERENCES])
    wts = x.new_tensor([wt for _, wt in REFERENCES])
    dtn = refs[:, None] - s[None]                # (K, N)
    imgs = bspline_images(x[None] + dtn * flow[:, 0], y[None] + dtn * flow[:, 1], shape)
    return (wts * mean_gradmag(imgs)).sum() / (wts.sum() * g0)


def value_grad(loss_of, dtype=torch.float32):
    """``theta -> (loss, d loss / d theta)`` (a float and a float64 array) of
    ``loss_of(theta_tensor)``, by autograd in ``dtype``: what the polishes' BFGS calls.

    Examples
    --------
    >>> f = value_grad(lambda p: (p * p).sum(), torch.float64)
    >>> v, g = f(np.array([1.0, -2.0]))
    >>> v, g.tolist()
    (5.0, [2.0, -4.0])
    """
    def fun_grad(theta):
        p = torch.tensor(np.asarray(theta), dtype=dtype, requires_grad=True)
        with torch.enable_grad():
            loss = loss_of(p)
            loss.backward()
        return float(loss.detach()), p.grad.numpy().astype(np.float64)

    return fun_grad
