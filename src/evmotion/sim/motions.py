"""Motions of simulated layers, expressed with the parametric warps of chapter 3.

A :class:`Motion` is one motion model of :mod:`evmotion.geometry` (those of the warps of
:mod:`evmotion.core.warps`) with a parameter vector ``theta`` and a reference time
``t_ref_s`` (seconds from the start of the recording). The scene seen at pixel ``x`` at time ``t`` is the reference texture at ``M(t - t_ref) x``
(homogeneous pixels), where ``M`` is the warp's matrix: the simulator renders exactly the
motion model that the warp fits, so the ground-truth ``theta`` is the answer an estimator
using the same warp with ``t_ref`` should find.

Instantaneous quantities at time ``t`` come from the generator ``L(t) = -M^-1 dM/dt``
(3x3, defined up to a multiple of the identity): the image velocity at pixel ``x`` is
``u = (L x)_xy - x (L x)_z`` in px/s, and the point at ``x`` at time ``t0`` is at
``M(t1)^-1 M(t0) x`` at time ``t1`` -- exact along the trajectories, also for motions
whose flow changes over time (zoom, affine, homography).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evmotion.errors import ParameterError
from evmotion.geometry import MotionModel, make_model

__all__ = ["Motion", "make_motion"]


@dataclass(frozen=True, eq=False)
class Motion:
    """A constant-velocity parametric motion.

    Attributes
    ----------
    warp : MotionModel
        The warp model (its ``param_names`` / ``param_units`` name ``theta``).
    theta : ndarray (P,)
        Parameters of the warp referenced at ``t_ref_s`` (rates per second).
    t_ref_s : float
        Reference time in seconds from the start of the recording.
    """

    warp: MotionModel
    theta: np.ndarray
    t_ref_s: float = 0.0

    def matrix(self, t_s: float) -> np.ndarray:
        """``M`` (3, 3): homogeneous pixel at time ``t_s`` (seconds) -> reference pixel."""
        M, _ = self.warp.matrices(np.array([t_s - self.t_ref_s]), self.theta)
        return np.real(M[0])

    def matrices(self, t_s: np.ndarray) -> np.ndarray:
        """``M`` (N, 3, 3) at the times ``t_s`` (seconds), vectorized."""
        M, _ = self.warp.matrices(np.asarray(t_s, dtype=np.float64) - self.t_ref_s, self.theta)
        return np.ascontiguousarray(np.real(M))

    def generator(self, t_s: float) -> np.ndarray:
        """``L = -M^-1 dM/dt`` (3, 3) at time ``t_s`` (seconds); flow ``(Lx)_xy - x (Lx)_z``."""
        M, Md = self.warp.matrices(np.array([t_s - self.t_ref_s]), self.theta)
        L = -np.linalg.solve(np.real(M[0]), np.real(Md[0]))
        return L - L[2, 2] * np.eye(3)

    def transport(self, t0_s: float, t1_s: float) -> np.ndarray:
        """(3, 3) homogeneous map from the pixel of a scene point at ``t0_s`` to its pixel
        at ``t1_s`` (seconds)."""
        return np.linalg.solve(self.matrix(t1_s), self.matrix(t0_s))

    def flow(self, x: np.ndarray, y: np.ndarray, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Image velocity ``(u, v)`` in px/s of the scene point at pixel ``(x, y)`` at
        time ``t_s`` (seconds)."""
        return apply_generator(self.generator(t_s), x, y)

    def params_at(self, t_s: float) -> np.ndarray:
        """Parameters of the same warp referenced at ``t_s`` that reproduce the motion's
        instantaneous velocity field there (least squares on the generator; exact for
        every warp whose generator the parametrization spans)."""
        if abs(t_s - self.t_ref_s) < 1e-15:
            return self.theta.copy()
        target = self.generator(t_s)
        th = self.theta.astype(np.float64).copy()

        def gen(p):
            _, Md = self.warp.matrices(np.array([0.0]), p)
            g = -np.real(Md[0])
            return (g - g[2, 2] * np.eye(3)).ravel()

        eps = 1e-6
        for _ in range(8):  # Gauss-Newton; linear warps converge in one step
            r = gen(th) - target.ravel()
            J = np.empty((9, th.size))
            for j in range(th.size):
                d = np.zeros_like(th)
                d[j] = eps * max(1.0, abs(th[j]))
                J[:, j] = (gen(th + d) - gen(th - d)) / (2 * d[j])
            step = np.linalg.lstsq(J, -r, rcond=None)[0]
            th = th + step
            if np.all(np.abs(step) <= 1e-12 * (1.0 + np.abs(th))):
                break
        return th


def apply_generator(L: np.ndarray, x, y) -> tuple[np.ndarray, np.ndarray]:
    """Velocity ``(Lx)_xy - x (Lx)_z`` of the projective vector field ``L`` at pixels."""
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    gz = L[2, 0] * x + L[2, 1] * y + L[2, 2]
    u = L[0, 0] * x + L[0, 1] * y + L[0, 2] - x * gz
    v = L[1, 0] * x + L[1, 1] * y + L[1, 2] - y * gz
    return u, v


def make_motion(warp: str, theta, sensor_size: tuple[int, int], *, K: np.ndarray | None = None,
                center: tuple[float, float] | None = None, t_ref_s: float = 0.0) -> Motion:
    """Build a :class:`Motion` from a warp name and its parameters.

    Parameters
    ----------
    warp : str
        Warp name (see :data:`evmotion.core.warps.WARPS`).
    theta : array_like (P,)
        Parameters in the warp's units (``make_warp(warp, ...).param_units``).
    sensor_size : (int, int)
        ``(height, width)``.
    K : array (3, 3), optional
        Intrinsics (required by ``rotation``).
    center : (float, float), optional
        Centre of the centred warps (default: image centre).
    t_ref_s : float
        Reference time, seconds from the start.

    Examples
    --------
    >>> m = make_motion("translation", [100.0, -50.0], (20, 30))
    >>> u, v = m.flow(np.array([3.0]), np.array([4.0]), 0.01)
    >>> float(u[0]), float(v[0])
    (100.0, -50.0)
    """
    w = make_model(warp, sensor_size, K=K, center=center)
    th = np.asarray(theta, dtype=np.float64)
    if th.shape != (w.n_params,):
        raise ParameterError(f"motion '{warp}' takes {w.n_params} parameters "
                             f"{w.param_names} in {w.param_units}, got {np.asarray(theta).tolist()}")
    if not np.all(np.isfinite(th)):
        raise ParameterError(f"motion '{warp}': parameters must be finite, got {th.tolist()}")
    return Motion(w, th, float(t_ref_s))
