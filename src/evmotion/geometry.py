"""Motion models of chapter 3 and Appendix A as 3x3 trajectory matrices (plain numpy).

A motion model maps the homogeneous pixel of an event at time ``t_ref + dt`` to that of the
same scene point at ``t_ref``: ``x' ~ M(dt; theta) (x, y, 1)^T``. This module holds the
matrices ``M`` and ``dM/dt`` of every model and the SO(3) exponential they need, with no
numba and no dependency on the rest of the package, so that the simulator
(:mod:`evmotion.sim`) and the warps (:mod:`evmotion.core.warps`, whose numba kernels compute
the same maps fast) share one definition.

Examples
--------
>>> m = make_model("translation", sensor_size=(10, 10))
>>> M, Md = m.matrices(np.array([0.5]), np.array([2.0, 0.0]))
>>> M[0, 0, 2], Md[0, 0, 2]
(np.float64(-1.0), np.float64(-2.0))
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from evmotion.errors import CalibrationError, ParameterError

__all__ = ["MODELS", "MotionModel", "hat", "make_model", "rodrigues", "sinc_terms"]


def sinc_terms(z):
    """``sin(a)/a``, ``(1-cos a)/a^2``, ``(a-sin a)/a^3`` as functions of ``z = a^2``.

    Safe for complex ``z`` (complex-step derivatives) and for ``z -> 0`` (series below 1).

    Examples
    --------
    >>> [round(float(v), 6) for v in sinc_terms(np.array(0.0))]
    [1.0, 0.5, 0.166667]
    """
    z = np.asarray(z)
    small = np.abs(z) < 1.0
    zs = np.where(small, z, 0.0)
    a_ = np.zeros_like(zs)
    b_ = np.zeros_like(zs)
    c_ = np.zeros_like(zs)
    term_a = np.ones_like(zs)
    term_b = 0.5 * np.ones_like(zs)
    term_c = np.ones_like(zs) / 6.0
    for k in range(12):  # |z| < 1: 12 terms of the series reach 1e-20
        a_ = a_ + term_a
        b_ = b_ + term_b
        c_ = c_ + term_c
        term_a = -term_a * zs / ((2 * k + 2) * (2 * k + 3))
        term_b = -term_b * zs / ((2 * k + 3) * (2 * k + 4))
        term_c = -term_c * zs / ((2 * k + 4) * (2 * k + 5))
    if np.all(small):
        return a_, b_, c_
    zl = np.where(small, 1.0, z)
    a = np.sqrt(zl)
    with np.errstate(all="ignore"):
        al, bl, cl = np.sin(a) / a, (1 - np.cos(a)) / zl, (a - np.sin(a)) / (zl * a)
    return np.where(small, a_, al), np.where(small, b_, bl), np.where(small, c_, cl)


def hat(w):
    """The skew matrix ``w^`` (3, 3, ...) of ``w`` (3, ...): ``w^ v = w x v``."""
    o = np.zeros_like(w[0])
    return np.array([[o, -w[2], w[1]], [w[2], o, -w[0]], [-w[1], w[0], o]])


def rodrigues(rotvec: np.ndarray) -> np.ndarray:
    """Rotation matrix ``exp(rotvec^)`` (exponential coordinates, radians).

    Parameters
    ----------
    rotvec : array (3,) or (N, 3)
        Rotation vectors in radians (axis times angle).

    Returns
    -------
    R : array (3, 3) or (N, 3, 3)

    Examples
    --------
    >>> np.round(rodrigues(np.array([0.0, 0.0, np.pi / 2])), 6)[0]
    array([ 0., -1.,  0.])
    """
    r = np.asarray(rotvec)
    single = r.ndim == 1
    r = np.atleast_2d(r)
    z = np.sum(r * r, axis=1)
    a, b, _ = sinc_terms(z)
    W = np.moveaxis(hat(r.T), -1, 0)
    W2 = W @ W
    R = np.eye(3) + a[:, None, None] * W + b[:, None, None] * W2
    return R[0] if single else R


# ---------------------------------------------------------------------------------------
# M(dt) and dM/dt (N, 3, 3) of each model in its own coordinates: centred pixels, or
# normalized ones (K^-1) for the rotation

def _stack33(rows, n):
    return np.moveaxis(np.array([[np.broadcast_to(v, (n,)) for v in r] for r in rows]), -1, 0)


def _zoom(dt, th):
    n = dt.shape[0]
    s = 1 - dt * th[0]
    o, i = 0 * s, 1 + 0 * s
    M = _stack33([[s, o, o], [o, s, o], [o, o, i]], n)
    h = -th[0] + 0 * dt
    Md = _stack33([[h, o, o], [o, h, o], [o, o, o]], n)
    return M, Md


def _translation(dt, th):
    n = dt.shape[0]
    z = 0 * dt * th[0]
    o, i = z, 1 + z
    M = _stack33([[i, o, -dt * th[0]], [o, i, -dt * th[1]], [o, o, i]], n)
    Md = _stack33([[o, o, -th[0] + z], [o, o, -th[1] + z], [o, o, o]], n)
    return M, Md


def _similarity(dt, th):
    n = dt.shape[0]
    s = th[3] if th.shape[0] == 4 else 0.0  # SE(2): 3 parameters, no scaling
    w = -th[2]  # the image's rotation rate (A.11's w_z): wz has the rotation warp's sign
    c, sn = np.cos(-dt * w), np.sin(-dt * w)
    ib = 1.0 / (1.0 + dt * s)
    # A = R(-dt w)/beta, b = -A dt v
    a00, a01, a10, a11 = c * ib, -sn * ib, sn * ib, c * ib
    b0 = -(a00 * th[0] + a01 * th[1]) * dt
    b1 = -(a10 * th[0] + a11 * th[1]) * dt
    # dA/dt = (dR/dt)/beta - R s/beta^2, dR/dt = -w R'(a)
    dib = -s * ib * ib
    d00 = w * sn * ib + c * dib
    d01 = w * c * ib - sn * dib
    d10 = -w * c * ib + sn * dib
    d11 = w * sn * ib + c * dib
    e0 = -(d00 * th[0] + d01 * th[1]) * dt - (a00 * th[0] + a01 * th[1])
    e1 = -(d10 * th[0] + d11 * th[1]) * dt - (a10 * th[0] + a11 * th[1])
    o = 0 * a00
    i = 1 + o
    M = _stack33([[a00, a01, b0], [a10, a11, b1], [o, o, i]], n)
    Md = _stack33([[d00, d01, e0], [d10, d11, e1], [o, o, o]], n)
    return M, Md


def _inplane(dt, th):
    n = dt.shape[0]
    c, s = np.cos(th[2]), np.sin(th[2])
    k = th[3] + 1
    z = 0 * dt * th[0]
    o, i = z, 1 + z
    M = _stack33([[1 + dt - dt * k * c, dt * k * s, -dt * th[0]],
                  [-dt * k * s, 1 + dt - dt * k * c, -dt * th[1]], [o, o, i]], n)
    Md = _stack33([[1 - k * c + z, k * s + z, -th[0] + z],
                   [-k * s + z, 1 - k * c + z, -th[1] + z], [o, o, o]], n)
    return M, Md


def _affine(dt, th):
    n = dt.shape[0]
    G = np.array([[th[2], th[3]], [th[4], th[5]]])
    A = np.eye(2) + dt[:, None, None] * G
    Ai = np.linalg.inv(A)
    v = np.array([th[0], th[1]])
    b = -(Ai @ v) * dt[:, None]
    Aid = -Ai @ G @ Ai
    bd = -(Aid @ v) * dt[:, None] - Ai @ v
    M = np.zeros((n, 3, 3), dtype=Ai.dtype)
    Md = np.zeros((n, 3, 3), dtype=Ai.dtype)
    M[:, :2, :2] = Ai
    M[:, :2, 2] = b
    M[:, 2, 2] = 1
    Md[:, :2, :2] = Aid
    Md[:, :2, 2] = bd
    return M, Md


def _homography(dt, th):
    G = np.array([[th[0], th[1], th[2]], [th[3], th[4], th[5]], [th[6], th[7], 0 * th[0]]])
    H = np.eye(3) + dt[:, None, None] * G
    M = np.linalg.inv(H)
    return M, -M @ G @ M


def _rotation(dt, th):
    r = dt[:, None] * th[None, :]
    R = rodrigues(r)
    return R, hat(th).astype(R.dtype) @ R


class Model(NamedTuple):
    """A motion model: its parameters' names and units, and ``matrices(dt, theta)`` ->
    ``(M, dM/dt)`` (N, 3, 3) in its own coordinates (centred pixels; normalized ones,
    ``K^-1`` pixels, where ``intrinsics``)."""

    param_names: tuple[str, ...]
    param_units: tuple[str, ...]
    matrices: object
    intrinsics: bool = False


#: The motion models by name (the warps of :func:`evmotion.core.warps.make_warp`).
MODELS: dict[str, Model] = {
    "zoom": Model(("hz",), ("1/s",), _zoom),
    "translation": Model(("vx", "vy"), ("px/s", "px/s"), _translation),
    "rotation": Model(("wx", "wy", "wz"), ("rad/s",) * 3, _rotation, True),
    "se2": Model(("vx", "vy", "wz"), ("px/s", "px/s", "rad/s"), _similarity),
    # (A.22)'s per-second rate matrix (1 + hz) R(phi) - I: phi an angle and hz a factor;
    # the rotation rate is (1 + hz) sin(phi) rad/s and the zoom rate (1 + hz) cos(phi) - 1
    # per s (phi, hz only for small ones: a 2 rad/s rotation is phi = atan 2, hz = 1.24)
    # phi and hz parameterize the per-second rate matrix (h_z + 1) R(phi) - Id: rates
    # (estimates keep their value whatever the window's duration; probe)
    "inplane": Model(("vx", "vy", "phi", "hz"), ("px/s", "px/s", "rad/s", "1/s"), _inplane),
    "similarity": Model(("vx", "vy", "wz", "s"), ("px/s", "px/s", "rad/s", "1/s"),
                        _similarity),
    "affine": Model(("vx", "vy", "g11", "g12", "g21", "g22"),
                    ("px/s", "px/s") + ("1/s",) * 4, _affine),
    "homography": Model(("g11", "g12", "g13", "g21", "g22", "g23", "g31", "g32"),
                        ("1/s", "1/s", "px/s", "1/s", "1/s", "px/s", "1/(px s)", "1/(px s)"),
                        _homography),
}


@dataclass(frozen=True, eq=False)
class MotionModel:
    """A parametric motion on a sensor (see :func:`make_model`).

    Attributes
    ----------
    name : str
    param_names, param_units : tuple of str
    sensor_size : (int, int)
        ``(height, width)`` in pixels.
    center : (float, float)
        ``(cx, cy)`` pixel position of the origin of the centred coordinates.
    K : ndarray (3, 3) or None
        Camera intrinsics (pixels); required by ``rotation``.
    """

    name: str
    param_names: tuple[str, ...]
    param_units: tuple[str, ...]
    sensor_size: tuple[int, int]
    center: tuple[float, float]
    K: np.ndarray | None = None

    def __post_init__(self):
        kinv = None if self.K is None else np.linalg.inv(self.K)
        object.__setattr__(self, "_kinv", kinv)

    @property
    def n_params(self) -> int:
        return len(self.param_names)

    @property
    def K_inv(self) -> np.ndarray | None:
        """``K^-1`` (3, 3), or None without intrinsics."""
        return self._kinv

    def identity(self) -> np.ndarray:
        """Parameters of the identity motion, float64 (P,)."""
        return np.zeros(self.n_params)

    def check_theta(self, theta, allow_complex: bool = False) -> np.ndarray:
        """``theta`` as a finite float64 (P,) array (complex128 if ``allow_complex`` and
        complex), or :class:`~evmotion.errors.ParameterError`."""
        th = np.asarray(theta)
        if th.shape != (self.n_params,):
            raise ParameterError(f"warp '{self.name}' takes theta of shape ({self.n_params},) "
                                 f"{self.param_names}, got shape {th.shape}")
        if np.iscomplexobj(th) and allow_complex:
            return th.astype(np.complex128)
        th = th.astype(np.float64)
        if not all(map(math.isfinite, th.tolist())):  # cheaper than numpy for P <= 8
            raise ParameterError(f"warp '{self.name}': theta must be finite, got {th!r}")
        return th

    def _mats_c(self, dt, th):
        """``M`` and ``dM/dt`` (N, 3, 3) in the model's own (centred/normalized) coordinates."""
        return MODELS[self.name].matrices(dt, th)

    def _conj(self):
        """(T, T^-1): pixel <- own coordinates."""
        if self.name in MODELS and MODELS[self.name].intrinsics:
            return self.K, self._kinv
        cx, cy = self.center
        T = np.array([[1.0, 0, cx], [0, 1.0, cy], [0, 0, 1.0]])
        Ti = np.array([[1.0, 0, -cx], [0, 1.0, -cy], [0, 0, 1.0]])
        return T, Ti

    def matrices(self, dt, theta):
        """``M(dt)`` and ``dM/dt`` (N, 3, 3) acting on homogeneous sensor pixels.

        ``x' ~ M (x, y, 1)^T``. Accepts complex ``theta`` (used for complex-step
        derivatives)."""
        th = self.check_theta(theta, allow_complex=True)
        dt = np.atleast_1d(np.asarray(dt, dtype=np.float64))
        M, Md = self._mats_c(dt, th)
        T, Ti = self._conj()
        return T @ M @ Ti, T @ Md @ Ti


def checked_intrinsics(K, name: str) -> np.ndarray | None:
    """``K`` as a float64 (3, 3) intrinsics matrix (None stays None unless the model
    ``name`` needs one), or :class:`~evmotion.errors.CalibrationError`."""
    if K is not None:
        Kmat = np.ascontiguousarray(K, dtype=np.float64)
        if Kmat.shape != (3, 3) or not np.all(np.isfinite(Kmat)) or \
                abs(np.linalg.det(Kmat)) < 1e-12 or np.any(Kmat[2] != (0, 0, 1)):
            raise CalibrationError(f"K must be a finite invertible 3x3 intrinsics matrix with "
                                   f"last row (0, 0, 1), got {np.asarray(K).tolist()!r}")
        return Kmat
    if name in MODELS and MODELS[name].intrinsics:
        raise CalibrationError(f"the {name} warp needs the camera intrinsics K (3x3, pixels)")
    return None


def sensor_shape(size, name: str = "shape") -> tuple[int, int]:
    """``size`` as ``(height, width)`` positive ints, or
    :class:`~evmotion.errors.ParameterError` naming ``name``."""
    try:
        h, w = (int(v) for v in size)
    except (TypeError, ValueError):
        raise ParameterError(f"{name} must be (height, width), got {size!r}") from None
    if h <= 0 or w <= 0:
        raise ParameterError(f"{name} must be positive, got {size!r}")
    return h, w


def make_model(name: str, sensor_size: tuple[int, int], K: np.ndarray | None = None,
               center: tuple[float, float] | None = None) -> MotionModel:
    """Build a motion model by name (one of :data:`MODELS`).

    Parameters are those of :func:`evmotion.core.warps.make_warp`, which builds the same
    model with its numba kernels.

    Examples
    --------
    >>> make_model("zoom", (4, 6)).center
    (2.5, 1.5)
    """
    if name not in MODELS:
        raise ParameterError(f"unknown warp '{name}'; choose one of {sorted(MODELS)}")
    m = MODELS[name]
    return MotionModel(*model_fields(name, m.param_names, m.param_units, sensor_size, K,
                                     center))


def model_fields(name, param_names, param_units, sensor_size, K, center) -> tuple:
    """The checked fields ``(name, param_names, param_units, sensor_size, center, K)`` of a
    :class:`MotionModel` (default centre: the image centre ``((W - 1) / 2, (H - 1) / 2)``)."""
    h, w = sensor_shape(sensor_size, "sensor_size")
    Kmat = checked_intrinsics(K, name)
    if center is None:
        center = ((w - 1) / 2.0, (h - 1) / 2.0)
    center = (float(center[0]), float(center[1]))
    return name, tuple(param_names), tuple(param_units), (h, w), center, Kmat
