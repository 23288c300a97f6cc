"""Motion segmentation by contrast maximization with several warps (thesis Sec. 3.6.6).

Events are explained by ``n_warps`` motions at once (Stoffregen et al., 2019): an
expectation-maximization loop alternates

* **M-step** -- each warp's parameters maximize the contrast of its own IWE, in which every
  event votes with its probability of belonging to that cluster;
* **E-step** -- the probability that event k belongs to cluster j is proportional to the
  (Gaussian-smoothed) IWE of cluster j at the event's position warped by warp j: an event
  belongs where it sharpens the image.

Initialization is seeded: spatial k-means of the events gives the first memberships.

Examples
--------
>>> import numpy as np
>>> from evmotion.events import EventArray
>>> rng = np.random.default_rng(0)
>>> n = 6000
>>> dots = np.concatenate([rng.uniform([10, 10], [50, 70], (40, 2)),
...                        rng.uniform([80, 10], [120, 70], (40, 2))])
>>> k = rng.integers(0, 80, n)
>>> t = np.sort(rng.integers(0, 40_000, n))
>>> v = np.where(k < 40, 300.0, -300.0)         # left half right, right half left
>>> ev = EventArray(dots[k, 0] + v * t * 1e-6, dots[k, 1], t, np.ones(n, int), (80, 130),
...                 validate=False)
>>> seg = segment_motion(ev, n_warps=2, warp="translation", seed=0)
>>> sorted(np.round(seg.params[:, 0], -2).tolist())
[-300.0, 300.0]
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from evmotion.core.iwe import accumulate
from evmotion.core.optim import gradient_minimize
from evmotion.errors import ParameterError, PoorFitWarning
from evmotion.events import EventArray, require_events
from evmotion.methods.cmax import make_cost, param_scales
from evmotion.methods.diagnostics import collapse_diagnostics, warn_collapse
from evmotion.methods.measured import warn_by_chance, warp_alignment_chance
from evmotion.utils import check_number, whole_number

__all__ = ["SegmentationResult", "segment_motion"]


@dataclass(frozen=True)
class SegmentationResult:
    """Outcome of :func:`segment_motion`.

    Attributes
    ----------
    params : ndarray (n_warps, P)
        Parameters of each cluster's warp (units in ``param_units``).
    labels : ndarray (N,) int
        Most likely cluster of each event.
    probabilities : ndarray (N, n_warps)
        Cluster memberships (rows sum to 1).
    iwes : ndarray (n_warps, H, W)
        Each cluster's IWE (membership-weighted) at its parameters.
    param_names, param_units : tuple of str
    warp : str
    n_iter : int
        EM iterations run.
    history : ndarray (n_iter,)
        Sum over clusters of the focus (G/G0) after each M-step.
    seconds : float
    gains : ndarray (n_warps,)
        Each cluster's contrast gain: the variance of its IWE at its parameters over that
        of its events unwarped (membership-weighted alike).
    valid : ndarray (n_warps,) bool
        Clusters that are measurements: at least :data:`MIN_CLUSTER_EVENTS` events, a gain
        of at least :data:`MIN_CLUSTER_GAIN`, no event collapse, a warp that aligns the
        window's events, or its territory's, better than chance (``chance_gains``,
        ``chance_z``) and a motion
        of their own (each other cluster is warned about: no motion, noise, a warp that
        fits nothing, its events squeezed together, or one motion split in two).
    collapsed : ndarray (n_warps,) bool
        Clusters whose warp collapses their events
        (:func:`~evmotion.methods.diagnostics.collapse_diagnostics` on the cluster's
        membership-weighted events): not measurements, however sharp.
    same_as : ndarray (n_warps,) int
        The larger cluster whose motion a cluster repeats (within :data:`SAME_MOTION_PX`
        over the window), else -1.
    split : str
        The first split the clusters grew from (``"dominant"`` or ``"spatial"``; ``""``
        for one cluster).
    chance_gains, chance_z : ndarray (n_warps,)
        How much better each cluster's warp aligns the window's events than the same
        per-event motions with their times shuffled, and by how many standard deviations
        of the shuffles' scatter
        (:func:`~evmotion.methods.measured.warp_alignment_chance`): of all the events or
        of the cluster's territory (every event of the blocks where it holds most of the
        membership), whichever lies further beyond chance; a cluster is valid only with
        at least :data:`~evmotion.methods.measured.MIN_CONTRAST_GAIN` and
        :data:`~evmotion.methods.measured.MIN_CHANCE_Z`. NaN for the clusters not tested
        (too few events, too little gain, collapsed).
    """

    params: np.ndarray
    labels: np.ndarray = field(repr=False)
    probabilities: np.ndarray = field(repr=False)
    iwes: np.ndarray = field(repr=False)
    param_names: tuple[str, ...]
    param_units: tuple[str, ...]
    warp: str
    n_iter: int
    history: np.ndarray = field(repr=False)
    seconds: float
    gains: np.ndarray = field(default_factory=lambda: np.empty(0))
    valid: np.ndarray = field(default_factory=lambda: np.empty(0, bool))
    same_as: np.ndarray = field(default_factory=lambda: np.empty(0, int))
    split: str = ""
    collapsed: np.ndarray = field(default_factory=lambda: np.empty(0, bool))
    chance_gains: np.ndarray = field(default_factory=lambda: np.empty(0))
    chance_z: np.ndarray = field(default_factory=lambda: np.empty(0))


#: Fewest events a cluster needs to be a measurement.
MIN_CLUSTER_EVENTS = 50
#: Least contrast gain of a cluster that is a measurement. Higher than one warp's
#: :data:`~evmotion.methods.diagnostics.MIN_CONTRAST_GAIN`: the memberships are fitted to
#: make each cluster sharp, which sharpens even noise (measured 2026-11-29 through the CLI:
#: 1.00-1.09 on pure noise and flicker, 1.46-2.5 on moving scenes and an ECD window;
#: tests/test_segmentation.py checks noise and static dots).
MIN_CLUSTER_GAIN = 1.2


def _bilinear_sample(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    h, w = img.shape
    xc = np.clip(x, 0, w - 1.000001)
    yc = np.clip(y, 0, h - 1.000001)
    x0 = np.floor(xc).astype(np.intp)
    y0 = np.floor(yc).astype(np.intp)
    fx, fy = xc - x0, yc - y0
    out = (img[y0, x0] * (1 - fx) * (1 - fy) + img[y0, x0 + 1] * fx * (1 - fy)
           + img[y0 + 1, x0] * (1 - fx) * fy + img[y0 + 1, x0 + 1] * fx * fy)
    inside = (x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1)
    return np.where(inside, out, 0.0)


def _kmeans(pts: np.ndarray, k: int, rng: np.random.Generator, n_iter: int = 15) -> np.ndarray:
    centers = pts[rng.choice(pts.shape[0], k, replace=False)]
    lab = np.zeros(pts.shape[0], dtype=np.intp)
    for _ in range(n_iter):
        d = ((pts[:, None, :] - centers[None]) ** 2).sum(-1)
        lab = d.argmin(axis=1)
        for j in range(k):
            if np.any(lab == j):
                centers[j] = pts[lab == j].mean(axis=0)
    return lab


#: How the events are first split among the clusters (:func:`segment_motion`'s ``split``).
SPLITS = ("best", "dominant", "spatial")


def segment_motion(events: EventArray, n_warps: int = 2, warp: str = "translation",
                   objective: str = "variance", K=None, t_ref: str | int = "start",
                   n_iter: int = 10, init=None, seed: int = 0, sigma: float = 1.0,
                   tol: float = 1e-3, regularizer: str | None = None,
                   weight: float | None = None, dataset: str | None = None,
                   split: str = "best") -> SegmentationResult:
    """Segment events into ``n_warps`` motions by expectation-maximization (Sec. 3.6.6).

    Parameters
    ----------
    events : EventArray
        One window (undistorted for the rotation warp).
    n_warps : int
        Number of motion clusters (>= 1).
    warp : str
        Warp of every cluster (see :data:`evmotion.core.warps.WARPS`).
    objective : str
        Focus objective (``variance`` or ``gradient_magnitude``).
    K : array (3, 3) or Camera, optional
        Intrinsics (rotation warp).
    t_ref : {"start", "mid", "end"} or int
        Reference time (int: absolute µs, within the window's span or 1 s of its events,
        as in :func:`~evmotion.methods.egomotion.estimate_egomotion`).
    n_iter : int
        Maximum EM iterations.
    init : array (n_warps, P), optional
        Initial parameters of the first M-step; default zero.
    seed : int
        Seed of the ``"spatial"`` split's k-means.
    sigma : float
        Gaussian IWE width (px) used for the memberships.
    tol : float
        Stop when no membership changes by more than ``tol``.
    regularizer : {None, "divergence", "deformation", "rcad"}
        Collapse penalty added to every cluster's cost (3.6), as in Sec. 3.6.6. It is
        evaluated on all events of the window, not membership-weighted. For the warps of
        Sec. 3.6.6 this makes no difference to divergence and RCAD (the zoom's divergence is
        the same for every event, the translation's is zero, RCAD has closed forms); for
        the deformation map and the rotation/homography maps it is an approximation.
    weight : float, optional
        ``lambda``; default derived from the window
        (:func:`evmotion.methods.weights.window_weight`), or the thesis' (Sec. 3.6.1) for a
        named ``dataset``.
    dataset : {None, "mvsec", "dsec", "ecd"}
        Use the thesis' weights of this data set (default None: the window's).
    split : {"best", "dominant", "spatial"}
        How the events are first split among the clusters. ``"dominant"``: the motion
        that best sharpens all the events is fitted, the events its warp lines up better
        than they lie unwarped are its cluster, and the next motion is fitted to the
        rest, and so on (an object of 10-30 % of the events over a moving background is
        found: ``benchmarks/results/segment.md``).
        ``"spatial"``: a seeded k-means of the events' positions. ``"best"`` (default):
        both, kept the one whose clusters together (the sum of their IWEs) sharpen the
        events most; twice the time. Each fails where the other does not: a fast,
        textured object gathers the k-means' centres, whose clusters then each took a
        part of it and its motion, the background's never found (probe BJ: both at
        (-80, 60) px/s where the background moved at (50, 0); dominant: (50.5-51.9,
        0-0.6)); where no motion dominates, the dominant one mixes the two (another
        scene: (57.7, 69.5) for (60, 0) and (-40, 70); spatial: right). The sum's
        sharpness chose the right one in all 6 windows of the two scenes.

    Returns
    -------
    SegmentationResult

    Examples
    --------
    See the module docstring.
    """
    require_events(events, "segment_motion")
    t_start = time.perf_counter()
    # (2.0 failed in range(): TypeError, probe DB)
    n_warps = whole_number("n_warps", n_warps, lo=1)
    # (1e30, NaN or -1 reached numpy's SeedSequence, probe API)
    seed = whole_number("seed", seed, lo=0)
    if not (isinstance(n_iter, (int, np.integer)) and n_iter >= 1):
        raise ParameterError(f"n_iter must be an integer >= 1, got {n_iter!r}")
    if objective not in ("variance", "gradient_magnitude"):
        raise ParameterError(f"segmentation supports the variance and gradient_magnitude "
                             f"objectives, got '{objective}'")
    if regularizer not in (None, "divergence", "deformation", "rcad"):
        raise ParameterError(f"segmentation supports the divergence, deformation and rcad "
                             f"regularizers (or None), got '{regularizer}'")
    cost, _ = make_cost(events, warp, objective, regularizer, weight, K, t_ref,
                        dataset=dataset)
    w = cost.warp
    n = cost.x.shape[0]
    if n < 10 * n_warps:
        raise ParameterError(f"{n} events are too few for {n_warps} clusters")
    if split not in SPLITS:
        raise ParameterError(f"split must be one of {', '.join(SPLITS)}, got {split!r}")
    # (tol=nan was taken: no change is below NaN, so every run went to n_iter, probe DB)
    check_number("tol", tol)
    check_number("sigma", sigma, lo_open=True, units="px")
    scale = param_scales(w)
    params0 = np.zeros((n_warps, w.n_params))
    if init is not None:
        given = np.array(init, dtype=np.float64)
        # (a (3, 2) init for 2 clusters failed in numpy's reshape, probe DB)
        if given.size != params0.size or not np.isfinite(given).all():
            raise ParameterError(f"init must hold {n_warps} x {w.n_params} finite "
                                 f"{w.name} parameters (one row per cluster), got shape "
                                 f"{given.shape}")
        params0 = given.reshape(params0.shape)
    tried = ("dominant", "spatial") if split == "best" and n_warps > 1 else (split,)
    runs = [_em(cost, _first_memberships(cost, s, n_warps, scale, sigma, seed),
                params0.copy(), n_iter, tol, sigma, scale) for s in tried]
    # the split whose clusters together sharpen all the events most: each alone is the
    # sharper where a motion is split in two or two are mixed, which the sum shows
    sharpness = [float(np.var(iwes.sum(axis=0))) for _, _, _, iwes in runs]
    kept = int(np.argmax(sharpness))
    params, prob, history, iwes = runs[kept]
    labels = prob.argmax(axis=1)
    gains, valid = np.empty(n_warps), np.zeros(n_warps, bool)
    unwarped = [accumulate(cost.x, cost.y, cost.shape, prob[:, j]) for j in range(n_warps)]
    for j in range(n_warps):
        still = np.var(unwarped[j])
        gains[j] = np.var(iwes[j]) / still if still > 0 else np.nan
        enough = int(np.sum(labels == j)) >= MIN_CLUSTER_EVENTS
        if not enough:
            warnings.warn(PoorFitWarning(
                f"cluster {j} holds {int(np.sum(labels == j))} events (fewer than "
                f"{MIN_CLUSTER_EVENTS}): its {w.name} parameters are not a measurement"),
                stacklevel=2)
        elif not gains[j] >= MIN_CLUSTER_GAIN:
            warnings.warn(PoorFitWarning(
                f"no focus: cluster {j}'s {w.name} warp sharpens its events by "
                f"{100 * (gains[j] - 1):.1f} % only (threshold "
                f"{100 * (MIN_CLUSTER_GAIN - 1):.0f} %): not a measurement"), stacklevel=2)
        else:
            valid[j] = True
    collapsed = np.zeros(n_warps, bool)
    for j in np.flatnonzero(valid):
        # egomotion's check on the cluster's own images: the EM sharpens a cluster as
        # freely as one warp's CMax does (a homography cluster squeezed 14k events onto
        # one dot, gain 999, and was valid; probe DA)
        diag = collapse_diagnostics(w, params[j], cost.span, unwarped[j], iwes[j])
        collapsed[j] = warn_collapse(diag, regularizer, cost.weight, stacklevel=3,
                                     what=f"cluster {j}") is not None
    valid &= ~collapsed
    chance = np.full((2, n_warps), np.nan)
    for j in np.flatnonzero(valid):
        # The memberships are fitted to make each cluster sharp, so its own gain sharpens
        # noise too (2.4-8 on 8x8 and 16x16 sensors, 1.2-1.6 on 32x32; probe DB), and its
        # own events, chosen for lining up under its warp, do as well with their times
        # shuffled. All the window's events under the cluster's warp carry no such choice:
        # a motion some of them follow aligns them beyond what shuffled times scatter to.
        with np.errstate(all="ignore"):
            xw, yw = w.warp(cost.x, cost.y, cost.dt, params[j])
        chance[:, j] = warp_alignment_chance(cost.x, cost.y, cost.dt, xw, yw, cost.shape)
        # All the events can hide a minority motion: an object of 16 % moving against
        # the background's (100, 0) px/s was found at (-100, 0) yet refused at z -6.5 to
        # -19.7, the background's events warped by it scattering beyond their shuffles
        # (probe DG). So the events of its territory are tried too: every event of the
        # blocks where it holds most of the membership (z 41-106 on the probe's scenes;
        # 2.9 at most on noise of 8x8-32x32, where blocks choose less)
        mine = _territory(cost, prob[:, j])
        if np.count_nonzero(mine) >= MIN_CLUSTER_EVENTS:
            own = warp_alignment_chance(cost.x[mine], cost.y[mine], cost.dt[mine], xw[mine],
                                        yw[mine], cost.shape)
            if own[1] > chance[1, j] or not np.isfinite(chance[1, j]):
                chance[:, j] = own
        valid[j] = warn_by_chance(chance[0, j], f"{w.name} warp of cluster {j}",
                                  z=chance[1, j]) is None
    same_as = _duplicates(w, cost, params, labels, valid, gains)
    for k in np.flatnonzero(same_as >= 0):
        warnings.warn(PoorFitWarning(
            f"cluster {k} moves its events as cluster {same_as[k]} does (within "
            f"{SAME_MOTION_PX:g} px over the window): one motion split in two, not another "
            "measurement -- use fewer --warps"), stacklevel=2)
        valid[k] = False
    return SegmentationResult(params=params, labels=labels, probabilities=prob,
                              iwes=iwes, param_names=tuple(w.param_names),
                              param_units=tuple(w.param_units), warp=w.name, n_iter=len(history),
                              history=np.asarray(history),
                              seconds=time.perf_counter() - t_start, gains=gains, valid=valid,
                              same_as=same_as, split=tried[kept] if n_warps > 1 else "",
                              collapsed=collapsed, chance_gains=chance[0], chance_z=chance[1])


#: Events a block of a cluster's territory holds on average (:func:`_territory`).
TERRITORY_BLOCK_EVENTS = 1000


def _territory(cost, weights: np.ndarray) -> np.ndarray:
    """The events of the square blocks (about :data:`TERRITORY_BLOCK_EVENTS` events each
    on average, 4 px at least) whose membership ``weights`` sum to more than half their
    events: where a cluster holds sway, all the events there, its own or not."""
    h, w = cost.shape
    side = max(4.0, float(np.sqrt(h * w * TERRITORY_BLOCK_EVENTS / len(cost.x))))
    nx = int(w // side) + 1
    bx = np.clip((np.asarray(cost.x) / side).astype(np.int64), 0, nx - 1)
    by = np.clip((np.asarray(cost.y) / side).astype(np.int64), 0, int(h // side))
    block = by * nx + bx
    held = np.bincount(block, weights) > 0.5 * np.bincount(block)
    return held[block]


def _first_memberships(cost, split: str, n_warps: int, scale, sigma: float, seed: int
                       ) -> np.ndarray:
    """The memberships ``(N, n_warps)`` the EM starts from: 0.9 to each event's cluster
    of the ``split``, the rest shared among the others."""
    n = cost.x.shape[0]
    if n_warps == 1:
        return np.ones((n, 1))
    lab = (_dominant_split(cost, n_warps, scale, sigma) if split == "dominant" else
           _kmeans(np.stack([cost.x, cost.y], axis=1), n_warps, np.random.default_rng(seed)))
    prob = np.full((n, n_warps), 0.1 / (n_warps - 1))
    prob[np.arange(n), lab] = 0.9
    return prob


def _em(cost, prob: np.ndarray, params: np.ndarray, n_iter: int, tol: float, sigma: float,
        scale) -> tuple[np.ndarray, np.ndarray, list[float], np.ndarray]:
    """Expectation-maximization from memberships ``prob`` and parameters ``params``:
    ``(params, memberships, focus history, each cluster's membership-weighted IWE)``."""
    w = cost.warp
    n_warps = prob.shape[1]
    history: list[float] = []
    for _ in range(n_iter):
        focus = 0.0
        for j in range(n_warps):
            cost.weights = np.ascontiguousarray(prob[:, j])
            cost.normalize_focus()
            res = gradient_minimize(cost.value_grad, params[j], "bfgs", scale=scale,
                                    max_iter=30)
            params[j] = res.x
            focus += -res.fun
        history.append(focus)
        like = np.stack([_aligned(cost, params[j], prob[:, j], sigma)
                         for j in range(n_warps)], axis=1)
        like += 1e-9
        new = like / like.sum(axis=1, keepdims=True)
        change = float(np.abs(new - prob).max())
        prob = new
        if change < tol:
            break
    iwes = np.stack([accumulate(*w.warp(cost.x, cost.y, cost.dt, params[j]), cost.shape,
                                prob[:, j]) for j in range(n_warps)])
    return params, prob, history, iwes


def _aligned(cost, params: np.ndarray, weights: np.ndarray, sigma: float) -> np.ndarray:
    """How well each event lines up with the others under the warp ``params``: the
    Gaussian IWE of the ``weights``-weighted events, sampled at its warped position (the
    E-step's likelihood)."""
    xw, yw = cost.warp.warp(cost.x, cost.y, cost.dt, params)
    img = accumulate(xw, yw, cost.shape, weights, kernel="gaussian", sigma=sigma)
    return _bilinear_sample(img, xw, yw)


def _dominant_split(cost, n_warps: int, scale, sigma: float) -> np.ndarray:
    """Each event's first cluster: motion j is fitted to the events no earlier motion
    took, and takes those of them its warp lines up better than they lie unwarped (the
    Gaussian IWE at their warped positions against the unwarped image at their own); the
    last cluster keeps the rest. Where that leaves fewer than :data:`MIN_CLUSTER_EVENTS`
    on either side (no motion, or one that sharpens everything), motion j takes the
    ``1 / (n_warps - j)`` of them its image aligns best (half of all for two motions).

    (A fixed half gave the second motion as many background events as the object's: an
    object of 20-30 % of the events never got a cluster of its own, both following the
    background, one flagged as its duplicate. Halves at every step left nothing to the
    later of 50 clusters: numpy's "Mean of empty slice" on every window, probe CE.)"""
    w = cost.warp
    n = cost.x.shape[0]
    labels = np.full(n, n_warps - 1)
    free = np.ones(n, bool)
    for j in range(n_warps - 1):
        cost.weights = np.ascontiguousarray(free, dtype=np.float64)
        cost.normalize_focus()
        fit = gradient_minimize(cost.value_grad, np.zeros(w.n_params), "bfgs", scale=scale,
                                max_iter=30)
        aligned = _aligned(cost, fit.x, cost.weights, sigma)
        unwarped = _aligned(cost, np.zeros(w.n_params), cost.weights, sigma)
        mine = free & (aligned > unwarped)
        taken = int(np.sum(mine))
        if min(taken, int(np.sum(free)) - taken) < MIN_CLUSTER_EVENTS:
            mine = free & (aligned >= np.quantile(aligned[free], 1.0 - 1.0 / (n_warps - j)))
        labels[mine] = j
        free &= ~mine
    return labels


def _duplicates(w, cost, params, labels, valid, gains) -> np.ndarray:
    """For each valid cluster, the sharper valid cluster (higher contrast gain) whose warp
    moves the events of both to within :data:`SAME_MOTION_PX` of where its own does
    (median over the window), else -1: EM splits one motion in two when asked for more
    clusters than there are. The sharper one is the cleaner measurement of that motion:
    kept by size, a cluster that had taken an object's events into the background's
    motion (gain 1.23) stood as the measurement and the pure background (gain 1.99) as
    its duplicate (probe)."""
    same_as = np.full(len(params), -1)
    order = sorted(np.flatnonzero(valid), key=lambda j: -gains[j])
    for a, j in enumerate(order):
        for k in order[a + 1:]:
            if same_as[k] >= 0:
                continue
            sel = (labels == j) | (labels == k)
            xj, yj = w.warp(cost.x[sel], cost.y[sel], cost.dt[sel], params[j])
            xk, yk = w.warp(cost.x[sel], cost.y[sel], cost.dt[sel], params[k])
            if np.median(np.hypot(xj - xk, yj - yk)) < SAME_MOTION_PX:
                same_as[k] = j
    return same_as


#: Two clusters whose warps put their events within this many pixels of each other
#: (median over the window) measure one motion (:func:`segment_motion`).
SAME_MOTION_PX = 1.0
