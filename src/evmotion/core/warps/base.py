"""The :class:`Warp` base class: the hot-path interface and the plain-numpy reference of
every differential quantity, from the trajectory matrices of :mod:`evmotion.geometry`."""

from __future__ import annotations

import numpy as np

from evmotion.core.warps.common import EMPTY2
from evmotion.errors import ParameterError
from evmotion.geometry import MotionModel

__all__ = ["Warp"]

_CSTEP = 1e-30  # complex-step size: exact derivatives to machine precision, any tiny value works

class Warp(MotionModel):
    """A parametric warp (see the module docstring for conventions): the attributes of
    :class:`~evmotion.geometry.MotionModel` (``name``, ``n_params``, ``param_names``,
    ``param_units``, ``sensor_size``, ``center``, ``K``), with the warp, its differential
    quantities and their parameter derivatives."""

    @staticmethod
    def check_events(x, y, dt):
        """``x, y, dt`` as float64 contiguous 1-D arrays of equal length, or
        :class:`~evmotion.errors.ParameterError`."""
        x = np.ascontiguousarray(x, dtype=np.float64)
        y = np.ascontiguousarray(y, dtype=np.float64)
        dt = np.ascontiguousarray(dt, dtype=np.float64)
        if x.ndim != 1 or x.shape != y.shape or x.shape != dt.shape:
            raise ParameterError(f"x, y, dt must be 1-D arrays of equal length, got shapes "
                                 f"{x.shape}, {y.shape}, {dt.shape}")
        return x, y, dt

    # -- hot path --------------------------------------------------------------------------
    def warp(self, x, y, dt, theta, jacobian: bool = False):
        """Warp events to ``t_ref``.

        Parameters
        ----------
        x, y : array (N,)
            Event pixels.
        dt : array (N,)
            ``t_k - t_ref`` in seconds.
        theta : array (P,)
            Parameters (rates per second, see ``param_units``).
        jacobian : bool
            Also return ``jx, jy`` (N, P): ``d x'/d theta`` and ``d y'/d theta``.

        Returns
        -------
        xw, yw : array (N,) -- warped pixels; and ``jx, jy`` if ``jacobian``.

        Examples
        --------
        >>> from evmotion.core.warps import make_warp
        >>> w = make_warp("translation", sensor_size=(10, 10))
        >>> w.warp(np.array([5.0]), np.array([5.0]), np.array([0.1]), np.array([10.0, 0.0]))
        (array([4.]), array([5.]))
        """
        x, y, dt = self.check_events(x, y, dt)
        n = x.shape[0]
        xw = np.empty(n)
        yw = np.empty(n)
        if jacobian:
            jx = np.empty((n, self.n_params))
            jy = np.empty((n, self.n_params))
            self.warp_into(x, y, dt, theta, xw, yw, jx, jy)
            return xw, yw, jx, jy
        self.warp_into(x, y, dt, theta, xw, yw)
        return xw, yw

    def warp_into(self, x, y, dt, theta, xw, yw, jx=None, jy=None) -> None:
        """Allocation-free :meth:`warp`: writes into ``xw, yw`` (N,) and, if given,
        ``jx, jy`` (N, P); all float64 C-contiguous. Inputs must be float64 contiguous."""
        th = self.check_theta(theta)
        jac = jx is not None
        n = np.shape(x)[0] if np.ndim(x) == 1 else -1
        for nm, a in (("x", x), ("y", y), ("dt", dt), ("xw", xw), ("yw", yw)):
            if not (isinstance(a, np.ndarray) and a.dtype == np.float64 and a.shape == (n,)
                    and a.flags.c_contiguous):
                raise ParameterError(f"warp_into: '{nm}' must be a C-contiguous float64 array "
                                     f"of shape (N,) like x, got {getattr(a, 'dtype', type(a))} "
                                     f"{np.shape(a)}")
        if jac:
            for nm, a in (("jx", jx), ("jy", jy)):
                if not (isinstance(a, np.ndarray) and a.dtype == np.float64
                        and a.shape == (n, self.n_params) and a.flags.c_contiguous):
                    raise ParameterError(f"warp_into: '{nm}' must be a C-contiguous float64 "
                                         f"array of shape ({n}, {self.n_params}), got "
                                         f"{np.shape(a)}")
        else:
            jx = jy = EMPTY2
        self._kernel(x, y, dt, th, xw, yw, jx, jy, jac)

    def _kernel(self, x, y, dt, th, xw, yw, jx, jy, jac):  # pragma: no cover - abstract
        raise NotImplementedError

    def _geom(self, x, y, dt, theta):
        M, Md = self.matrices(dt, theta)
        xt = np.stack([x, y, np.ones_like(x)], axis=-1)[..., None]
        q = (M @ xt)[..., 0]
        p = (Md @ xt)[..., 0]
        return M, Md, q, p

    # -- differential quantities ----------------------------------------------------------
    def flow(self, x, y, dt, theta):
        """(3.8) ``f = dW/dt`` at each event, px/s: returns ``fx, fy`` (N,).

        It is minus the image velocity of the scene (see :meth:`optical_flow`)."""
        x, y, dt = self.check_events(x, y, dt)
        _, _, q, p = self._geom(x, y, dt, self.check_theta(theta))
        xw = q[:, 0] / q[:, 2]
        yw = q[:, 1] / q[:, 2]
        return (p[:, 0] - xw * p[:, 2]) / q[:, 2], (p[:, 1] - yw * p[:, 2]) / q[:, 2]

    def optical_flow(self, x, y, theta):
        """Image velocity (u, v) in px/s of the scene point at pixel ``(x, y)`` at ``t_ref``
        (the motion field the warp models; u right, v down)."""
        x, y, _ = self.check_events(x, y, np.zeros(np.shape(x)))
        fx, fy = self.flow(x, y, np.zeros_like(x), theta)
        return -fx, -fy

    def jacobian(self, x, y, dt, theta) -> np.ndarray:
        """(3.13) ``J = dW/dx`` at each event, (N, 2, 2), rows (x', y'), columns (x, y)."""
        x, y, dt = self.check_events(x, y, dt)
        M, _, q, _ = self._geom(x, y, dt, self.check_theta(theta))
        w = q[:, :2] / q[:, 2:3]
        J = (M[:, :2, :2] - w[:, :, None] * M[:, 2:3, :2]) / q[:, 2, None, None]
        return J

    def _det(self, x, y, dt, th):
        M, _, q, _ = self._geom(x, y, dt, th)
        return np.linalg.det(M) / q[:, 2] ** 3

    def _div(self, x, y, dt, th):
        M, Md, q, p = self._geom(x, y, dt, th)
        q3 = q[:, 2]
        out = 0.0
        for i in range(2):
            a = M[:, :, i]
            b = Md[:, :, i]
            out = (out + b[:, i] / q3
                   - (p[:, i] * a[:, 2] + a[:, i] * p[:, 2] + q[:, i] * b[:, 2]) / q3 ** 2
                   + 2.0 * q[:, i] * p[:, 2] * a[:, 2] / q3 ** 3)
        return out

    def _rcad(self, x, y, dt, th):
        M, Md, _, _ = self._geom(x, y, dt, th)
        L = -np.linalg.solve(M, Md)
        lx = L[:, 2, 0] * x + L[:, 2, 1] * y + L[:, 2, 2]
        return L[:, 0, 0] + L[:, 1, 1] + L[:, 2, 2] - 3.0 * lx

    def _with_grad(self, fn, x, y, dt, theta, grad: bool):
        th = self.check_theta(theta)
        val = np.real(fn(x, y, dt, th))
        if not grad:
            return val
        g = np.empty((x.shape[0], self.n_params))
        for j in range(self.n_params):
            tc = th.astype(np.complex128)
            tc[j] += 1j * _CSTEP
            g[:, j] = np.imag(fn(x, y, dt, tc)) / _CSTEP
        return val, g

    def divergence(self, x, y, dt, theta, grad: bool = False):
        """Divergence of the flow (3.8) at each event, 1/s (3.9).

        Returns ``div`` (N,), and ``d div / d theta`` (N, P) if ``grad``."""
        x, y, dt = self.check_events(x, y, dt)
        return self._with_grad(self._div, x, y, dt, theta, grad)

    def jacobian_det(self, x, y, dt, theta, grad: bool = False):
        """``det(dW/dx)`` at each event (3.13), (A.4): the area amplification factor
        from ``t_k`` to ``t_ref``. Returns (N,), and (N, P) derivatives if ``grad``."""
        x, y, dt = self.check_events(x, y, dt)
        return self._with_grad(self._det, x, y, dt, theta, grad)

    def rcad(self, x, y, dt, theta, grad: bool = False):
        """Rate of change of area deformation at each event, 1/s ((3.20), (3.27), (A.6)).

        ``d det(dx(t+h)/dx(t)) / dh`` at ``h = 0`` for the point trajectory through the
        event: positive where the trajectories spread forward in time (warping back to
        ``t_ref`` contracts them)."""
        x, y, dt = self.check_events(x, y, dt)
        return self._with_grad(self._rcad, x, y, dt, theta, grad)

    def trajectory(self, x_ref, y_ref, dt, theta):
        """Position at ``t_ref + dt`` (seconds) of the point at ``(x_ref, y_ref)`` at
        ``t_ref``: the inverse of :meth:`warp`. Returns ``x, y`` (N,)."""
        x, y, dt = self.check_events(x_ref, y_ref, dt)
        M, _ = self.matrices(dt, self.check_theta(theta))
        xt = np.stack([x, y, np.ones_like(x)], axis=-1)[..., None]
        q = np.linalg.solve(M, xt)[..., 0]
        return q[:, 0] / q[:, 2], q[:, 1] / q[:, 2]

    def _area_log(self, x, y, t, th):
        Mi = np.linalg.inv(self.matrices(np.array([t]), th)[0][0])
        q3 = Mi[2, 0] * x + Mi[2, 1] * y + Mi[2, 2]
        return -3.0 * np.log(q3 * np.sign(np.real(q3))) + np.log(
            np.linalg.det(Mi) * np.sign(np.real(np.linalg.det(Mi))))

    def area_log_ratio(self, x_ref, y_ref, t0: float, t1: float, theta, grad: bool = False):
        """RCAD integrated along the trajectory through ``(x_ref, y_ref)`` at ``t_ref`` over
        ``[t0, t1]`` (seconds relative to ``t_ref``); dimensionless.

        Equals ``log|det dx(t1)/dx_ref| - log|det dx(t0)/dx_ref|`` (Liouville), which is
        (3.21) for the zoom, (3.28) for the rotation, (A.44)/(A.53) for similarity/affine.
        Returns (N,), and (N, P) derivatives if ``grad``."""
        x, y, _ = self.check_events(x_ref, y_ref, np.zeros(np.shape(x_ref)))

        def fn(x, y, _dt, th):
            return self._area_log(x, y, t1, th) - self._area_log(x, y, t0, th)

        return self._with_grad(fn, x, y, x, theta, grad)
