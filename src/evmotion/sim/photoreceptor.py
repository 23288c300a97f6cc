"""Shot noise and bandwidth of an event pixel's photoreceptor in low light.

An event pixel compares the log of its photocurrent, as its photoreceptor reports it, with
a memorized level. In low light that report is noisy (photon shot noise) and, in a real
DVS, slow: the photoreceptor's cutoff frequency is roughly proportional to the
photocurrent (Lichtsteiner, Posch & Delbruck, IEEE JSSC 43(2), 2008; modelled by the v2e
simulator as an intensity-dependent first-order low-pass, Hu, Liu & Delbruck, CVPRW
2021). Two models of it, both callables ``log_at(t_us, pix)`` for
:func:`evmotion.sim.simulator.simulate_log_function`, built on a radiance function
``radiance(t_s, pix)`` (relative to white, (H, W) for ``pix=None`` else (P,)) and
``event_photons``, the expected photons of a white pixel per ``tau_us``:

``"fixed"`` (worst case)
    The log radiance plus Gaussian noise of standard deviation ``1 / sqrt(event_photons
    * I)`` drawn independently every ``tau_us`` at every light level and linear in
    between; no low-pass of the signal. Its noise grows as ``1 / sqrt(photons)`` as the
    light dims.
``"intensity"`` (the standard DVS model)
    A first-order low-pass of the log photocurrent, ``dy/dt = (log I - y) / tau`` plus its
    shot noise, with the time constant set by the pixel's photon count per ``tau_us``,
    ``n = event_photons * I``::

        tau(n) = tau_us * clip(NOISE_PHOTONS / n, 1, TAU_RATIO_MAX)

    ``tau_us`` is the bright-light time constant; below ``NOISE_PHOTONS`` photons per
    ``tau_us`` the time constant is ``NOISE_PHOTONS`` over the photon flux (whatever
    ``tau_us``): the pixel integrates over ``NOISE_PHOTONS`` photons, so its noise (the
    stationary standard deviation of ``y - log I``, ``1 / sqrt(n * tau / tau_us)``) stays
    at ``1 / sqrt(NOISE_PHOTONS)`` while its response slows, down to ``TAU_RATIO_MAX``
    times ``tau_us``; darker still, the noise grows again. The filter is advanced exactly
    (an Ornstein-Uhlenbeck step for an input linear between knots) on knots every
    ``step_us`` and read between knots by linear interpolation.

Literature values (not fitted to any result of this project): ``NOISE_PHOTONS = 162``,
i.e. a log-intensity noise of 0.0785 in dim light: the photoreceptor noise that v2e's
``compute_photoreceptor_noise_voltage`` (the fit to Graca & Delbruck 2021, "Unraveling
the paradox of intensity-dependent DVS pixel noise", Fig. 3) gives for v2e's dim-light
preset ``noisy`` (cutoff 30 Hz, shot noise 5 Hz per pixel, threshold 0.2).
``TAU_RATIO_MAX = 275 / 20``: v2e's longest to shortest photoreceptor time constant
(its intensity ``(DN + 20) / 275`` of an 8-bit frame).

>>> import numpy as np
>>> flat = lambda t_s, pix: np.full((2, 3) if pix is None else len(pix), 0.5)
>>> pr = Photoreceptor(flat, (2, 3), event_photons=40.0, tau_us=1000,
...                    bandwidth="intensity")
>>> float(pr.time_constant_us(np.array([0.5]))[0])  # 162 / (40 * 0.5) ms
8100.0
>>> round(float(pr.noise_std(np.array([0.5]))[0]), 4)  # 1 / sqrt(162)
0.0786
>>> pr(0, None).shape
(2, 3)
"""

from __future__ import annotations

import math

import numpy as np

from evmotion.errors import ParameterError

__all__ = ["EVENT_BANDWIDTHS", "NOISE_PHOTONS", "TAU_RATIO_MAX", "Photoreceptor"]

EVENT_BANDWIDTHS = ("fixed", "intensity")
NOISE_PHOTONS = 162.0  # photons per time constant in dim light: noise 1/sqrt(162) = 0.0785
TAU_RATIO_MAX = 275.0 / 20.0  # slowest / fastest time constant (v2e)
_KEEP = 8  # knots kept: the sampler reads back at most one step (<= step_us) at a time


class Photoreceptor:
    """The log intensity an event pixel reports, with shot noise (module docstring).

    Parameters
    ----------
    radiance : callable
        ``radiance(t_s, pix)``: radiance relative to white at time ``t_s`` (seconds),
        (H, W) when ``pix`` is None else (P,) for row-major pixel indices ``pix``.
    shape : (int, int)
        ``(H, W)``.
    event_photons : float
        Expected photons of a white pixel per ``tau_us`` (> 0).
    tau_us : int
        ``"fixed"``: the noise's redraw interval, µs; ``"intensity"``: the bright-light
        time constant, µs.
    bandwidth : {"fixed", "intensity"}
    seed : int
        Seeds the noise (any time is reproducible whatever order it is asked in).
    step_us : int, optional
        ``"intensity"``: knot spacing of the filter, µs (default ``tau_us``; at most
        ``tau_us``).

    Notes
    -----
    ``"intensity"`` advances its state forward in time: reading a time more than
    ``8 * step_us`` before the latest one asked raises RuntimeError (the event sampler
    never does).
    """

    def __init__(self, radiance, shape: tuple[int, int], *, event_photons: float,
                 tau_us: int, bandwidth: str = "fixed", seed: int = 0,
                 step_us: int | None = None) -> None:
        if bandwidth not in EVENT_BANDWIDTHS:
            raise ParameterError(f"event_bandwidth must be one of {list(EVENT_BANDWIDTHS)}, "
                                 f"got {bandwidth!r}")
        ep = float(event_photons)
        if not (math.isfinite(ep) and ep > 0):
            raise ParameterError(f"event_photons must be a finite number > 0, got "
                                 f"{event_photons!r}")
        self.radiance, self.shape, self.event_photons = radiance, tuple(shape), ep
        self.tau_us, self.bandwidth, self.seed = int(tau_us), bandwidth, int(seed)
        self.step_us = self.tau_us if step_us is None else max(1, min(int(step_us),
                                                                      self.tau_us))
        self.n_pix = int(np.prod(self.shape))
        self._normals: dict = {}
        self._knots: dict = {}

    def time_constant_us(self, rad: np.ndarray) -> np.ndarray:
        """Time constant (µs) of pixels of radiance ``rad`` (relative to white)."""
        if self.bandwidth == "fixed":
            return np.full(np.shape(rad), float(self.tau_us))
        n = self.event_photons * np.asarray(rad, dtype=np.float64)
        ratio = np.clip(NOISE_PHOTONS / np.maximum(n, 1e-300), 1.0, TAU_RATIO_MAX)
        return self.tau_us * ratio

    def noise_std(self, rad: np.ndarray) -> np.ndarray:
        """Stationary standard deviation of the reported log intensity's noise."""
        n = self.event_photons * np.asarray(rad, dtype=np.float64)
        return 1.0 / np.sqrt(n * self.time_constant_us(rad) / self.tau_us)

    def __call__(self, t, pix=None) -> np.ndarray:
        t = int(t)
        if self.bandwidth == "fixed":
            return self._fixed(t, pix)
        k, r = divmod(t, self.step_us)
        a = r / self.step_us
        y0 = self._knot(k)[0]
        y = y0 if a == 0 else (1 - a) * y0 + a * self._knot(k + 1)[0]
        return y.reshape(self.shape) if pix is None else y[np.asarray(pix)]

    # -- "fixed" ----------------------------------------------------------------------
    def _normal(self, k: int) -> np.ndarray:
        """Standard normals of every pixel at noise knot ``k`` (seeded by k); the last few
        are kept."""
        if k not in self._normals:
            if len(self._normals) >= 4:
                self._normals.pop(next(iter(self._normals)))
            rng = np.random.default_rng(np.random.SeedSequence([self.seed, 0xE7E, k]))
            self._normals[k] = rng.standard_normal(self.n_pix)
        return self._normals[k]

    def _fixed(self, t: int, pix) -> np.ndarray:
        rad = self.radiance(t * 1e-6, pix)
        k, r = divmod(t, self.tau_us)
        a = r / self.tau_us
        sel = slice(None) if pix is None else pix
        z = ((1 - a) * self._normal(k)[sel] + a * self._normal(k + 1)[sel]).reshape(rad.shape)
        return np.log(rad) + z / np.sqrt(self.event_photons * rad)

    # -- "intensity" ------------------------------------------------------------------
    def _knot(self, k: int):
        """``(y, log I, I)`` of every pixel at knot ``k`` (time ``k * step_us``), advancing
        the filter from the latest knot computed."""
        if k in self._knots:
            return self._knots[k]
        last = max(self._knots) if self._knots else None
        if last is not None and k < last:
            raise RuntimeError(f"photoreceptor state at {k * self.step_us} us was dropped "
                               f"(latest {last * self.step_us} us)")
        if last is None:
            rad = np.asarray(self.radiance(0.0, None), dtype=np.float64).ravel()
            x = np.log(rad)
            self._knots[0] = (x + self.noise_std(rad) * self._z(0), x, rad)
            last = 0
        h = float(self.step_us)
        for j in range(last + 1, k + 1):
            y0, x0, rad0 = self._knots[j - 1]
            rad = np.asarray(self.radiance(j * h * 1e-6, None), dtype=np.float64).ravel()
            x = np.log(rad)
            mid = 0.5 * (rad0 + rad)
            tau = self.time_constant_us(mid)
            e = np.exp(-h / tau)
            s_tau = (x - x0) / h * tau  # input slope times tau: the steady lag
            y = x - s_tau + (y0 - x0 + s_tau) * e
            y += self.noise_std(mid) * np.sqrt(1.0 - e * e) * self._z(j)
            self._knots[j] = (y, x, rad)
            while len(self._knots) > _KEEP:
                self._knots.pop(min(self._knots))
        return self._knots[k]

    def _z(self, k: int) -> np.ndarray:
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, 0x1B0, k]))
        return rng.standard_normal(self.n_pix)
