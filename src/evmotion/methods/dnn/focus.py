"""numpy twins of multicm's multi-reference focus (4.6) and its gradient, for what the
network's path optimizes after the network (:mod:`.planar`, :mod:`.tiles`): the same
B-spline images and Sobel focus as multicm's numba kernels (tested equal), with their
analytic adjoints, and neither a numba compilation nor torch's import (2.4 s) in a
one-window command.
"""

from __future__ import annotations

import numpy as np

from evmotion.events import EventArray

__all__ = ["REFERENCES", "binned_shape", "bspline_images", "identity_focus", "mean_gradmag",
           "multi_focus", "window_times"]

#: Multi-reference times (fractions of the window) and weights of the focus (4.6).
REFERENCES = ((0.0, 1.0), (0.5, 2.0), (1.0, 1.0))
#: Pixels of zero margin around the images: a point's taps off the image land in it
#: (its centre is clamped 2 px off the image) and are cropped, with no boolean masks.
_MARGIN = 3
_TAPS = np.arange(-1, 2)


def binned_shape(shape: tuple[int, int], k: int) -> tuple[int, int]:
    """The shape of an image of ``shape`` binned ``k`` x ``k`` (partial bins kept)."""
    return -(-shape[0] // k), -(-shape[1] // k)


def window_times(events: EventArray) -> np.ndarray:
    """Each event's time as the fraction of the window, ``(t - t_1) / (t_N - t_1)``."""
    t = np.asarray(events.t, np.int64)
    return (t - t[0]).astype(np.float64) / max(int(t[-1] - t[0]), 1)


def _bspline_weights(d: np.ndarray) -> np.ndarray:
    """The quadratic B-spline's three tap weights (3, ...) at offsets ``d`` from the
    nearest centre."""
    out = np.empty((3, *d.shape), d.dtype)
    out[0] = 0.5 * (0.5 - d) ** 2
    out[1] = 0.75 - d * d
    out[2] = 0.5 * (0.5 + d) ** 2
    return out


def _bspline_slopes(d: np.ndarray) -> np.ndarray:
    """The derivatives of :func:`_bspline_weights` in ``d``."""
    out = np.empty((3, *d.shape), d.dtype)
    out[0] = d - 0.5
    out[1] = -2.0 * d
    out[2] = d + 0.5
    return out


class _Splat:
    """The quadratic B-spline splat of K sets of points (K, N) on images with a margin:
    each point's 3 x 3 taps (flat indices into the K padded images) and weights, and the
    weights' derivatives for the adjoint."""

    def __init__(self, xw: np.ndarray, yw: np.ndarray, shape: tuple[int, int]):
        h, w = shape
        m = _MARGIN
        k = xw.shape[0]
        hp, wp = h + 2 * m, w + 2 * m
        self.padded = (k, hp, wp)
        cx, cy = np.floor(xw + 0.5), np.floor(yw + 0.5)
        self.dx, self.dy = xw - cx, yw - cy
        self.wx, self.wy = _bspline_weights(self.dx), _bspline_weights(self.dy)
        centre = ((np.clip(cy, -2, h + 1).astype(np.intp) + m) * wp
                  + np.clip(cx, -2, w + 1).astype(np.intp) + m
                  + (np.arange(k) * (hp * wp))[:, None])
        offsets = _TAPS[:, None] * wp + _TAPS[None]                       # (3, 3)
        self.idx = centre[None, None] + offsets[:, :, None, None]          # (3, 3, K, N)

    def images(self) -> np.ndarray:
        """The K images (K, H, W)."""
        m = _MARGIN
        img = np.bincount(self.idx.ravel(), (self.wy[:, None] * self.wx[None]).ravel(),
                          minlength=int(np.prod(self.padded))).reshape(self.padded)
        return img[:, m:-m, m:-m]

    def adjoint(self, grad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The gradient of a function of the images (``grad``, its gradient in the
        images, (K, H, W)) in the points' x and y, (K, N) each."""
        m = _MARGIN
        full = np.zeros(self.padded, self.dx.dtype)  # (float32 points: half the traffic)
        full[:, m:-m, m:-m] = grad
        g = full.ravel()[self.idx]                                         # (3, 3, K, N)
        gx = (np.einsum("ijkn,jkn->ikn", g, _bspline_slopes(self.dx)) * self.wy).sum(0)
        gy = (np.einsum("ijkn,jkn->ikn", g, self.wx) * _bspline_slopes(self.dy)).sum(0)
        return gx, gy


def bspline_images(xw: np.ndarray, yw: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Quadratic B-spline images (as multicm's ``iwe_forward``) of K sets of points
    ``xw``, ``yw`` (K, N), one bincount for all: 3 x 3 weights per point, taps off the
    image dropped. (K, H, W) float64.

    Examples
    --------
    >>> img = bspline_images(np.array([[1.0]]), np.array([[1.0]]), (3, 3))
    >>> img[0].round(3).tolist()
    [[0.016, 0.094, 0.016], [0.094, 0.562, 0.094], [0.016, 0.094, 0.016]]
    """
    return _Splat(np.asarray(xw), np.asarray(yw), tuple(shape)).images()


def _sobel(img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The Sobel derivatives of images (K, H, W) on their interior pixels (K, H-2, W-2),
    separably: a central difference along one axis, [1 2 1] along the other (in place:
    each temporary of a 346x260 window's three images is a page-faulting 2 MB)."""
    dx = img[:, :, 2:] - img[:, :, :-2]
    gx = dx[:, :-2] + dx[:, 2:]
    gx += dx[:, 1:-1]
    gx += dx[:, 1:-1]
    dy = img[:, 2:] - img[:, :-2]
    gy = dy[:, :, :-2] + dy[:, :, 2:]
    gy += dy[:, :, 1:-1]
    gy += dy[:, :, 1:-1]
    return gx, gy


def _sobel_adjoint(ax: np.ndarray, ay: np.ndarray) -> np.ndarray:
    """The transpose of :func:`_sobel`: the images' gradient (K, H, W) of a function whose
    gradients in the Sobel derivatives are ``ax``, ``ay`` (K, H-2, W-2): each derivative's
    [1 2 1] transposed, then its central difference's."""
    k, hi, wi = ax.shape
    out = np.zeros((k, hi + 2, wi + 2), ax.dtype)
    t = np.zeros((k, hi + 2, wi), ax.dtype)
    t[:, :-2] += ax
    t[:, 1:-1] += ax
    t[:, 1:-1] += ax
    t[:, 2:] += ax
    out[:, :, 2:] += t
    out[:, :, :-2] -= t
    t = np.zeros((k, hi, wi + 2), ax.dtype)
    t[:, :, :-2] += ay
    t[:, :, 1:-1] += ay
    t[:, :, 1:-1] += ay
    t[:, :, 2:] += ay
    out[:, 2:] += t
    out[:, :-2] -= t
    return out


def mean_gradmag(img: np.ndarray) -> np.ndarray:
    """Mean squared Sobel magnitude over the interior pixels (multicm's focus) of each
    image (K, H, W): (K,).

    Examples
    --------
    >>> img = np.zeros((1, 5, 5)); img[0, 2, 2] = 1.0
    >>> mean_gradmag(img).tolist()
    [2.6666666666666665]
    """
    if img.shape[-2] < 3 or img.shape[-1] < 3:
        return np.zeros(img.shape[0])
    gx, gy = _sobel(img)
    return (gx * gx + gy * gy).mean((1, 2))


def identity_focus(x: np.ndarray, y: np.ndarray, shape: tuple[int, int]) -> float:
    """The focus of the unwarped events, which (4.6) is normalized by."""
    return float(mean_gradmag(bspline_images(x[None], y[None], shape))[0])


def multi_focus(x: np.ndarray, y: np.ndarray, s: np.ndarray, flow: np.ndarray,
                shape: tuple[int, int], g0: float, grad: bool = False):
    """Multi-reference focus (4.6) of the per-event flows ``flow`` (N, 2) px per window,
    normalized by the identity warp's ``g0``; with ``grad``, ``(focus, d focus / d flow)``
    (the gradient (N, 2)).

    Examples
    --------
    >>> x, y = np.array([3.0, 4, 5, 6]), np.full(4, 2.0)
    >>> s = np.array([0.0, 1 / 3, 2 / 3, 1.0])
    >>> g0 = identity_focus(x, y, (5, 10))
    >>> right = np.tile([3.0, 0.0], (4, 1))                  # 3 px per window
    >>> multi_focus(x, y, s, right, (5, 10), g0) > multi_focus(x, y, s, 0 * right, (5, 10), g0)
    True
    """
    refs = np.array([r for r, _ in REFERENCES], s.dtype)
    wts = np.array([wt for _, wt in REFERENCES])
    dtn = refs[:, None] - s[None]                                        # (K, N)
    splat = _Splat(x[None] + dtn * flow[:, 0], y[None] + dtn * flow[:, 1], tuple(shape))
    # (the images in the points' precision: float32 points halve the Sobel's traffic)
    imgs = splat.images().astype(dtn.dtype, copy=False)
    norm = wts.sum() * g0
    if imgs.shape[-2] < 3 or imgs.shape[-1] < 3:
        return (0.0, np.zeros_like(flow)) if grad else 0.0
    gx, gy = _sobel(imgs)
    sq = (np.einsum("kij,kij->k", gx, gx, dtype=np.float64)
          + np.einsum("kij,kij->k", gy, gy, dtype=np.float64)) / (gx.shape[1] * gx.shape[2])
    value = float((wts * sq).sum() / norm)
    if not grad:
        return value
    scale = ((2.0 / (gx.shape[1] * gx.shape[2]) / norm) * wts).astype(gx.dtype)[:, None, None]
    gx *= scale
    gy *= scale
    px, py = splat.adjoint(_sobel_adjoint(gx, gy))
    return value, np.stack((np.einsum("kn,kn->n", dtn, px), np.einsum("kn,kn->n", dtn, py)), 1)
