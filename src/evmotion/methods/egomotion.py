"""Ego-motion by contrast maximization, with event-collapse regularizers (thesis ch. 3).

:func:`estimate_egomotion` fits the parameters ``theta`` of a warp (zoom, translation,
rotation, SE(2), in-plane, similarity, affine, homography; see
:mod:`evmotion.core.warps`) to one window of events by minimizing (3.6)

    ``J(theta) = -G(theta) / G(0) + lambda * R(theta)``

with ``G`` a focus objective of the image of warped events (:mod:`evmotion.core.objectives`)
and ``R`` a collapse penalty (:mod:`evmotion.core.collapse`). Two choices make the
weights ``lambda`` of Sec. 3.6.1 transferable between windows and sensors:

* ``G`` is divided by its value at the identity warp, so the data term is dimensionless and
  independent of the event count and image size (for the variance objective ``G/G(0)`` is
  the FWL, the thesis' own sharpness measure). The thesis does not state the scale of ``G``
  behind its weights. With this choice its Sec. 3.6.1 weights (``DEFAULT_WEIGHTS``, chosen
  by naming a ``dataset``) apply as they are: on simulated forward motion
  (``benchmarks/results/collapse.md``) the DSEC set cures the collapse of the zoom and the
  4-DOF in-plane warp with every regularizer, the MVSEC set with divergence and
  deformation, while its RCAD weight (0.2) is too weak for the 4-DOF warp there. Without a
  ``dataset`` the weight is derived from the window (:mod:`evmotion.methods.weights`: it
  scales with the focus gain a collapse can reach), which cures those cases too;
* the penalties are used as :mod:`evmotion.core.collapse` returns them: the divergence
  is measured per window (1/s times the window duration, the normalized time of (3.7)), so
  the thesis' margins and weights apply unchanged and the penalty does not depend on the
  time unit;
* the RCAD penalty enters one-sided, ``max(R, 0)``: (3.21) is negative for expanding warps
  and would otherwise reward them (the RCAD map variant is thresholded for the same reason).
  The thesis' intent is a barrier against contraction (collapse); expansion is not collapse.

Every result is checked (:mod:`evmotion.methods.diagnostics`): ``collapsed`` and
``diagnostics`` report event collapse (area amplification of the warp, displacement beyond
the sensor, IWE concentrated on few pixels) and how much of the image the warp explains
(per-tile sharpness against each tile's own best translation), with a
:class:`~evmotion.errors.CollapseWarning` or :class:`~evmotion.errors.PoorFitWarning`
that names the cure.

The gradient is exact: chain rule through the warp Jacobian (numba), the IWE adjoint and the
objective (:class:`CMaxCost`). ``regularizer="whitening"`` instead whitens the warped events
before the objective (the baseline of Tables 3.1/3.2).

Examples
--------
>>> import numpy as np
>>> from evmotion.events import EventArray
>>> rng = np.random.default_rng(0)
>>> dots = rng.uniform(10, 60, (200, 2))           # a scene of 200 dots ...
>>> k = rng.integers(0, 200, 6000)
>>> t = np.sort(rng.integers(0, 50_000, 6000))     # ... moving right at 400 px/s
>>> ev = EventArray(dots[k, 0] + 400.0 * t * 1e-6, dots[k, 1], t, np.ones(6000, int),
...                 sensor_size=(80, 128), validate=False)
>>> res = estimate_egomotion(ev, warp="translation")
>>> np.round(res.params, -1).tolist()  # image velocity, px/s
[400.0, 0.0]
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field, replace

import numpy as np

from evmotion.core.collapse import regularizer_maps
from evmotion.core.objectives import OBJECTIVES
from evmotion.core.optim import OptimResult, landscape, minimize
from evmotion.core.warps import Warp
from evmotion.errors import EvmotionWarning, ParameterError
from evmotion.events import EventArray, require_events
from evmotion.jitcache import compile_seconds
from evmotion.methods.cmax import (
    COMBINED_REGULARIZERS,
    REGULARIZER_CHOICES,
    CMaxCost,
    default_bounds,
    make_cost,
    param_scales,
)
from evmotion.methods.diagnostics import (
    MIN_CONTRAST_GAIN,
    POOR_FIT_SHARE,
    collapse_diagnostics,
    fit_diagnostics,
    image_variance,
    unchecked_fit,
    warn_collapse,
    warn_no_gain,
    warn_poor_fit,
    warn_too_few,
)
from evmotion.methods.measured import (
    MAX_GAP_SHARE,
    gap_share,
    min_motion_px,
    warn_by_chance,
    warn_gap,
    warn_small_motion,
    warp_alignment_chance,
)
from evmotion.methods.options import merge_options
from evmotion.utils import is_finite_number

__all__ = [
    "COMBINED_REGULARIZERS",
    "REGULARIZER_CHOICES",
    "CMaxCost",
    "EgomotionOptions",
    "EgomotionResult",
    "cost_landscape",
    "landscape_verdict",
    "default_bounds",
    "estimate_egomotion",
    "make_cost",
    "reference_time",
]

#: BFGS restarts for the average-timestamp objectives, whose kinks (a ratio of event
#: images; a count of active pixels) stop a run far from the minimum: on a simulated
#: rotation (0.5, -0.7, 1.2 rad/s) BFGS stopped at wz 0.15 (and -0.005 with the
#: normalized loss) with a large gradient; restarted, 1.08 and 1.21.
TIMESTAMP_RESTARTS = 5


@dataclass(frozen=True)
class EgomotionResult:
    """Outcome of :func:`estimate_egomotion`.

    Attributes
    ----------
    params : ndarray (P,)
        Estimated warp parameters (rates per second, see ``param_units``).
    param_names, param_units : tuple of str
    warp : str
    objective, optimizer : str
    regularizer : str or None
    weight : float or dict
        ``lambda`` used (per term for ``"divergence+deformation"``).
    t_ref_us : int
        Reference time of the warp (µs, absolute).
    window_us : (int, int)
        First and last event time (µs).
    n_events : int
    cost, focus, penalty : float
        ``J``, ``G/G0`` and ``lambda R`` at ``params``.
    iwe_before, iwe_after : ndarray (H, W) or None
        IWE with the identity warp and with ``params``; None where a caller dropped them
        (``evmotion egomotion`` keeps them only for the windows it draws a PNG panel of).
    history : ndarray
        Cost per optimizer iteration.
    maps : dict of ndarray
        Divergence (DIWE) and deformation (IWA) maps at ``params`` for plotting.
    timings : dict
        Seconds: ``setup``, ``optimize``, ``diagnose``, ``total`` (wall), ``compile`` (of
        it, numba's first-use compilation of kernels:
        :func:`evmotion.jitcache.compile_seconds`), ``estimate`` (``total - compile``);
        ``n_evals``.
    collapsed : bool
        The estimate shows event collapse (see ``diagnostics["collapse"]``); it is not a
        measurement.
    diagnostics : dict
        ``"collapse"`` (:func:`evmotion.methods.diagnostics.collapse_diagnostics`),
        ``"fit"`` (:func:`evmotion.methods.diagnostics.fit_diagnostics`: ``explained_share``
        of the image, per tile), ``"contrast_gain"`` (variance of the IWE at the estimate
        over that at the identity warp), ``"weight_source"`` (``"window"``, ``"given"`` or
        the data set) and ``"warnings"`` (the messages issued); empty with
        ``diagnose=False``.
    poor_fit : bool
        (property) The warp explains too little of the image (or no tile holds enough
        events to test it), sharpens it by less than
        :data:`~evmotion.methods.measured.MIN_CONTRAST_GAIN`, the window holds too few
        events for its contrast to mean anything, or a time gap without events longer
        than :data:`~evmotion.methods.measured.MAX_GAP_SHARE` of it (False when not
        diagnosed).
    valid : bool
        (property) A measurement: not collapsed, not a poor fit, finite parameters.
    """

    params: np.ndarray
    param_names: tuple[str, ...]
    param_units: tuple[str, ...]
    warp: str
    objective: str
    regularizer: str | None
    weight: float | dict
    optimizer: str
    t_ref_us: int
    window_us: tuple[int, int]
    n_events: int
    cost: float
    focus: float
    penalty: float
    iwe_before: np.ndarray | None = field(repr=False)
    iwe_after: np.ndarray | None = field(repr=False)
    history: np.ndarray = field(repr=False)
    maps: dict = field(repr=False, default_factory=dict)
    timings: dict = field(default_factory=dict)
    collapsed: bool = False
    diagnostics: dict = field(default_factory=dict)

    @property
    def poor_fit(self) -> bool:
        d = self.diagnostics
        share = float(d.get("fit", {}).get("explained_share", np.nan))
        gain = float(d.get("contrast_gain", np.nan))
        # not diagnosed, or collapsed (said by itself): not a poor fit; a fit test that ran
        # and found nothing to test is one (too few events)
        return bool(share < POOR_FIT_SHARE or gain < MIN_CONTRAST_GAIN
                    or unchecked_fit(d.get("fit", {})) or d.get("too_few_events", False)
                    or float(d.get("motion_px", np.inf)) < min_motion_px(self.warp)
                    or float(d.get("chance_gain", np.inf)) < MIN_CONTRAST_GAIN
                    or float(d.get("gap_share", 0.0)) > MAX_GAP_SHARE)

    @property
    def valid(self) -> bool:
        return bool(not self.collapsed and not self.poor_fit
                    and np.isfinite(self.params).all())

    def as_dict(self) -> dict:
        """JSON-friendly summary: parameters with names and units, cost, timings, and the
        verdict (``valid``, ``poor_fit``)."""
        return {
            "warp": self.warp,
            "params": {n: float(v) for n, v in zip(self.param_names, self.params, strict=True)},
            "units": dict(zip(self.param_names, self.param_units, strict=True)),
            "objective": self.objective, "regularizer": self.regularizer,
            "weight": self.weight, "optimizer": self.optimizer,
            "t_ref_us": self.t_ref_us, "t0_us": self.window_us[0], "t1_us": self.window_us[1],
            "n_events": self.n_events, "cost": self.cost, "focus": self.focus,
            "penalty": self.penalty, "timings": dict(self.timings),
            "collapsed": self.collapsed, "poor_fit": self.poor_fit, "valid": self.valid,
            "diagnostics": _summary_diagnostics(self.diagnostics),
        }


def _summary_diagnostics(diag: dict) -> dict:
    """The diagnostics of a result without the per-tile rows (for JSON and tables)."""
    out = dict(diag)
    if "fit" in out:
        out["fit"] = {k: v for k, v in out["fit"].items() if k != "tile_support"}
    return out


@dataclass(frozen=True)
class EgomotionOptions:
    """Tuning of :func:`estimate_egomotion`, as one object (every field is also a keyword of
    the function, with the same default).

    Attributes
    ----------
    objective : str
        Focus objective: ``"variance"``, ``"gradient_magnitude"``, ``"avg_timestamp"`` or
        ``"avg_timestamp_norm"`` (dimensionless after division by its value at the
        identity warp).
    regularizer : {None, "divergence", "deformation", "rcad", "whitening", \
"divergence+deformation"}
        Event-collapse penalty (or the whitening baseline); None: none.
    weight : float or mapping, optional
        ``lambda`` (dimensionless, the penalty is per window); None: derived from the
        window, or the thesis' for ``dataset``.
    optimizer : {"bfgs", "newton-cg", "adam", "tpe"}
    t_ref : {"start", "mid", "end"} or int or None
        Reference time of the warp; an int is absolute, µs. None:
        :func:`reference_time`.
    seed : int
        Seed of the TPE sampler.
    starts : list of arrays, optional
        Extra starting points (multi-start), each (P,) in the warp's parameter units.
    bounds : (lower, upper), optional
        TPE search box, each (P,) in the warp's parameter units.
    n_samples : int, optional
        TPE samples (None: 300 for 1 DOF, 600 otherwise).
    n_iter : int
        Adam iterations.
    lr : float
        Adam step, in units of the parameter scale.
    kernel : {"bilinear", "gaussian"}
        IWE delta approximation.
    sigma : float
        Gaussian standard deviation, px.
    use_polarity : bool
        Signed IWE.
    dataset : {None, "mvsec", "dsec", "ecd"}
        Use the thesis' weights of this data set (Sec. 3.6.1).
    maps : bool
        Compute the divergence/deformation maps at the estimate.
    diagnose : bool
        Check the estimate for collapse and model fit (about 0.1 s per 30k events).

    Examples
    --------
    >>> opts = EgomotionOptions(regularizer="divergence", dataset="dsec")
    >>> opts.optimizer
    'bfgs'
    """

    objective: str = "variance"
    regularizer: str | None = None
    weight: float | dict | None = None
    optimizer: str = "bfgs"
    t_ref: str | int | None = None
    seed: int = 0
    starts: list | None = None
    bounds: tuple | None = None
    n_samples: int | None = None
    n_iter: int = 100
    lr: float = 0.05
    kernel: str = "bilinear"
    sigma: float = 1.0
    use_polarity: bool = False
    dataset: str | None = None
    maps: bool = True
    diagnose: bool = True

    def __post_init__(self):
        def whole(name, lo, allow_none=False):
            v = getattr(self, name)
            if v is None and allow_none:
                return
            if not (isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= lo):
                raise ParameterError(f"{name} must be an integer >= {lo}, got {v!r}")

        whole("n_iter", 1)
        whole("seed", 0)
        whole("n_samples", 1, allow_none=True)
        for name in ("lr", "sigma"):
            v = getattr(self, name)
            if not (is_finite_number(v) and v > 0):
                raise ParameterError(f"{name} must be a finite number > 0, got {v!r}")
        # an option of another optimizer or kernel changed nothing, without a word
        # (n_iter=5 and sigma=3.0 under the bfgs / bilinear defaults, probe CB)
        for name, default, needs, what in (("n_iter", 100, "adam", "optimizer"),
                                           ("lr", 0.05, "adam", "optimizer"),
                                           ("n_samples", None, "tpe", "optimizer"),
                                           ("bounds", None, "tpe", "optimizer"),
                                           ("sigma", 1.0, "gaussian", "kernel")):
            v = getattr(self, name)
            changed = v is not None if default is None else v != default
            if getattr(self, what) != needs and changed:
                raise ParameterError(f"{name}={v!r} applies to {what}={needs!r} only "
                                     f"({what} is {getattr(self, what)!r})")


def _checked_bounds(bounds, w: Warp) -> tuple[np.ndarray, np.ndarray]:
    """``bounds`` as (lower, upper) arrays of the warp's parameters, or ParameterError."""
    try:
        lo, hi = (np.asarray(b, float) for b in bounds)
    except (TypeError, ValueError):
        raise ParameterError(f"bounds must be (lower, upper), each {w.n_params} numbers "
                             f"{w.param_names}, got {bounds!r}") from None
    if lo.shape != (w.n_params,) or hi.shape != (w.n_params,):
        raise ParameterError(f"bounds must be (lower, upper), each {w.n_params} numbers "
                             f"{w.param_names}, got shapes {lo.shape} and {hi.shape}")
    if not (np.isfinite(lo).all() and np.isfinite(hi).all() and np.all(lo < hi)):
        raise ParameterError(f"bounds must be finite with lower < upper, got {bounds!r}")
    return lo, hi


def reference_time(t_ref: str | int | None, regularizer: str | None,
                   t_first: int | None = None) -> str | int:
    """The warp's reference time of an estimate: ``t_ref``, or by default ``"mid"``
    (``"start"`` with a collapse ``regularizer``, whose penalties are defined for it;
    another time with one is warned about; ``t_first``, the window's first event time in
    µs, is the start too).

    Examples
    --------
    >>> reference_time(None, None), reference_time(None, "divergence")
    ('mid', 'start')
    """
    if t_ref is None:
        return "start" if regularizer else "mid"
    if isinstance(t_ref, str):
        at_start = t_ref == "start"
    else:
        # (NaN, inf or a list failed here in int(): ValueError, OverflowError, TypeError;
        # the window's check refuses them in a line, probe DB)
        try:
            at_start = t_first is not None and int(t_ref) == int(t_first)
        except (TypeError, ValueError, OverflowError):
            at_start = False
    if regularizer and not at_start:
        warnings.warn(EvmotionWarning(
            f"t_ref={t_ref!r} with the {regularizer} regularizer: the collapse penalties are "
            "defined for a warp referenced at the window's start; after it, the parts of "
            "the window before and after penalize opposite motions and partly cancel (a "
            "zoom collapsed with a divergence penalty of 0): t_ref='start', the default "
            "with a regularizer, is the safe choice"), stacklevel=3)
    return t_ref


def estimate_egomotion(events: EventArray, warp: str | Warp = "rotation",
                       objective: str = "variance", regularizer: str | None = None,
                       weight: float | None = None, optimizer: str = "bfgs", K=None,
                       t_ref: str | int | None = None, init=None, seed: int = 0, *,
                       starts=None, bounds=None, n_samples: int | None = None,
                       n_iter: int = 100, lr: float = 0.05, kernel: str = "bilinear",
                       sigma: float = 1.0, use_polarity: bool = False,
                       dataset: str | None = None, maps: bool = True,
                       diagnose: bool = True,
                       options: EgomotionOptions | None = None) -> EgomotionResult:
    """Estimate the warp parameters of one window by contrast maximization (ch. 3).

    Parameters
    ----------
    events : EventArray
        One window; undistorted coordinates for the rotation warp (see
        :meth:`evmotion.camera.Camera.undistort_events`).
    warp : str or Warp
        Warp name (:data:`evmotion.core.warps.WARPS`) or a built warp.
    objective : str
        ``"variance"``, ``"gradient_magnitude"``, ``"avg_timestamp"`` or
        ``"avg_timestamp_norm"``.
    regularizer : {None, "divergence", "deformation", "rcad", "whitening", \
"divergence+deformation"}
        ``"divergence+deformation"`` is the sum of both penalties (the thesis' "Div. + Def.").
    weight : float or mapping, optional
        ``lambda``; default derived from the window
        (:func:`evmotion.methods.weights.window_weight`), or the thesis' (Sec. 3.6.1) for a
        named ``dataset``. For ``"divergence+deformation"``: ``{"divergence": ...,
        "deformation": ...}`` or one float for both.
    optimizer : {"bfgs", "newton-cg", "adam", "tpe"}
    K : array (3, 3) or Camera, optional
        Intrinsics (pixels), required by ``rotation`` unless ``events.meta`` holds them
        (``"K"``, or the ``"calibration"`` a reader took from the recording).
    t_ref : {"start", "mid", "end"} or int, optional
        Reference time of the warp; an int is absolute µs, within the window's span (or
        1 s if longer) of its events (:func:`evmotion.events.check_reference_time`; a time
        farther away is another window's, and warped every event off the sensor). Default
        ``"mid"`` (the more
        accurate: ``benchmarks/results/egomotion_tref.md``), and ``"start"`` with a
        ``regularizer``, whose collapse penalties are defined for it (at the middle the
        halves of the window penalize opposite motions and cancel: a zoom collapsed with a
        divergence penalty of 0); another time with one is warned about.
    init : array (P,), optional
        Starting parameters (default: identity warp).
    seed : int
        Seed of the TPE sampler.
    starts : list of arrays, optional
        Extra starting points (multi-start) for gradient methods.
    bounds : (lower, upper), optional
        TPE search box; default :func:`default_bounds`.
    n_samples : int, optional
        TPE samples (300 for 1 DOF, 600 otherwise).
    n_iter, lr : Adam iterations (100) and step (in units of the parameter scale).
    kernel : {"bilinear", "gaussian"}
        IWE delta approximation, the same whatever the dtype of the events (default
        bilinear, the fast fused path). Bilinear votes events that all lie on the integer
        pixel grid spread over their pixel (:func:`evmotion.core.iwe.dequantize`;
        deterministic); Gaussian (``sigma`` px) is smooth without it, about 10x slower.
        The kernel's width biases scale rates: on simulated forward motion the zoom came
        out 3.5 % (variance) and 2.5 % (gradient magnitude) low with bilinear, within 1 %
        with Gaussian, at 14x the time (``benchmarks/results/zoom_kernel.md``); on the
        ECD windows the similarity's larger translation components differed by 0-10 %
        between the two (``egomotion_real.md``).
    sigma : float
        Gaussian standard deviation in px (default 1).
    use_polarity : bool
        Signed IWE.
    dataset : {None, "mvsec", "dsec", "ecd"}
        Use the thesis' weights of this data set instead of the window's (default None).
    maps : bool
        Compute the divergence/deformation maps at the estimate.
    diagnose : bool
        Check the estimate for collapse and model fit (``collapsed``, ``diagnostics``;
        warnings :class:`~evmotion.errors.CollapseWarning`,
        :class:`~evmotion.errors.PoorFitWarning`); about 0.1 s per 30k-event window.
    options : EgomotionOptions, optional
        All of the above but ``events``, ``warp``, ``K`` and ``init`` as one object; the
        keywords must then be left at their defaults.

    Returns
    -------
    EgomotionResult

    Examples
    --------
    See the module docstring.
    """
    require_events(events, "estimate_egomotion")
    o = merge_options(EgomotionOptions, options, objective=objective, regularizer=regularizer,
                      weight=weight, optimizer=optimizer, t_ref=t_ref, seed=seed,
                      starts=starts, bounds=bounds, n_samples=n_samples, n_iter=n_iter, lr=lr,
                      kernel=kernel, sigma=sigma, use_polarity=use_polarity, dataset=dataset,
                      maps=maps, diagnose=diagnose)
    if o.regularizer is None and o.weight not in (None, 0, 0.0):
        raise ParameterError(f"weight={o.weight!r} weighs a regularizer, but regularizer is "
                             "None: give regularizer= too (or leave weight out)")
    o = replace(o, t_ref=reference_time(o.t_ref, o.regularizer,
                                        int(events.t[0]) if len(events) else None))
    c0 = compile_seconds()
    t0 = time.perf_counter()
    cost, t_ref_us = make_cost(events, warp, o.objective, o.regularizer, o.weight, K, o.t_ref,
                               o.kernel, o.sigma, o.use_polarity, o.dataset)
    w = cost.warp
    try:
        x0 = w.identity() if init is None else np.asarray(init, dtype=np.float64)
    except (TypeError, ValueError):
        raise ParameterError(f"init must be {w.n_params} numbers {w.param_names}, "
                             f"got {init!r}") from None
    if x0.shape == (w.n_params,) and not np.isfinite(x0).all():
        raise ParameterError(f"init must be finite, got {init!r}")
    if x0.shape != (w.n_params,):
        raise ParameterError(f"init must have shape ({w.n_params},) {w.param_names}, "
                             f"got {x0.shape}")
    lo, hi = default_bounds(w) if o.bounds is None else _checked_bounds(o.bounds, w)
    t1 = time.perf_counter()
    search = dict(lower=lo, upper=hi, scale=param_scales(w), starts=o.starts,
                  n_samples=o.n_samples, n_iter=o.n_iter, lr=o.lr, seed=o.seed,
                  restarts=TIMESTAMP_RESTARTS if OBJECTIVES[o.objective].needs_time else 0)
    res: OptimResult = minimize(cost.value_grad, x0, o.optimizer, **search)
    if o.optimizer == "tpe":
        res = _polished(cost, res, param_scales(w))
    elif o.regularizer is not None and np.array_equal(res.x, x0):
        res = _from_plain_optimum(events, warp, K, o, cost, res, x0, search)
    t2 = time.perf_counter()
    theta = res.x
    parts = cost.parts(theta)
    out_maps = {}
    if o.maps:
        for name, key in (("divergence", "diwe"), ("deformation", "iwa")):
            m = regularizer_maps(name, w, cost.x, cost.y, cost.dt, theta, cost.shape)
            out_maps[key] = m[key]
    iwe_before, iwe_after = cost.iwe_at(w.identity()), cost.iwe_at(theta)
    t3 = time.perf_counter()
    source = "given" if o.weight is not None else (o.dataset or "window")
    diagnostics = (_diagnose(cost, theta, iwe_before, iwe_after, o.regularizer, source,
                             o.optimizer)
                   if o.diagnose else {})
    t4 = time.perf_counter()
    total = t4 - t0
    # numba's first-use compilation is not the estimate's time: reported apart
    compiled = compile_seconds() - c0
    timings = {"setup": t1 - t0, "optimize": t2 - t1, "diagnose": t4 - t3, "total": total,
               "compile": compiled, "estimate": total - compiled, "n_evals": res.n_evals}
    return EgomotionResult(
        params=theta.copy(), param_names=tuple(w.param_names), param_units=tuple(w.param_units),
        warp=w.name, objective=o.objective, regularizer=o.regularizer,
        weight=cost.weight if o.regularizer else 0.0,
        optimizer=o.optimizer, t_ref_us=t_ref_us,
        window_us=(int(events.t[0]), int(events.t[-1])), n_events=len(events),
        cost=parts["cost"], focus=parts["focus"], penalty=parts["penalty"],
        iwe_before=iwe_before, iwe_after=iwe_after,
        history=res.history, maps=out_maps, timings=timings,
        collapsed=bool(diagnostics.get("collapse", {}).get("collapsed", False)),
        diagnostics=diagnostics)


def _from_plain_optimum(events, warp, K, o: EgomotionOptions, cost: CMaxCost,
                        res: OptimResult, x0: np.ndarray, search: dict) -> OptimResult:
    """A regularized estimate that never left its start, started again from the plain
    (unregularized) optimum, both searched as the first was (``search``: the keywords of
    :func:`~evmotion.core.optim.minimize`); the lower regularized cost is kept. At the
    identity the divergence and deformation penalties can leave the optimizer no slope to
    follow: on a forward motion (hz 2.0 1/s) ``--reg divergence`` returned hz = 0.000 at
    cost -1.00 in 2 of 5 windows, where its own cost at the plain optimum was -1.97 (probe
    AH). Where the plain optimum collapsed, the penalty there keeps the first answer."""
    plain, _ = make_cost(events, warp, o.objective, None, None, K, o.t_ref, o.kernel,
                         o.sigma, o.use_polarity, o.dataset)
    start = minimize(plain.value_grad, x0, o.optimizer, **search).x
    again = minimize(cost.value_grad, start, o.optimizer, **search)
    return again if again.fun < res.fun else res


def _polished(cost: CMaxCost, res: OptimResult, scale: np.ndarray) -> OptimResult:
    """TPE's best sample refined by BFGS from there. The samples find the basin but not
    its bottom: 600 of them in a 3-DOF box left a rotation 1 rad/s off its optimum
    (wz 2.57 for 1.5 on a rendered scene), marked valid."""
    from evmotion.core.optim import gradient_minimize

    local = gradient_minimize(cost.value_grad, res.x, method="bfgs", scale=scale)
    best = local if local.fun < res.fun else res
    return replace(res, x=best.x, fun=best.fun,
                   history=np.concatenate([res.history, local.history]),
                   n_evals=res.n_evals + local.n_evals, seconds=res.seconds + local.seconds)


def _diagnose(cost: CMaxCost, theta, iwe_before, iwe_after, regularizer, weight_source,
              optimizer: str = "") -> dict:
    """Collapse and fit checks of an estimate (:mod:`evmotion.methods.diagnostics`); issues
    their warnings (pointing at the caller of :func:`estimate_egomotion`)."""
    w = cost.warp
    coll = collapse_diagnostics(w, theta, cost.span, iwe_before, iwe_after)
    msgs = [warn_collapse(coll, regularizer, cost.weight, stacklevel=4)]
    if coll["collapsed"]:
        # a collapsed estimate explains nothing; the tile test would only repeat it
        fit, moved, chance = {}, float("nan"), float("nan")
    else:
        with np.errstate(all="ignore"):
            xw, yw = w.warp(cost.x, cost.y, cost.dt, theta)
        fit = fit_diagnostics(cost.x, cost.y, cost.dt, xw, yw, cost.shape)
        msgs.append(warn_poor_fit(fit, w.name, stacklevel=4))
        moved = _moved_px(cost, xw, yw)
        # how much better the warp aligns the events than the same per-event motions with
        # the times permuted: an estimate that fits the window's own event clusters
        # instead of its motion (real ECD windows of 10k events, about a pixel of motion:
        # twice the IMU rate, valid) sharpens them as well with the times shuffled
        chance = warp_alignment_chance(cost.x, cost.y, cost.dt, xw, yw, cost.shape,
                                       draws=1)[0]
    # (from the images' non-zero pixels: np.var passed over the whole sensor, probe DB)
    v0 = image_variance(iwe_before)
    gain = image_variance(iwe_after) / v0 if v0 > 0 else float("nan")
    too_few = warn_too_few(int(cost.x.shape[0]), f"{w.name} motion", stacklevel=4)
    msgs.append(too_few)
    t_us = np.sort(cost.dt) * 1e6
    gap = gap_share(t_us)
    msgs.append(warn_gap(t_us, f"{w.name} warp", stacklevel=4))
    if not coll["collapsed"] and too_few is None:
        hint = "" if optimizer == "tpe" else " (--optimizer tpe searches the whole box)"
        if regularizer is not None:
            # its penalty can hold the estimate at the identity (probe AH: divergence on a
            # forward motion, cost -1.00 at hz = 0 against -0.37 at its own optimum 2.52,
            # where the plain warp finds 2.92)
            hint += (f", or the {regularizer} regularizer holding the warp at rest (try "
                     "without it, or a lower --weight)")
        no_gain = warn_no_gain(gain, w.name, stacklevel=4, optimum_hint=hint)
        msgs.append(no_gain)
        if no_gain is None:  # (no focus says it already)
            small = warn_small_motion(moved, w.name, stacklevel=4)
            msgs.append(small)
            if small is None:
                msgs.append(warn_by_chance(chance, f"{w.name} warp", stacklevel=4))
    return {"collapse": coll, "fit": fit, "contrast_gain": gain, "motion_px": moved,
            "chance_gain": chance, "gap_share": gap,
            "too_few_events": too_few is not None,
            "weight_source": weight_source, "warnings": [m for m in msgs if m]}


def _moved_px(cost: CMaxCost, xw, yw) -> float:
    """Median over the events of how far the estimate moves each over the whole window,
    px: its displacement to ``t_ref`` scaled from its own time offset to the window's
    duration (events at ``t_ref`` itself carry no rate and are left out)."""
    span = cost.span[1] - cost.span[0]
    dt = np.abs(cost.dt)
    keep = dt > 1e-3 * span
    if span <= 0 or not keep.any():
        return 0.0
    d = np.hypot(xw[keep] - cost.x[keep], yw[keep] - cost.y[keep])
    return float(np.median(d / dt[keep]) * span)


def landscape_verdict(values, cost, focus, objective: str = "variance") -> dict:
    """What a scanned landscape (:func:`cost_landscape`) measures: ``minimum`` (the value
    where ``cost`` is lowest), ``at_edge`` (it lies on the range's edge: the true one may
    lie beyond), ``best_gain`` (the highest focus G/G0 over the range; for the
    average-timestamp ``objective``, whose G/G0 is minus the loss over the identity
    warp's, that loss over the best one) and ``flat`` (no value sharpens the events by
    :data:`~evmotion.methods.measured.MIN_CONTRAST_GAIN`: the minimum is no measurement).

    Examples
    --------
    >>> v = landscape_verdict([0.0, 1.0, 2.0], [-1.0, -1.5, -1.2], [1.0, 1.5, 1.2])
    >>> v["minimum"], v["at_edge"], v["flat"]
    (1.0, False, False)
    """
    values, cost = np.asarray(values, float), np.asarray(cost, float)
    focus = np.asarray(focus, float)
    i = int(np.argmin(cost))
    if OBJECTIVES[objective].needs_time:
        loss = -focus[focus < 0]  # 1 at the identity warp, lower where sharper
        gain = float(np.max(1.0 / loss)) if loss.size else float("nan")
    else:
        gain = float(np.max(focus)) if len(focus) else float("nan")
    return {"minimum": float(values[i]), "at_edge": i in (0, len(values) - 1),
            "best_gain": gain, "flat": not gain >= MIN_CONTRAST_GAIN}


def cost_landscape(events: EventArray, warp: str | Warp, param: int, values,
                   theta=None, objective: str = "variance", regularizer: str | None = None,
                   weight: float | None = None, K=None, t_ref: str | int = "start",
                   dataset: str | None = None) -> dict[str, np.ndarray]:
    """Scan one parameter (Fig. 3.12): cost, focus and penalty along ``values``.

    Parameters
    ----------
    events : EventArray
    warp : str or Warp
    param : int
        Index of the scanned parameter.
    values : array (S,)
        Its values (units of that parameter).
    theta : array (P,), optional
        Values of the other parameters (default identity).
    objective, regularizer, weight, K, t_ref, dataset
        As in :func:`estimate_egomotion`.

    Returns
    -------
    dict with ``values``, ``cost``, ``focus`` (G/G0) and ``penalty`` (lambda R), each (S,).

    Examples
    --------
    >>> ev = EventArray([1, 2, 3], [1, 1, 2], [0, 10, 20], [1, 0, 1], sensor_size=(4, 5))
    >>> cost_landscape(ev, "translation", 0, [0.0, 10.0])["cost"].shape
    (2,)
    """
    cost, _ = make_cost(events, warp, objective, regularizer, weight, K, t_ref,
                        dataset=dataset)
    base = cost.warp.identity() if theta is None else np.asarray(theta, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    # a scan far past any motion a window holds (--range 0 1e300) overflows the warp:
    # its cost is not finite there, which the verdict reads, not numpy's warning with
    # its source line (probe CE)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        rows = [cost.parts(np.where(np.arange(base.size) == param, v, base)) for v in values]
        curve = landscape(cost.value, base, param, values)
    focus = np.array([r["focus"] for r in rows])
    pen = np.array([r["penalty"] for r in rows])
    return {"values": values, "cost": curve, "focus": focus, "penalty": pen}
