"""Event-collapse regularizers of ch. 3 (3.6): divergence, deformation, RCAD.

The augmented objective is ``J(theta) = -G(theta) + lambda R(theta)`` (3.6). Every
regularizer here is a *penalty*: larger means more collapse. The thesis' statistics are
signed so that collapse gives small values (negative divergence, area amplification below
one); the penalties negate them:

* ``"divergence"`` -- per-event divergence of the warp flow (3.9) measured per window
  (``div f`` in 1/s times the window duration ``T = max dt - min dt``: the thesis'
  normalized time, so that its margin and weights apply unchanged), averaged per pixel into
  the DIWE map (3.11) (bilinear votes of the warped events, empty pixels 0); the penalty is
  minus the trimmed mean (3.12) of the DIWE pixels below ``alpha = -0.2`` (0 when none).
* ``"deformation"`` -- per-event area amplification ``|det J|`` (3.14), averaged per pixel
  into the IWA map (3.16) (empty pixels 1); the penalty is the mean of ``1 - IWA`` over the
  pixels with ``IWA < 0.8`` (the trimmed mean (3.17), negated and shifted).
* ``"rcad"`` -- the rate of change of area deformation integrated over the window's time
  span ``[min dt, max dt]`` (see :meth:`evmotion.core.warps.Warp.area_log_ratio`):
  the closed form (3.21) for the zoom, the scaling DOF for the similarity (A.44) and the
  in-plane warp (its ``h_z``, as the thesis prescribes), (A.53) for the affine warp, zero
  for translation and SE(2); for the rotation and the homography the (3.28)/(A.6) map over
  a pixel grid, penalized as the mean of the map values above ``0.2`` (the thesis
  thresholds the sign-flipped map at -0.2). It needs no event accumulation: O(1), or
  O(pixels / stride^2) for the map.

Each returns its value and analytic gradient with respect to theta
(:func:`regularizer_value_grad`) and its maps for plotting (:func:`regularizer_maps`). The
trimmed means are piecewise smooth: the gradient is that of the current piece (the set of
pixels below the margin held fixed).

Cost (what CMax pays per evaluation on top of its data term; ``benchmarks/bench_regularizers``):

* the per-event values come first (closed forms, or for the rotation one vectorized pass
  from the warped pixels); when none is below the margin no pixel mean can be, and the
  penalty is 0 without building any map -- the usual case away from collapse;
* otherwise one pass votes the count image (``count=`` reuses a caller's) and marks the
  tiles of the events below the margin, the image of values is voted only around them
  (the blocks of events that reach those tiles; both images in one pass where most
  values are below: :mod:`evmotion.core.trim`), one pass trims them into their padded
  adjoint images, and the gradient takes one pass over the events with no per-event
  output, so that it vectorizes: :meth:`~evmotion.core.warps.Warp.reduce_pair` chains
  the votes' adjoint through the warp (its Jacobian recomputed, never stored) and the
  values' own derivatives (closed forms; for the rotation from the warped point) with the
  same gathered pixels,
  the values' image gathered only in the flagged blocks (the rotation). CMax
  (:class:`evmotion.methods.cmax.CMaxCost`) votes the count image as its IWE and folds
  the penalty's adjoint images into its data term's, so that that one pass chains both
  (:func:`~evmotion.core.collapse.trimmed.trimmed_parts`). Warps without fused adjoints
  (or given ``jx, jy``) chain per-event derivatives through the stored Jacobians;
* RCAD maps test their threshold on the area ratio, without logarithms, sum the selected
  values as the logarithm of a product and their gradients as three sums contracted once
  (:mod:`~evmotion.core.collapse.rcad`); ``span=(min dt, max dt)`` spares the pass over
  the times when the caller knows them.

Layout: :mod:`~evmotion.core.collapse.values` (per-event values),
:mod:`~evmotion.core.collapse.trimmed` (DIWE/IWA trimmed means),
:mod:`~evmotion.core.collapse.rcad`, and the public API here. Whitening, the baseline the
thesis compares with, is not a penalty: :mod:`evmotion.core.whitening`.

"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evmotion.core.collapse.rcad import rcad_closed_form, rcad_value_grad
from evmotion.core.collapse.trimmed import (
    MIN_COUNT,
    chains_pair,
    pixel_average,
    trimmed_value_grad,
)
from evmotion.core.collapse.values import PenaltyEvents, time_span, window_span
from evmotion.core.warps import Warp
from evmotion.errors import ParameterError
from evmotion.geometry import sensor_shape

__all__ = [
    "DEFAULT_MARGINS",
    "DEFAULT_WEIGHTS",
    "RCAD_STRIDE",
    "PenaltyEvents",
    "PenaltyOptions",
    "REGULARIZERS",
    "chains_pair",
    "window_span",
    "regularizer_maps",
    "regularizer_value_grad",
]

#: Regularizer weights lambda of (3.6) per data set (Sec. 3.6.1). The thesis gives no
#: rcad weight for ECD (rotation, a well-posed warp); the DSEC value is used there.
DEFAULT_WEIGHTS: dict[str, dict[str, float]] = {
    "mvsec": {"divergence": 2.0, "deformation": 5.0, "rcad": 0.2},
    "dsec": {"divergence": 50.0, "deformation": 100.0, "rcad": 1.0},
    "ecd": {"divergence": 5.0, "deformation": 10.0, "rcad": 1.0},
}


#: Pixel stride of the RCAD map's grid (rotation, homography).
RCAD_STRIDE = 8


#: Margins of the trimmed means (Sec. 3.4): DIWE < -0.2, IWA < 0.8, RCAD map > 0.2.
DEFAULT_MARGINS: dict[str, float] = {"divergence": -0.2, "deformation": 0.8, "rcad": 0.2}


def _check_kernel(kernel):
    if kernel != "bilinear":
        raise ParameterError(f"the DIWE/IWA maps use bilinear votes (kernel='bilinear'), "
                             f"got kernel={kernel!r}")


@dataclass(frozen=True)
class PenaltyOptions:
    """Settings of a collapse penalty (:func:`regularizer_value_grad`).

    Attributes
    ----------
    margin : float, optional
        Trimming margin; None: :data:`DEFAULT_MARGINS` of the penalty.
    kernel : {"bilinear"}
        Vote kernel of the DIWE/IWA maps (the bilinear votes of core.iwe, fused here into
        one forward and one adjoint pass).
    stride : int
        Pixel stride of the RCAD map grid (rotation, homography).

    Examples
    --------
    >>> PenaltyOptions(margin=-0.5).margin_of("divergence")
    -0.5
    >>> PenaltyOptions().margin_of("rcad")
    0.2
    """

    margin: float | None = None
    kernel: str = "bilinear"
    stride: int = RCAD_STRIDE

    def __post_init__(self):
        _check_kernel(self.kernel)

    def margin_of(self, name: str) -> float:
        """The margin of penalty ``name``: ``margin``, or its default."""
        return DEFAULT_MARGINS[name] if self.margin is None else float(self.margin)


def _divergence(warp, ev, theta, shape, options, grad):
    return trimmed_value_grad("divergence", warp, ev, theta, shape,
                              options.margin_of("divergence"), grad)


def _deformation(warp, ev, theta, shape, options, grad):
    return trimmed_value_grad("deformation", warp, ev, theta, shape,
                              options.margin_of("deformation"), grad)


def _rcad(warp, ev, theta, shape, options, grad):
    return rcad_value_grad(warp, ev.x, ev.y, ev.dt, theta, shape, options.margin_of("rcad"),
                           int(options.stride), grad, ev.span)


_DEFAULT_OPTIONS = PenaltyOptions()


#: Name -> function(warp, events (:class:`PenaltyEvents`), theta, shape, options
#: (:class:`PenaltyOptions`), grad) -> (value, grad (P,)).
REGULARIZERS = {"divergence": _divergence, "deformation": _deformation, "rcad": _rcad}


def regularizer_value_grad(name: str, warp: Warp, x, y, dt, theta, shape,
                           xw=None, yw=None, *,
                           jac: tuple[np.ndarray, np.ndarray] | None = None,
                           span: tuple[float, float] | None = None,
                           count: np.ndarray | None = None, grad: bool = True,
                           options: PenaltyOptions | None = None,
                           ) -> tuple[float, np.ndarray | None]:
    """Value of a collapse penalty and its gradient with respect to ``theta``.

    Parameters
    ----------
    name : {"divergence", "deformation", "rcad"}
    warp : Warp
        From :func:`evmotion.core.warps.make_warp`.
    x, y : array (N,)
        Event pixels.
    dt : array (N,)
        ``t_k - t_ref`` in seconds.
    theta : array (P,)
        Warp parameters.
    shape : (int, int)
        ``(H, W)`` of the DIWE/IWA maps, pixels.
    xw, yw : array (N,), optional
        The events warped with ``theta`` (saves a warp; the rotation's per-event values are
        read from them), in the order of ``x, y, dt``.
    jac : (jx, jy), optional
        The parameter Jacobians (N, P) of ``xw, yw``. Without them, warps with a ``vjp``
        contract the adjoint themselves (no (N, P) buffers); others compute the Jacobians
        when a pixel is trimmed.
    span : (float, float), optional
        ``(min dt, max dt)`` in seconds, when the caller knows it (e.g. once per window for
        many evaluations): saves a pass over ``dt`` per call. It must be that of ``dt``.
    count : array (H, W) float64, optional
        The bilinear IWE of ``xw, yw`` without weights, when the caller has it (CMax's data
        term): the DIWE/IWA vote-count map is then not accumulated again (divergence,
        deformation; ignored by rcad). It must be that of ``xw, yw``; it is not modified.
    grad : bool
        Compute the gradient (else ``None`` is returned in its place).
    options : PenaltyOptions, optional
        Margin, vote kernel and RCAD grid stride (defaults: :class:`PenaltyOptions`).

    Returns
    -------
    value : float
        The penalty (dimensionless; >= 0 for the trimmed ones; larger = more collapse).
    grad : array (P,)
        ``d value / d theta``.

    Examples
    --------
    >>> from evmotion.core.warps import make_warp
    >>> w = make_warp("zoom", (260, 346))
    >>> x = np.array([10.0, 200.0]); y = np.array([10.0, 100.0]); dt = np.array([0.0, 0.05])
    >>> v, g = regularizer_value_grad("rcad", w, x, y, dt, np.array([4.0]), (260, 346))
    >>> round(v, 4), round(float(g[0]), 4)  # (3.21): -2 log|1 - 4 * 0.05|
    (0.4463, 0.125)
    """
    if name not in REGULARIZERS:
        raise ParameterError(f"unknown regularizer '{name}'; choose one of "
                             f"{sorted(REGULARIZERS)}")
    shape = sensor_shape(shape)
    jx, jy = (None, None) if jac is None else jac
    ev = PenaltyEvents(x, y, dt, xw, yw, jx, jy, span, count)
    return REGULARIZERS[name](warp, ev, theta, shape,
                              _DEFAULT_OPTIONS if options is None else options, grad)


def regularizer_maps(name: str, warp: Warp, x, y, dt, theta, shape, *,
                     kernel: str = "bilinear", margin: float | None = None,
                     ) -> dict[str, np.ndarray]:
    """Maps for plotting (H, W) float64.

    * divergence: ``"diwe"`` (3.11, per window as in the thesis, empty pixels 0),
      ``"count"`` (the IWE of vote mass), ``"trimmed"`` (bool, the pixels below the
      margin);
    * deformation: ``"iwa"`` (3.16, empty pixels 1), ``"count"``, ``"trimmed"``;
    * rcad: ``"rcad"`` -- the integrated rate (area log-ratio) at every pixel's trajectory,
      dense (also where no event warps), and ``"trimmed"``.

    Examples
    --------
    >>> from evmotion.core.warps import make_warp
    >>> w = make_warp("zoom", (4, 5))
    >>> m = regularizer_maps("divergence", w, np.array([2.0]), np.array([1.0]),
    ...                      np.array([0.01]), np.array([1.0]), (4, 5))
    >>> float(m["diwe"][1, 2])  # -2 h_z per window; one event: T = 1
    -2.0
    """
    if name not in REGULARIZERS:
        raise ParameterError(f"unknown regularizer '{name}'; choose one of "
                             f"{sorted(REGULARIZERS)}")
    _check_kernel(kernel)
    shape = sensor_shape(shape)
    x, y, dt = Warp.check_events(x, y, dt)
    th = warp.check_theta(theta)
    m = DEFAULT_MARGINS[name] if margin is None else float(margin)
    if name == "rcad":
        t0, t1 = time_span(dt) if x.shape[0] else (0.0, 0.0)
        closed = rcad_closed_form(warp, th, t0, t1)
        if closed is not None:
            vals = np.full(shape, closed[0])
            return {"rcad": vals, "trimmed": np.ones(shape, dtype=bool)}
        ys, xs = np.mgrid[0:shape[0], 0:shape[1]]
        vals = warp.area_log_ratio(xs.ravel().astype(float), ys.ravel().astype(float), t0, t1,
                                   th).reshape(shape)
        return {"rcad": vals, "trimmed": vals > m}
    xw, yw = warp.warp(x, y, dt, th)
    _, _, cnt, num = pixel_average(name, warp, x, y, dt, th, shape, xw, yw)
    support = cnt > MIN_COUNT
    mean = np.zeros(shape)
    np.divide(num, cnt, out=mean, where=support)
    cnt = cnt.copy()
    if name == "divergence":
        return {"diwe": mean, "count": cnt, "trimmed": support & (mean < m)}
    iwa = 1.0 + mean
    return {"iwa": iwa, "count": cnt, "trimmed": support & (iwa < m)}
