"""Is an estimate a measurement? Collapse and model-fit checks of ego-motion results, and the
event support of dense flow.

Contrast maximization always returns *some* parameters. Three ways in which they are not a
measurement of the camera's motion, each checked here from the window itself:

* **event collapse** (:func:`collapse_diagnostics`): the warp squeezes the events onto few
  pixels. Seen in the geometry of the estimate -- the area amplification ``det J`` of the
  warp over the window falls near zero (or the warp folds, ``det J <= 0``), or a pixel is
  displaced over the window by more than the sensor's diagonal (a speed the window cannot
  hold) -- or in the image of warped events, whose mass concentrates on a few pixels;
* **a poor model fit** (:func:`fit_diagnostics`): the warp explains only part of the
  window, e.g. independently moving objects before a static camera. Per sensor tile, the
  sharpness of the events under the estimate is compared with the best the tile's events
  allow under a local translation (a coarse-to-fine search) and under no motion; the
  *explained share* is the share of the tiles with structure that the estimate sharpens
  about as well as their own best translation;
* **flow without events** (:func:`event_support`): dense flow where no event was seen is an
  extrapolation, not a measurement; the support mask marks the pixels near events.

The checks return plain dicts (stored on the results) and the warnings of
:mod:`evmotion.errors` (:class:`~evmotion.errors.CollapseWarning`,
:class:`~evmotion.errors.PoorFitWarning`) name the cure.

Examples
--------
>>> import numpy as np
>>> from evmotion.core.warps import make_warp
>>> w = make_warp("zoom", (60, 80))
>>> d = collapse_diagnostics(w, np.array([19.0]), (0.0, 0.05))  # h_z T = 0.95
>>> d["collapsed"], round(d["min_det"], 4)
(True, 0.0025)
>>> collapse_diagnostics(w, np.array([1.0]), (0.0, 0.05))["collapsed"]
False
"""

from __future__ import annotations

import math
import warnings

import numpy as np
from numba import njit

from evmotion.core.warps import Warp
from evmotion.errors import CollapseWarning, ParameterError, PoorFitWarning
from evmotion.methods.flowresult import event_support  # here too: the checks of estimates
from evmotion.methods.measured import (  # noqa: F401 (re-exported: callers import them here)
    MIN_CONTRAST_GAIN,
    MIN_FIT_EVENTS,
    pixel_counts,
    warn_no_gain,
    warn_too_few,
)

__all__ = [
    "COLLAPSE_MAX_TOP_SHARE",
    "COLLAPSE_MIN_DET",
    "POOR_FIT_SHARE",
    "collapse_diagnostics",
    "effective_pixels",
    "event_support",
    "fit_diagnostics",
    "image_variance",
    "warn_collapse",
    "warn_poor_fit",
]

#: Smallest area amplification ``det J`` of the warp over the window (on a grid over the
#: sensor) that is not collapse: the thesis' deformation margin is 0.8 per event; a window
#: whose true motion compresses the image to a fifth of its area does not occur at the
#: usual window lengths, a collapsing estimate reaches it.
COLLAPSE_MIN_DET = 0.2

#: Share of the IWE's mass in its top 1 % of pixels above which an estimate is collapsed,
#: when the identity warp's share is below half of it (a sparse scene that is already
#: concentrated is not). A sharp estimate of 200 dots puts 63 % there; a collapse onto a
#: point or a line nearly all.
COLLAPSE_MAX_TOP_SHARE = 0.9
#: ... the top share of the pixels the unwarped events cover
TOP_SHARE_FRAC = 0.01

#: Explained share below which the fit is poor (:func:`fit_diagnostics`).
POOR_FIT_SHARE = 0.55

#: A tile supports the estimate when its sharpness under the estimate reaches this fraction
#: of the best local translation's ...
_AGREE = 0.8
#: ... and the estimate sharpens it by this factor over no motion (or moves it by < 1 px).
_SHARPEN = 1.05
_MIN_TILE_EVENTS = 50
#: A tile whose best sharpness stays below this mean count per event holds no structure
#: (sensor noise: each event on its own pixel) and says nothing about the motion.
_MIN_STRUCTURE = 1.5


def effective_pixels(x, y, shape) -> float:
    """Participation ratio ``N^2 / sum(n_i^2)`` of the events' count image: how many pixels
    the events effectively cover (``N`` if all pixels differ, 1 if all share one).

    It bounds the focus gain that collapse can reach: the variance of the count image
    grows at most ``N^2 / sum(n_i^2)``-fold when every event lands on one pixel.

    Parameters
    ----------
    x, y : array (N,)
        Event pixels (rounded to the nearest pixel; outside the sensor ignored).
    shape : (int, int)
        ``(H, W)``.

    Examples
    --------
    >>> effective_pixels(np.array([0, 1, 1, 1]), np.array([0, 0, 0, 0]), (2, 2))
    1.6
    """
    counts = pixel_counts(x, y, shape)
    ss = float(np.dot(counts, counts))
    n = float(counts.sum())
    return n * n / ss if ss > 0 else 0.0


def image_variance(img: np.ndarray) -> float:
    """``np.var(img)`` from the image's non-zero pixels (equal within round-off): the
    variance of an image of a few thousand events on a large sensor without a pass of
    arithmetic over its empty pixels (0.5 s for two 4096x4096 images, probe DB).

    Examples
    --------
    >>> img = np.zeros((40, 60)); img[3, 4], img[10, 20] = 2.0, -1.0
    >>> bool(np.isclose(image_variance(img), np.var(img)))
    True
    """
    a = np.asarray(img, dtype=np.float64).ravel()
    n = a.size
    if n == 0:
        return float("nan")
    nz = a[a != 0.0]
    mean = nz.sum() / n
    # the empty pixels each lie ``mean`` below it (np.var's two passes, the zeros summed
    # in closed form)
    return float((np.sum((nz - mean) ** 2) + (n - nz.size) * mean * mean) / n)


def _top_share(iwe: np.ndarray, k: int) -> float:
    """Share of the (non-negative part of the) image's mass in its top ``k`` pixels."""
    a = np.asarray(iwe, dtype=np.float64).ravel()
    # only the positive pixels hold mass (the rest add zeros to the top k): partitioning
    # the whole sensor's image took 3.5 s for 21k events on 4096x4096 (probe DB)
    a = a[a > 0.0]
    total = a.sum()
    if total <= 0:
        return 0.0
    k = min(max(1, int(k)), a.size)
    return float(np.partition(a, a.size - k)[a.size - k:].sum() / total)


def collapse_diagnostics(warp: Warp, theta, span: tuple[float, float],
                         iwe_before: np.ndarray | None = None,
                         iwe_after: np.ndarray | None = None, n_grid: int = 9) -> dict:
    """Signs of event collapse in an estimate.

    Parameters
    ----------
    warp : Warp
    theta : array (P,)
        The estimate.
    span : (float, float)
        ``(min dt, max dt)`` of the window's events relative to ``t_ref``, seconds.
    iwe_before, iwe_after : array (H, W), optional
        Images of events at the identity warp and at ``theta`` (for the concentration test).
    n_grid : int
        The warp's geometry is evaluated on an ``n_grid x n_grid`` grid over the sensor at
        both ends of the window.

    Returns
    -------
    dict
        ``min_det``, ``max_det`` (area amplification over the window), ``max_displacement_px``
        and ``sensor_diagonal_px``, ``top_share_before``/``top_share_after`` (mass in the top
        1 % of the pixels the identity IWE covers, when the IWEs are given), ``collapsed`` (bool) and ``reasons``
        (list of str).
    """
    h, w = warp.sensor_size
    ys, xs = np.meshgrid(np.linspace(0, h - 1, n_grid), np.linspace(0, w - 1, n_grid),
                         indexing="ij")
    gx, gy = xs.ravel(), ys.ravel()
    dets, disp = [], []
    theta = np.asarray(theta, dtype=np.float64)
    with np.errstate(all="ignore"):
        for t in span:
            dt = np.full(gx.shape, float(t))
            xw, yw = warp.warp(gx, gy, dt, theta)
            dets.append(warp.jacobian_det(gx, gy, dt, theta))
            disp.append(np.hypot(xw - gx, yw - gy))
    det = np.concatenate(dets)
    d = np.concatenate(disp)
    finite = bool(np.all(np.isfinite(det)) and np.all(np.isfinite(d)))
    diag = float(math.hypot(h, w))
    out = {"min_det": float(np.nanmin(det)) if finite else float("nan"),
           "max_det": float(np.nanmax(det)) if finite else float("nan"),
           "max_displacement_px": float(np.nanmax(d)) if finite else float("inf"),
           "sensor_diagonal_px": diag}
    reasons = []
    if not finite:
        reasons.append("the warp sends pixels to infinity within the window")
    else:
        if out["min_det"] < COLLAPSE_MIN_DET:
            reasons.append(f"area amplification det J down to {out['min_det']:.3g} "
                           f"(< {COLLAPSE_MIN_DET}) over the window")
        if out["max_displacement_px"] > diag:
            reasons.append(f"pixels move {out['max_displacement_px']:.3g} px over the window, "
                           f"more than the sensor diagonal ({diag:.0f} px)")
    if iwe_before is not None and iwe_after is not None:
        # 1 % of the pixels the events cover, not of the sensor: a 240x180 scene declared
        # on a 1280x720 sensor, sharply translated, put 90 % on 1 % of the sensor (probe)
        k = math.ceil(TOP_SHARE_FRAC * np.count_nonzero(np.asarray(iwe_before) > 0))
        before, after = _top_share(iwe_before, k), _top_share(iwe_after, k)
        out["top_share_before"], out["top_share_after"] = before, after
        if after > COLLAPSE_MAX_TOP_SHARE and after > 2.0 * before:
            reasons.append(f"{100 * after:.0f} % of the warped events on 1 % of the pixels "
                           f"the events cover (identity warp: {100 * before:.0f} %)")
    out["collapsed"] = bool(reasons)
    out["reasons"] = reasons
    return out


def warn_collapse(diag: dict, regularizer: str | None, weight,
                  stacklevel: int = 3, what: str = "") -> str | None:
    """Issue a :class:`~evmotion.errors.CollapseWarning` naming the cure, if ``diag`` (from
    :func:`collapse_diagnostics`) says collapsed; returns its message (else None).
    ``what``: the estimate it is about, opening the message ("cluster 1")."""
    if not diag.get("collapsed"):
        return None
    if regularizer in (None, "whitening"):
        cure = ("add a collapse regularizer: --reg divergence (API regularizer='divergence') "
                "or deformation")
    elif regularizer == "rcad":
        cure = (f"use --reg divergence or deformation, or a larger --weight than {weight:g} "
                f"(API weight=)")
    else:
        cure = f"raise --weight (now {_fmt_weight(weight)}; API weight=)"
    msg = (f"{what + ': ' if what else ''}event collapse: {'; '.join(diag['reasons'])}; the "
           f"estimate is not the motion -- {cure}")
    warnings.warn(msg, CollapseWarning, stacklevel=stacklevel)
    return msg


def _fmt_weight(weight) -> str:
    if isinstance(weight, dict):
        return "/".join(f"{v:g}" for v in weight.values())
    return f"{float(weight):g}"


# ---------------------------------------------------------------------------------------
# Model fit: per-tile sharpness under the estimate vs the tile's best local translation

@njit(cache=True)
def _sharpness(xl, yl, s, dxs, dys, cell, img, out):
    """Mean count at an event's cell, ``sum(n^2) / N``, of the events at ``(xl - dx s,
    yl - dy s)`` voted to the nearest cell of side ``cell`` (px) of ``img`` (zeroed on
    entry and on return; events outside are dropped), for every candidate ``(dx, dy)``."""
    hh, ww = img.shape
    n = xl.shape[0]
    at = np.empty(n, np.int64)
    inv = 1.0 / cell
    for c in range(dxs.shape[0]):
        tot = 0.0
        for k in range(n):
            i = int(math.floor((yl[k] - dys[c] * s[k]) * inv))
            j = int(math.floor((xl[k] - dxs[c] * s[k]) * inv))
            if 0 <= i < hh and 0 <= j < ww:
                v = img[i, j]
                tot += 2.0 * v + 1.0
                img[i, j] = v + 1.0
                at[k] = i * ww + j
            else:
                at[k] = -1
        flat = img.ravel()
        for k in range(n):
            if at[k] >= 0:
                flat[at[k]] = 0.0
        out[c] = tot / max(n, 1)


def _scan(xl, yl, s, cands, cell, img):
    out = np.empty(cands.shape[0])
    _sharpness(xl, yl, s, np.ascontiguousarray(cands[:, 0]), np.ascontiguousarray(cands[:, 1]),
               float(cell), img, out)
    return out


#: Events per tile at which the coarse levels of the search subsample (every k-th event):
#: the argmax over cells of several px needs fewer; the 1-px level uses them all.
_COARSE_EVENTS = 256


def _best_translation(xl, yl, s, dmax, pad):
    """Coarse-to-fine search of the displacement over the window (px) that makes one
    tile's events sharpest; returns its sharpness at 1 px cells."""
    cell = 1
    while cell * 4 < dmax:
        cell *= 2
    best = np.zeros(2)
    radius = 4
    step = max(1, xl.shape[0] // _COARSE_EVENTS)
    while True:
        r = np.arange(-radius, radius + 1) * float(cell)
        cands = best + np.stack(np.meshgrid(r, r, indexing="ij"), -1).reshape(-1, 2)
        img = np.zeros((int(math.ceil(pad / cell)) + 1,) * 2)
        if cell == 1:
            vals = _scan(xl, yl, s, cands, cell, img)
            return float(vals.max())
        vals = _scan(xl[::step], yl[::step], s[::step], cands, cell, img)
        best = cands[int(np.argmax(vals))]
        cell //= 2
        radius = 2


def fit_diagnostics(x, y, dt, xw, yw, shape, tile: int | None = None) -> dict:
    """How well one warp explains a window: per-tile sharpness under the estimate vs the
    tile's own best translation.

    For each tile of ``tile`` px (default ``min(H, W) / 6``, at least 16; the last of a row
    or column takes the remainder) holding at least
    50 events, the sharpness ``S = sum(n^2) / N`` (mean count at an event's pixel) of its
    events is measured under the estimate (``xw, yw``), under no motion and under the best
    translation of the tile (a coarse-to-fine search of the displacement over the window,
    covering 1.5 times the estimate's). Tiles whose best ``S`` stays below 1.5 hold no
    structure (sensor noise) and are left out, as are tiles that no translation sharpens
    by 5 % over no motion and that the estimate does not smear (below 80 % of their best):
    they say nothing of the motion. A tile *supports* the estimate when the
    estimate reaches 80 % of the best sharpness and either sharpens the tile by 5 % over no
    motion or moves its events by less than 1 px (a static estimate there). Static
    structure (flicker, hot pixels) that the estimate smears, and objects that move
    otherwise, do not. A camera motion moves the whole image, so the share is counted over
    the tiles (the sensor area with structure), not the events, which the fastest object
    dominates.

    Parameters
    ----------
    x, y : array (N,)
        Event pixels.
    dt : array (N,)
        ``t_k - t_ref``, seconds.
    xw, yw : array (N,)
        The events warped by the estimate.
    shape : (int, int)
        ``(H, W)``.
    tile : int, optional
        Tile side in px.

    Returns
    -------
    dict
        ``explained_share`` (share of the evaluated tiles that support the estimate; NaN
        when no tile has structure), ``explained_event_share`` (the same share counted in
        events), ``n_tiles`` (evaluated), ``tile_px``,
        ``tile_support`` (per evaluated tile: x0, y0, events, S_estimate, S_static, S_best,
        supports) as a list of rows.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> n = 4000
    >>> t = np.sort(rng.uniform(0, 0.05, n)); x0 = rng.integers(0, 60, n) * 1.0
    >>> y0 = rng.integers(0, 60, n) % 7 * 8.0 + 4        # 7 horizontal lines ...
    >>> y = y0 + 200 * t                                  # ... moving down at 200 px/s
    >>> d = fit_diagnostics(x0, y, t, x0, y - 200 * t, (64, 64), tile=16)
    >>> d["explained_share"]
    1.0
    """
    x = np.ascontiguousarray(x, dtype=np.float64)
    y = np.ascontiguousarray(y, dtype=np.float64)
    dt = np.ascontiguousarray(dt, dtype=np.float64)
    xw = np.ascontiguousarray(xw, dtype=np.float64)
    yw = np.ascontiguousarray(yw, dtype=np.float64)
    n = x.shape[0]
    if not (y.shape == dt.shape == xw.shape == yw.shape == (n,)):
        raise ParameterError("fit_diagnostics: x, y, dt, xw, yw must be (N,) arrays alike")
    h, w = int(shape[0]), int(shape[1])
    side = int(tile) if tile else max(16, min(h, w) // 6)
    if side < 4:
        raise ParameterError(f"fit_diagnostics: tile must be >= 4 px, got {side}")
    span = float(dt.max() - dt.min()) if n else 0.0
    rows = []
    if n and span > 0:
        # a displacement of d px over the window moves an event by d * s
        s_all = dt / span
        # the last tile of a row / column takes the remainder: 346 = 8 x 43 + 2 px made
        # 2 px strips along two edges that all failed, and a DAVIS346 window of a true
        # zoom poor (0.48 of the tiles; 0.63 with them merged, probe AW)
        nx, ny = max(1, w // side), max(1, h // side)
        tx = np.clip(np.floor(x / side), 0, nx - 1).astype(np.int64)
        ty = np.clip(np.floor(y / side), 0, ny - 1).astype(np.int64)
        key = ty * nx + tx
        order = np.argsort(key, kind="stable")
        bounds = np.flatnonzero(np.diff(key[order])) + 1
        for idx in np.split(order, bounds):
            if idx.size < _MIN_TILE_EVENTS:
                continue
            ox, oy = float(tx[idx[0]] * side), float(ty[idx[0]] * side)
            ex, ey = xw[idx] - x[idx], yw[idx] - y[idx]
            if not (np.all(np.isfinite(ex)) and np.all(np.isfinite(ey))):
                moved = np.inf
            else:
                moved = float(np.max(np.hypot(ex, ey)))
            dmax = float(min(max(side / 2.0, 1.5 * moved), 4.0 * side)) if np.isfinite(
                moved) else 4.0 * side
            pad = int(math.ceil(dmax * 1.5)) + 4
            # local coordinates, the tile at the centre of an image of its side + 2 pad px
            xl = x[idx] - ox + pad
            yl = y[idx] - oy + pad
            s = s_all[idx]
            zero = np.zeros(idx.size)
            tw = side if tx[idx[0]] < nx - 1 else w - int(ox)
            th = side if ty[idx[0]] < ny - 1 else h - int(oy)
            full = max(tw, th) + 2 * pad + 1
            img = np.zeros((full, full))
            s_static = float(_scan(xl, yl, zero, np.zeros((1, 2)), 1, img)[0])
            s_best = max(_best_translation(xl, yl, s, dmax, full), s_static)
            if np.isfinite(moved):
                s_est = float(_scan(xw[idx] - ox + pad, yw[idx] - oy + pad, zero,
                                    np.zeros((1, 2)), 1, img)[0])
            else:
                s_est = 0.0
            s_best = max(s_best, s_est)
            if s_best < _MIN_STRUCTURE:
                continue
            if s_best < _SHARPEN * s_static and s_est >= _AGREE * s_best:
                # no translation sharpens the tile over no motion, and the estimate keeps
                # its sharpness: the tile says nothing of the motion (a smooth texture, or
                # a zoom's centre), and it counted against a true zoom fitted to within
                # 0.04 px (explained 52 %, probe CD); one the estimate smears still does
                continue
            supports = bool(s_est >= _AGREE * s_best
                            and (s_est >= _SHARPEN * s_static or moved < 1.0))
            rows.append((ox, oy, int(idx.size), s_est, s_static, s_best, supports))
    total = sum(r[2] for r in rows)
    good = sum(r[2] for r in rows if r[6])
    n_good = sum(1 for r in rows if r[6])
    # no tile with structure: nothing to check the estimate against (NaN, not 100 %)
    return {"explained_share": n_good / len(rows) if rows else float("nan"),
            "explained_event_share": good / total if total else float("nan"),
            "n_tiles": len(rows),
            "tile_px": side,
            "tile_support": [{"x0": r[0], "y0": r[1], "n_events": r[2], "S_estimate": r[3],
                              "S_static": r[4], "S_best": r[5], "supports": r[6]}
                             for r in rows]}


def unchecked_fit(diag: dict) -> bool:
    """Whether :func:`fit_diagnostics` ran (``diag`` not empty) but found no tile to test
    the estimate against (``explained_share`` NaN): on a window of too few events, where
    the optimizer finds speeds of chance that sharpen the image by a few percent."""
    return bool(diag) and not np.isfinite(diag.get("explained_share", np.nan))


def warn_poor_fit(diag: dict, warp: str, stacklevel: int = 3) -> str | None:
    """Issue a :class:`~evmotion.errors.PoorFitWarning` when the explained share of
    ``diag`` (from :func:`fit_diagnostics`) is below :data:`POOR_FIT_SHARE`; returns its
    message (else None)."""
    share = diag.get("explained_share", 1.0)
    if unchecked_fit(diag):
        msg = (f"unchecked fit: no tile of {diag.get('tile_px', '?')} px holds enough events "
               f"with structure to test the {warp} warp against -- too few events to tell a "
               "motion from chance (windows of a few hundred or thousand events find wild "
               "speeds); the estimate is not a measurement -- use longer windows")
        warnings.warn(msg, PoorFitWarning, stacklevel=stacklevel)
        return msg
    if not share < POOR_FIT_SHARE:
        return None
    msg = (f"poor fit: the {warp} warp explains only {100 * share:.0f} % of the image "
           f"(tiles it sharpens about as well as their own motion; threshold "
           f"{100 * POOR_FIT_SHARE:.0f} %) -- independently moving objects or a static "
           f"camera? the estimate is not the camera's motion; use shorter windows, a "
           f"richer warp, or dense flow (evmotion flow)")
    warnings.warn(msg, PoorFitWarning, stacklevel=stacklevel)
    return msg
