"""Parametric event warps of chapter 3 and Appendix A, with their differential quantities.

Every warp transports an event at pixel ``(x, y)`` and time ``t_ref + dt`` back to the
reference time ``t_ref`` along the point trajectory through it, ``x' = W(x, dt; theta)``.

Conventions (the same for every warp):

* ``x, y`` are plain sensor pixels (column, row; origin top-left), float64 arrays (N,);
  warps that the thesis writes in centred coordinates (zoom, SE(2), in-plane, similarity,
  affine, homography) centre them internally on ``center`` (default: the image centre
  ``((W - 1) / 2, (H - 1) / 2)``), the rotation warp normalizes them with the intrinsics
  ``K``. Inputs and outputs are always sensor pixels.
* ``dt`` is ``t_k - t_ref`` in **seconds** (t_ref may be the window's start, middle or end);
  parameters are rates per second (``param_units`` names them). The thesis writes the zoom
  (3.7) in time normalized to [0, 1]; :func:`zoom_normalized_to_rate` converts.
* Each warp is a 3x3 matrix ``M(dt; theta)`` acting on homogeneous pixel coordinates,
  ``x' ~ M(dt; theta) (x, y, 1)^T``: the inverse of the trajectory homography ``H`` of (A.1).
  The differential quantities below follow from ``M`` and ``dM/dt`` in closed form:

  - :meth:`Warp.flow` -- (3.8) ``f = dW/dt`` at the event, px/s. It is minus the image
    velocity: at ``dt = 0`` the optical flow of the scene is ``-f``
    (:meth:`Warp.optical_flow`).
  - :meth:`Warp.divergence` -- ``div f = tr(df/dx)``, 1/s (3.9); negative = contraction.
  - :meth:`Warp.jacobian_det` -- ``det(dW/dx)`` (3.13), (A.4): ``det M / (e3^T M x)^3``.
  - :meth:`Warp.rcad` -- the rate of change of area deformation at the event,
    ``d|J_{t,t+h}|/dh`` at ``h = 0`` (3.20), (3.27), 1/s. It is the divergence of the
    image velocity along the trajectory, positive where the trajectories spread forward in
    time, i.e. where warping back to ``t_ref`` contracts (collapse-enabling).
  - :meth:`Warp.area_log_ratio` -- the RCAD integrated along the trajectory over a time
    span, (3.21), (3.28), (A.44), (A.53). By Liouville's formula the integral of the
    divergence along a trajectory is the log of the area ratio between its ends, so the
    integral is exact: ``log|det dx(t1)/dx_ref| - log|det dx(t0)/dx_ref|``.

Layout: :mod:`~evmotion.core.warps.base` (the :class:`Warp` interface and its numpy
reference), :mod:`~evmotion.core.warps.adjoint` (fused adjoints),
:mod:`~evmotion.core.warps.so3` and :mod:`~evmotion.core.warps.common` (series and helpers
of the kernels), one module per warp family (:mod:`~evmotion.core.warps.simple`: zoom,
translation, in-plane; :mod:`~evmotion.core.warps.similarity`: SE(2), similarity;
:mod:`~evmotion.core.warps.projective`: affine, homography;
:mod:`~evmotion.core.warps.rotation`), each with its forward kernels, Jacobians, adjoints
and collapse values, and the registry :data:`WARP_CLASSES` below (adding a warp: one module
and one line there, ``docs/adding_a_warp.rst``). The trajectory matrices are
:mod:`evmotion.geometry`'s.

Parameter derivatives: the hot path (:meth:`Warp.warp` / :meth:`Warp.warp_into` with the
Jacobian ``d x'/d theta``) is a hand-derived numba kernel per warp. The warps up to 4 DOF
also chain per-event gradients through their Jacobian without storing it
(``vjp``, ``reduce_bilinear``: the Jacobian recomputed inside the adjoint pass, fused with
the bilinear IWE adjoint), the hot path of gradient-based contrast maximization. The rotation's
divergence and determinant have hand-derived omega-derivatives too (numba); the other
derivatives of the divergence, determinant and area ratio with respect to ``theta`` are
computed exactly by complex-step differentiation of the same closed forms (no step-size
error), and the regularizers use closed forms where the thesis gives them.

Sign conventions of the parameters (camera frame x right, y down, z forward):

* ``translation``: ``theta = (vx, vy)`` is the image velocity in px/s: ``x' = x - dt v``
  (3.5.1 writes ``x + dt theta``; this is the sign used by the rest of the package).
* ``rotation``: ``theta = omega`` is the camera's angular velocity in rad/s:
  ``x'_n ~ exp(dt omega^) x_n`` in normalized coordinates (3.22). Its flow at dt = 0 is minus
  the rotational part of the feature sensitivity matrix (3.29), its divergence is (3.23).
  Right-handed about the camera axes: ``wz > 0`` turns the image content counter-clockwise
  on screen (x right, y down).
* ``se2``, ``similarity``: ``wz`` in rad/s has the rotation's sign (the camera's rate about
  the optical axis; the thesis' A.11/A.36 ``w_z`` is minus it), so that a camera turning
  about z gives the same-sign ``wz`` from ``rotation`` and ``se2``.

Examples
--------
>>> import numpy as np
>>> w = make_warp("zoom", sensor_size=(260, 346))
>>> x = np.array([10.0, 300.0]); y = np.array([20.0, 200.0]); dt = np.array([0.0, 0.05])
>>> xw, yw = w.warp(x, y, dt, np.array([2.0]))
>>> float(w.divergence(x, y, dt, np.array([2.0]))[0])
-4.0
"""

from __future__ import annotations

import numpy as np

from evmotion.core.warps.base import Warp
from evmotion.core.warps.projective import AffineWarp, HomographyWarp
from evmotion.core.warps.rotation import RotationWarp
from evmotion.core.warps.similarity import SE2Warp, SimilarityWarp
from evmotion.core.warps.simple import InPlaneWarp, TranslationWarp, ZoomWarp
from evmotion.errors import ParameterError
from evmotion.geometry import MODELS, model_fields, rodrigues

__all__ = [
    "WARPS",
    "WARP_CLASSES",
    "Warp",
    "make_warp",
    "rodrigues",
    "zoom_normalized_to_rate",
    "zoom_rate_to_normalized",
]


def zoom_normalized_to_rate(b_z: float, window_s: float) -> float:
    """Convert the thesis' zoom parameter of (3.7) (time normalized to [0, 1]) to a rate.

    (3.7) warps ``x' = (1 - t~ b_z) x`` with ``t~ = (t - t_1) / T`` for a window of duration
    ``T`` seconds; with ``dt = t - t_1`` that is ``x' = (1 - dt * rate) x``, so
    ``rate = b_z / T`` in 1/s.

    Examples
    --------
    >>> zoom_normalized_to_rate(0.2, 0.05)
    4.0
    """
    if not window_s > 0:
        raise ParameterError(f"window_s must be > 0 seconds, got {window_s!r}")
    return float(b_z) / float(window_s)


def zoom_rate_to_normalized(rate: float, window_s: float) -> float:
    """Inverse of :func:`zoom_normalized_to_rate`: ``b_z = rate * T`` (dimensionless)."""
    if not window_s > 0:
        raise ParameterError(f"window_s must be > 0 seconds, got {window_s!r}")
    return float(rate) * float(window_s)


#: The registry: warp name -> class. Parameter names and units come from the motion model
#: of the same name (:data:`evmotion.geometry.MODELS`) unless the class defines
#: ``param_spec = (names, units)``.
WARP_CLASSES: dict[str, type[Warp]] = {
    "zoom": ZoomWarp,
    "translation": TranslationWarp,
    "rotation": RotationWarp,
    "se2": SE2Warp,
    "inplane": InPlaneWarp,
    "similarity": SimilarityWarp,
    "affine": AffineWarp,
    "homography": HomographyWarp,
}


def _param_spec(name: str) -> tuple[tuple[str, ...], tuple[str, ...]]:
    spec = getattr(WARP_CLASSES[name], "param_spec", None)
    if spec is None:
        return MODELS[name].param_names, MODELS[name].param_units
    return spec


#: Names of the warps :func:`make_warp` builds, with their number of parameters.
WARPS: dict[str, int] = {k: len(_param_spec(k)[0]) for k in WARP_CLASSES}


def make_warp(name: str, sensor_size: tuple[int, int], K: np.ndarray | None = None,
              center: tuple[float, float] | None = None) -> Warp:
    """Build a warp by name.

    Parameters
    ----------
    name : str
        One of :data:`WARPS`: zoom (1 DOF), translation (2), rotation (3), se2 (3),
        inplane (4), similarity (4), affine (6), homography (8).
    sensor_size : (int, int)
        ``(height, width)`` in pixels.
    K : array (3, 3), optional
        Camera intrinsics in pixels; required for ``rotation``.
    center : (float, float), optional
        Pixel ``(cx, cy)`` of the centred coordinates; default the image centre
        ``((W - 1) / 2, (H - 1) / 2)``.

    Examples
    --------
    >>> K = np.array([[200.0, 0, 120], [0, 200.0, 90], [0, 0, 1]])
    >>> w = make_warp("rotation", sensor_size=(180, 240), K=K)
    >>> w.param_names, w.param_units[0]
    (('wx', 'wy', 'wz'), 'rad/s')
    """
    if name not in WARP_CLASSES:
        raise ParameterError(f"unknown warp '{name}'; choose one of {sorted(WARP_CLASSES)}")
    names, units = _param_spec(name)
    return WARP_CLASSES[name](*model_fields(name, names, units, sensor_size, K, center))
