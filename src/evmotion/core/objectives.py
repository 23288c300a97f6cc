"""Focus objectives of contrast maximization and their analytic gradients.

Every objective is a *focus score* ``G``: higher means sharper (better motion compensation),
so the contrast-maximization cost of (3.6) is always ``J = -G + lambda R``.

* ``"variance"`` -- IWE variance (3.4), ``mean((I - mean I)^2)`` over all pixels.
* ``"gradient_magnitude"`` -- mean squared Sobel gradient magnitude over the interior
  pixels, ``mean(Sx(I)^2 + Sy(I)^2)``.
* ``"avg_timestamp"`` -- minus the loss of Zhu et al. (2018): per polarity, the image of
  average (normalized) timestamps ``T = S / (N + eps)`` with ``N`` the IWE of the events and
  ``S`` the IWE weighted by their timestamps; ``G = -sum(T_pos^2 + T_neg^2)``.
* ``"avg_timestamp_norm"`` -- the normalized variant of Hagenaars et al. (2021): the same sum
  divided by the number of pixels where any event lands (that count is piecewise constant
  and contributes no gradient).

Single-image objectives take ``iwe`` and return ``(G, dG/dIWE)``. The timestamp objectives
take the four images ``iwe_pos, iwe_neg, tiwe_pos, tiwe_neg`` and return ``(G, grads)`` with
``grads`` a dict of ``dG/d<image>`` under the same keys. :func:`events_value_grad` goes all
the way from warped events to ``(G, dG/dxw, dG/dyw)`` for any objective.

Examples
--------
>>> import numpy as np
>>> iwe = np.zeros((4, 4)); iwe[1, 1] = 4.0
>>> val, grad = objective_value_grad("variance", iwe)
>>> round(val, 4), grad.shape
(0.9375, (4, 4))
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np
from numba import njit

from evmotion.core.iwe import accumulate_backward_into, accumulate_into
from evmotion.errors import ParameterError

__all__ = [
    "OBJECTIVES",
    "ObjectiveSpec",
    "events_value_grad",
    "objective_value_grad",
    "variance_stats",
]

_TS_KEYS = ("iwe_pos", "iwe_neg", "tiwe_pos", "tiwe_neg")
#: Regularizes the average-timestamp ratio where almost no vote lands (events per pixel).
TS_EPS = 1e-3


@dataclass(frozen=True)
class ObjectiveSpec:
    """Description of one focus objective.

    Attributes
    ----------
    name : str
    needs_time : bool
        Needs per-event timestamps and polarities (the average-timestamp family).
    description : str
    """

    name: str
    needs_time: bool
    description: str


#: Registry of focus objectives by name.
OBJECTIVES: dict[str, ObjectiveSpec] = {
    "variance": ObjectiveSpec("variance", False, "IWE variance (3.4)"),
    "gradient_magnitude": ObjectiveSpec("gradient_magnitude", False,
                                        "mean squared Sobel gradient magnitude of the IWE"),
    "avg_timestamp": ObjectiveSpec("avg_timestamp", True,
                                   "minus the sum of squared average timestamps (Zhu et al.)"),
    "avg_timestamp_norm": ObjectiveSpec(
        "avg_timestamp_norm", True,
        "avg_timestamp normalized by the number of active pixels (Hagenaars et al.)"),
}


@njit(cache=True, nogil=True)
def _variance(img, grad):
    h, w = img.shape
    n = h * w
    s = 0.0
    for i in range(h):
        for j in range(w):
            s += img[i, j]
    mu = s / n
    v = 0.0
    c = 2.0 / n
    for i in range(h):
        for j in range(w):
            d = img[i, j] - mu
            v += d * d
            # the mean's own derivative term sums to zero: sum(d) == 0
            grad[i, j] = c * d
    return v / n


@njit(cache=True, nogil=True, fastmath={"reassoc", "contract", "nsz"})
def _gradmag(img, grad, work):
    """Mean squared Sobel magnitude over the interior pixels and its adjoint image, in one
    streaming pass over the rows: the (scaled) Sobel responses of rows r - 1, r, r + 1 live
    in a ring of row buffers, and row r of the adjoint is gathered from them (the Sobel
    transposes, separably), so every pixel of ``grad`` is written once, by a loop that
    vectorizes. ``work`` is (8, W + 2) scratch."""
    h, w = img.shape
    n = (h - 2) * (w - 2)
    if n <= 0:
        grad[:, :] = 0.0
        return 0.0
    c = 2.0 / n
    # rows of c Sx(I), c Sy(I) for image rows r - 1, r, r + 1 (index j + 1 for column j;
    # zero off the interior), and the vertical parts of the transposed kernels
    for a in range(8):
        for j in range(w + 2):
            work[a, j] = 0.0
    xp, xc, xn = work[0], work[1], work[2]
    yp, yc, yn = work[3], work[4], work[5]
    vv = work[6]
    uu = work[7]
    v = 0.0
    for r in range(h):
        i = r + 1
        if i <= h - 2:
            # Sobel responses of row i into the buffer of row r + 1
            up = img[i - 1]
            mid = img[i]
            dn = img[i + 1]
            for j in range(1, w - 1):
                gx = (up[j + 1] - up[j - 1]) + 2.0 * (mid[j + 1] - mid[j - 1]) \
                    + (dn[j + 1] - dn[j - 1])
                gy = (dn[j - 1] + 2.0 * dn[j] + dn[j + 1]) - (up[j - 1] + 2.0 * up[j] + up[j + 1])
                v += gx * gx + gy * gy
                xn[j + 1] = c * gx
                yn[j + 1] = c * gy
        else:
            for j in range(w + 2):
                xn[j] = 0.0
                yn[j] = 0.0
        # grad = Sx^T (c gx) + Sy^T (c gy): vertical [1 2 1] / [1 0 -1], then horizontal
        for j in range(w + 2):
            vv[j] = xp[j] + 2.0 * xc[j] + xn[j]
            uu[j] = yp[j] - yn[j]
        g = grad[r]
        for q in range(w):
            g[q] = (vv[q] - vv[q + 2]) + (uu[q] + 2.0 * uu[q + 1] + uu[q + 2])
        # shift the ring: row r becomes r - 1, r + 1 becomes r
        xp, xc, xn = xc, xn, xp
        yp, yc, yn = yc, yn, yp
    return v / n


@njit(cache=True, nogil=True)
def _avg_ts(np_, nn, sp, sn, normalize, gnp, gnn, gsp, gsn):
    h, w = np_.shape
    total = 0.0
    active = 0
    for i in range(h):
        for j in range(w):
            a = np_[i, j]
            b = nn[i, j]
            if a > 0.0 or b > 0.0:
                active += 1
            ia = 1.0 / (a + TS_EPS)
            ib = 1.0 / (b + TS_EPS)
            tp = sp[i, j] * ia
            tn = sn[i, j] * ib
            total += tp * tp + tn * tn
            gsp[i, j] = 2.0 * tp * ia
            gsn[i, j] = 2.0 * tn * ib
            gnp[i, j] = -2.0 * tp * tp * ia
            gnn[i, j] = -2.0 * tn * tn * ib
    scale = 1.0
    if normalize:
        scale = 1.0 / (active + 1e-9) if active > 0 else 0.0
    # G = -scale * total: flip signs once here
    for i in range(h):
        for j in range(w):
            gsp[i, j] *= -scale
            gsn[i, j] *= -scale
            gnp[i, j] *= -scale
            gnn[i, j] *= -scale
    return -scale * total


@njit(cache=True, nogil=True, fastmath={"reassoc", "contract", "nsz"})
def _mean_var(img):
    h, w = img.shape
    s = 0.0
    s2 = 0.0
    for i in range(h):
        for j in range(w):
            v = img[i, j]
            s += v
            s2 += v * v
    n = h * w
    mu = s / n
    return mu, max(s2 / n - mu * mu, 0.0)


def variance_stats(iwe: np.ndarray) -> tuple[float, float]:
    """Mean and variance (3.4) of an image in one pass; ``dVar/dIWE = 2 (IWE - mean) / n``.

    Examples
    --------
    >>> variance_stats(np.array([[0.0, 2.0]]))
    (1.0, 1.0)
    """
    mu, var = _mean_var(np.ascontiguousarray(iwe, dtype=np.float64))
    return float(mu), float(var)


_TLS = threading.local()


def _work(width: int) -> np.ndarray:
    """The (8, width + 2) row scratch of :func:`_gradmag`, kept per thread and width."""
    cache = getattr(_TLS, "work", None)
    if cache is None:
        cache = _TLS.work = {}
    buf = cache.get(width)
    if buf is None:
        if len(cache) > 8:
            cache.clear()
        buf = cache[width] = np.empty((8, width + 2))
    return buf


def _img(name: str, a) -> np.ndarray:
    if a is None:
        raise ParameterError(f"objective needs the image '{name}'")
    arr = np.ascontiguousarray(a, dtype=np.float64)
    if arr.ndim != 2:
        raise ParameterError(f"'{name}' must be an (H, W) image, got shape {arr.shape}")
    return arr


def objective_value_grad(name: str, iwe: np.ndarray | None = None, *,
                         iwe_pos: np.ndarray | None = None, iwe_neg: np.ndarray | None = None,
                         tiwe_pos: np.ndarray | None = None, tiwe_neg: np.ndarray | None = None,
                         out=None):
    """Focus score ``G`` and its gradient with respect to the input image(s).

    Parameters
    ----------
    name : str
        One of :data:`OBJECTIVES`.
    iwe : array (H, W)
        The IWE, for ``variance`` and ``gradient_magnitude``.
    iwe_pos, iwe_neg, tiwe_pos, tiwe_neg : array (H, W)
        For the average-timestamp objectives: per-polarity event counts ``N`` and
        timestamp-weighted counts ``S`` (timestamps normalized, typically to [0, 1]).
    out : array (H, W) or dict of arrays, optional
        Gradient buffer(s) to write into (allocation-free use).

    Returns
    -------
    G : float
        Focus score (higher = sharper).
    grad : array (H, W) or dict
        ``dG/dIWE``; for timestamp objectives a dict keyed like the inputs.

    Examples
    --------
    >>> img = np.ones((3, 3))
    >>> objective_value_grad("gradient_magnitude", img)[0]
    0.0
    """
    spec = OBJECTIVES.get(name)
    if spec is None:
        raise ParameterError(f"unknown objective '{name}'; choose one of {sorted(OBJECTIVES)}")
    if not spec.needs_time:
        img = _img("iwe", iwe)
        g = np.empty_like(img) if out is None else out
        if name == "variance":
            return float(_variance(img, g)), g
        return float(_gradmag(img, g, _work(img.shape[1]))), g
    imgs = [_img(k, v) for k, v in zip(_TS_KEYS, (iwe_pos, iwe_neg, tiwe_pos, tiwe_neg),
                                       strict=True)]
    if len({a.shape for a in imgs}) != 1:
        raise ParameterError(f"timestamp images must share one shape, got "
                             f"{[a.shape for a in imgs]}")
    grads = out if out is not None else {k: np.empty_like(imgs[0]) for k in _TS_KEYS}
    val = _avg_ts(*imgs, name == "avg_timestamp_norm", *(grads[k] for k in _TS_KEYS))
    return float(val), grads


def events_value_grad(name: str, xw: np.ndarray, yw: np.ndarray, shape: tuple[int, int],
                      polarity: np.ndarray | None = None, tn: np.ndarray | None = None,
                      weights: np.ndarray | None = None, kernel: str = "bilinear",
                      sigma: float = 1.0) -> tuple[float, np.ndarray, np.ndarray]:
    """Focus score of warped events and its gradient with respect to their positions.

    Parameters
    ----------
    name : str
        One of :data:`OBJECTIVES`.
    xw, yw : array (N,)
        Warped event positions (px).
    shape : (int, int)
        ``(H, W)``.
    polarity : array (N,), optional
        Polarity 0/1 or -1/+1; required by the timestamp objectives.
    tn : array (N,), optional
        Event times normalized to [0, 1] over the window; required by the timestamp
        objectives.
    weights : array (N,), optional
        Per-event IWE weights for the single-image objectives (e.g. polarity +-1).
    kernel, sigma
        IWE delta approximation (see :func:`evmotion.core.iwe.accumulate`).

    Returns
    -------
    G : float
    gx, gy : array (N,)
        ``dG/dxw`` and ``dG/dyw`` per event (1/px).

    Examples
    --------
    >>> g, gx, gy = events_value_grad("variance", np.array([1.2]), np.array([1.0]), (3, 3))
    >>> gx.shape
    (1,)
    """
    spec = OBJECTIVES.get(name)
    if spec is None:
        raise ParameterError(f"unknown objective '{name}'; choose one of {sorted(OBJECTIVES)}")
    xw = np.ascontiguousarray(xw, dtype=np.float64)
    yw = np.ascontiguousarray(yw, dtype=np.float64)
    n = xw.shape[0]
    gx = np.empty(n)
    gy = np.empty(n)
    if not spec.needs_time:
        iwe = accumulate_into(xw, yw, np.empty(tuple(shape)), weights, kernel, sigma)
        val, g = objective_value_grad(name, iwe)
        accumulate_backward_into(xw, yw, g, gx, gy, weights, kernel, sigma)
        return val, gx, gy
    if polarity is None or tn is None:
        raise ParameterError(f"objective '{name}' needs per-event polarity and normalized time")
    pos = np.asarray(polarity) > 0
    tn = np.ascontiguousarray(tn, dtype=np.float64)
    imgs = {}
    for key, sel in (("pos", pos), ("neg", ~pos)):
        imgs["iwe_" + key] = accumulate_into(xw[sel], yw[sel], np.empty(tuple(shape)), None,
                                             kernel, sigma)
        imgs["tiwe_" + key] = accumulate_into(xw[sel], yw[sel], np.empty(tuple(shape)),
                                              tn[sel], kernel, sigma)
    val, grads = objective_value_grad(name, **imgs)
    bx = np.empty(n)
    by = np.empty(n)
    gx.fill(0.0)
    gy.fill(0.0)
    for key, sel in (("pos", pos), ("neg", ~pos)):
        m = int(sel.sum())
        for img, wts in (("iwe_", None), ("tiwe_", tn[sel])):
            accumulate_backward_into(xw[sel], yw[sel], grads[img + key], bx[:m], by[:m], wts,
                                     kernel, sigma)
            gx[sel] += bx[:m]
            gy[sel] += by[:m]
    return val, gx, gy
