"""Background-oriented schlieren (BOS) simulator with exact ground truth (thesis ch. 6).

Model
-----
* **Background**: random dots (printed black dots on white paper, 1-3 px in the image),
  seeded, each an isotropic Gaussian of darkness; the radiance is
  ``I(x) = 1 - contrast * (1 - exp(-D(x)))`` with ``D`` the sum of the dots' darkness
  (overlapping dots saturate smoothly). The dots are band-limited (their width includes
  the pixel's own box, σ² + 1/12), so sampling ``I`` at a point is the pixel's value;
  ``I`` is evaluated analytically at sub-pixel positions, never looked up on a grid.
* **Air**: a scalar field ``φ(x, t)`` (the projected density, a sum of Gaussian puffs
  advected by the scene's flow: a rising thermal plume, a turbulent jet, breath puffs,
  a falling cold stream). By (6.1)-(6.3) the background seen at pixel ``x`` is displaced
  by ``d(x, t) = ∇φ(x, t)`` (the gain is folded into φ): the frame shows
  ``I(x - d(x, t))``, so the pattern appears moved by ``+d`` (to first order in ∇d) and
  ``d`` is the image motion that optical flow measures. The optical flow between frames at ``t1 < t2`` is
  ``v = (d(t2) - d(t1)) / (t2 - t1) = ∇q`` with ``q = (φ(t2) - φ(t1)) / (t2 - t1)`` (6.4)-(6.6):
  a curl-free field, the thesis' Poisson parameterization ``v = ∇q``. The field is
  scaled so that the largest inter-frame displacement ``|v| Δt`` is ``magnitude_px``.
* **Frames** (default 120 fps): the radiance averaged over the exposure (centred on the
  frame time), shot noise (Poisson photons, seeded) when ``photons`` (expected
  photoelectrons of a white pixel) is given, Gaussian read noise (``read_noise_e``,
  electrons rms), a gain (grey levels per electron: by default full scale at any light,
  or fixed as a real camera's at a fixed exposure), ``bit_depth``-bit quantization with
  clipping, and optionally each frame stretched to the full range (``normalize``).
* **Events** from the same radiance (its log) through the project's event model
  (:func:`evmotion.sim.simulator.simulate_log_function`: per-pixel threshold mismatch,
  crossings at interpolated times, refractory period, noise), with every frame time a
  sample time, so the events between two frames sum (times their thresholds) to the
  log-intensity change within a threshold at each end (6.7)-(6.8). Low light for the
  events: ``event_photons`` adds shot noise to the log intensity they see, with a
  fixed noise bandwidth (worst case) or, ``event_bandwidth="intensity"``, through a
  photoreceptor whose bandwidth falls with the light (:mod:`evmotion.sim.photoreceptor`).

Ground truth (:class:`SchlierenGT`): the exact flow between consecutive frames (px/s),
``q`` per frame interval, the displacement ``d`` at every frame, the contrast
thresholds, and the scene's metadata (e.g. the plume's rise speed in px/s, which a
kymogram along the plume's axis measures).

Speed (one core, ``benchmarks/bench_bos_sim.py``): 720x640 at a largest inter-frame
displacement of 2 px, 0.4-0.7 CPU s per frame interval (frames and events); 96x96, about
20 ms per interval.

>>> sim = simulate_schlieren("plume", sensor_size=(48, 40), duration_s=1 / 60, seed=0)
>>> sim.frames.images.shape, sim.gt.flow.shape, sim.gt.t_us.tolist()
((3, 48, 40), (2, 48, 40, 2), [0, 8333, 16667])
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numba import njit

from evmotion.errors import EvmotionWarning, FormatError, ParameterError
from evmotion.events import EventArray
from evmotion.io.flowread import SCHLIEREN_GT_FORMAT
from evmotion.io.frames import Frames
from evmotion.io.guard import guarded, open_h5
from evmotion.io.h5attrs import read_attrs
from evmotion.io.pngfile import write_png
from evmotion.sim.options import SchlierenOptions, check_number
from evmotion.sim.photoreceptor import Photoreceptor
from evmotion.sim.scenes import BOS_SCENES
from evmotion.sim.simulator import parse_sensor_size, simulate_log_function
from evmotion.utils import resolve_options, whole_number

__all__ = ["BOS_SCENES", "Background", "PuffField", "SchlierenGT", "SchlierenSim",
           "is_schlieren_gt", "make_background", "make_field", "normalize_range",
           "read_schlieren_gt",
           "read_schlieren_q", "simulate_schlieren", "write_schlieren"]

GT_FORMAT = SCHLIEREN_GT_FORMAT
BLOB_CUTOFF = 4.0  # puffs are evaluated within this many widths (exp(-8) beyond)
DOT_CUTOFF = 5.0  # dots within this many widths (a darkness of 2 exp(-12.5) beyond)
DOT_PEAK = 2.0  # darkness at a dot's centre: 1 - exp(-2) of full contrast


# ---------------------------------------------------------------------------------------
# background


@njit(cache=True)
def _bg_kernel(sx, sy, dx, dy, inv2s2, amp, r2max, cell_start, gx0, gy0, cs, ncx, ncy,
               contrast, out):
    # dots are stored in cell order: the cells around a point are contiguous runs
    for i in range(sx.shape[0]):
        px = sx[i]
        py = sy[i]
        cx = int(math.floor((px - gx0) / cs))
        cy = int(math.floor((py - gy0) / cs))
        dark = 0.0
        # cells are half the cut-off radius: the 5x5 cells around the point cover it
        for jy in range(max(cy - 2, 0), min(cy + 3, ncy)):
            row = jy * ncx
            for k in range(cell_start[row + max(cx - 2, 0)],
                           cell_start[row + min(cx + 3, ncx)]):
                ex = px - dx[k]
                ey = py - dy[k]
                r2 = ex * ex + ey * ey
                if r2 < r2max[k]:
                    dark += amp[k] * math.exp(-r2 * inv2s2[k])
        out[i] = 1.0 - contrast * (1.0 - math.exp(-dark))


@dataclass(frozen=True, eq=False)
class Background:
    """A random-dot BOS background: dot centres ``x``, ``y`` (px), widths ``sigma`` (px,
    including the pixel box), peak darkness ``amp`` and the print ``contrast``.

    Use :meth:`radiance` (numba, binned dots) or :meth:`radiance_reference` (plain numpy
    over every dot, for tests) to evaluate it at sub-pixel points.
    """

    x: np.ndarray
    y: np.ndarray
    sigma: np.ndarray
    amp: np.ndarray
    contrast: float
    origin: tuple[float, float]
    cell: float
    grid: tuple[int, int]
    cell_start: np.ndarray = field(repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_inv2s2", 0.5 / self.sigma ** 2)
        object.__setattr__(self, "_r2max", (DOT_CUTOFF * self.sigma) ** 2)

    def radiance(self, sx: np.ndarray, sy: np.ndarray) -> np.ndarray:
        """Radiance in (0, 1] at points ``(sx, sy)`` (px, any shape), float64."""
        sx = np.asarray(sx, dtype=np.float64)
        shape = sx.shape
        fx = np.ascontiguousarray(sx.ravel())
        fy = np.ascontiguousarray(np.asarray(sy, dtype=np.float64).ravel())
        out = np.empty(fx.size)
        _bg_kernel(fx, fy, self.x, self.y, self._inv2s2, self.amp, self._r2max,
                   self.cell_start, self.origin[0], self.origin[1], self.cell, self.grid[1],
                   self.grid[0], self.contrast, out)
        return out.reshape(shape)

    def radiance_reference(self, sx: np.ndarray, sy: np.ndarray) -> np.ndarray:
        """Plain-numpy reference of :meth:`radiance` summing every dot (no cut-off)."""
        sx = np.asarray(sx, dtype=np.float64)[..., None]
        sy = np.asarray(sy, dtype=np.float64)[..., None]
        r2 = (sx - self.x) ** 2 + (sy - self.y) ** 2
        dark = (self.amp * np.exp(-r2 / (2 * self.sigma ** 2))).sum(axis=-1)
        return 1.0 - self.contrast * (1.0 - np.exp(-dark))


def make_background(sensor_size: tuple[int, int], *, density: float = 0.06,
                    radius_px: float = 1.0, contrast: float = 0.85, margin_px: float = 8.0,
                    seed: int = 0) -> Background:
    """Random dots over the sensor plus a margin (points displaced off the sensor still
    see dots).

    Parameters
    ----------
    sensor_size : (int, int)
        ``(height, width)``.
    density : float
        Dots per px² (0.06 with radius 1 px darkens about a third of the area).
    radius_px : float
        Mean dot radius (px) in the image; radii vary uniformly by ±25 %. The printed
        disc of radius r is modelled as a Gaussian of σ = r / 1.2, widened by the pixel box.
    contrast : float
        Darkest radiance is ``1 - contrast`` (white paper is 1).
    margin_px : float
        Extra border, px.
    seed : int

    Examples
    --------
    >>> bg = make_background((32, 32), seed=1)
    >>> v = bg.radiance(np.array([3.25]), np.array([7.5]))
    >>> bool(0 < v[0] <= 1)
    True
    """
    h, w = sensor_size
    density = float(density)
    radius_px = float(radius_px)
    if not (math.isfinite(density) and 0 < density <= 2):
        raise ParameterError(f"dot_density must be in (0, 2] dots per px², got {density!r}")
    if not (math.isfinite(radius_px) and 0.2 <= radius_px <= 10):
        raise ParameterError(f"dot_radius_px must be in [0.2, 10] px, got {radius_px!r}")
    if not (math.isfinite(contrast) and 0 < contrast < 1):
        raise ParameterError(f"contrast must be in (0, 1), got {contrast!r}")
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x0B05]))
    x0, y0 = -margin_px, -margin_px
    ww, hh = w + 2 * margin_px, h + 2 * margin_px
    n = int(rng.poisson(density * ww * hh))
    x = x0 + ww * rng.random(n)
    y = y0 + hh * rng.random(n)
    r = radius_px * (0.75 + 0.5 * rng.random(n))
    sigma = np.sqrt((r / 1.2) ** 2 + 1.0 / 12.0)
    amp = np.full(n, DOT_PEAK)
    cell = float(max(0.5, 0.5 * DOT_CUTOFF * sigma.max(initial=1.0)))
    ncx, ncy = int(math.ceil(ww / cell)) + 1, int(math.ceil(hh / cell)) + 1
    cid = (np.floor((y - y0) / cell).astype(np.int64) * ncx
           + np.floor((x - x0) / cell).astype(np.int64))
    order = np.argsort(cid, kind="stable")
    start = np.searchsorted(cid[order], np.arange(ncx * ncy + 1)).astype(np.int64)
    return Background(x=x[order], y=y[order], sigma=sigma[order], amp=amp[order],
                      contrast=float(contrast), origin=(x0, y0), cell=cell, grid=(ncy, ncx),
                      cell_start=start)


# ---------------------------------------------------------------------------------------
# air: a sum of advected Gaussian puffs


@njit(cache=True)
def _field_full(cx, cy, s, a, phi, gx, gy):
    h, w = phi.shape
    phi[:] = 0.0
    gx[:] = 0.0
    gy[:] = 0.0
    for j in range(cx.shape[0]):
        r = BLOB_CUTOFF * s[j]
        x0 = max(0, int(math.ceil(cx[j] - r)))
        x1 = min(w - 1, int(math.floor(cx[j] + r)))
        y0 = max(0, int(math.ceil(cy[j] - r)))
        y1 = min(h - 1, int(math.floor(cy[j] + r)))
        if x1 < x0 or y1 < y0:
            continue
        inv = 1.0 / (s[j] * s[j])
        # the Gaussian is separable: one exp per column and per row, not per pixel
        n = x1 - x0 + 1
        ex = np.empty(n)
        fx = np.empty(n)
        for i in range(n):
            ex[i] = x0 + i - cx[j]
            fx[i] = math.exp(-0.5 * ex[i] * ex[i] * inv)
        for y in range(y0, y1 + 1):
            ey = y - cy[j]
            fy = a[j] * math.exp(-0.5 * ey * ey * inv)
            for i in range(n):
                g = fy * fx[i]
                phi[y, x0 + i] += g
                gx[y, x0 + i] -= g * ex[i] * inv
                gy[y, x0 + i] -= g * ey * inv


@njit(cache=True)
def _field_pix(xs, ys, cx, cy, s, a, phi, gx, gy):
    for i in range(xs.shape[0]):
        p = 0.0
        qx = 0.0
        qy = 0.0
        for j in range(cx.shape[0]):
            ex = xs[i] - cx[j]
            ey = ys[i] - cy[j]
            r = BLOB_CUTOFF * s[j]
            if abs(ex) > r or abs(ey) > r:
                continue
            inv = 1.0 / (s[j] * s[j])
            g = a[j] * math.exp(-0.5 * (ex * ex + ey * ey) * inv)
            p += g
            qx -= g * ex * inv
            qy -= g * ey * inv
        phi[i] = p
        gx[i] = qx
        gy[i] = qy


def _smooth(u):
    u = np.clip(u, 0.0, 1.0)
    return u * u * (3 - 2 * u)


@dataclass(eq=False)
class PuffField:
    """The projected density ``φ`` as Gaussian puffs born at times ``birth`` (s), moving
    from ``p0`` (px) with initial velocity ``v0`` (px/s), drag time ``drag`` (s, 0 for
    none), acceleration ``acc`` (px/s²) and a sideways wobble; width ``s0`` growing by
    ``grow`` per px travelled; amplitude ``amp`` faded in/out over ``fade_in``/``fade_out``
    (s) within the life ``life`` (s), and by ``(s0 / s) ** dilute`` as it spreads (2: its
    integral is kept). ``gain`` scales ``φ`` (px², so that ``∇φ`` is the displacement in
    px)."""

    sensor_size: tuple[int, int]
    birth: np.ndarray
    p0: np.ndarray
    v0: np.ndarray
    acc: np.ndarray
    drag: np.ndarray
    s0: np.ndarray
    grow: np.ndarray
    amp: np.ndarray
    life: np.ndarray
    fade_in: np.ndarray
    fade_out: np.ndarray
    wobble_amp: np.ndarray
    wobble_freq: np.ndarray
    wobble_phase: np.ndarray
    dilute: np.ndarray | None = None
    gain: float = 1.0

    def puffs_at(self, t_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Centres ``cx, cy`` (px), widths (px) and amplitudes of the live puffs at ``t_s``."""
        age = t_s - self.birth
        live = (age >= 0) & (age <= self.life)
        age = age[live]
        drag = self.drag[live]
        travel = np.where(drag > 0, drag * (1 - np.exp(-age / np.where(drag > 0, drag, 1.0))),
                          age)
        v0 = self.v0[live]
        path = v0 * travel[:, None] + 0.5 * self.acc[live] * (age ** 2)[:, None]
        speed = np.hypot(v0[:, 0], v0[:, 1])
        perp = np.stack([-v0[:, 1], v0[:, 0]], axis=1) / np.where(speed > 0, speed, 1.0)[:, None]
        perp[speed == 0] = (1.0, 0.0)
        wob = (self.wobble_amp[live] * (age / self.life[live])
               * np.sin(2 * np.pi * self.wobble_freq[live] * age + self.wobble_phase[live]))
        pos = self.p0[live] + path + wob[:, None] * perp
        s = self.s0[live] + self.grow[live] * np.hypot(path[:, 0], path[:, 1])
        env = (_smooth(age / self.fade_in[live])
               * _smooth((self.life[live] - age) / self.fade_out[live]))
        if self.dilute is not None:  # a spreading puff keeps its heat: peak ~ (s0 / s)^k
            env = env * (self.s0[live] / s) ** self.dilute[live]
        a = self.gain * self.amp[live] * env
        keep = a != 0
        return (np.ascontiguousarray(pos[keep, 0]), np.ascontiguousarray(pos[keep, 1]),
                np.ascontiguousarray(s[keep]), np.ascontiguousarray(a[keep]))

    def evaluate(self, t_s: float, pix: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
        """``φ`` (px²) and the displacement ``∇φ`` (px, last axis ``dx, dy``) at time
        ``t_s``, on the whole sensor ((H, W) and (H, W, 2)) or at the row-major pixel
        indices ``pix`` ((P,) and (P, 2))."""
        h, w = self.sensor_size
        cx, cy, s, a = self.puffs_at(t_s)
        if pix is None:
            phi, gx, gy = (np.empty((h, w)) for _ in range(3))
            _field_full(cx, cy, s, a, phi, gx, gy)
        else:
            pix = np.asarray(pix, dtype=np.int64)
            ys, xs = np.divmod(pix, w)
            phi, gx, gy = (np.empty(pix.size) for _ in range(3))
            _field_pix(xs.astype(np.float64), ys.astype(np.float64), cx, cy, s, a, phi, gx, gy)
        return phi, np.stack([gx, gy], axis=-1)


#: The longest the air may take to cross the view (its larger side), s.
MAX_CROSSING_S = 1000.0
#: The air's largest displacement, in widths of the view (the larger side), a scene may
#: reach: the defaults reach 0.7-12 px on 48x48 to 720x640 px views, magnitude 3 px 81 px
#: on 48x40 (ice); at speeds of 1 px/s and below, 900 px to 9e8 px.
MAX_REACH_VIEWS = 10


#: The most puffs of warm air a scene may hold: their number grows with the speed and the
#: duration (the defaults: tens to a few thousand).
MAX_PUFFS = 1_000_000


def _births(rng, t0: float, t1: float, every: float) -> np.ndarray:
    """Birth times (s) of puffs about every ``every`` s over ``[t0, t1)``, jittered."""
    n = (t1 - t0) / every
    if not n <= MAX_PUFFS:
        # (probe OPT: speed 1e30 px/s reached numpy's "Maximum allowed size exceeded")
        raise ParameterError(f"speed_px_s and duration_s make {n:.3g} puffs of warm air, "
                             f"at most {MAX_PUFFS:g}: give a lower speed (--speed) or a "
                             "shorter duration (--duration)")
    n = max(1, int(math.ceil(n)))
    return t0 + every * (np.arange(n) + rng.uniform(-0.3, 0.3, n))


def _plume_puffs(h: int, w: int, duration_s: float, speed: float, rng) -> dict:
    """A plume of warm air rising from the bottom centre."""
    u = float(min(h, w))
    s0 = 0.012 * u + 2.5
    life = 1.3 * h / speed
    b = _births(rng, -life, duration_s, 1.1 * s0 / speed)
    n = b.size
    return dict(p0=np.stack([w / 2 + rng.normal(0, 0.01 * w, n), np.full(n, h + 2 * s0)], 1),
                v0=np.stack([np.zeros(n), np.full(n, -speed)], 1),
                acc=np.zeros((n, 2)), drag=np.zeros(n), s0=s0 * rng.uniform(0.8, 1.2, n),
                grow=np.full(n, 1.2 * s0 / h), amp=rng.uniform(0.3, 1.0, n),
                life=np.full(n, life), fade_in=np.full(n, 0.1 * life),
                fade_out=np.full(n, 0.1 * life), wobble_amp=np.full(n, 0.06 * w),
                wobble_freq=rng.uniform(0.5, 1.5, n) * speed / h,
                wobble_phase=np.full(n, rng.uniform(0, 2 * np.pi)),
                birth=b)


def _jet_puffs(h: int, w: int, duration_s: float, speed: float, rng) -> dict:
    """A turbulent jet from the left edge, eddies of both signs (mostly warm)."""
    u = float(min(h, w))
    s0 = 0.008 * u + 2.0
    drag = 1.3 * w / speed
    life = 2.0 * drag
    b = _births(rng, -life, duration_s, 1.0 * s0 / speed)
    n = b.size
    theta = rng.normal(0, 0.12, n)
    v = speed * rng.uniform(0.8, 1.2, n)
    return dict(p0=np.stack([np.full(n, -2 * s0), h / 2 + rng.normal(0, s0, n)], 1),
                v0=np.stack([v * np.cos(theta), v * np.sin(theta)], 1),
                acc=np.zeros((n, 2)), drag=np.full(n, drag),
                s0=s0 * rng.uniform(0.6, 1.4, n), grow=np.full(n, 2.0 * s0 / w),
                amp=rng.uniform(0.3, 1.0, n) * np.where(rng.random(n) < 0.75, 1.0, -1.0),
                life=np.full(n, life), fade_in=np.full(n, 0.05 * life),
                fade_out=np.full(n, 0.3 * life), wobble_amp=np.full(n, 0.08 * h),
                wobble_freq=rng.uniform(2.0, 6.0, n) * speed / w,
                wobble_phase=rng.uniform(0, 2 * np.pi, n),
                birth=b)


def _breath_puffs(h: int, w: int, duration_s: float, speed: float, rng) -> dict:
    """Breath: a pulsed, decelerating turbulent jet of warm air, eddies of both signs
    (mostly warm) that spread and thin out, so no warm lump piles up in front of the
    mouth."""
    u = float(min(h, w))
    s0 = 0.01 * u + 2.5
    drag = 0.8 * w / speed
    life = 2.0 * drag
    # exhaling 1 s of every 2.5 s; the first exhale began 0.5 s before the recording
    period, exhale = 2.5, 1.0
    starts = np.arange(-0.5 - period * math.ceil(life / period), duration_s, period)
    per = [_births(rng, t, t + exhale, 0.8 * s0 / speed) for t in starts]
    b = np.concatenate(per)
    phase = np.concatenate([(bb - t) / exhale for t, bb in zip(starts, per, strict=True)])
    n = b.size
    theta = np.deg2rad(20.0) + rng.normal(0, 0.15, n)
    v = speed * (0.5 + 0.5 * np.sin(np.pi * np.clip(phase, 0, 1))) * rng.uniform(0.8, 1.2, n)
    return dict(p0=np.stack([np.full(n, 0.08 * w), 0.4 * h + rng.normal(0, s0, n)], 1),
                v0=np.stack([v * np.cos(theta), v * np.sin(theta)], 1),
                acc=np.zeros((n, 2)), drag=np.full(n, drag),
                s0=s0 * rng.uniform(0.7, 1.3, n), grow=np.full(n, 0.12),
                dilute=np.full(n, 1.0),
                amp=rng.uniform(0.5, 1.0, n) * np.where(rng.random(n) < 0.7, 1.0, -1.0),
                life=np.full(n, life), fade_in=np.full(n, 0.12 * life),
                fade_out=np.full(n, 0.5 * life), wobble_amp=np.full(n, 0.06 * h),
                wobble_freq=rng.uniform(2.0, 5.0, n) * speed / w,
                wobble_phase=rng.uniform(0, 2 * np.pi, n),
                birth=b)


def _ice_puffs(h: int, w: int, duration_s: float, speed: float, rng) -> dict:
    """Cold air falling from the top centre (an ice cube), accelerating."""
    u = float(min(h, w))
    s0 = 0.012 * u + 2.5
    g = speed ** 2 / (2 * 1.1 * h)  # reaches `speed` at the bottom
    v0y = 0.1 * speed
    life = (-v0y + math.sqrt(v0y ** 2 + 2 * g * 1.3 * h)) / g
    b = _births(rng, -life, duration_s, 1.2 * s0 / (0.5 * speed))
    n = b.size
    return dict(p0=np.stack([w / 2 + rng.normal(0, 0.02 * w, n), np.full(n, -2 * s0)], 1),
                v0=np.stack([np.zeros(n), np.full(n, v0y)], 1),
                acc=np.tile([0.0, g], (n, 1)), drag=np.zeros(n),
                s0=s0 * rng.uniform(0.8, 1.2, n), grow=np.full(n, 0.8 * s0 / h),
                amp=-rng.uniform(0.3, 1.0, n), life=np.full(n, life),
                fade_in=np.full(n, 0.1 * life), fade_out=np.full(n, 0.1 * life),
                wobble_amp=np.full(n, 0.03 * w),
                wobble_freq=rng.uniform(0.5, 1.5, n) * speed / h,
                wobble_phase=rng.uniform(0, 2 * np.pi, n),
                birth=b)


_PUFFS = {"plume": _plume_puffs, "jet": _jet_puffs, "breath": _breath_puffs, "ice": _ice_puffs}


def _scene_table(scene: str, sensor_size, duration_s: float, speed: float, rng) -> dict:
    """Puff parameters of a scene (see :data:`BOS_SCENES`), in px, s, px/s."""
    if scene not in _PUFFS:
        raise ParameterError(f"unknown schlieren scene {scene!r}; choose one of "
                             f"{sorted(BOS_SCENES)}")
    h, w = sensor_size
    return _PUFFS[scene](h, w, duration_s, speed, rng)


DEFAULT_SPEED = {  # px/s at the thesis ROI (720 px high, 640 wide); scaled with the size
    "plume": 2400.0,  # Sec. 6.6.5: 166 px in 68.8 ms
    "jet": 3000.0,
    "breath": 1500.0,
    "ice": 1200.0,
}


def make_field(scene: str, sensor_size: tuple[int, int], duration_s: float, *,
               speed_px_s: float | None = None, seed: int = 0) -> PuffField:
    """The (unscaled, ``gain=1``) puff field of a scene; ``speed_px_s`` defaults to
    :data:`DEFAULT_SPEED` scaled by the sensor size relative to 720x640 (rise speed of the
    plume, exit speed of the jet and breath, speed of the cold stream at the bottom).

    Examples
    --------
    >>> f = make_field("plume", (64, 48), 0.05, speed_px_s=300.0)
    >>> phi, d = f.evaluate(0.0)
    >>> phi.shape, d.shape
    ((64, 48), (64, 48, 2))
    """
    if scene not in BOS_SCENES:
        raise ParameterError(f"unknown schlieren scene {scene!r}; choose one of "
                             f"{sorted(BOS_SCENES)}")
    h, w = sensor_size
    if speed_px_s is None:
        ref = h / 720.0 if scene in ("plume", "ice") else w / 640.0
        speed_px_s = DEFAULT_SPEED[scene] * ref
    speed = float(speed_px_s)
    if not (math.isfinite(speed) and speed > 0):
        raise ParameterError(f"speed_px_s must be finite and > 0, got {speed_px_s!r}")
    slowest = max(h, w) / MAX_CROSSING_S
    if speed < slowest:
        # the puffs live as long as the air takes to cross the view, and are born over
        # that long before the recording: at 1e-6 px/s a breath's exhalations numbered
        # in the hundreds of millions (probe)
        raise ParameterError(f"speed_px_s={speed_px_s!r}: air that slow takes over "
                             f"{MAX_CROSSING_S:g} s to cross the {w}x{h} px view; give at "
                             f"least {slowest:.3g} px/s")
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0xA1E]))
    tab = _scene_table(scene, sensor_size, duration_s, speed, rng)
    return PuffField(sensor_size=(h, w), **{k: np.asarray(v, dtype=np.float64)
                                            for k, v in tab.items()})


# ---------------------------------------------------------------------------------------
# results


@dataclass(frozen=True, eq=False)
class SchlierenGT:
    """Exact ground truth of a simulated schlieren recording.

    Attributes
    ----------
    flow : ndarray (N-1, H, W, 2) float32
        Optical flow between consecutive frames, px/s (u right, v down):
        ``(displacement[i+1] - displacement[i]) / (t[i+1] - t[i])``.
    q : ndarray (N-1, H, W) float32
        Poisson field of each frame interval, px²/s: ``flow = ∇q`` (analytic gradient).
    displacement : ndarray (N, H, W, 2) float32
        Apparent displacement of the background at each frame time, px (the frame at
        pixel x shows the background at x - displacement).
    t_us : ndarray (N,) int64
        Frame times, µs.
    contrast_threshold : float
        Nominal contrast threshold C of the events.
    thresholds : (ndarray, ndarray) or None
        Per-pixel ON and OFF thresholds (H, W) after mismatch.
    meta : dict
        Scene parameters (scene, fps, exposure, magnitude, speeds, seed...).
    """

    flow: np.ndarray
    q: np.ndarray
    displacement: np.ndarray
    t_us: np.ndarray
    contrast_threshold: float
    thresholds: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False)
    meta: dict = field(default_factory=dict)


@dataclass(eq=False)
class SchlierenSim:
    """Output of :func:`simulate_schlieren`: ``events``, ``frames``, ground truth ``gt``,
    the ``background`` and ``air`` (puff field) models used, and ``stats``."""

    events: EventArray
    frames: Frames
    gt: SchlierenGT
    background: Background = field(repr=False)
    air: PuffField = field(repr=False)
    stats: dict = field(default_factory=dict)


def simulate_schlieren(scene: str = "plume", sensor_size: tuple[int, int] = (720, 640),
                       duration_s: float = 0.1, fps: float = 120.0, seed: int = 0, *,
                       show_progress: bool = False, options: SchlierenOptions | None = None,
                       **keywords) -> SchlierenSim:
    """Simulate an event camera and a frame camera watching a BOS scene.

    Parameters
    ----------
    scene : str
        One of :data:`BOS_SCENES`: ``plume``, ``jet``, ``breath``, ``ice``.
    sensor_size : (int, int)
        ``(height, width)``; default the thesis' ROI 720x640 (Table 6.3).
    duration_s : float
        Length in seconds; frames at ``0, 1/fps, ...`` up to it (at least two frames), the
        events up to the last frame (``gt.meta["span_s"]``).
    fps : float
        Frame rate, Hz (120 in the thesis).
    seed : int
        Seeds the background, the air, threshold mismatch, event noise and shot noise.
    show_progress : bool
        Progress bar of the events on stderr (only when it is a terminal).
    options : SchlierenOptions, optional
        The air, background, frame and event cameras as one object; then no keyword
        below may be given.

    Other Parameters
    ----------------
    magnitude_px : float
        Largest inter-frame displacement ``|v| Δt`` over the pixels and frame intervals,
        px (the thesis' scenes: about 0.05-3 px).
    dot_density, dot_radius_px, dot_contrast
        Background: dots per px², mean dot radius (px), print contrast
        (:func:`make_background`).
    speed_px_s : float, optional
        The air's speed (plume rise speed; see :func:`make_field`).
    photons : float, optional
        Expected photons of a white pixel per frame: Poisson shot noise. None: noise-free
        frames. A few photons is the low-light case of Fig. 6.12.
    gain : float, optional
        Grey levels per photon (default ``(2**bit_depth - 1) / photons``: a white pixel is
        at full scale at any light level, as if the gain followed the light). A real
        camera at a fixed exposure keeps the gain of the bright scene: give it here.
    read_noise_e : float
        Frame camera's temporal dark noise, electrons rms (Gaussian, seeded), added to the
        photoelectrons before the gain; needs ``photons``. Default 0.
    bit_depth : int
        ADC bits of the frames, 1-16 (default 8): rounded, clipped to
        ``[0, 2**bit_depth - 1]``; uint8 up to 8 bits, uint16 above.
    normalize : bool
        Stretch each quantized frame to the full range (min to 0, max to full scale,
        :func:`normalize_range`), as the thesis did with its dark frames (§6.6.3,
        §6.6.6). Default False.
    exposure_s : float, optional
        Exposure time centred on each frame time (default half the frame period); the
        radiance is averaged over it (enough samples that the background moves at most
        ``max_step_px`` between them).
    contrast_threshold, mismatch, refractory_us, noise_rate
        Event sensor (:func:`evmotion.sim.simulator.simulate_log_function`).
    event_photons : float, optional
        Low light for the events: expected photons of a white pixel of the event sensor
        per ``event_tau_us``. The log intensity the sensor sees then carries shot noise,
        a Gaussian of standard deviation ``1 / sqrt(event_photons * I)`` drawn
        independently every ``event_tau_us`` (the photoreceptor's time constant) and
        linear in between, so dark dots and dim scenes fire noise events. None: no
        shot noise (bright light). Independent of the frames' ``photons`` (two sensors
        behind a beam splitter); e.g. ``photons * event_tau_us * 1e-6 / exposure_s``
        gives both the same illumination.
    event_tau_us : int
        Time constant of the event pixels' shot noise, µs.
    max_step_px : float
        Largest displacement change between full samples of the radiance for the events
        and within the exposure, px.
    max_step_fraction : float
        Bound on the log-intensity change between samples of an event pixel, as a
        fraction of the threshold.
    event_bandwidth : {"fixed", "intensity"}
        The event pixels' photoreceptor under ``event_photons``
        (:mod:`evmotion.sim.photoreceptor`): ``"fixed"`` (default), the worst case above,
        noise redrawn every ``event_tau_us`` at any light level; ``"intensity"``, the
        standard DVS model: a first-order low-pass of the log photocurrent whose time
        constant grows as the photon count falls (``event_tau_us`` in bright light, up to
        13.75 x in the dark), so its noise stays at about 0.079 in dim light while its
        response slows (Lichtsteiner et al. 2008; v2e, Hu et al. 2021). Needs
        ``event_photons``.

    Returns
    -------
    SchlierenSim

    Examples
    --------
    >>> sim = simulate_schlieren("jet", sensor_size=(40, 48), duration_s=1 / 60,
    ...                          magnitude_px=0.5)
    >>> dt = np.diff(sim.gt.t_us) * 1e-6
    >>> round(float((np.linalg.norm(sim.gt.flow, axis=-1).max(axis=(1, 2)) * dt).max()), 3)
    0.5
    """
    o = resolve_options(SchlierenOptions, options, keywords, "simulate_schlieren")
    if scene not in BOS_SCENES:
        raise ParameterError(f"unknown schlieren scene {scene!r}; choose one of "
                             f"{sorted(BOS_SCENES)}")
    h, w = parse_sensor_size(sensor_size, 8)
    seed = whole_number("seed", seed, lo=0)
    fps = check_number("fps", fps, 0.0, 1e5, lo_open=True, units="Hz")
    duration_s = check_number("duration_s", duration_s, 0.0, 1e4, lo_open=True, units="s")
    n_frames = int(math.floor(duration_s * fps + 1e-9)) + 1
    if n_frames < 2:
        raise ParameterError(f"duration_s={duration_s} holds fewer than two frames at "
                             f"fps={fps}; use duration_s >= {1 / fps:.6g}")
    exposure_s = 0.5 / fps if o.exposure_s is None else check_number(
        "exposure_s", o.exposure_s, 0.0, 1.0 / fps, units="s, at most the frame period")
    t_us = np.round(np.arange(n_frames) * 1e6 / fps).astype(np.int64)
    air, (disp, flow, q), vmax = _air_truth(scene, (h, w), duration_s, t_us * 1e-6,
                                            o.magnitude_px, o.speed_px_s, seed)
    reach = float(np.abs(disp).max())
    if not reach <= MAX_REACH_VIEWS * max(h, w):
        # the air's change between frames is held at magnitude_px: air far slower than
        # that change needs a displacement far beyond the view, and a background that wide
        # (3 TiB of dots at speed 1e-3 px/s; probe)
        raise ParameterError(f"speed_px_s={o.speed_px_s!r} with magnitude_px="
                             f"{o.magnitude_px!r}: the air's displacement reaches "
                             f"{reach:.3g} px, over {MAX_REACH_VIEWS} times the {w}x{h} px "
                             "view; give a higher speed or a lower magnitude")
    margin = reach * 1.5 + 6.0
    bg = make_background((h, w), density=o.dot_density, radius_px=o.dot_radius_px,
                         contrast=o.dot_contrast, margin_px=margin, seed=seed)
    radiance = _radiance_of(bg, air, (h, w))
    # frames: exposures sampled finely enough that the background moves at most
    # max_step_px between samples
    n_exp = 1 if exposure_s == 0 else int(min(64, max(1, math.ceil(
        vmax * exposure_s / o.max_step_px))))
    frames = _frames(radiance, t_us, exposure_s, n_exp, o, seed, scene)
    # events from the log of the same radiance, every frame time a sample time
    max_step_us = int(min(t_us[1] - t_us[0], max(1.0, 1e6 * o.max_step_px / max(vmax, 1e-9))))
    if o.event_photons is not None:
        max_step_us = min(max_step_us, o.event_tau_us)
    log_at = _log_radiance(radiance, o, seed, (h, w), max_step_us)
    res = simulate_log_function(log_at, (h, w), int(t_us[-1]), breaks_us=t_us,
                                max_step_us=max_step_us, seed=seed, show_progress=show_progress,
                                meta={"scene": f"schlieren-{scene}"},
                                options=o.event_options())
    # span_s: the frames' (and events') span, whole frame intervals of duration_s, which
    # had been the only length said (probe BA: 0.02 s asked, 0.0167 s made)
    meta = dict(scene=scene, description=BOS_SCENES[scene], sensor_size=[h, w], fps=fps,
                duration_s=duration_s, span_s=float(t_us[-1]) * 1e-6, seed=int(seed), magnitude_px=o.magnitude_px,
                exposure_s=exposure_s, exposure_samples=n_exp, photons=o.photons, gain=o.gain,
                read_noise_e=o.read_noise_e, bit_depth=o.bit_depth, normalize=o.normalize,
                dot_density=float(o.dot_density), dot_radius_px=float(o.dot_radius_px),
                dot_contrast=float(o.dot_contrast), n_dots=int(bg.x.size),
                field_gain_px2=air.gain, n_puffs=int(air.birth.size), max_flow_px_s=vmax,
                mismatch=float(o.mismatch), refractory_us=int(o.refractory_us),
                noise_rate=float(o.noise_rate), event_photons=o.event_photons,
                event_tau_us=o.event_tau_us, event_bandwidth=o.event_bandwidth,
                **_air_meta(scene, air, (h, w)))
    gt = SchlierenGT(flow=flow, q=q, displacement=disp, t_us=t_us,
                     contrast_threshold=float(o.contrast_threshold),
                     thresholds=res.thresholds, meta=meta)
    stats = dict(res.stats, max_step_us=max_step_us, n_frames=n_frames)
    if not len(res.events):
        # (probe OPT: contrast threshold 1e30, or a background of 1e-30 dots per px², wrote
        # a recording of no event, rc 0)
        warnings.warn(EvmotionWarning(
            f"simulate_schlieren('{scene}'): no event in {duration_s:g} s: the contrast "
            f"threshold {o.contrast_threshold:g} is above the background's log-intensity "
            f"changes (magnitude_px {o.magnitude_px:g}, {int(bg.x.size)} dots of contrast "
            f"{o.dot_contrast:g})"), stacklevel=2)
    return SchlierenSim(events=res.events, frames=frames, gt=gt, background=bg, air=air,
                        stats=stats)


def _air_truth(scene, shape, duration_s, t_s, magnitude_px, speed_px_s, seed):
    """The air of ``scene`` scaled so that the largest inter-frame displacement is
    ``magnitude_px``, and its exact ground truth at the frame times ``t_s`` (s):
    ``(displacement, flow, q)`` (float32, as :class:`SchlierenGT`) and the largest speed
    (px/s)."""
    h, w = shape
    n_frames = len(t_s)
    air = make_field(scene, (h, w), duration_s, speed_px_s=speed_px_s, seed=seed)
    # one pass over the frames at unit gain, float32 storage (a 1 s sequence at 720x640
    # holds about 1 GB of ground truth); differences in float64 from consecutive frames
    disp = np.empty((n_frames, h, w, 2), np.float32)
    flow = np.empty((n_frames - 1, h, w, 2), np.float32)
    q = np.empty((n_frames - 1, h, w), np.float32)
    prev = None
    steps, speeds = [], []  # per interval: largest displacement change (px) and |v| (px/s)
    for i, t in enumerate(t_s):
        phi_i, d_i = air.evaluate(float(t))
        disp[i] = d_i
        if prev is not None:
            dt = t_s[i] - t_s[i - 1]
            step = d_i - prev[1]
            steps.append(float(np.sqrt((step ** 2).sum(axis=-1)).max()))
            speeds.append(steps[-1] / dt)
            flow[i - 1] = step / dt
            q[i - 1] = (phi_i - prev[0]) / dt
        prev = (phi_i, d_i)
    peak = max(steps)
    if peak <= 0:
        raise ParameterError(f"scene {scene!r} has no air moving within {duration_s} s "
                             f"on a {h}x{w} sensor; use a longer duration")
    air.gain = magnitude_px / peak
    for arr in (disp, flow, q):
        arr *= np.float32(air.gain)
    return air, (disp, flow, q), max(speeds) * air.gain


def _radiance_of(bg: Background, air: PuffField, shape):
    """``radiance(t, pix=None)``: the background seen through the air at time ``t`` (s),
    (H, W), or at the row-major pixels ``pix`` (P,)."""
    h, w = shape
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    xs_f, ys_f = xs.ravel(), ys.ravel()
    still = bg.radiance(xs_f, ys_f)

    def radiance(t, pix=None):
        # the puffs are cut off: where no puff reaches, d is exactly 0 and the pixel sees
        # the still background (most of the sensor): only the others are rendered
        _, d = air.evaluate(t, pix)
        d = d.reshape(-1, 2)
        idx = np.arange(h * w) if pix is None else np.asarray(pix)
        out = still[idx]
        moved = np.nonzero((d[:, 0] != 0) | (d[:, 1] != 0))[0]
        out[moved] = bg.radiance(xs_f[idx[moved]] - d[moved, 0],
                                 ys_f[idx[moved]] - d[moved, 1])
        return out.reshape(h, w) if pix is None else out

    return radiance


def _frames(radiance, t_us, exposure_s: float, n_exp: int, o: SchlierenOptions, seed: int,
            scene: str) -> Frames:
    """The frame camera: the radiance averaged over ``n_exp`` samples of the exposure
    centred on each frame time, shot noise (``o.photons``), read noise, gain, ADC
    (``o.bit_depth`` bits, clipped) and the optional per-frame normalization."""
    offs = (np.arange(n_exp) + 0.5) / n_exp * exposure_s - 0.5 * exposure_s
    rng_shot = np.random.default_rng(np.random.SeedSequence([seed, 0x5407]))
    # its own stream: the shot noise is drawn the same with and without read noise
    rng_read = np.random.default_rng(np.random.SeedSequence([seed, 0x8EAD]))
    full = 2 ** o.bit_depth - 1
    images = []
    for t in t_us * 1e-6:
        rad = np.mean([radiance(float(t + off)) for off in offs], axis=0)
        if o.photons is None:
            val = full * rad
        else:
            electrons = rng_shot.poisson(o.photons * rad).astype(np.float64)
            if o.read_noise_e > 0:
                electrons += rng_read.normal(0.0, o.read_noise_e, electrons.shape)
            val = o.gain * electrons
        img = np.clip(np.rint(val), 0, full)
        if o.normalize:
            img = normalize_range(img, full)
        images.append(img.astype(np.uint8 if o.bit_depth <= 8 else np.uint16))
    stack = np.stack(images)
    if stack.max() == stack.min():
        # (probe API: photons=1e-30 or gain=1e-30 made black frames, gain=1e30 white ones,
        # unsaid; the frames show no background for BOS)
        warnings.warn(EvmotionWarning(
            f"simulate_schlieren('{scene}'): every frame is {int(stack.max())} everywhere "
            f"(0..{full}): no background shows (photons {o.photons}, gain {o.gain})"),
            stacklevel=3)
    return Frames(stack, t_us, source=f"simulate_schlieren({scene!r})",
                  bit_depth=o.bit_depth, exposure_start=t_us - round(exposure_s * 5e5),
                  exposure_end=t_us + round(exposure_s * 5e5))


def normalize_range(image: np.ndarray, full: int) -> np.ndarray:
    """Stretch a quantized frame to the full range: its minimum to 0, its maximum to
    ``full`` (grey levels), rounded back to integers, as a camera's 8-bit frames
    normalized after capture (thesis §6.6.3). A flat frame is returned unchanged: there
    is no range to stretch. The stretch cannot add levels: a frame holding ``k``
    distinct values still holds ``k`` after it.

    Examples
    --------
    >>> normalize_range(np.array([[2.0, 3.0, 4.0]]), 255).tolist()
    [[0.0, 128.0, 255.0]]
    """
    lo, hi = float(image.min()), float(image.max())
    if hi <= lo:
        return image
    return np.rint((image - lo) * (full / (hi - lo)))


def _log_radiance(radiance, o: SchlierenOptions, seed: int, shape, step_us: int):
    """``log_at(t_us, pix)`` of :func:`simulate_log_function`: the log of the radiance,
    through the event pixels' photoreceptor (:class:`Photoreceptor`, shot noise of the
    ``o.event_bandwidth`` model) when ``o.event_photons`` is given."""
    if o.event_photons is None:
        def log_at(t, pix):
            return np.log(radiance(t * 1e-6, pix))
        return log_at
    return Photoreceptor(radiance, shape, event_photons=o.event_photons,
                         tau_us=o.event_tau_us, bandwidth=o.event_bandwidth, seed=seed,
                         step_us=step_us)


def _air_meta(scene: str, air: PuffField, shape) -> dict:
    """The scene's own speeds, for the ground truth's metadata."""
    h, w = shape
    if scene == "plume":
        return {"rise_speed_px_s": float(-air.v0[0, 1]), "plume_axis_x_px": w / 2}
    if scene == "ice":
        return {"fall_acceleration_px_s2": float(air.acc[0, 1]),
                "fall_speed_bottom_px_s": float(math.sqrt(2 * air.acc[0, 1] * 1.1 * h))}
    return {"exit_speed_px_s": float(np.median(np.hypot(air.v0[:, 0], air.v0[:, 1])))}


# ---------------------------------------------------------------------------------------
# files


def write_schlieren(sim: SchlierenSim, out_dir: str | Path) -> Path:
    """Write a simulated recording as an ECD-style folder.

    ``events.txt`` (``t[s] x y p``), ``images.txt`` (``t[s] images/frame_XXXXXXXX.png``),
    ``images/`` (8-bit PNGs; 16-bit above 8 bits; the samples shifted to the top bits as
    cameras store 10- and 12-bit frames, so that the full scale stays white, and below 8
    bits likewise; frames a longer simulation left there are removed) and
    ``schlieren_gt.h5``: the flow in the project's flow
    layout (:func:`evmotion.io.flowfiles.read_flow_h5` reads it; windows = frame
    intervals) plus datasets ``q``, ``displacement``, ``frame_t``, ``thresholds_on``,
    ``thresholds_off`` and the metadata as JSON (attribute ``schlieren_meta``).

    Returns
    -------
    Path
        The ground-truth file.

    Examples
    --------
    >>> sim = simulate_schlieren("plume", sensor_size=(40, 48), duration_s=2 / 120, seed=0)
    >>> write_schlieren(sim, "plume_sim/").name
    'schlieren_gt.h5'
    """
    import shutil

    from evmotion.utils import staging_folder

    out = Path(out_dir)
    # built whole beside the folder, then published with the ground truth last: an
    # interrupted run had left new events and frames beside an earlier scene's ground
    # truth, or some frames, looking complete (probe BA)
    tmp = staging_folder(out)
    try:
        n_frames = _write_recording(sim, tmp)
        _write_gt(tmp / "schlieren_gt.h5", sim.gt)
        if not out.exists():
            os.replace(tmp, out)
            return out / "schlieren_gt.h5"
        _publish(tmp, out, n_frames)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return out / "schlieren_gt.h5"


def _write_recording(sim: SchlierenSim, out: Path) -> int:
    """events.txt, images/ and images.txt of ``sim`` into the new folder ``out``; returns
    the number of frames."""
    from evmotion.io import ecd

    (out / "images").mkdir()
    ecd.write(out / "events.txt", sim.events, header=False)  # the frames give the size
    lines = []
    shift = 8 * sim.frames.images.dtype.itemsize - sim.frames.bit_depth
    for i, (t, img) in enumerate(zip(sim.frames.t, sim.frames.images, strict=True)):
        name = f"images/frame_{i:08d}.png"
        write_png(out / name, img << shift if shift else img)
        lines.append(f"{t * 1e-6:.6f} {name}\n")
    (out / "images.txt").write_text("".join(lines))
    return len(lines)


def _publish(tmp: Path, out: Path, n_frames: int) -> None:
    """Move the recording built in ``tmp`` into the existing folder ``out``: first away
    the earlier scene's ground truth, events and frame list (an interruption then leaves
    no folder that pairs one scene's data with another's truth), then the frames (and
    away those a longer simulation left), the events, the list, the truth last."""
    for name in ("schlieren_gt.h5", "images.txt", "events.txt"):
        (out / name).unlink(missing_ok=True)
    (out / "images").mkdir(exist_ok=True)
    for png in sorted((tmp / "images").iterdir()):
        os.replace(png, out / "images" / png.name)
    for old in (out / "images").glob("frame_*.png"):
        stem = old.stem.removeprefix("frame_")
        if len(stem) == 8 and stem.isdigit() and int(stem) >= n_frames:
            old.unlink()
    for name in ("events.txt", "images.txt", "schlieren_gt.h5"):
        os.replace(tmp / name, out / name)


def _write_gt(path: Path, gt: SchlierenGT) -> Path:
    import h5py

    from evmotion.io.flowfiles import write_flow_group
    from evmotion.utils import atomic_path

    with atomic_path(path) as tmp, h5py.File(tmp, "w") as f:
        write_flow_group(f, gt.flow, gt.t_us[:-1], gt.t_us[1:])
        kw = {"compression": "gzip", "compression_opts": 1, "shuffle": True}
        f.create_dataset("q", data=gt.q, chunks=(1, *gt.q.shape[1:]), **kw)
        f.create_dataset("displacement", data=gt.displacement,
                         chunks=(1, *gt.displacement.shape[1:]), **kw)
        f.create_dataset("frame_t", data=gt.t_us)
        if gt.thresholds is not None:
            f.create_dataset("thresholds_on", data=gt.thresholds[0].astype(np.float32), **kw)
            f.create_dataset("thresholds_off", data=gt.thresholds[1].astype(np.float32), **kw)
        f.attrs["schlieren_format"] = GT_FORMAT
        f.attrs["contrast_threshold"] = gt.contrast_threshold
        f.attrs["schlieren_meta"] = json.dumps(gt.meta)
    return path


@guarded('schlieren ground truth')
def read_schlieren_gt(path: str | Path) -> SchlierenGT:
    """Read ``schlieren_gt.h5`` written by :func:`write_schlieren` (a folder holding it too).

    Examples
    --------
    >>> sim = simulate_schlieren("plume", sensor_size=(40, 48), duration_s=2 / 120, seed=0)
    >>> gt = read_schlieren_gt(write_schlieren(sim, "plume_sim/"))
    >>> gt.flow.shape                   # one flow per frame interval
    (2, 40, 48, 2)
    """
    with _gt_file(path) as (f, attrs):
        thr = None
        if "thresholds_on" in f and "thresholds_off" in f:
            thr = (f["thresholds_on"][()].astype(np.float64),
                   f["thresholds_off"][()].astype(np.float64))
        return SchlierenGT(flow=f["flow"][()], q=f["q"][()],
                           displacement=f["displacement"][()],
                           t_us=f["frame_t"][()].astype(np.int64),
                           contrast_threshold=float(attrs["contrast_threshold"]),
                           thresholds=thr, meta=json.loads(attrs["schlieren_meta"]))


@guarded('schlieren ground truth')
def read_schlieren_q(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """``(q, t_us)`` of ``schlieren_gt.h5`` (:func:`read_schlieren_gt`'s ``q`` and
    ``t_us``) without reading its flows and displacements, which are most of the file.

    Examples
    --------
    >>> sim = simulate_schlieren("plume", sensor_size=(40, 48), duration_s=2 / 120, seed=0)
    >>> q, t_us = read_schlieren_q(write_schlieren(sim, "plume_sim/"))
    >>> q.shape, t_us.shape             # one q per frame interval
    ((2, 40, 48), (3,))
    """
    with _gt_file(path) as (f, _):
        q, t = f["q"], f["frame_t"]
        # (a q of 3 windows for 4 frame intervals was an IndexError traceback; a frame_t
        # of another length scored other intervals, silently: probe AQ)
        if q.ndim != 3 or q.dtype.kind != "f":
            raise FormatError(path, f"'q' is {q.dtype} {q.shape}, expected float (N, H, W)")
        if t.ndim != 1 or t.dtype.kind not in "iu" or t.shape[0] != q.shape[0] + 1:
            raise FormatError(path, f"'frame_t' is {t.dtype} {t.shape}, expected "
                              f"{q.shape[0] + 1} integer times (one more than 'q' windows)")
        times = t[()].astype(np.int64)
        if np.any(np.diff(times) <= 0):
            raise FormatError(path, "'frame_t' does not increase")
        return q[()], times


def is_schlieren_gt(path: str | Path) -> bool:
    """Whether ``path`` (or the ``schlieren_gt.h5`` in that folder) is schlieren ground
    truth: an HDF5 file whose ``schlieren_format`` attribute says so.

    Examples
    --------
    >>> sim = simulate_schlieren("plume", sensor_size=(40, 48), duration_s=1 / 120, seed=0)
    >>> is_schlieren_gt(write_schlieren(sim, "plume_sim/")), is_schlieren_gt("plume_sim/")
    (True, True)
    >>> is_schlieren_gt("plume_sim/events.txt")
    False
    """
    path = _gt_path(path)
    if not path.is_file():
        return False
    try:
        with open_h5(path) as f:
            return read_attrs(path, f, ("schlieren_format",)).get("schlieren_format") == GT_FORMAT
    except (FormatError, OSError):
        return False


def _gt_path(path: str | Path) -> Path:
    path = Path(path)
    return path / "schlieren_gt.h5" if path.is_dir() else path


@contextlib.contextmanager
def _gt_file(path: str | Path):
    """The open ground-truth file and its attributes, checked to be schlieren ground truth
    with all its datasets (a folder holding ``schlieren_gt.h5`` too)."""
    path = _gt_path(path)
    with open_h5(path) as f:
        attrs = read_attrs(path, f)
        if attrs.get("schlieren_format") != GT_FORMAT:
            raise FormatError(path, "not schlieren ground truth (attribute "
                              f"schlieren_format={attrs.get('schlieren_format')!r})")
        for name in ("flow", "q", "displacement", "frame_t"):
            if name not in f:
                raise FormatError(path, f"schlieren ground truth lacks dataset '{name}'")
        yield f, attrs
